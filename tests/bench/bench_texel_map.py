"""Texel <-> surface maps (rasterising the UV atlas): the painter's and the baker's first step.

.venv/bin/python tests/bench/bench_texel_map.py [--sizes 512,1024] [--out out/bench/texel_map.json]
"""

from __future__ import annotations

import argparse
import sys

from fixtures import template
import harness
from harness import report, timeit
from proctex.texture.uv import texel_map


def run(args) -> dict:
    shape, grouping, tex, _ = template(args.model, 64)
    results = {}
    for size in (int(x) for x in args.sizes.split(",")):
        results[f"{args.model} template, {len(shape.faces)} faces, {size}²"] = timeit(lambda: texel_map(shape.vertices, shape.faces, tex.uv.corner_uv, size, size), repeats=args.repeats)
    return report("texel_map", vars(args), results, args.out)


def parser() -> argparse.ArgumentParser:
    ap = harness.parser(__doc__, repeats=7)
    ap.add_argument("--model", default="chair")
    ap.add_argument("--sizes", default="512,1024")
    return ap


if __name__ == "__main__":
    run(parser().parse_args())
    sys.exit(0)
