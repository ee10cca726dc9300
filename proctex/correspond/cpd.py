"""Non-rigid Coherent Point Drift (Myronenko & Song, TPAMI 2010), in PyTorch.

The moving set ``Y (M, 3)`` is the centroid set of a Gaussian mixture fitted to the fixed set
``X (N, 3)``; its displacement is a smooth field ``v(z) = sum_m G(z, y_m) w_m`` with a Gaussian
kernel of width ``beta``, regularised by ``lambda``. EM alternates posterior responsibilities
(with a uniform outlier component of weight ``w``) and the linear solve for ``W``. Because the
field is defined everywhere, it can be fitted on a subsample and then applied to any point
(:meth:`CPDResult.transform`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import torch
from proctex.torch_kernels import resolve_vml

resolve_vml()  # MKL's kernels chosen on one thread (see proctex.torch_kernels)


@dataclass
class CPDResult:
    """Fitted field. ``Y (M, 3)``, ``W (M, 3)``, ``beta``; ``sigma2`` final variance; ``iterations``; ``converged``."""

    Y: np.ndarray
    W: np.ndarray
    beta: float
    sigma2: float
    iterations: int
    converged: bool

    def transform(self, points: np.ndarray) -> np.ndarray:
        """Move ``points (k, 3)`` by the fitted displacement field."""
        pts = np.asarray(points, dtype=np.float64)
        d2 = ((pts[:, None, :] - self.Y[None, :, :]) ** 2).sum(-1)
        return pts + np.exp(-d2 / (2 * self.beta**2)) @ self.W


def cpd_nonrigid(
    Y: np.ndarray,
    X: np.ndarray,
    beta: float = 0.5,
    lam: float = 2.0,
    w: float = 0.0,
    max_iter: int = 100,
    tol: float = 1e-5,
    device: str = "cpu",
) -> CPDResult:
    """Fit the non-rigid CPD field moving ``Y (M, 3)`` onto ``X (N, 3)`` (float64).

    Args:
        beta: kernel width (data units); lam: smoothness weight; w: outlier weight in [0, 1).
        max_iter, tol: stop when the relative change of sigma^2 falls below ``tol``.
    """
    Y = np.asarray(Y, dtype=np.float64)
    X = np.asarray(X, dtype=np.float64)
    for name, a in (("Y", Y), ("X", X)):
        if a.ndim != 2 or a.shape[1] != 3 or len(a) == 0:
            raise ValueError(f"CPD {name} must be a non-empty (k, 3) array, got {a.shape}")
        if not np.all(np.isfinite(a)):
            raise ValueError(f"CPD {name} contains NaN or inf")
    if not (beta > 0 and lam > 0 and 0 <= w < 1):
        raise ValueError(f"CPD needs beta > 0, lam > 0, 0 <= w < 1; got {beta}, {lam}, {w}")
    dev = torch.device(device if (device != "cuda" or torch.cuda.is_available()) else "cpu")
    y = torch.as_tensor(Y, device=dev)
    x = torch.as_tensor(X, device=dev)
    M, N, D = len(Y), len(X), 3
    G = torch.exp(-(torch.cdist(y, y) ** 2) / (2 * beta**2))
    T = y.clone()
    Wt = torch.zeros_like(y)
    sigma2 = float((torch.cdist(x, y) ** 2).sum()) / (D * M * N)
    converged, it = False, 0
    for it in range(1, max_iter + 1):
        d2 = torch.cdist(x, T) ** 2  # (N, M)
        P = torch.exp(-d2 / (2 * sigma2))
        c = (2 * math.pi * sigma2) ** (D / 2) * w / (1 - w) * M / N
        den = P.sum(1, keepdim=True) + c
        P = (P / torch.clamp(den, min=1e-300)).T  # (M, N)
        P1, Pt1 = P.sum(1), P.sum(0)
        Np = float(P1.sum())
        PX = P @ x
        A = P1[:, None] * G + lam * sigma2 * torch.eye(M, device=dev, dtype=y.dtype)
        Wt = torch.linalg.solve(A, PX - P1[:, None] * y)
        T = y + G @ Wt
        new = float((Pt1 * (x * x).sum(1)).sum() - 2 * (PX * T).sum() + (P1 * (T * T).sum(1)).sum()) / max(Np * D, 1e-300)
        new = max(new, 1e-12)
        if abs(new - sigma2) <= tol * sigma2:
            sigma2 = new
            converged = True
            break
        sigma2 = new
    return CPDResult(Y, Wt.cpu().numpy(), float(beta), float(sigma2), it, converged)
