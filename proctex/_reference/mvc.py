"""Slow, obviously correct references of :mod:`proctex.correspond.mvc` (loops over points, pixels or
texels), which the tests compare the shipped fast versions with; not used by the library."""

from __future__ import annotations

import math

import numpy as np

from proctex.correspond.mvc import _check_cage


def mean_value_coordinates_reference(points: np.ndarray, cage_vertices: np.ndarray, cage_faces: np.ndarray, eps: float = 1e-9) -> np.ndarray:
    """Slow, obviously-correct MVC: the paper's pseudo-code, one point and one triangle at a time.

    Args:
        points: (n, 3) float64 query points.
        cage_vertices: (V, 3) float64; cage_faces: (F, 3) int64, closed and consistently oriented.
        eps: distance / angle tolerance of the guards.

    Returns:
        (n, V) float64 weights.
    """
    pts = np.asarray(points, dtype=np.float64)
    cv = np.asarray(cage_vertices, dtype=np.float64)
    cf = np.asarray(cage_faces, dtype=np.int64)
    _check_cage(cv, cf)
    out = np.zeros((len(pts), len(cv)))
    for row, x in enumerate(pts):
        d = [math.dist(p, x) for p in cv]
        hit = [j for j, dj in enumerate(d) if dj < eps]
        if hit:
            out[row, hit[0]] = 1.0
            continue
        u = [(cv[j] - x) / d[j] for j in range(len(cv))]
        w = np.zeros(len(cv))
        for tri in cf:
            idx = [int(tri[0]), int(tri[1]), int(tri[2])]
            theta, c, s = [0.0] * 3, [0.0] * 3, [0.0] * 3
            for i in range(3):
                a, b = u[idx[(i + 1) % 3]], u[idx[(i - 1) % 3]]
                # The angle 2 asin(|a - b| / 2), computed as atan2 to stay accurate near pi.
                theta[i] = math.atan2(float(np.linalg.norm(np.cross(a, b))), float(np.dot(a, b)))
            h = sum(theta) / 2.0
            if math.pi - h < eps:
                # x lies on this triangle: 2D barycentric coordinates.
                w[:] = 0.0
                for i in range(3):
                    w[idx[i]] = math.sin(theta[i]) * d[idx[(i - 1) % 3]] * d[idx[(i + 1) % 3]]
                break
            sign = 1.0 if np.linalg.det(np.stack([u[idx[0]], u[idx[1]], u[idx[2]]])) >= 0 else -1.0
            skip = False
            for i in range(3):
                den = math.sin(theta[(i + 1) % 3]) * math.sin(theta[(i - 1) % 3])
                if abs(den) < eps:
                    skip = True
                    break
                c[i] = 2.0 * math.sin(h) * math.sin(h - theta[i]) / den - 1.0
                s[i] = sign * math.sqrt(max(1.0 - c[i] * c[i], 0.0))
                if abs(s[i]) <= eps:
                    skip = True  # x is outside t but on its plane: t contributes nothing
            if skip:
                continue
            for i in range(3):
                ip, im = (i + 1) % 3, (i - 1) % 3
                w[idx[i]] += (theta[i] - c[ip] * theta[im] - c[im] * theta[ip]) / (d[idx[i]] * math.sin(theta[ip]) * s[im])
        out[row] = w / w.sum()
    return out
