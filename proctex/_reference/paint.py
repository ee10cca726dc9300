"""Slow, obviously correct references of :mod:`proctex.texture.paint` (loops over points, pixels or
texels), which the tests compare the shipped fast versions with; not used by the library."""

from __future__ import annotations

import numpy as np

from proctex.texture.painters.base import REFINE
from proctex.texture.render import Buffers


def backproject_reference(points: np.ndarray, part: int, buffers: Buffers, trimap_: np.ndarray, view: np.ndarray, plane_tol: float = 1.0) -> dict[int, tuple[np.ndarray, float]]:
    """Slow :func:`backproject`: one point at a time. Returns ``{index: (colour (3,), cos)}``."""
    cam = buffers.camera
    H, W = buffers.face.shape
    right, up, fwd = cam.basis()
    out = {}
    for k, p in enumerate(np.asarray(points, dtype=np.float64)):
        d = p - np.asarray(cam.eye)
        z = d @ fwd
        if z <= 0:
            continue
        x = ((d @ right) / (z * cam.tan_half * W / H) + 1) / 2 * W - 0.5
        y = (1 - (d @ up) / (z * cam.tan_half)) / 2 * H - 0.5
        if not (0 <= x < W - 1 and 0 <= y < H - 1):
            continue
        i, j = int(np.floor(y)), int(np.floor(x))
        tol = plane_tol * 2 * cam.tan_half / H * np.linalg.norm(d)
        acc, wsum, cs = np.zeros(3), 0.0, 0.0
        for di in (0, 1):
            for dj in (0, 1):
                ii, jj = i + di, j + dj
                if buffers.part[ii, jj] != part or trimap_[ii, jj] < REFINE:
                    continue
                if abs((p - buffers.points[ii, jj]) @ buffers.normal[ii, jj]) > tol:
                    continue
                w = (y - i if di else 1 - (y - i)) * (x - j if dj else 1 - (x - j)) + 1e-6
                acc += w * view[ii, jj]
                cs += w * buffers.cos[ii, jj]
                wsum += w
        if wsum > 0:
            out[k] = (acc / wsum, cs / wsum)
    return out
