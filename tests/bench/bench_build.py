"""Benchmark: a whole family build, stage by stage, in process or on a local Ray, with its figures.

Builds a fresh store for each ``--runs`` entry (``process``: :func:`proctex.build.pipeline.build`
with ``--workers`` worker processes; ``ray``: :func:`workflows.build.build_on_ray` on a private local
Ray of ``--cpus`` CPUs, as many Ray Train workers) and prints the wall seconds of every stage, the
total and what the evaluate stage measured on the test shapes (ground-truth and pseudo-ground-truth
mean error, tracked-point variance), so a faster build shows it is no worse. ``--repeats`` builds
each run that many times and reports the median total.

    .venv/bin/python tests/bench/bench_build.py --preset demo --runs process,ray --out out/bench/build_demo.json
    .venv/bin/python tests/bench/bench_build.py --folder ../shared/data/procedural_sofa --runs process,ray --out out/bench/build_sofa.json
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import shutil
import statistics
import sys
import time
from pathlib import Path
from typing import Any


def figures(state: dict[str, Any]) -> dict[str, Any]:
    """The evaluate stage's measurements from a build's state (empty without the stage)."""
    ev = state.get("stages", {}).get("evaluate", {})
    if not ev:
        return {}
    return {"gt_mean": (ev.get("gt_error") or {}).get("mean"), "pgt_mean": (ev.get("pgt_error") or {}).get("mean"),
            "tracked_point_variance": ev.get("tracked_point_variance")}


def build_once(kind: str, root: Path, config: Any, workers: int, cpus: int) -> dict[str, Any]:
    shutil.rmtree(root, ignore_errors=True)
    t0 = time.perf_counter()
    if kind == "process":
        from proctex.build.pipeline import build
        from proctex.build.plan import local_executor
        from proctex.store.layout import FamilyStore

        state = build(FamilyStore(root), config, log=lambda *_: None, executor=local_executor(workers))
    elif kind == "ray":
        import ray

        from workflows.build import build_on_ray

        ray.init(address="local", num_cpus=cpus, include_dashboard=False, log_to_driver=False)
        try:
            state = build_on_ray(str(root), config, train_workers=cpus, quiet=True, log=lambda *_: None)
        finally:
            ray.shutdown()
    else:
        raise ValueError(f"unknown run {kind!r}: process or ray")
    return {"wall_seconds": state["wall_seconds"], "total_seconds": round(time.perf_counter() - t0, 2), **figures(state)}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    src = ap.add_mutually_exclusive_group(required=True)
    src.add_argument("--preset", help="a named build preset (demo)")
    src.add_argument("--folder", help="a folder of exports (the real sofa)")
    ap.add_argument("--runs", default="process", help="comma-separated: process, ray")
    ap.add_argument("--workers", type=int, default=2, help="in-process worker processes")
    ap.add_argument("--cpus", type=int, default=2, help="CPUs of the local Ray")
    ap.add_argument("--repeats", type=int, default=1)
    ap.add_argument("--set", action="append", default=[], help="a config override as JSON, e.g. '{\"train\": {\"autocast\": \"none\"}}'")
    ap.add_argument("--work", default="out/bench/build")
    ap.add_argument("--out", default="")
    args = ap.parse_args(argv)

    from proctex.store.config import BuildConfig, merge, sections

    data: dict[str, Any] = {} if args.preset else {"source": {"folder": os.path.abspath(args.folder)}}
    for extra in args.set:
        data = merge(data, sections(json.loads(extra)))
    config = BuildConfig.from_dict(data, preset=args.preset)
    report: dict[str, Any] = {"benchmark": "build", "preset": args.preset, "config": data, "runs": {},
                              "machine": {"python": platform.python_version(), "cpus": os.cpu_count()}, "time": time.strftime("%Y-%m-%d %H:%M:%S")}
    for kind in args.runs.split(","):
        builds = []
        for r in range(args.repeats):
            out = build_once(kind, Path(args.work) / f"{kind}{r}", config, args.workers, args.cpus)
            builds.append(out)
            stages = ", ".join(f"{k} {v:.1f}s" for k, v in out["wall_seconds"].items())
            figs = ", ".join(f"{k} {v:.5g}" for k, v in out.items() if k not in ("wall_seconds", "total_seconds") and v is not None)
            print(f"{kind} #{r + 1}: {stages}; total {out['total_seconds']:.1f}s; {figs}", flush=True)
        report["runs"][kind] = {"builds": builds, "median_total_seconds": statistics.median(b["total_seconds"] for b in builds)}
    if "process" in report["runs"] and "ray" in report["runs"]:
        ratio = report["runs"]["ray"]["median_total_seconds"] / report["runs"]["process"]["median_total_seconds"]
        report["ray_over_process"] = round(ratio, 3)
        print(f"ray / process: {ratio:.2f}")
    if args.out:
        from harness import write_json

        write_json(args.out, report)
    return 0


if __name__ == "__main__":
    sys.exit(main())
