"""Benchmark: ``proctex generate`` throughput, variants per second, in one process and on Ray Data with
1 and 2 CPUs, and the cost of one variant (making the shape, texturing it, writing it).

For each family, each way of running writes N fresh variants into its own folder. The rate is given
twice: over the whole run (Ray's start and the actors' family loading included) and over the steady
part (between the 10th and 90th percentile of the rows' finish times, the pace a 10,000-row job sees). The
per-variant costs are the medians of the manifest's columns from the in-process run.

    .venv/bin/python tests/bench/bench_generate.py --family out/bench/gen_families/sofa --family out/bench/gen_families/chair --n 60
"""

from __future__ import annotations

import argparse
import json
import shutil
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import pyarrow.parquet as pq

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))
sys.path.insert(0, str(HERE.parents[1]))

from harness import machine, versions, write_json  # noqa: E402


def steady_rate(rows: list[dict]) -> float:
    """Rows per second between the 10th and the 90th percentile of the rows' finish times: the pace
    of a long run, without the start (Ray, actors loading the family) or the tail."""
    t = np.sort([r["finished"] for r in rows])
    lo, hi = int(0.1 * (len(t) - 1)), int(0.9 * (len(t) - 1))
    return (hi - lo) / max(t[hi] - t[lo], 1e-9)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--family", action="append", required=True, help="a built family (repeat for several)")
    ap.add_argument("--n", type=int, default=60)
    ap.add_argument("--batch-size", type=int, default=4)
    ap.add_argument("--out", default="out/bench/generate.json")
    args = ap.parse_args(argv)

    import ray

    from proctex.generate import GenerateSettings, run_in_process
    from workflows.generate import generate_on_ray

    work = Path(tempfile.mkdtemp(prefix="bench-generate-"))
    families = {}
    for family in args.family:
        name = Path(family).name
        runs = {}
        for way in ("process", "ray1", "ray2"):
            out = work / f"{name}-{way}"
            settings = GenerateSettings(family, str(out), n=args.n, seed=0, batch_size=args.batch_size)
            t0 = time.perf_counter()
            if way == "process":
                summary = run_in_process(settings, log=lambda *_: None, quiet=True)
            else:
                ray.init(address="local", num_cpus=int(way[-1]), include_dashboard=False, log_to_driver=False)
                try:
                    summary = generate_on_ray(settings, log=lambda *_: None, quiet=True)
                finally:
                    ray.shutdown()
            total = time.perf_counter() - t0
            assert summary["written"] == args.n, summary
            rows = pq.read_table(out / "manifest.parquet").to_pylist()
            steady = steady_rate(rows)
            runs[way] = {"seconds": round(total, 2), "rate": round(args.n / total, 2), "steady_rate": round(steady, 2), "actors": summary.get("actors")}
            print(f"{name} {way}: {args.n} variants in {total:.1f}s, {args.n / total:.2f}/s overall, {steady:.2f}/s steady", flush=True)
            if way == "process":
                runs["cost"] = {k: round(float(np.median([r[k] for r in rows])) * 1000, 2) for k in ("generate_seconds", "transfer_seconds", "write_seconds")}
                runs["cost"]["bytes"] = int(np.median([r["bytes"] for r in rows]))
                runs["cost"]["faces"] = int(np.median([r["faces"] for r in rows]))
            shutil.rmtree(out, ignore_errors=True)
        runs["speedup_steady_1_to_2"] = round(runs["ray2"]["steady_rate"] / runs["ray1"]["steady_rate"], 2)
        runs["speedup_overall_1_to_2"] = round(runs["ray2"]["rate"] / runs["ray1"]["rate"], 2)
        print(f"{name}: 1 -> 2 CPUs {runs['speedup_steady_1_to_2']}x steady, {runs['speedup_overall_1_to_2']}x overall; cost (ms) {runs['cost']}", flush=True)
        families[name] = runs
    write_json(
        args.out, {"benchmark": "generate", "n": args.n, "batch_size": args.batch_size, "families": families, "machine": machine(), "versions": versions(), "time": time.strftime("%Y-%m-%d %H:%M:%S")}
    )
    print(json.dumps(families, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
