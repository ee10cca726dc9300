"""An intrinsic sweep chart of a tube-like part: where along it (``s``) and where around it (``theta``).

A coil, a rail or a handle is a tube swept along a curve. Procedural parameters change that curve
(more turns, a longer rail) while the tube stays a tube, so a point keeps its place *along* the
part and *around* it, not in space: a box map or a cage that fits the bounding volume maps the third
turn of a coil onto the second. The chart gives every surface point

- ``s`` in [0, 1]: arc length along the part's centre line, from the Fiedler vector of the
  cotangent Laplacian (the second eigenvector of ``L f = lambda M f``; intrinsic, so it follows the
  part however it winds, and it hardly depends on the tessellation), turned into arc length of the
  centre line through the centroids of its level sets;
- ``theta`` in [-pi, pi): the angle around the centre line, measured from a fixed reference
  direction (the world axis the centre line's tangents avoid most: a coil's axis) projected onto
  the plane normal to the tangent, so the angle origin does not twist with the curve.

:func:`sweep_chart` also reports how tube-like the part is (``aspect``: centre-line length over
mean distance to it) and how many times the centre line turns about the reference axis
(``turns``).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp
from scipy.sparse.csgraph import connected_components
from scipy.sparse.linalg import eigsh

from .meshio import weld_all
from .surface import triangle_areas

#: Most vertices a chart is computed on (the eigen-solve is the bound on the work).
MAX_CHART_VERTICES = 200_000


@dataclass
class SweepChart:
    """The chart of one part.

    Attributes:
        s: (n,) float64 position along the part in [0, 1] per input vertex (unused vertices: nan).
        theta: (n,) float64 angle around the centre line per input vertex, in [-pi, pi).
        centerline: (b, 3) float64 centroids of ``b`` level sets of ``s``, in order; knots: (b,)
            their ``s``.
        reference: (3,) the world axis angles are measured from.
        length: centre-line length; radius: mean distance of the surface to it (their ratio is
            :attr:`aspect`).
        turns: turns of the centre line about ``reference`` through its mean (a coil's winding
            count; segments passing within 0.2 of the median distance of that axis count nothing).
        eigenvalue: the Fiedler eigenvalue.
        tube_fit: surface area over ``2 pi radius length`` (about 1 for a tube; see :attr:`tubular`).
        spread: mean over level sets of the coefficient of variation of the distances to the
            centre line (0 for a round tube).
    """

    s: np.ndarray
    theta: np.ndarray
    centerline: np.ndarray
    knots: np.ndarray
    reference: np.ndarray
    length: float
    radius: float
    turns: float
    eigenvalue: float
    tube_fit: float = float("nan")
    spread: float = float("nan")

    @property
    def aspect(self) -> float:
        """Centre-line length over the mean distance of the surface to it (large for a long tube)."""
        return self.length / max(self.radius, 1e-300)

    @property
    def tubular(self) -> bool:
        """The chart describes a tube: the surface area is that of a tube of the chart's length
        and radius (``tube_fit`` within [2/3, 3/2]) and each level set is a ring about its
        centroid (``spread`` at most 0.3). When the Fiedler vector runs *around* a wide part
        instead of along it (a short, wide vessel) the level sets are strips and the area is far
        from ``2 pi r L``; a flat slab's level sets are long thin rectangles (spread ~0.5). How
        long the tube is, is :attr:`aspect`'s to say (a cube is a short, fat "tube")."""
        return bool(2.0 / 3.0 <= self.tube_fit <= 1.5 and self.spread <= 0.3)

    def frame(self, s: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Centre point, tangent, normal and binormal, each (k, 3), at positions ``s (k,)``."""
        s = np.clip(np.asarray(s, dtype=np.float64), 0.0, 1.0)
        c = np.stack([np.interp(s, self.knots, self.centerline[:, j]) for j in range(3)], axis=1)
        tan = np.gradient(self.centerline, self.knots, axis=0) if len(self.knots) > 1 else np.zeros_like(self.centerline)
        t = np.stack([np.interp(s, self.knots, tan[:, j]) for j in range(3)], axis=1)
        t /= np.maximum(np.linalg.norm(t, axis=1, keepdims=True), 1e-300)
        n = self.reference[None, :] - (t @ self.reference)[:, None] * t
        n /= np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-300)
        return c, t, n, np.cross(t, n)

    def angle(self, points: np.ndarray, s: np.ndarray) -> np.ndarray:
        """Angle around the centre line (k,) of ``points (k, 3)`` lying at positions ``s (k,)``."""
        c, _, n, b = self.frame(s)
        d = np.asarray(points, dtype=np.float64) - c
        return np.arctan2(np.einsum("kd,kd->k", d, b), np.einsum("kd,kd->k", d, n))


def cotangent_laplacian(vertices: np.ndarray, faces: np.ndarray) -> tuple[sp.csr_matrix, np.ndarray]:
    """Cotangent stiffness ``L (n, n)`` (positive semi-definite) and lumped vertex areas ``(n,)``.

    Cotangents are clamped to [-1e3, 1e3] (needle triangles).
    """
    v = np.asarray(vertices, dtype=np.float64)
    f = np.asarray(faces, dtype=np.int64)
    n = len(v)
    rows, cols, vals = [], [], []
    for k in range(3):
        i, j, o = f[:, (k + 1) % 3], f[:, (k + 2) % 3], f[:, k]
        a, b = v[i] - v[o], v[j] - v[o]
        cross = np.linalg.norm(np.cross(a, b), axis=1)
        cot = np.clip(np.einsum("kd,kd->k", a, b) / np.maximum(cross, 1e-300), -1e3, 1e3)
        w = 0.5 * cot
        rows += [i, j]
        cols += [j, i]
        vals += [w, w]
    W = sp.coo_matrix((np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))), shape=(n, n)).tocsr()
    L = sp.diags(np.asarray(W.sum(axis=1)).ravel()) - W
    area = np.zeros(n)
    np.add.at(area, f.reshape(-1), np.repeat(triangle_areas(v, f) / 3.0, 3))
    return L.tocsr(), area


def sweep_chart(vertices: np.ndarray, faces: np.ndarray, bins: int | None = None, weld_tol: float = 1e-9, reference: np.ndarray | None = None) -> SweepChart:
    """The sweep chart of a connected part mesh.

    Vertices split along UV seams are welded first (``weld_tol``, relative to the part's size), so
    the seams do not cut the part in two.

    Args:
        vertices: (n, 3) float64; faces: (m, 3) int64.
        bins: level sets of the Fiedler vector that make the centre line (default: from the
            vertex count, 8..128).
        reference: (3,) the direction angles are measured from (default: the world axis the
            centre line's tangents avoid most); give the template's to chart a shape like it.

    Raises:
        ValueError: fewer than 4 used vertices, non-finite input, more than
            :data:`MAX_CHART_VERTICES`, a part in several pieces, no surface.
    """
    v = np.asarray(vertices, dtype=np.float64)
    f = np.asarray(faces, dtype=np.int64)
    if v.ndim != 2 or v.shape[1] != 3 or f.ndim != 2 or f.shape[1] != 3 or len(f) == 0:
        raise ValueError(f"sweep chart needs vertices (n, 3) and faces (m >= 1, 3), got {v.shape} and {f.shape}")
    if f.min() < 0 or f.max() >= len(v):
        raise ValueError("sweep chart: face indices out of range")
    used = np.unique(f)
    if len(used) < 4:
        raise ValueError(f"sweep chart needs at least 4 vertices, got {len(used)}")
    if len(used) > MAX_CHART_VERTICES:
        raise ValueError(f"sweep chart: {len(used)} vertices, more than {MAX_CHART_VERTICES}")
    if not np.isfinite(v[used]).all():
        raise ValueError("sweep chart: vertices contain NaN or inf")
    size = float(np.ptp(v[used], axis=0).max())
    if not size > 0:
        raise ValueError("sweep chart: the part has no extent")
    # weld (UV seams), then compact to the used vertices
    rep = weld_all(v[used], weld_tol * size)
    keep, inv = np.unique(rep, return_inverse=True)
    pos = v[used][keep]
    lookup = np.full(len(v), -1, dtype=np.int64)
    lookup[used] = inv
    ff = lookup[f]
    ff = ff[(ff[:, 0] != ff[:, 1]) & (ff[:, 1] != ff[:, 2]) & (ff[:, 0] != ff[:, 2])]
    nv = len(pos)
    L, area = cotangent_laplacian(pos, ff)
    if not area.sum() > 0:
        raise ValueError("sweep chart: the part has no surface")
    adj = sp.coo_matrix((np.ones(3 * len(ff)), (ff.reshape(-1), np.roll(ff, 1, axis=1).reshape(-1))), shape=(nv, nv))
    ncomp, _ = connected_components(adj, directed=False)
    if ncomp != 1:
        raise ValueError(f"sweep chart: the part is in {ncomp} pieces; a chart needs one connected surface")
    mass = np.maximum(area, 1e-12 * area.max())
    M = sp.diags(mass)
    scale = float(mass.sum())  # eigenvalues scale as 1/area: shift relative to it
    # a fixed start vector: the solve is deterministic even where the eigenvalue is degenerate
    # (the two angular modes of a surface of revolution)
    v0 = np.random.default_rng(0).standard_normal(nv)
    evals, evecs = eigsh(L.tocsc(), k=2, M=M.tocsc(), sigma=-1e-3 / scale, which="LM", v0=v0)
    order = np.argsort(evals)
    fied = evecs[:, order[1]]
    lam = float(evals[order[1]])
    # level sets -> centre line; arc length of the centre line -> s
    b = int(bins) if bins else int(np.clip(nv // 20, 8, 128))
    # Vertices a symmetry makes equal (a ring of a surface of revolution) have Fiedler values equal
    # in exact arithmetic but apart by the eigensolver's last bits, and a bin edge falls among them:
    # which of them land in which level set, so the centre line itself, would depend on the CPU's
    # kernels. Values rounded to a grid far above that noise (1e-8 of the range; the solve is good to
    # ~1e-13) and far below any real spacing of level sets keep such vertices together.
    span = float(np.ptp(fied))
    if span > 0:
        grid = 1e-8 * span
        fied = np.round(fied / grid) * grid
    edges = np.quantile(fied, np.linspace(0.0, 1.0, b + 1))
    which = np.clip(np.searchsorted(edges, fied, side="right") - 1, 0, b - 1)
    wsum = np.bincount(which, weights=mass, minlength=b)
    ok = wsum > 0
    cent = np.stack([np.bincount(which, weights=mass * pos[:, j], minlength=b) for j in range(3)], axis=1)[ok] / wsum[ok, None]
    fmid = np.bincount(which, weights=mass * fied, minlength=b)[ok] / wsum[ok]
    # level sets whose centroids coincide (a symmetric part's middle) would repeat a knot
    distinct = np.concatenate([[True], np.linalg.norm(np.diff(cent, axis=0), axis=1) > 1e-9 * size])
    cent, fmid = cent[distinct], fmid[distinct]
    seg = np.linalg.norm(np.diff(cent, axis=0), axis=1)
    arc = np.concatenate([[0.0], np.cumsum(seg)])
    length = float(arc[-1])
    knots = arc / length if length > 0 else np.linspace(0.0, 1.0, len(arc))
    s_w = np.interp(fied, fmid, knots)
    # reference axis: the world axis the tangents avoid most
    tang = np.diff(cent, axis=0)
    tang /= np.maximum(np.linalg.norm(tang, axis=1, keepdims=True), 1e-300)
    weights = seg / max(seg.sum(), 1e-300)
    align = (weights[:, None] * tang**2).sum(axis=0) if len(tang) else np.zeros(3)
    if reference is None:
        # the first of the axes that tie for the least (a straight part avoids two equally): a
        # last-bit difference between them must not turn the chart by 90 degrees
        reference = np.eye(3)[int(np.flatnonzero(align <= align.min() + 1e-9)[0])]
    else:
        reference = np.asarray(reference, dtype=np.float64)
        if reference.shape != (3,) or not np.isfinite(reference).all() or not np.linalg.norm(reference) > 0:
            raise ValueError("sweep chart: reference must be a finite non-zero (3,) direction")
        reference = reference / np.linalg.norm(reference)
    chart = SweepChart(np.full(len(v), np.nan), np.full(len(v), np.nan), cent, knots, reference, length, 0.0, 0.0, lam)
    c, _, _, _ = chart.frame(s_w)
    dist = np.linalg.norm(pos - c, axis=1)
    radius = float(np.average(dist, weights=mass))
    # spread of the distances to the centre line within each level set: ~0 for a round tube
    lvl_mean = np.bincount(which, weights=mass * dist, minlength=b) / np.maximum(wsum, 1e-300)
    lvl_var = np.bincount(which, weights=mass * (dist - lvl_mean[which]) ** 2, minlength=b) / np.maximum(wsum, 1e-300)
    spread = float(np.average(np.sqrt(lvl_var[ok]) / np.maximum(lvl_mean[ok], 1e-300), weights=wsum[ok]))
    th = chart.angle(pos, s_w)
    chart.s[used] = s_w[inv]
    chart.theta[used] = th[inv]
    chart.radius = radius
    chart.tube_fit = float(area.sum() / max(2 * np.pi * radius * length, 1e-300))
    chart.spread = spread
    # winding of the centre line about the reference axis (through its mean)
    rel = cent - cent.mean(axis=0)
    u_ax = np.cross(reference, np.eye(3)[int(np.argmin(np.abs(reference)))])
    u_ax /= np.linalg.norm(u_ax)
    w_ax = np.cross(reference, u_ax)
    px, py = rel @ u_ax, rel @ w_ax
    rad = np.hypot(px, py)
    step = np.diff(np.unwrap(np.arctan2(py, px)))
    # a segment passing close to the axis (a straight part through its own middle) turns nothing
    near = np.maximum(rad[:-1], rad[1:]) < 0.2 * max(float(np.median(rad)), 1e-300)
    chart.turns = float(abs(step[~near].sum()) / (2 * np.pi)) if len(step) else 0.0
    return chart
