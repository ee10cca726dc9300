"""Slow, obviously correct references of :mod:`proctex.geometry.raster` (loops over points, pixels or
texels), which the tests compare the shipped fast versions with; not used by the library."""

from __future__ import annotations

import numpy as np

from proctex.geometry.raster import _check


def rasterise_reference(xy: np.ndarray, height: int, width: int, depth: np.ndarray | None = None, eps: float = 1e-9) -> tuple[np.ndarray, np.ndarray]:
    """Slow, obviously correct :func:`rasterise`: every pixel against every triangle."""
    xy, depth = _check(xy, height, width, depth)
    face = np.full((height, width), -1, dtype=np.int64)
    bary = np.zeros((height, width, 3))
    best = np.full((height, width), np.inf)
    for f, (a, b, c) in enumerate(xy):
        det = (b[0] - a[0]) * (c[1] - a[1]) - (c[0] - a[0]) * (b[1] - a[1])
        if abs(det) < 1e-14:
            continue
        for i in range(height):
            for j in range(width):
                p = np.array([j + 0.5, i + 0.5])
                l1 = ((p[0] - a[0]) * (c[1] - a[1]) - (c[0] - a[0]) * (p[1] - a[1])) / det
                l2 = ((b[0] - a[0]) * (p[1] - a[1]) - (p[0] - a[0]) * (b[1] - a[1])) / det
                lam = np.array([1 - l1 - l2, l1, l2])
                if (lam < -eps).any():
                    continue
                z = float(lam @ depth[f]) if depth is not None else 0.0
                if depth is not None and z >= best[i, j]:
                    continue
                best[i, j] = z
                face[i, j] = f
                bary[i, j] = lam
    return face, bary
