"""Mean value coordinates of points with respect to a closed triangle cage.

Ju, Schaefer & Warren, "Mean value coordinates for closed triangular meshes" (SIGGRAPH 2005).
For a point ``x`` and a closed, consistently oriented cage ``(V, F)``, the weights ``w (V,)`` sum to
one and reproduce linear functions: ``sum_j w_j V_j = x``. A cage deformation moves ``x`` to
``w @ V'``.

- :func:`mean_value_coordinates`: vectorised PyTorch (any device and float dtype), processed in
  chunks of points, differentiable with respect to the cage vertices (and the points).
- :func:`proctex._reference.mvc.mean_value_coordinates_reference`: the paper's pseudo-code with plain Python loops in
  float64, for tests.

Numerical guards (both versions): a point within ``eps`` of a cage vertex gets that vertex's
indicator; a point on a cage triangle gets the triangle's barycentric coordinates; a triangle
coplanar with the point but not containing it contributes nothing.
"""

from __future__ import annotations

import math

import numpy as np
import torch
from proctex.torch_kernels import resolve_vml

resolve_vml()  # MKL's kernels chosen on one thread (see proctex.torch_kernels)


def _check_cage(cage_vertices: np.ndarray | torch.Tensor, cage_faces: np.ndarray | torch.Tensor) -> None:
    if cage_vertices.ndim != 2 or cage_vertices.shape[1] != 3 or cage_vertices.shape[0] < 4:
        raise ValueError(f"cage vertices must be (V >= 4, 3), got {tuple(cage_vertices.shape)}")
    if cage_faces.ndim != 2 or cage_faces.shape[1] != 3 or cage_faces.shape[0] < 4:
        raise ValueError(f"cage faces must be (F >= 4, 3), got {tuple(cage_faces.shape)}")
    if int(cage_faces.min()) < 0 or int(cage_faces.max()) >= cage_vertices.shape[0]:
        raise ValueError("cage face indices out of range")


# ------------------------------------------------------------------------------------- reference
# ----------------------------------------------------------------------------------- vectorised
def _mvc_chunk(x: torch.Tensor, cv: torch.Tensor, cf: torch.Tensor, eps: float) -> torch.Tensor:
    """Weights of points ``x (n, 3)`` in the cage ``cv``: one ``(V, 3)`` for all, or ``(n, V, 3)``
    a cage per point (batched pairs, :mod:`proctex.correspond.cage_batch`)."""
    n, V = x.shape[0], cv.shape[-2]
    F = cf.shape[0]
    diff = (cv if cv.ndim == 3 else cv[None, :, :]) - x[:, None, :]  # (n, V, 3)
    d = torch.sqrt((diff * diff).sum(-1) + 1e-300)  # safe norm: finite gradient at 0
    at_vertex = d < eps
    d_safe = torch.where(at_vertex, torch.ones_like(d), d)
    u = diff / d_safe[..., None]
    uf = u[:, cf]  # (n, F, 3, 3): unit vectors to the triangle corners
    df = d_safe[:, cf]  # (n, F, 3)
    nxt, prv = [1, 2, 0], [2, 0, 1]
    a, b = uf[:, :, nxt], uf[:, :, prv]
    cr = torch.cross(a, b, dim=-1)
    # theta_i = 2 asin(|a - b| / 2) of the paper, as atan2: accurate near pi (points on a face).
    theta = torch.atan2(torch.sqrt((cr * cr).sum(-1) + 1e-300), (a * b).sum(-1))
    h = theta.sum(-1) / 2.0  # (n, F)
    on_face = (math.pi - h) < eps
    sin_t = torch.sin(theta)
    den = sin_t[..., nxt] * sin_t[..., prv]
    bad_den = den.abs() < eps
    c = 2.0 * torch.sin(h)[..., None] * torch.sin(h[..., None] - theta) / torch.where(bad_den, torch.ones_like(den), den) - 1.0
    sign = torch.sign((uf[:, :, 0] * torch.cross(uf[:, :, 1], uf[:, :, 2], dim=-1)).sum(-1))
    sign = torch.where(sign == 0, torch.ones_like(sign), sign)
    s = sign[..., None] * torch.sqrt(torch.clamp(1.0 - c * c, min=0.0) + 1e-300)
    skip = (s.abs() <= eps).any(-1) | bad_den.any(-1) | on_face  # (n, F)
    s_prev = s[..., prv]
    den_w = df * sin_t[..., nxt] * s_prev
    den_w = torch.where(skip[..., None], torch.ones_like(den_w), den_w)
    w_tri = (theta - c[..., nxt] * theta[..., prv] - c[..., prv] * theta[..., nxt]) / den_w
    w_tri = torch.where(skip[..., None], torch.zeros_like(w_tri), w_tri)
    w = torch.zeros(n, V, dtype=x.dtype, device=x.device).index_add(1, cf.reshape(-1), w_tri.reshape(n, F * 3))
    total = w.sum(-1, keepdim=True)
    w = w / torch.where(total.abs() < 1e-300, torch.ones_like(total), total)
    # Guard: on a triangle -> its barycentric coordinates (sin(theta_i) d_{i-1} d_{i+1}).
    face_rows = on_face.any(-1)
    if bool(face_rows.any()):
        first = torch.argmax(on_face.to(torch.int8), dim=-1)  # (n,)
        rows = torch.arange(n, device=x.device)
        th, dd = theta[rows, first], df[rows, first]  # (n, 3)
        wb = torch.sin(th) * dd[:, prv] * dd[:, nxt]
        wb = wb / torch.clamp(wb.sum(-1, keepdim=True), min=1e-300)
        wf = torch.zeros(n, V, dtype=x.dtype, device=x.device).scatter_add(1, cf[first], wb)
        w = torch.where(face_rows[:, None], wf, w)
    # Guard: at a cage vertex -> that vertex's indicator.
    vert_rows = at_vertex.any(-1)
    if bool(vert_rows.any()):
        first = torch.argmax(at_vertex.to(torch.int8), dim=-1)
        wv = torch.nn.functional.one_hot(first, V).to(x.dtype)
        w = torch.where(vert_rows[:, None], wv, w)
    return w


def mean_value_coordinates(
    points: torch.Tensor | np.ndarray,
    cage_vertices: torch.Tensor | np.ndarray,
    cage_faces: torch.Tensor | np.ndarray,
    eps: float = 1e-9,
    chunk: int = 1024,
) -> torch.Tensor:
    """Mean value coordinates, vectorised and differentiable.

    Args:
        points: (n, 3) query points (tensor or array).
        cage_vertices: (V, 3) cage positions; gradients flow to it when it requires grad.
        cage_faces: (F, 3) int64, a closed, consistently oriented triangle cage.
        eps: tolerance of the vertex / on-face / coplanar guards.
        chunk: points per batch (memory is O(chunk * F)).

    Returns:
        (n, V) weights on the device and dtype of ``cage_vertices`` (float64 when arrays are given).
    """
    cv = cage_vertices if isinstance(cage_vertices, torch.Tensor) else torch.as_tensor(np.asarray(cage_vertices, dtype=np.float64))
    cf = cage_faces if isinstance(cage_faces, torch.Tensor) else torch.as_tensor(np.asarray(cage_faces, dtype=np.int64))
    cf = cf.to(device=cv.device, dtype=torch.long)
    x = points if isinstance(points, torch.Tensor) else torch.as_tensor(np.asarray(points, dtype=np.float64))
    x = x.to(device=cv.device, dtype=cv.dtype)
    if x.ndim != 2 or x.shape[1] != 3:
        raise ValueError(f"points must be (n, 3), got {tuple(x.shape)}")
    _check_cage(cv, cf)
    if not bool(torch.isfinite(x).all()) or not bool(torch.isfinite(cv).all()):
        raise ValueError("points and cage vertices must be finite (got NaN or inf)")
    if x.shape[0] == 0:
        return torch.zeros(0, cv.shape[0], dtype=cv.dtype, device=cv.device)
    parts = [_mvc_chunk(x[i : i + chunk], cv, cf, eps) for i in range(0, x.shape[0], max(int(chunk), 1))]
    return torch.cat(parts, dim=0)
