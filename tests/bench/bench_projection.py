"""Exact point-to-surface projection (``SurfaceIndex``): building the index of a mesh and
projecting near-surface points onto it (correspondence projection, ICP, metrics).

    .venv/bin/python tests/bench/bench_projection.py [--points 10000] [--out out/bench/projection.json]
"""

from __future__ import annotations

import argparse
import sys

import numpy as np

import harness
from harness import report, timeit
from proctex.geometry.surface import SurfaceIndex, sample_surface
from proctex.models import get_model


def run(args) -> dict:
    shape = get_model(args.model).generate()
    pts, _, _ = sample_surface(shape.vertices, shape.faces, args.points, seed=0)
    scale = float(np.ptp(shape.vertices, axis=0).max())
    query = pts + np.random.default_rng(1).normal(0, 0.01 * scale, pts.shape)  # near the surface
    index = SurfaceIndex(shape.vertices, shape.faces)
    results = {
        f"build index, {args.model} ({len(shape.faces)} faces)": timeit(lambda: SurfaceIndex(shape.vertices, shape.faces), repeats=args.repeats),
        f"project {args.points} points": timeit(lambda: index.query(query), repeats=args.repeats),
    }
    return report("projection", vars(args), results, args.out)


def parser() -> argparse.ArgumentParser:
    ap = harness.parser(__doc__, repeats=7)
    ap.add_argument("--model", default="sofa")
    ap.add_argument("--points", type=int, default=10000)
    return ap


if __name__ == "__main__":
    run(parser().parse_args())
    sys.exit(0)
