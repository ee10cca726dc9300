"""Swept parts: rings of profile points around an axis (:func:`revolve`, :func:`ring_surface`) and
tubes along a path (:func:`tube`), watertight, with canonical coordinates on the unit sphere or
cylinder. Boxes and the shared tessellation helpers are in :mod:`proctex.geometry.primitives`."""

from __future__ import annotations

from typing import Callable, Sequence

import numpy as np

from .primitives import Part, _orient_outward, resample


# ------------------------------------------------------------------------------------ ring surfaces
def sphere_canonical(s: np.ndarray, phi: np.ndarray) -> np.ndarray:
    """Canonical embedding of (profile parameter, angle) on the unit sphere: (..., 3) float64."""
    s = np.asarray(s, dtype=float)
    phi = np.asarray(phi, dtype=float)
    return np.stack([np.sin(np.pi * s) * np.cos(phi), np.sin(np.pi * s) * np.sin(phi), np.cos(np.pi * s)], axis=-1)


def ring_surface(
    rings: np.ndarray,
    s: np.ndarray,
    start_pole: np.ndarray | None,
    end_pole: np.ndarray | None,
    phi: np.ndarray | None = None,
) -> Part:
    """Closed surface from ``K`` rings of ``N`` points plus two pole vertices.

    Args:
        rings: (K, N, 3) float64 ring positions; consecutive rings are joined by quads and every
            ring is closed around.
        s: (K,) profile parameters of the rings, strictly inside (0, 1); poles get 0 and 1.
        start_pole, end_pole: (3,) positions of the pole vertices closing the ends. Both are
            required: parts are closed surfaces.
        phi: (N,) angles of the ring points (default: uniform in [0, 2 pi)).
    """
    rings = np.asarray(rings, dtype=float)
    if rings.ndim != 3 or rings.shape[2] != 3 or rings.shape[0] < 1 or rings.shape[1] < 3:
        raise ValueError(f"rings must be (K >= 1, N >= 3, 3), got {rings.shape}")
    if start_pole is None or end_pole is None:
        raise ValueError("ring_surface needs both poles to close the surface")
    K, N, _ = rings.shape
    s = np.asarray(s, dtype=float)
    if s.shape != (K,) or np.any(s <= 0) or np.any(s >= 1) or np.any(np.diff(s) <= 0):
        raise ValueError("s must be (K,) strictly increasing inside (0, 1)")
    if phi is None:
        phi = np.arange(N) * (2 * np.pi / N)
    vertices = np.concatenate([np.asarray(start_pole, float)[None], rings.reshape(-1, 3), np.asarray(end_pole, float)[None]])
    canonical = np.concatenate(
        [
            sphere_canonical(0.0, 0.0)[None],
            sphere_canonical(np.repeat(s, N), np.tile(phi, K)),
            sphere_canonical(1.0, 0.0)[None],
        ]
    )
    ring_id = lambda k, n: 1 + k * N + (n % N)  # noqa: E731
    n = np.arange(N)
    faces = [np.stack([np.zeros(N, int), ring_id(0, n + 1), ring_id(0, n)], axis=1)]
    for k in range(K - 1):
        a, b, c, d = ring_id(k, n), ring_id(k, n + 1), ring_id(k + 1, n + 1), ring_id(k + 1, n)
        faces.append(np.stack([a, b, c], axis=1))
        faces.append(np.stack([a, c, d], axis=1))
    last = 1 + K * N
    faces.append(np.stack([ring_id(K - 1, n), ring_id(K - 1, n + 1), np.full(N, last)], axis=1))
    part = Part(vertices, np.concatenate(faces).astype(np.int64), canonical)
    return _orient_outward(part)


def revolve(
    radius: np.ndarray,
    height: np.ndarray,
    s: np.ndarray | None = None,
    n_theta: int = 32,
    z_bottom: float | None = None,
    z_top: float | None = None,
    radial: Callable[[np.ndarray, np.ndarray], np.ndarray] | None = None,
    center: Sequence[float] = (0.0, 0.0, 0.0),
) -> Part:
    """Surface of revolution about the z axis, closed by poles on the axis.

    Args:
        radius: (K,) profile radii (> 0) from bottom to top (the profile may go back down, as for a
            thin-walled vessel: outside up, over the lip, inside down).
        height: (K,) profile z values.
        s: (K,) canonical profile parameters inside (0, 1) (default: uniform).
        n_theta: points per ring.
        z_bottom, z_top: z of the bottom and top poles (default: first and last profile z).
        radial: optional ``f(theta (N,), s (K,)) -> (K, N)`` radius multiplier (ribs, lobes).
        center: translation applied at the end.
    """
    radius = np.asarray(radius, dtype=float)
    height = np.asarray(height, dtype=float)
    K = len(radius)
    if radius.shape != (K,) or height.shape != (K,) or K < 1:
        raise ValueError("radius and height must be equal-length 1-D arrays")
    if np.any(radius <= 0):
        raise ValueError("profile radii must be positive (poles are added automatically)")
    if s is None:
        s = (np.arange(K) + 1.0) / (K + 1.0)
    theta = np.arange(n_theta) * (2 * np.pi / n_theta)
    mult = np.ones((K, n_theta)) if radial is None else np.asarray(radial(theta, np.asarray(s, float)), float)
    if mult.shape != (K, n_theta) or not np.all(np.isfinite(mult)) or np.any(mult <= 0):
        raise ValueError(f"radial must return positive finite ({K}, {n_theta}) multipliers, got shape {mult.shape}")
    r = radius[:, None] * mult
    rings = np.stack([r * np.cos(theta)[None], r * np.sin(theta)[None], np.repeat(height[:, None], n_theta, 1)], axis=-1)
    c = np.asarray(center, dtype=float)
    zb = height[0] if z_bottom is None else z_bottom
    zt = height[-1] if z_top is None else z_top
    return ring_surface(rings + c, s, c + [0, 0, zb], c + [0, 0, zt], phi=theta)


def _frames(path: np.ndarray, up: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Rotation-minimising frames (tangent, normal, binormal), each (K, 3), along a polyline."""
    t = np.gradient(path, axis=0)
    t /= np.linalg.norm(t, axis=1, keepdims=True)
    n0 = up - np.dot(up, t[0]) * t[0]
    if np.linalg.norm(n0) < 1e-8:
        alt = np.array([1.0, 0.0, 0.0]) if abs(t[0, 0]) < 0.9 else np.array([0.0, 1.0, 0.0])
        n0 = alt - np.dot(alt, t[0]) * t[0]
    normals = [n0 / np.linalg.norm(n0)]
    for k in range(1, len(path)):
        n = normals[-1] - np.dot(normals[-1], t[k]) * t[k]
        normals.append(n / np.linalg.norm(n))
    nrm = np.array(normals)
    return t, nrm, np.cross(t, nrm)


def tube(
    path: np.ndarray,
    radius: np.ndarray | float,
    n_sides: int = 12,
    s: np.ndarray | None = None,
    up: Sequence[float] = (0.0, 0.0, 1.0),
    cap_offset: float = 0.0,
    scale_xy: Sequence[float] = (1.0, 1.0),
    normals: np.ndarray | None = None,
) -> Part:
    """Closed tube swept along a polyline, with pole caps at both ends.

    Args:
        path: (K, 3) centre line, K >= 2.
        radius: scalar or (K,) radii.
        n_sides: points per ring.
        s: (K,) canonical parameters inside (0, 1) (default uniform).
        up: hint for the frame's normal at the start, so the angle origin is stable across
            parameter settings. Frames are rotation-minimising: on a path that winds in 3D (a
            helix) the angle origin twists by an amount that depends on the path, so for such
            paths build the rings with a fixed reference direction and :func:`ring_surface`.
        cap_offset: how far beyond the end rings the poles sit (0: flat caps).
        scale_xy: (2,) ellipse factors of the cross-section along (normal, binormal).
        normals: optional (K, 3) directions of the cross-sections' angle origin (made orthogonal
            to the tangent), e.g. from :func:`resampled_normals`; default: the frames above.
    """
    path = np.asarray(path, dtype=float)
    K = len(path)
    if path.ndim != 2 or path.shape[1] != 3 or K < 2:
        raise ValueError(f"path must be (K >= 2, 3), got {path.shape}")
    rad = np.broadcast_to(np.asarray(radius, dtype=float), (K,))
    if np.any(rad <= 0):
        raise ValueError("tube radii must be positive")
    if s is None:
        s = (np.arange(K) + 1.0) / (K + 1.0)
    t, nrm, bin_ = _frames(path, np.asarray(up, dtype=float))
    if normals is not None:
        nrm = np.asarray(normals, dtype=float)
        if nrm.shape != path.shape:
            raise ValueError(f"normals must be {path.shape}, got {nrm.shape}")
        nrm = nrm - np.einsum("ij,ij->i", nrm, t)[:, None] * t
        nrm /= np.linalg.norm(nrm, axis=1, keepdims=True)
        bin_ = np.cross(t, nrm)
    phi = np.arange(n_sides) * (2 * np.pi / n_sides)
    cx = np.cos(phi)[None, :, None] * scale_xy[0]
    cy = np.sin(phi)[None, :, None] * scale_xy[1]
    rings = path[:, None] + rad[:, None, None] * (cx * nrm[:, None] + cy * bin_[:, None])
    start = path[0] - t[0] * cap_offset * rad[0]
    end = path[-1] + t[-1] * cap_offset * rad[-1]
    return ring_surface(rings, s, start, end, phi=phi)


def resampled_normals(reference_path: np.ndarray, u: np.ndarray, up: Sequence[float] = (0.0, 0.0, 1.0)) -> np.ndarray:
    """Rotation-minimising frame normals (k, 3) of a tube's ``reference_path`` (K, 3), sampled at
    uniform curve parameters, interpolated at the curve parameters ``u`` (k,) in [0, 1].

    On a path that winds in 3D the discrete frames' twist depends on the sampling; taking the
    angle origin from one fixed reference sampling keeps canonical angles on the same side of the
    tube whatever the tessellation.
    """
    reference_path = np.asarray(reference_path, dtype=float)
    _, nrm, _ = _frames(reference_path, np.asarray(up, dtype=float))
    return resample(nrm, np.linspace(0.0, 1.0, len(reference_path)), np.asarray(u, dtype=float))
