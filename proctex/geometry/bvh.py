"""The exact nearest triangle of many points, by a bounding-volume hierarchy compiled with numba
(:class:`TriangleTree`): what the run time's UV lookup asks per shape face
(:meth:`proctex.geometry.surface.SurfaceIndex.facing_faces`), a few thousand queries on a template
part of a few thousand triangles, where a call into libigl's tree cost about a microsecond per query
(measured on the demo family's parts: 8.7 ms of a 34 ms transfer; this tree: see
``tests/bench/bench_transfer.py``).

The tree splits the triangles by the binned surface-area heuristic (:func:`_sah_split`; the median
of their centroids along their longest axis where no bin separates them), down to :data:`LEAF`
triangles; a query walks it nearest box first and skips a box
farther than the best triangle so far. Ties go to the lowest face index, so the answer is exactly
the brute-force ``argmin`` of :func:`point_triangle_d2` over all faces (``tests/test_geometry.py``).
The kernels release the GIL (parts of one transfer run side by side in threads) and are cached on
disk by numba after their first compilation.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numba import njit

#: Triangles per leaf of the tree.
LEAF = 4

#: A box is skipped when farther than the best squared distance so far times this: a box's distance
#: and a triangle's are computed differently and may round a few ulps apart, and a box holding a
#: triangle exactly as near as the best must be opened for the tie to go to the lowest index
#: whatever the walk's order (the previous query's face, the split planes) found first.
SLACK = 1.0 + 1e-9


@njit(cache=True, nogil=True, inline="always")
def _d2(ax, ay, az, bx, by, bz, cx, cy, cz, px, py, pz):
    """Squared distance from point p to triangle abc (Ericson, Real-Time Collision Detection 5.1.5:
    the closest point by the Voronoi region of p); a degenerate triangle answers its nearest
    vertex or edge point as the regions fall."""
    abx, aby, abz = bx - ax, by - ay, bz - az
    acx, acy, acz = cx - ax, cy - ay, cz - az
    apx, apy, apz = px - ax, py - ay, pz - az
    d1 = abx * apx + aby * apy + abz * apz
    d2 = acx * apx + acy * apy + acz * apz
    if d1 <= 0.0 and d2 <= 0.0:
        qx, qy, qz = ax, ay, az
    else:
        bpx, bpy, bpz = px - bx, py - by, pz - bz
        d3 = abx * bpx + aby * bpy + abz * bpz
        d4 = acx * bpx + acy * bpy + acz * bpz
        if d3 >= 0.0 and d4 <= d3:
            qx, qy, qz = bx, by, bz
        else:
            vc = d1 * d4 - d3 * d2
            if vc <= 0.0 and d1 >= 0.0 and d3 <= 0.0 and d1 - d3 != 0.0:
                v = d1 / (d1 - d3)
                qx, qy, qz = ax + v * abx, ay + v * aby, az + v * abz
            else:
                cpx, cpy, cpz = px - cx, py - cy, pz - cz
                d5 = abx * cpx + aby * cpy + abz * cpz
                d6 = acx * cpx + acy * cpy + acz * cpz
                if d6 >= 0.0 and d5 <= d6:
                    qx, qy, qz = cx, cy, cz
                else:
                    vb = d5 * d2 - d1 * d6
                    if vb <= 0.0 and d2 >= 0.0 and d6 <= 0.0 and d2 - d6 != 0.0:
                        w = d2 / (d2 - d6)
                        qx, qy, qz = ax + w * acx, ay + w * acy, az + w * acz
                    else:
                        va = d3 * d6 - d5 * d4
                        if va <= 0.0 and (d4 - d3) >= 0.0 and (d5 - d6) >= 0.0 and (d4 - d3) + (d5 - d6) != 0.0:
                            w = (d4 - d3) / ((d4 - d3) + (d5 - d6))
                            qx, qy, qz = bx + w * (cx - bx), by + w * (cy - by), bz + w * (cz - bz)
                        else:
                            den = va + vb + vc
                            if den != 0.0:
                                v = vb / den
                                w = vc / den
                                qx, qy, qz = ax + abx * v + acx * w, ay + aby * v + acy * w, az + abz * v + acz * w
                            else:  # degenerate (a point or a line): its nearest vertex
                                da = apx * apx + apy * apy + apz * apz
                                db = bpx * bpx + bpy * bpy + bpz * bpz
                                dc = cpx * cpx + cpy * cpy + cpz * cpz
                                if da <= db and da <= dc:
                                    qx, qy, qz = ax, ay, az
                                elif db <= dc:
                                    qx, qy, qz = bx, by, bz
                                else:
                                    qx, qy, qz = cx, cy, cz
    dx, dy, dz = px - qx, py - qy, pz - qz
    return dx * dx + dy * dy + dz * dz


@njit(cache=True, nogil=True)
def point_triangle_d2(points, a, b, c):
    """(q, m) squared distances of ``points (q, 3)`` to triangles ``a, b, c (m, 3)`` (the brute-force
    reference of :meth:`TriangleTree.nearest`; the same function the tree uses)."""
    q, m = points.shape[0], a.shape[0]
    out = np.empty((q, m))
    for i in range(q):
        for j in range(m):
            out[i, j] = _d2(a[j, 0], a[j, 1], a[j, 2], b[j, 0], b[j, 1], b[j, 2], c[j, 0], c[j, 1], c[j, 2], points[i, 0], points[i, 1], points[i, 2])
    return out


#: Bins per axis of the surface-area heuristic (:func:`_sah_split`).
BINS = 16


@njit(cache=True, nogil=True, inline="always")
def _half_area(lo, hi):
    dx, dy, dz = max(hi[0] - lo[0], 0.0), max(hi[1] - lo[1], 0.0), max(hi[2] - lo[2], 0.0)
    return dx * dy + dy * dz + dz * dx


@njit(cache=True, nogil=True)
def _sah_split(lo_t, hi_t, cen, perm, s, e, cmin, cmax):
    """Partition ``perm[s:e]`` at the binned surface-area heuristic's best plane (the split whose
    children's areas times their triangle counts sum least, over :data:`BINS` bins of the centroids
    on each axis) and return the first index of the right child (``s`` or ``e``: no split found)."""
    best_cost, best_axis, best_bin = np.inf, -1, -1
    blo = np.empty((BINS, 3))
    bhi = np.empty((BINS, 3))
    cnt = np.zeros(BINS, np.int64)
    right_area = np.empty(BINS)
    right_cnt = np.zeros(BINS, np.int64)
    box_lo = np.empty(3)
    box_hi = np.empty(3)
    for axis in range(3):
        extent = cmax[axis] - cmin[axis]
        if not extent > 0.0:
            continue
        blo[:] = np.inf
        bhi[:] = -np.inf
        cnt[:] = 0
        for j in range(s, e):
            f = perm[j]
            k = min(int(BINS * (cen[f, axis] - cmin[axis]) / extent), BINS - 1)
            cnt[k] += 1
            for d in range(3):
                blo[k, d] = min(blo[k, d], lo_t[f, d])
                bhi[k, d] = max(bhi[k, d], hi_t[f, d])
        box_lo[:] = np.inf
        box_hi[:] = -np.inf
        n_right = 0
        for k in range(BINS - 1, 0, -1):  # right_area[k]: bins k.. together
            n_right += cnt[k]
            for d in range(3):
                box_lo[d] = min(box_lo[d], blo[k, d])
                box_hi[d] = max(box_hi[d], bhi[k, d])
            right_area[k], right_cnt[k] = _half_area(box_lo, box_hi), n_right
        box_lo[:] = np.inf
        box_hi[:] = -np.inf
        n_left = 0
        for k in range(BINS - 1):  # split between bins k and k + 1
            n_left += cnt[k]
            for d in range(3):
                box_lo[d] = min(box_lo[d], blo[k, d])
                box_hi[d] = max(box_hi[d], bhi[k, d])
            if n_left == 0 or right_cnt[k + 1] == 0:
                continue
            cost = _half_area(box_lo, box_hi) * n_left + right_area[k + 1] * right_cnt[k + 1]
            if cost < best_cost:
                best_cost, best_axis, best_bin = cost, axis, k
    if best_axis < 0:
        return s
    extent = cmax[best_axis] - cmin[best_axis]
    i, j = s, e - 1
    while i <= j:  # left: bins up to best_bin
        if min(int(BINS * (cen[perm[i], best_axis] - cmin[best_axis]) / extent), BINS - 1) <= best_bin:
            i += 1
        else:
            perm[i], perm[j] = perm[j], perm[i]
            j -= 1
    return i


@njit(cache=True, nogil=True)
def _build(lo_t, hi_t, cen, leaf):
    """The tree over triangles with boxes ``lo_t, hi_t (m, 3)`` and centroids ``cen (m, 3)``:
    ``(lo, hi (n, 3), left, right, start, count (n,), perm (m,))``; a leaf has ``left == -1`` and
    holds ``perm[start:start + count]``."""
    m = cen.shape[0]
    cap = max(1, 2 * m)
    lo = np.empty((cap, 3))
    hi = np.empty((cap, 3))
    left = np.full(cap, -1, np.int64)
    right = np.full(cap, -1, np.int64)
    start = np.zeros(cap, np.int64)
    count = np.zeros(cap, np.int64)
    perm = np.arange(m)
    stack = np.empty((128, 3), np.int64)
    stack[0, 0], stack[0, 1], stack[0, 2] = 0, 0, m
    sp, n = 1, 1
    while sp > 0:
        sp -= 1
        node, s, e = stack[sp, 0], stack[sp, 1], stack[sp, 2]
        for k in range(3):
            lo[node, k] = np.inf
            hi[node, k] = -np.inf
        cmin = np.full(3, np.inf)
        cmax = np.full(3, -np.inf)
        for j in range(s, e):
            f = perm[j]
            for k in range(3):
                lo[node, k] = min(lo[node, k], lo_t[f, k])
                hi[node, k] = max(hi[node, k], hi_t[f, k])
                cmin[k] = min(cmin[k], cen[f, k])
                cmax[k] = max(cmax[k], cen[f, k])
        axis = 0
        for k in range(1, 3):
            if cmax[k] - cmin[k] > cmax[axis] - cmin[axis]:
                axis = k
        start[node], count[node] = s, e - s
        if e - s <= leaf or not cmax[axis] > cmin[axis] or sp + 2 > stack.shape[0]:
            continue
        mid = _sah_split(lo_t, hi_t, cen, perm, s, e, cmin, cmax)
        if mid <= s or mid >= e:  # no binned split separates them: the median along the longest axis
            keys = np.empty(e - s)
            for j in range(s, e):
                keys[j - s] = cen[perm[j], axis]
            order = np.argsort(keys, kind="mergesort")
            perm[s:e] = perm[s:e][order]
            mid = (s + e) // 2
        left[node], right[node] = n, n + 1
        stack[sp, 0], stack[sp, 1], stack[sp, 2] = n, s, mid
        stack[sp + 1, 0], stack[sp + 1, 1], stack[sp + 1, 2] = n + 1, mid, e
        sp += 2
        n += 2
    return lo[:n].copy(), hi[:n].copy(), left[:n].copy(), right[:n].copy(), start[:n].copy(), count[:n].copy(), perm


@njit(cache=True, nogil=True, inline="always")
def _box_d2(lo, hi, node, px, py, pz):
    d = 0.0
    t = lo[node, 0] - px
    if t > 0.0:
        d += t * t
    t = px - hi[node, 0]
    if t > 0.0:
        d += t * t
    t = lo[node, 1] - py
    if t > 0.0:
        d += t * t
    t = py - hi[node, 1]
    if t > 0.0:
        d += t * t
    t = lo[node, 2] - pz
    if t > 0.0:
        d += t * t
    t = pz - hi[node, 2]
    if t > 0.0:
        d += t * t
    return d


@njit(cache=True, nogil=True)
def _nearest(points, a, b, c, lo, hi, left, right, start, count, perm, slot):
    """(q,) int64 nearest face of each point, ties to the lowest index; (q,) its squared distance."""
    q = points.shape[0]
    face = np.empty(q, np.int64)
    dist = np.empty(q)
    stack = np.empty(256, np.int64)
    for i in range(q):
        px, py, pz = points[i, 0], points[i, 1], points[i, 2]
        best, bf = np.inf, -1
        if i > 0:  # the previous point's face bounds the search (neighbouring queries land near each other)
            j = slot[face[i - 1]]
            best, bf = _d2(a[j, 0], a[j, 1], a[j, 2], b[j, 0], b[j, 1], b[j, 2], c[j, 0], c[j, 1], c[j, 2], px, py, pz), perm[j]
        stack[0] = 0
        sp = 1
        while sp > 0:
            sp -= 1
            node = stack[sp]
            if _box_d2(lo, hi, node, px, py, pz) > best * SLACK:
                continue
            if left[node] < 0:
                for j in range(start[node], start[node] + count[node]):  # a, b, c in leaf order
                    f = perm[j]
                    d = _d2(a[j, 0], a[j, 1], a[j, 2], b[j, 0], b[j, 1], b[j, 2], c[j, 0], c[j, 1], c[j, 2], px, py, pz)
                    if bf < 0 or d < best or (d == best and f < bf):
                        best, bf = d, f
                continue
            ln, rn = left[node], right[node]
            dl, dr = _box_d2(lo, hi, ln, px, py, pz), _box_d2(lo, hi, rn, px, py, pz)
            if dl <= dr:  # the nearer child is popped first
                if dr <= best * SLACK:
                    stack[sp] = rn
                    sp += 1
                if dl <= best * SLACK:
                    stack[sp] = ln
                    sp += 1
            else:
                if dl <= best * SLACK:
                    stack[sp] = ln
                    sp += 1
                if dr <= best * SLACK:
                    stack[sp] = rn
                    sp += 1
        face[i], dist[i] = bf, best
    return face, dist


@njit(cache=True, nogil=True)
def _facing_dots(normals, faces, nrm):
    q = faces.shape[0]
    dots = np.empty(q)
    zero = np.empty(q, np.bool_)
    for i in range(q):
        f = faces[i]
        dots[i] = (normals[f, 0] * nrm[i, 0] + normals[f, 1] * nrm[i, 1]) + normals[f, 2] * nrm[i, 2]
        zero[i] = nrm[i, 0] == 0.0 and nrm[i, 1] == 0.0 and nrm[i, 2] == 0.0
    return dots, zero


def facing_dots(normals: np.ndarray, faces: np.ndarray, query_normals: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``(dots (q,) float64, zero (q,) bool)``: each query normal ``query_normals (q, 3)`` against
    the normal of its face ``faces (q,)`` among ``normals (m, 3)`` (summed x, y, then z), and
    whether the query's normal is zero; one pass, nothing gathered. Checked inputs."""
    return _facing_dots(np.ascontiguousarray(normals, dtype=np.float64), np.ascontiguousarray(faces, dtype=np.int64), np.ascontiguousarray(query_normals, dtype=np.float64))


@dataclass(frozen=True)
class TriangleTree:
    """A triangle mesh's tree (:func:`triangle_tree`) for :meth:`nearest` queries."""

    a: np.ndarray  #: (m, 3) float64 first corners, in leaf order (``a[j]`` is face ``perm[j]``'s)
    b: np.ndarray
    c: np.ndarray
    lo: np.ndarray  #: (n, 3) node boxes
    hi: np.ndarray
    left: np.ndarray  #: (n,) int64 children (-1: a leaf)
    right: np.ndarray
    start: np.ndarray  #: (n,) int64 a leaf's range of ``perm``
    count: np.ndarray
    perm: np.ndarray  #: (m,) int64 faces in leaf order
    slot: np.ndarray  #: (m,) int64 each face's place in leaf order (``perm[slot[f]] == f``)

    def nearest(self, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``(face (q,) int64, squared distance (q,) float64)``: the nearest face of each of
        ``points (q, 3)`` (ties to the lowest face index). Raises ValueError for points not
        (q, 3) and finite, or a tree with no faces."""
        pts = np.ascontiguousarray(points, dtype=np.float64)
        if pts.ndim != 2 or pts.shape[1] != 3:
            raise ValueError(f"points must be (q, 3), got {pts.shape}")
        if not np.isfinite(pts).all():
            raise ValueError("points must be finite")
        if not len(self.a):
            raise ValueError("a tree of no faces has no nearest face")
        return self.walk(pts)

    def walk(self, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """:meth:`nearest` for points its caller has checked: (q, 3) C-ordered float64, finite, and a
        tree with faces (``SurfaceIndex`` checks them once for its own queries)."""
        return _nearest(points, self.a, self.b, self.c, self.lo, self.hi, self.left, self.right, self.start, self.count, self.perm, self.slot)


def triangle_tree(vertices: np.ndarray, faces: np.ndarray, leaf: int = LEAF) -> TriangleTree:
    """The :class:`TriangleTree` of a mesh (``vertices (n, 3)`` finite, ``faces (m, 3)`` int indices
    into them; ``leaf`` >= 1 triangles per leaf). Raises ValueError otherwise."""
    v = np.asarray(vertices, dtype=np.float64)
    f = np.asarray(faces)
    if v.ndim != 2 or v.shape[1] != 3 or not np.isfinite(v).all():
        raise ValueError(f"vertices must be (n, 3) and finite, got {v.shape}")
    if f.ndim != 2 or f.shape[1] != 3 or not np.issubdtype(f.dtype, np.integer):
        raise ValueError(f"faces must be (m, 3) integers, got {f.shape} {f.dtype}")
    if len(f) and (f.min() < 0 or f.max() >= len(v)):
        raise ValueError(f"faces index vertices 0..{len(v) - 1}, got {f.min()}..{f.max()}")
    if int(leaf) < 1:
        raise ValueError(f"leaf must be >= 1, got {leaf}")
    tri = v[f.astype(np.int64)]
    lo, hi, left, right, start, count, perm = _build(tri.min(axis=1), tri.max(axis=1), tri.mean(axis=1), int(leaf))
    slot = np.empty_like(perm)
    slot[perm] = np.arange(len(perm))
    a, b, c = (np.ascontiguousarray(tri[perm, k]) for k in range(3))
    return TriangleTree(a, b, c, lo, hi, left, right, start, count, perm, slot)


def warm() -> None:
    """Compile (or load from numba's cache) the tree's kernels on a tetrahedron: a process that
    serves calls this at start, so no request pays it."""
    v = np.array([[0.0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]])
    tree = triangle_tree(v, np.array([[0, 1, 2], [0, 1, 3], [0, 2, 3], [1, 2, 3]]))
    tree.nearest(np.array([[0.2, 0.2, 0.2]]))
    facing_dots(np.eye(3), np.zeros(1, np.int64), np.ones((1, 3)))
