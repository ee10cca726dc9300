"""Benchmark: SurfacePainter.paint throughput for representative prompts.

Paints ``--points`` uniform points on a sphere of radius 0.9 (normals radial) for each prompt,
``--repeats`` times, and reports the median seconds and millions of points per second. The budget
(the sofa template: ~3 M texels in < 10 s with rasterisation) is 1 M points in <= 1.5 s per prompt.

    python tests/bench/bench_surface_painter.py --points 1000000 --repeats 3 --out out/bench_surface_painter.json
"""

from __future__ import annotations

import argparse
import json
import platform
import statistics
import sys
import time
from pathlib import Path

PROMPTS = [
    "",  # default material
    "red velvet",
    "dark walnut",
    "white marble",
    "speckled pale pink granite",
    "brick",
    "blue and white striped ceramic",
    "gold",
    "rusty metal",
    "denim",
    "worn green leather",
    "red tartan",
    "yellow polka dot fabric",
    "floral cotton",
    "patchwork quilt",
    "orange peel",
    "mushroom",
    "worn scratched dirty faded floral linen",
    "old scratched patchwork leather",
    "weathered speckled marble",
]
BUDGET_S = 1.5


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--points", type=int, default=1_000_000)
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--prompts", default="", help="';'-separated prompts (default: a representative set)")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--out", default="", help="write the results as JSON here")
    args = ap.parse_args(argv)

    import numpy as np

    from proctex.texture.painters import SurfacePainter

    prompts = [p.strip() for p in args.prompts.split(";")] if args.prompts else PROMPTS
    rng = np.random.default_rng(args.seed)
    normals = rng.normal(size=(args.points, 3))
    normals /= np.linalg.norm(normals, axis=1, keepdims=True)
    points = 0.9 * normals

    rows = []
    print(f"{'prompt':42s} {'median s':>9s} {'min s':>7s} {'Mpts/s':>7s}  spec")
    for prompt in prompts:
        painter = SurfacePainter(prompt, seed=args.seed)
        painter.paint(points[:1000], normals[:1000])  # warm-up (lazy imports, caches)
        times = []
        for _ in range(args.repeats):
            t0 = time.perf_counter()
            painter.paint(points, normals)
            times.append(time.perf_counter() - t0)
        med = statistics.median(times)
        spec = painter.spec
        desc = f"{spec.variant}/{spec.material}" + (f" + {spec.pattern}" if spec.pattern else "") + (f" + wear {spec.wear:.2f}" if spec.wear else "")
        rows.append(
            {"prompt": prompt, "median_s": med, "min_s": min(times), "times_s": times, "mpts_per_s": args.points / med / 1e6, "spec": desc, "within_budget": med * 1e6 / args.points <= BUDGET_S}
        )
        print(f"{prompt!r:42s} {med:9.3f} {min(times):7.3f} {args.points / med / 1e6:7.2f}  {desc}", flush=True)

    slowest = max(rows, key=lambda r: r["median_s"])
    per_million = slowest["median_s"] * 1e6 / args.points
    print(f"slowest: {slowest['prompt']!r} {per_million:.3f} s per 1M points (budget {BUDGET_S} s)")
    if args.out:
        out = Path(args.out)
        out.parent.mkdir(parents=True, exist_ok=True)
        out.write_text(
            json.dumps({"points": args.points, "repeats": args.repeats, "budget_s_per_million": BUDGET_S, "machine": platform.platform(), "python": sys.version.split()[0], "rows": rows}, indent=2)
        )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
