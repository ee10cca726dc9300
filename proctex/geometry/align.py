"""Rigid / similarity alignment: Kabsch-Umeyama, point-to-surface ICP, Chamfer distances.

Transforms are ``(R (3, 3), t (3,), s float)`` acting as ``x -> s R x + t``; ``R`` may be a
reflection (det -1) when asked for.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

from .surface import SurfaceIndex


def umeyama(src: np.ndarray, dst: np.ndarray, scale: bool = False, reflection: bool | None = False) -> tuple[np.ndarray, np.ndarray, float]:
    """Least-squares transform mapping ``src (k, 3)`` onto ``dst (k, 3)`` (Umeyama 1991).

    Args:
        scale: also fit a uniform scale.
        reflection: ``False`` proper rotations only, ``True`` reflections only, ``None`` whichever
            fits better.

    Returns:
        ``(R (3, 3), t (3,), s)`` with ``dst ≈ s R src + t``.
    """
    src = np.asarray(src, dtype=float)
    dst = np.asarray(dst, dtype=float)
    if src.shape != dst.shape or src.ndim != 2 or src.shape[1] != 3 or len(src) == 0:
        raise ValueError(f"umeyama needs two equal (k >= 1, 3) arrays, got {src.shape} and {dst.shape}")
    mu_s, mu_d = src.mean(0), dst.mean(0)
    xs, xd = src - mu_s, dst - mu_d
    cov = xd.T @ xs / len(src)
    U, S, Vt = np.linalg.svd(cov)
    d = np.sign(np.linalg.det(U @ Vt)) or 1.0
    if reflection is None:
        flip = 1.0  # the unconstrained optimum: plain U V^T
        D = np.eye(3)
    else:
        want = -1.0 if reflection else 1.0
        flip = want * d
        D = np.diag([1.0, 1.0, flip])
    R = U @ D @ Vt
    var_s = (xs**2).sum() / len(src)
    s = float(np.trace(np.diag(S) @ D) / var_s) if (scale and var_s > 0) else 1.0
    t = mu_d - s * R @ mu_s
    return R, t, s


def umeyama_batch(src: np.ndarray, dst: np.ndarray, scale: bool = False, reflection: bool = False) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """:func:`umeyama` of one ``src (k, 3)`` onto each of ``dst (m, k, 3)`` at once: ``(R (m, 3, 3),
    t (m, 3), s (m,))`` with ``dst[i] ≈ s[i] R[i] src + t[i]``. ``reflection``: ``False`` proper
    rotations only, ``True`` reflections only."""
    src = np.asarray(src, dtype=float)
    dst = np.asarray(dst, dtype=float)
    if src.ndim != 2 or src.shape[1] != 3 or len(src) == 0 or dst.ndim != 3 or dst.shape[1:] != src.shape:
        raise ValueError(f"umeyama_batch needs src (k >= 1, 3) and dst (m, k, 3), got {src.shape} and {dst.shape}")
    mu_s, mu_d = src.mean(0), dst.mean(1)
    xs, xd = src - mu_s, dst - mu_d[:, None]
    cov = np.swapaxes(xd, 1, 2) @ xs / len(src)  # (m, 3, 3)
    U, S, Vt = np.linalg.svd(cov)
    d = np.sign(np.linalg.det(U @ Vt))
    d[d == 0] = 1.0
    flip = (-1.0 if reflection else 1.0) * d
    D = np.broadcast_to(np.eye(3), (len(dst), 3, 3)).copy()
    D[:, 2, 2] = flip
    R = U @ D @ Vt
    var_s = (xs**2).sum() / len(src)
    s = (S * np.diagonal(D, axis1=1, axis2=2)).sum(1) / var_s if (scale and var_s > 0) else np.ones(len(dst))
    t = mu_d - s[:, None] * (R @ mu_s)
    return R, t, s


def affine_fit(src: np.ndarray, dst: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Least-squares affine map of ``src (k, 3)`` onto ``dst (k, 3)`` (point i onto point i):
    ``(A (3, 3), t (3,), fitted (k, 3))`` with ``fitted = src A^T + t ≈ dst``; not finite where the
    points are."""
    src = np.asarray(src, dtype=np.float64)
    dst = np.asarray(dst, dtype=np.float64)
    if src.shape != dst.shape or src.ndim != 2 or src.shape[1] != 3 or len(src) == 0:
        raise ValueError(f"affine_fit needs two equal (k >= 1, 3) arrays, got {src.shape} and {dst.shape}")
    X = np.concatenate([src, np.ones((len(src), 1))], axis=1)
    sol = np.linalg.lstsq(X, dst, rcond=None)[0]  # (4, 3): dst ≈ src sol[:3] + sol[3]
    return sol[:3].T.copy(), sol[3].copy(), X @ sol


def apply(points: np.ndarray, R: np.ndarray, t: np.ndarray, s: float = 1.0) -> np.ndarray:
    """``s R x + t`` for ``points (k, 3)``."""
    return s * points @ R.T + t


def rotation_angle(R: np.ndarray) -> float:
    """Angle in radians of the rotation part of ``R`` (a reflection is first made proper by -R)."""
    Rp = R if np.linalg.det(R) > 0 else -R
    return float(np.arccos(np.clip((np.trace(Rp) - 1) / 2, -1.0, 1.0)))


def chamfer(a: np.ndarray, b: np.ndarray) -> float:
    """Symmetric mean nearest-neighbour distance between point sets ``a (k, 3)`` and ``b (l, 3)``."""
    da, _ = cKDTree(b).query(a)
    db, _ = cKDTree(a).query(b)
    return float(0.5 * (da.mean() + db.mean()))


@dataclass
class ICPResult:
    """Outcome of :func:`icp_to_surface`.

    ``R, t, s``: transform of the source points; ``error``: mean point-to-surface distance after
    alignment; ``iterations``; ``converged``: the error stopped improving before the limit.
    """

    R: np.ndarray
    t: np.ndarray
    s: float
    error: float
    iterations: int
    converged: bool


def icp_to_surface(
    src: np.ndarray,
    target: SurfaceIndex,
    R0: np.ndarray | None = None,
    t0: np.ndarray | None = None,
    scale: bool = False,
    max_iter: int = 50,
    tol: float = 1e-7,
    exact: bool = True,
) -> ICPResult:
    """Point-to-surface ICP: align ``src (k, 3)`` to a target surface.

    Each iteration matches every transformed source point to its closest point on the target
    surface (exact, or with ``exact=False`` the best of the index's first candidates) and refits
    the transform with :func:`umeyama`, keeping the handedness of the initial ``R0`` (a reflection
    stays a reflection).
    """
    R = np.eye(3) if R0 is None else np.asarray(R0, dtype=float)
    t = np.zeros(3) if t0 is None else np.asarray(t0, dtype=float)
    s = 1.0
    reflection = bool(np.linalg.det(R) < 0)
    zero = 1e-10 * float(np.linalg.norm(src.max(0) - src.min(0)))  # "zero" at the data's scale
    converged = False
    it = 0
    cp = target.query(apply(src, R, t, s), exact=exact)
    err = float(cp.distance.mean())
    for it in range(1, max_iter + 1):
        if err <= zero:
            converged = True
            break
        R_new, t_new, s_new = umeyama(src, cp.points, scale=scale, reflection=reflection)
        cp_new = target.query(apply(src, R_new, t_new, s_new), exact=exact)
        err_new = float(cp_new.distance.mean())
        if err_new > err:  # a refit never increases the error in exact arithmetic; stop if it does
            converged = True
            break
        prev, err, cp = err, err_new, cp_new
        R, t, s = R_new, t_new, s_new
        if prev - err <= tol * prev:
            converged = True
            break
    return ICPResult(R, t, s, err, it, converged)


def icp_points(
    src: np.ndarray,
    dst: np.ndarray,
    dst_tree: cKDTree | None = None,
    R0: np.ndarray | None = None,
    t0: np.ndarray | None = None,
    max_iter: int = 30,
    tol: float = 1e-6,
) -> ICPResult:
    """Point-to-point ICP of ``src (k, 3)`` onto the point set ``dst (l, 3)`` (nearest neighbours).

    Cheaper and coarser than :func:`icp_to_surface` (its error floor is the sampling spacing of
    ``dst``); keeps the handedness of ``R0``. ``error`` is the mean nearest-neighbour distance.
    """
    tree = dst_tree if dst_tree is not None else cKDTree(dst)
    R = np.eye(3) if R0 is None else np.asarray(R0, dtype=float)
    t = np.zeros(3) if t0 is None else np.asarray(t0, dtype=float)
    reflection = bool(np.linalg.det(R) < 0)
    converged, it = False, 0
    d, j = tree.query(apply(src, R, t))
    err = float(d.mean())
    for it in range(1, max_iter + 1):
        R_new, t_new, _ = umeyama(src, dst[j], reflection=reflection)
        d_new, j_new = tree.query(apply(src, R_new, t_new))
        err_new = float(d_new.mean())
        if err_new > err:
            converged = True
            break
        prev, err, j, R, t = err, err_new, j_new, R_new, t_new
        if prev - err <= tol * max(prev, 1e-300):
            converged = True
            break
    return ICPResult(R, t, 1.0, err, it, converged)


@dataclass
class AffineResult:
    """Outcome of :func:`affine_icp_to_surface`.

    ``A (3, 3), t (3,)``: the map ``x -> A x + t``; ``error``: mean point-to-plane distance of the
    oriented matches after the last refit; ``start_error``: the same at the start; ``iterations``;
    ``converged``: the error stopped improving before the limit; ``accepted``: the map kept the
    start's handedness and no axis was stretched or squeezed past ``max_stretch`` relative to the
    start (otherwise ``A, t`` are the start's).
    """

    A: np.ndarray
    t: np.ndarray
    error: float
    start_error: float
    iterations: int
    converged: bool
    accepted: bool


def affine_icp_to_surface(
    src: np.ndarray,
    src_normals: np.ndarray,
    target: SurfaceIndex,
    A0: np.ndarray | None = None,
    t0: np.ndarray | None = None,
    max_iter: int = 30,
    tol: float = 1e-6,
    min_dot: float = 0.5,
    max_stretch: float = 2.0,
    damping: float = 1e-3,
) -> AffineResult:
    """Facet-matched affine alignment: point-to-plane ICP with a general affine map.

    Every mapped source point ``p`` (with its normal carried by the inverse transpose) is matched
    to its closest template point ``q`` on a face whose normal ``m`` agrees (``dot > min_dot``;
    :meth:`SurfaceIndex.query_oriented`), and ``(A, t)`` is refitted by linear least squares on
    ``m . (A p + t) = m . q``: each source point must land on the *plane* of its matched template
    facet. A sheared or tapered box is an exact affine image of another box, and its facet planes
    fix the map exactly, which a Chamfer distance between near-equal fits cannot. Points may still
    slide within a facet: each Gauss-Newton step moves only along the eigen-directions of the normal
    equations stronger than ``damping`` times the strongest, so what no plane constrains (a turn
    about the axis of a surface of revolution, a slide along a cylinder) keeps the start's value,
    and an exact fit stays exact.

    Args:
        src: (k, 3) float64 source points; src_normals: (k, 3) their unit normals.
        target: the template surface.
        A0, t0: the start (default identity), e.g. the per-axis box scale.
        max_stretch: reject the result (``accepted=False``) when a singular value of
            ``A @ inv(A0)`` leaves ``[1/max_stretch, max_stretch]`` or the handedness flips.

    Raises:
        ValueError: shapes that do not match, non-finite input, a singular start.
    """
    p = np.asarray(src, dtype=np.float64)
    n = np.asarray(src_normals, dtype=np.float64)
    if p.ndim != 2 or p.shape[1] != 3 or n.shape != p.shape or len(p) < 4:
        raise ValueError(f"affine ICP needs (k >= 4, 3) points and normals of the same shape, got {p.shape} and {n.shape}")
    if not (np.isfinite(p).all() and np.isfinite(n).all()):
        raise ValueError("affine ICP: points or normals contain NaN or inf")
    A = np.eye(3) if A0 is None else np.asarray(A0, dtype=np.float64).copy()
    t = np.zeros(3) if t0 is None else np.asarray(t0, dtype=np.float64).copy()
    if A.shape != (3, 3) or t.shape != (3,) or not np.isfinite(A).all() or abs(np.linalg.det(A)) < 1e-12:
        raise ValueError("affine ICP: the start must be a finite, invertible (3, 3) map and a (3,) offset")
    A_start, t_start = A.copy(), t.copy()

    def matches(A: np.ndarray, t: np.ndarray) -> tuple[np.ndarray, np.ndarray, float]:
        moved = p @ A.T + t
        nm = n @ np.linalg.inv(A)  # normals: inverse transpose, as rows
        nm /= np.maximum(np.linalg.norm(nm, axis=1, keepdims=True), 1e-300)
        hit, oriented = target.query_oriented(moved, nm, min_dot=min_dot, exact=False)
        m = target.normals[hit.faces]
        w = oriented.astype(np.float64)
        plane = np.einsum("kd,kd->k", m, moved - hit.points)
        err = float(np.sum(w * np.abs(plane)) / max(w.sum(), 1.0))
        return m * w[:, None], np.einsum("kd,kd->k", m, hit.points) * w, err

    m, rhs, err = matches(A, t)
    start_error = err
    converged, it = False, 0
    k = len(p)
    for it in range(1, max_iter + 1):
        # rows: m_i (x) p_i for the 9 entries of A (row-major), m_i for t
        M = np.concatenate([(m[:, :, None] * p[:, None, :]).reshape(k, 9), m], axis=1)
        x_prev = np.concatenate([A.reshape(-1), t])
        # Gauss-Newton step on the directions the planes constrain: eigen-directions of M^T M
        # weaker than ``damping`` times the strongest (points sliding within facets, a turn about
        # a surface of revolution's axis) keep their current value.
        H = M.T @ M
        evals, evecs = np.linalg.eigh(H)
        keep = evals > damping * max(float(evals[-1]), 1e-300)
        g = evecs.T @ (M.T @ (rhs - M @ x_prev))
        x = x_prev + evecs[:, keep] @ (g[keep] / evals[keep])
        A_new, t_new = x[:9].reshape(3, 3), x[9:]
        if not np.isfinite(x).all() or np.linalg.det(A_new) * np.linalg.det(A) <= 0:
            break
        m_new, rhs_new, err_new = matches(A_new, t_new)
        if err_new > err:
            converged = True
            break
        prev = err
        A, t, m, rhs, err = A_new, t_new, m_new, rhs_new, err_new
        if prev - err <= tol * max(prev, 1e-12):
            converged = True
            break
    sv = np.linalg.svd(A @ np.linalg.inv(A_start), compute_uv=False)
    accepted = bool(np.linalg.det(A) * np.linalg.det(A_start) > 0 and sv.max() <= max_stretch and sv.min() >= 1.0 / max_stretch)
    if not accepted:
        A, t, err = A_start, t_start, start_error
    return AffineResult(A, t, err, start_error, it, converged, accepted)
