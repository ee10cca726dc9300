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
    import proctex.geometry.surface as surface

    results = {f"build index, {args.model} ({len(shape.faces)} faces)": timeit(lambda: SurfaceIndex(shape.vertices, shape.faces), repeats=args.repeats)}
    # the same queries by each exact backend, in this run: the compiled tree, libigl's AABB tree, the proxy search
    faces = {}
    for name, bvh, backend in (("the compiled tree", None, "aabb"), ("libigl's AABB tree", [None], "aabb"), ("the proxy search", None, "proxies")):
        saved = list(surface._BVH)
        if bvh is not None:
            surface._BVH[:] = bvh
        try:
            index = SurfaceIndex(shape.vertices, shape.faces, backend=backend)
            index.query(query[:10])  # builds the tree (or the proxies' KD-tree) and compiles
            results[f"project {args.points} points, {name}"] = timeit(lambda: index.query(query), repeats=args.repeats)
            faces[name] = index.query(query).distance
        finally:
            surface._BVH[:] = saved
    distances = list(faces.values())
    if not all(np.allclose(d, distances[0], rtol=0, atol=1e-12) for d in distances):
        raise SystemExit("the backends disagree on the distances")
    return report("projection", vars(args), results, args.out)


def parser() -> argparse.ArgumentParser:
    ap = harness.parser(__doc__, repeats=7)
    ap.add_argument("--model", default="sofa")
    ap.add_argument("--points", type=int, default=10000)
    return ap


if __name__ == "__main__":
    run(parser().parse_args())
    sys.exit(0)
