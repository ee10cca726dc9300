"""Real-time transfer of a built family, in process: random parameter settings of the family's own
model (built-in or Blender), or with ``--meshes`` the meshes of a folder (uploads), timed through
``FamilyService.transfer`` (segment, assign, map, UVs, new parts, GLB); the shapes are generated or
read before timing.

    .venv/bin/python tests/bench/bench_family_transfer.py out/fam/chair [--settings 6] [--repeats 2] [--seed 123]
    .venv/bin/python tests/bench/bench_family_transfer.py out/fam/sofa --meshes $PROCTEX_DATA/procedural_sofa/inference --repeats 13
    .venv/bin/python tests/bench/bench_family_transfer.py out/fam/sofa --code ../before ...   # another checkout's code

Prints the median, the 10th-90th percentiles and range over shapes and repeats, the median of each
stage, and how the parts of the shapes were assigned (slot, extra, new).
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
    ap.add_argument("--meshes", help="a folder of mesh files to transfer (a folder family: uploads) instead of the model's settings")
    ap.add_argument("--code", help="import proctex from this checkout (a git worktree of older code) instead of this one")
    ap.add_argument("--out", help="write the figures as JSON here")
    args = ap.parse_args(argv)
    if args.code:
        sys.path.insert(0, str(Path(args.code).resolve()))

    from proctex.geometry.meshio import load_mesh_bytes
    from proctex.serve.service import FamilyService
    from proctex.store.layout import FamilyStore

    svc = FamilyService(FamilyStore(args.family))
    if args.meshes:
        files = sorted(p for p in Path(args.meshes).iterdir() if p.suffix.lower() in (".obj", ".ply", ".glb", ".stl", ".off"))
        if not files:
            raise SystemExit(f"no mesh files in {args.meshes}")
        shapes = [svc.check_shape(load_mesh_bytes(p.read_bytes(), "upload" + p.suffix.lower(), groups=True)[0]) for p in files]
    elif svc.model is None:
        raise SystemExit(f"{args.family} comes from a folder of meshes: give --meshes")
    else:
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
    import numpy as np

    result = {
        "family": args.family,
        "shapes": len(shapes),
        "repeats": args.repeats,
        "transfers": len(totals),
        "median_ms": 1000 * statistics.median(totals),
        "p10_ms": 1000 * float(np.percentile(totals, 10)),
        "p90_ms": 1000 * float(np.percentile(totals, 90)),
        "min_ms": 1000 * min(totals),
        "max_ms": 1000 * max(totals),
        "stages_median_ms": {k: 1000 * statistics.median(v) for k, v in stages.items()},
        "parts": dict(how),
        "parts_per_shape": sum(how.values()) / len(shapes),
    }
    print(
        f"{args.family}: transfer median {result['median_ms']:.1f} ms (p10-p90 {result['p10_ms']:.1f}-{result['p90_ms']:.1f}, range {result['min_ms']:.0f}-{result['max_ms']:.0f})"
        f" over {len(shapes)} shapes x {args.repeats}; parts {dict(how)}"
    )
    print("stages (median ms): " + ", ".join(f"{k} {v:.1f}" for k, v in result["stages_median_ms"].items()))
    if args.out:
        write_json(args.out, result)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
