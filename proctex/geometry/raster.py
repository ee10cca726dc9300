"""Vectorised triangle rasterisation (pixel centres, barycentrics, optional z-buffer).

One routine serves both the UV texel maps (triangles in texel coordinates, no depth) and the pure
renderer fallback (screen-space triangles with depth). Pixel ``(i, j)`` (row, column) has its centre at
``x = j + 0.5, y = i + 0.5``; a pixel belongs to a triangle when its centre lies inside it (closed,
up to ``eps`` in barycentric units).

The fast path works in spans: barycentrics are affine in the pixel position, so for every (triangle,
row) pair the columns with all three barycentrics >= -eps form one interval, computed in closed form;
only pixels inside triangles are ever enumerated (``np.repeat`` in chunks of bounded size). With depth,
the nearest fragment per pixel wins (``np.lexsort``). :func:`proctex._reference.raster.rasterise_reference` is the obvious double loop.
"""

from __future__ import annotations

import numpy as np

CHUNK = 1 << 21  # candidate pixels per chunk


def _check(xy: np.ndarray, height: int, width: int, depth: np.ndarray | None) -> tuple[np.ndarray, np.ndarray | None]:
    xy = np.asarray(xy, dtype=np.float64)
    if xy.ndim != 3 or xy.shape[1:] != (3, 2):
        raise ValueError(f"triangles must be (F, 3, 2), got {xy.shape}")
    if int(height) < 1 or int(width) < 1:
        raise ValueError(f"image size must be positive, got {height}x{width}")
    if not np.isfinite(xy).all():
        raise ValueError("triangle coordinates contain NaN or inf")
    if depth is not None:
        depth = np.asarray(depth, dtype=np.float64)
        if depth.shape != xy.shape[:2]:
            raise ValueError(f"depth must be {xy.shape[:2]}, got {depth.shape}")
        if not np.isfinite(depth).all():
            raise ValueError("depth contains NaN or inf")
    return xy, depth


def rasterise(
    xy: np.ndarray,
    height: int,
    width: int,
    depth: np.ndarray | None = None,
    eps: float = 1e-9,
) -> tuple[np.ndarray, np.ndarray]:
    """Rasterise triangles given in pixel coordinates.

    Args:
        xy: (F, 3, 2) float corner coordinates, x = column axis, y = row axis (pixel units).
        height, width: image size.
        depth: optional (F, 3) per-corner depth, interpolated linearly in the image plane; the nearest
            fragment wins. Without depth, a pixel covered by several triangles takes the one with the
            highest index (UV atlases have no overlaps, so it does not matter there).
        eps: tolerance on barycentrics (pixels exactly on an edge belong to both triangles).

    Returns:
        face: (H, W) int64 triangle index per pixel, -1 where uncovered.
        bary: (H, W, 3) float64 barycentrics of the pixel centre in its triangle (0 where uncovered).
    """
    xy, depth = _check(xy, height, width, depth)
    H, W = int(height), int(width)
    face = np.full(H * W, -1, dtype=np.int64)
    bary = np.zeros((H * W, 3))
    zbuf = np.full(H * W, np.inf)
    ax, ay = xy[:, 0, 0], xy[:, 0, 1]
    ex1, ey1 = xy[:, 1, 0] - ax, xy[:, 1, 1] - ay
    ex2, ey2 = xy[:, 2, 0] - ax, xy[:, 2, 1] - ay
    det = ex1 * ey2 - ex2 * ey1
    keep = np.abs(det) > 1e-14  # degenerate in the image plane: covers no pixel centre
    y0 = np.clip(np.ceil(xy[:, :, 1].min(axis=1) - 0.5), 0, H).astype(np.int64)
    y1 = np.clip(np.floor(xy[:, :, 1].max(axis=1) - 0.5), -1, H - 1).astype(np.int64)
    rows = np.where(keep, np.maximum(y1 - y0 + 1, 0), 0)
    live = np.flatnonzero(rows)
    if len(live) == 0:
        return face.reshape(H, W), bary.reshape(H, W, 3)
    # Barycentrics are affine in the pixel position: l_k(x, y) = c_k + gx_k x + gy_k y.
    inv = np.where(keep, 1.0 / np.where(keep, det, 1.0), 0.0)
    g1x, g1y = ey2 * inv, -ex2 * inv
    g2x, g2y = -ey1 * inv, ex1 * inv
    c1 = -(g1x * ax + g1y * ay)
    c2 = -(g2x * ax + g2y * ay)
    gx = np.stack([-g1x - g2x, g1x, g2x], axis=1)
    gy = np.stack([-g1y - g2y, g1y, g2y], axis=1)
    c = np.stack([1.0 - c1 - c2, c1, c2], axis=1)
    # One span of pixel columns per (triangle, row): intersect the three half-planes l_k >= -eps.
    t_row = np.repeat(live, rows[live])
    py = y0[t_row] + np.arange(len(t_row)) - np.repeat(np.cumsum(rows[live]) - rows[live], rows[live])
    alpha = c[t_row] + gy[t_row] * (py + 0.5)[:, None]  # (R, 3): l_k = alpha_k + beta_k x
    beta = gx[t_row]
    with np.errstate(divide="ignore", invalid="ignore"):
        bound = (-eps - alpha) / beta
    lower = np.where(beta > 0, bound, -np.inf).max(axis=1)
    upper = np.where(beta < 0, bound, np.inf).min(axis=1)
    empty = ((beta == 0) & (alpha < -eps)).any(axis=1)
    j0 = np.clip(np.ceil(np.maximum(lower, -1.0) - 0.5), 0, W).astype(np.int64)
    j1 = np.clip(np.floor(np.minimum(upper, W + 1.0) - 0.5), -1, W - 1).astype(np.int64)
    n = np.where(empty, 0, np.maximum(j1 - j0 + 1, 0))
    spans = np.flatnonzero(n)
    csum = np.cumsum(n[spans])
    start = 0
    while start < len(spans):
        base = csum[start - 1] if start else 0
        stop = max(int(np.searchsorted(csum, base + CHUNK, side="right")), start + 1)
        sp = spans[start:stop]
        cnt = n[sp]
        r = np.repeat(sp, cnt)
        px = j0[r] + np.arange(len(r)) - np.repeat(np.cumsum(cnt) - cnt, cnt)
        lam = alpha[r] + beta[r] * (px + 0.5)[:, None]
        t = t_row[r]
        pix = py[r] * W + px
        if depth is not None:
            z = np.einsum("ij,ij->i", lam, depth[t])
            order = np.lexsort((z, pix))  # by pixel, nearest first
            pix, t, lam, z = pix[order], t[order], lam[order], z[order]
            first = np.ones(len(pix), dtype=bool)
            first[1:] = pix[1:] != pix[:-1]
            win = first.copy()
            win[first] = z[first] < zbuf[pix[first]]
            pix, t, lam, z = pix[win], t[win], lam[win], z[win]
            zbuf[pix] = z
        face[pix] = t
        bary[pix] = lam
        start = stop
    return face.reshape(H, W), bary.reshape(H, W, 3)
