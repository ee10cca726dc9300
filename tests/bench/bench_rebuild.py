"""Benchmark: the pairs, train and evaluate stages of an already built family run again with
today's code and defaults (its samples, template and painting kept), stage by stage, against the
figures stored with the family.

    python tests/bench/bench_rebuild.py out/fidelity_real2/chair.blend --work out/bench/rebuild_chair

For families sampled by a tool that is slow or absent here (the Blender ones): sampling and painting
are not what changed, and a stored family keeps them.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))

from tests.bench.harness import copy_family, write_json  # noqa: E402

STAGES = ("pairs", "train", "evaluate")


def figures(store) -> dict:
    """The stored evaluation's corrnet figures and what serves each group."""
    m = store.read_json("metrics.json") if store.exists("metrics.json") else {"methods": {}}
    c = m["methods"].get("corrnet", {})
    groups = store.read_json("family.json")["stages"].get("train", {}).get("groups", {})
    return {
        "tracked_point_variance": c.get("tracked_point_variance"),
        "pgt_mean": (c.get("pgt_error") or {}).get("mean"),
        "ssim": c.get("ssim"),
        "psnr": c.get("psnr"),
        "coverage": c.get("coverage"),
        "serving": {g: (r.get("serving") or {}).get("serve") for g, r in groups.items()},
        "iterations": {g: r.get("iterations") for g, r in groups.items()},
    }


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("family")
    ap.add_argument("--work", required=True)
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--out")
    args = ap.parse_args(argv)

    from proctex.build.pipeline import build
    from proctex.build.plan import local_executor
    from proctex.store.layout import FamilyStore

    before = figures(FamilyStore(args.family))
    store, config = copy_family(args.family, args.work, drop=("correspondences", "pairs.parquet", "models", "metrics.json", "train_runs"), stages=STAGES)
    seconds = {}
    for stage in STAGES:
        t = time.perf_counter()
        build(store, config, stages=(stage,), log=lambda *_: None, executor=local_executor(args.workers))
        seconds[stage] = round(time.perf_counter() - t, 2)
    report = {"benchmark": "rebuild", "family": args.family, "seconds": seconds, "before": before, "after": figures(store)}
    print(json.dumps(report, indent=1))
    if args.out:
        write_json(args.out, report)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
