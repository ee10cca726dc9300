"""The benchmark suite (``make bench``): every hot operation, one JSON report each under ``--out``
(median and spread over repeats, parameters, machine, versions) and a Markdown summary table
(``summary.md``, also printed).

    .venv/bin/python tests/bench/run_all.py [--out out/bench] [--quick] [--skip serve]

Operations: MVC weights, one cage iteration, point-to-surface projection, texel maps, ProcCorrNet
forward, baking, the whole in-process transfer, and a Serve request over HTTP (a tiny mug family is
built for it under ``--out``).
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))

import bench_bake  # noqa: E402
import bench_cage_iteration  # noqa: E402
import bench_forward  # noqa: E402
import bench_mvc  # noqa: E402
import bench_projection  # noqa: E402
import bench_texel_map  # noqa: E402
from harness import machine, report, summary_table, versions  # noqa: E402

SUITE = {
    "mvc": bench_mvc,
    "cage_iteration": bench_cage_iteration,
    "projection": bench_projection,
    "texel_map": bench_texel_map,
    "forward": bench_forward,
    "bake_and_transfer": bench_bake,
}


def serve_report(out: Path, requests: int) -> dict:
    """A Serve request over HTTP: a tiny mug family built here, then ``bench_serve.py`` on it."""
    import bench_serve

    from proctex.build.pipeline import build
    from proctex.store.config import BuildConfig
    from proctex.store.layout import FamilyStore

    root = out / "families"
    cfg = BuildConfig.from_dict(
        dict(model="mug", n_train=3, n_test=0, corr_points=300, cage_iterations=40, texture_size=512, prompt="blue ceramic", train={"iterations": 60, "eval_every": 20})
    ).validate()
    build(FamilyStore(root / "mug"), cfg, stages=("sample", "template", "paint", "pairs", "train"), log=lambda *_: None)
    raw = out / "serve_raw.json"
    bench_serve.main(["--root", str(root), "--family", "mug", "--requests", str(requests), "--concurrency", "1,4", "--out", str(raw)])
    data = json.loads(raw.read_text())
    results = {}
    for lv in data["levels"]:
        q = {k: lv[f"{k}_ms"] / 1000 for k in ("p10", "p25", "p50", "p75", "p90")}
        results[f"POST transfer (JSON params -> GLB), {lv['concurrency']} client(s), {lv['rps']:.1f} req/s"] = {
            "median": q["p50"],
            "p10": q["p10"],
            "p90": q["p90"],
            "min": q["p10"],
            "max": lv["p99_ms"] / 1000,
            "mean": lv["mean_ms"] / 1000,
            "spread": (q["p75"] - q["p25"]) / q["p50"],
            "repeats": lv["requests"],
        }
    return report("serve_request", {"family": "mug", "requests": requests, "replicas": 1}, results, str(out / "serve_request.json"))


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", default="out/bench")
    ap.add_argument("--quick", action="store_true", help="fewer repeats (a smoke run)")
    ap.add_argument("--skip", default="", help="comma-separated benchmarks to leave out (e.g. serve)")
    args = ap.parse_args(argv)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    skip = {s.strip() for s in args.skip.split(",") if s.strip()}
    reports = []
    t0 = time.perf_counter()
    for name, mod in SUITE.items():
        if name in skip:
            continue
        bargs = mod.parser().parse_args(["--out", str(out / f"{name}.json")] + (["--repeats", "2"] if args.quick else []))
        print(f"== {name}", flush=True)
        reports.append(mod.run(bargs))
    if "serve" not in skip:
        print("== serve_request", flush=True)
        reports.append(serve_report(out, 20 if args.quick else 100))
    table = summary_table(reports)
    head = f"Benchmarks, {time.strftime('%Y-%m-%d %H:%M')}, {machine()['cpus']} CPUs ({machine()['cpu']}), torch {versions().get('torch')}\n\n"
    (out / "summary.md").write_text(head + table + "\n")
    print("\n" + head + table)
    print(f"\n{len(reports)} benchmarks in {time.perf_counter() - t0:.0f}s; reports in {out}/")
    return 0


if __name__ == "__main__":
    sys.exit(main())
