"""Real-time transfer of a built family, in process: random parameter settings of the family's own
model (built-in or Blender), timed through ``FamilyService.transfer`` (assign, map, UVs, new parts,
GLB); the shapes are generated before timing.

    .venv/bin/python tests/bench/bench_family_transfer.py out/fam/chair [--settings 6] [--repeats 2] [--seed 123]

Prints the median and range over settings and repeats, the median of each stage, and how the parts
of the shapes were assigned (slot, extra, new).
"""

from __future__ import annotations

import argparse
import collections
import statistics
import sys
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parents[1]))
sys.path.insert(0, str(HERE))

from harness import write_json  # noqa: E402


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("family", help="a built family folder (procedural or Blender source)")
    ap.add_argument("--settings", type=int, default=6)
    ap.add_argument("--repeats", type=int, default=2)
    ap.add_argument("--seed", type=int, default=123)
    ap.add_argument("--out", help="write the figures as JSON here")
    args = ap.parse_args(argv)

    from proctex.serve.service import FamilyService
    from proctex.store.layout import FamilyStore

    svc = FamilyService(FamilyStore(args.family))
    if svc.model is None:
        raise SystemExit(f"{args.family} comes from a folder of meshes: this benchmark samples the family's model")
    settings = [svc.model.space.settle(p) for p in svc.model.space.sample(args.settings, seed=args.seed)]
    shapes = [svc.check_shape(svc.model.generate(p)) for p in settings]
    svc.transfer(shapes[0])  # warm up (imports, kernels)
    totals, stages, how = [], collections.defaultdict(list), collections.Counter()
    for k in range(args.repeats):
        for shape in shapes:
            t0 = time.perf_counter()
            _, summary = svc.transfer(shape)
            totals.append(time.perf_counter() - t0)
            for name, v in (summary.get("timings") or {}).items():
                stages[name].append(v)
            if k == 0:
                how.update(p["how"] for p in summary["parts"])
    result = {
        "family": args.family,
        "settings": args.settings,
        "repeats": args.repeats,
        "median_ms": 1000 * statistics.median(totals),
        "min_ms": 1000 * min(totals),
        "max_ms": 1000 * max(totals),
        "stages_median_ms": {k: 1000 * statistics.median(v) for k, v in stages.items()},
        "parts": dict(how),
        "parts_per_shape": sum(how.values()) / len(shapes),
    }
    print(f"{args.family}: transfer median {result['median_ms']:.0f} ms ({result['min_ms']:.0f}-{result['max_ms']:.0f}) over {args.settings} settings x {args.repeats}; parts {dict(how)}")
    print("stages (median ms): " + ", ".join(f"{k} {v:.1f}" for k, v in result["stages_median_ms"].items()))
    if args.out:
        write_json(args.out, result)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
