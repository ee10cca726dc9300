"""Slow, obviously correct references of :mod:`proctex.texture.uv` (loops over points, pixels or
texels), which the tests compare the shipped fast versions with; not used by the library."""

from __future__ import annotations

import numpy as np

from proctex.texture.uv import _check_texel_args


def texel_map_reference(vertices: np.ndarray, faces: np.ndarray, corner_uv: np.ndarray, size: int) -> dict[tuple[int, int], tuple[int, np.ndarray]]:
    """Slow reference: for every texel centre and every face, barycentric inside test in UV space.

    Returns ``{(row, col): (face, bary)}`` for texels whose centre lies inside a face (the highest
    face index wins, as in :func:`proctex.geometry.raster.rasterise`). Does not add the lonely-face texels.
    """
    v, f, uv = _check_texel_args(vertices, faces, corner_uv, size, size)
    out: dict[tuple[int, int], tuple[int, np.ndarray]] = {}
    for i in range(size):
        for j in range(size):
            p = np.array([(j + 0.5) / size, 1.0 - (i + 0.5) / size])
            for k in range(len(f)):
                a, b, c = uv[k]
                m = np.array([[b[0] - a[0], c[0] - a[0]], [b[1] - a[1], c[1] - a[1]]])
                if abs(np.linalg.det(m)) < 1e-14 / size**2:
                    continue
                l1, l2 = np.linalg.solve(m, p - a)
                lam = np.array([1 - l1 - l2, l1, l2])
                if (lam >= -1e-9).all():
                    out[(i, j)] = (k, lam)
    return out
