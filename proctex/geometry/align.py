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
