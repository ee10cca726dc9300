"""Compiled (numba) kernels of the run time's UV lookup (:func:`proctex.transfer.uvlookup.part_uvs`):
each face's three corner UVs through its template triangle's affine map, clipped to [0, 1], in one
pass over the faces instead of some thirty array passes, the faces' centroids and the one-test
proof that a face reads only its chart (:func:`inside_rooms`); the same
operations in the same order as the array forms (:func:`proctex.transfer.uvlookup.affine_corner_uvs_arrays`,
``points[faces].mean(axis=1)``, which ``tests/test_transfer.py`` compares them with). Imported on first use, as
:mod:`proctex.texture.vertex_kernels` is.
"""

from __future__ import annotations

import numpy as np
from numba import njit


@njit(cache=True, nogil=True)
def _corner_uvs(mapped, faces, tv, tf, tuv, near):
    k = faces.shape[0]
    out = np.empty((k, 3, 2))
    for i in range(k):
        t = near[i]
        ia, ib, ic = tf[t, 0], tf[t, 1], tf[t, 2]
        ax, ay, az = tv[ia, 0], tv[ia, 1], tv[ia, 2]
        e1x, e1y, e1z = tv[ib, 0] - ax, tv[ib, 1] - ay, tv[ib, 2] - az
        e2x, e2y, e2z = tv[ic, 0] - ax, tv[ic, 1] - ay, tv[ic, 2] - az
        d11 = e1x * e1x + e1y * e1y + e1z * e1z
        d12 = e1x * e2x + e1y * e2y + e1z * e2z
        d22 = e2x * e2x + e2y * e2y + e2z * e2z
        den = d11 * d22 - d12 * d12
        if not abs(den) > 1e-30:
            den = np.inf
        for c in range(3):
            p = faces[i, c]
            dx, dy, dz = mapped[p, 0] - ax, mapped[p, 1] - ay, mapped[p, 2] - az
            p1 = dx * e1x + dy * e1y + dz * e1z
            p2 = dx * e2x + dy * e2y + dz * e2z
            l1 = (d22 * p1 - d12 * p2) / den
            l2 = (d11 * p2 - d12 * p1) / den
            l0 = 1 - l1 - l2
            for j in range(2):
                u = l0 * tuv[t, 0, j] + l1 * tuv[t, 1, j] + l2 * tuv[t, 2, j]
                out[i, c, j] = min(max(u, 0.0), 1.0)
    return out


@njit(cache=True, nogil=True)
def _centroids(points, faces):
    k = faces.shape[0]
    out = np.empty((k, 3))
    for i in range(k):
        a, b, c = faces[i, 0], faces[i, 1], faces[i, 2]
        for d in range(3):
            out[i, d] = (points[a, d] + points[b, d] + points[c, d]) / 3.0
    return out


def face_centroids(points: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """(k, 3) centroids of faces ``(k, 3)`` over ``points (j, 3)``: ``points[faces].mean(axis=1)``,
    the same bits (NumPy's mean adds the three corners in order, then divides by 3)."""
    return _centroids(np.ascontiguousarray(points, dtype=np.float64), np.ascontiguousarray(faces, dtype=np.int64))


@njit(cache=True, nogil=True)
def _rooms_inside(corner_uv, box, room, near, height, width):
    k = corner_uv.shape[0]
    out = np.empty(k, np.bool_)
    for i in range(k):
        t = near[i]
        d = -np.inf
        for c in range(3):
            r = (1.0 - corner_uv[i, c, 1]) * height - 0.5
            q = corner_uv[i, c, 0] * width - 0.5
            d = max(d, max(max(box[t, 0] - r, r - box[t, 1]), max(box[t, 2] - q, q - box[t, 3])))
        out[i] = np.ceil(max(d, 0.0)) <= room[t]
    return out


def inside_rooms(corner_uv: np.ndarray, box: np.ndarray, room: np.ndarray, near: np.ndarray, height: int, width: int) -> np.ndarray:
    """(k,) bool: :func:`proctex.transfer.uvlookup._inside_rooms` in one pass (``box (F, 4)`` and
    ``room (F,)`` of the template faces, :class:`~proctex.transfer.uvlookup.FaceRooms`); finite UVs."""
    return _rooms_inside(
        np.ascontiguousarray(corner_uv, dtype=np.float64),
        np.ascontiguousarray(box, dtype=np.float64),
        np.ascontiguousarray(room, dtype=np.int64),
        np.ascontiguousarray(near, dtype=np.int64),
        float(height),
        float(width),
    )


@njit(cache=True, nogil=True)
def _first_texel(u, v, height, width):
    """Row-major index of the first texel a bilinear lookup at ``(u, v)`` reads
    (:func:`proctex.texture.uv.bilinear_corner`)."""
    i0 = min(max(np.floor((1.0 - v) * height - 0.5), 0.0), height - 1.0)
    j0 = min(max(np.floor(u * width - 0.5), 0.0), width - 1.0)
    return int(i0) * int(width) + int(j0)


@njit(cache=True, nogil=True)
def _chart_inside(tri, chart, block_label, block_room, block_count, use_count, grid, height, width, leaf, max_level):
    k = tri.shape[0]
    w = int(width)
    ok = np.ones(k, np.bool_)
    cap = 4 * (max_level + 2)
    stack = np.empty((cap, 3, 2))
    depth = np.empty(cap, np.int64)
    size = np.empty(cap)
    for i in range(k):
        c = chart[i]
        if use_count:  # the whole UV box at once (uvlookup._inside_box)
            rmin, rmax, cmin, cmax = np.inf, -np.inf, np.inf, -np.inf
            for q in range(3):
                r = (1.0 - tri[i, q, 1]) * height - 0.5
                col = tri[i, q, 0] * width - 0.5
                rmin, rmax, cmin, cmax = min(rmin, r), max(rmax, r), min(cmin, col), max(cmax, col)
            i0 = int(min(max(np.floor(rmin), 0.0), height - 1.0))
            j0 = int(min(max(np.floor(cmin), 0.0), width - 1.0))
            i1 = int(min(max(np.floor(rmax), 0.0), height - 1.0)) + 1
            j1 = int(min(max(np.floor(cmax), 0.0), width - 1.0)) + 1
            count = block_count[i1, j1] - block_count[i0, j1] - block_count[i1, j0] + block_count[i0, j0]
            if count == (i1 - i0) * (j1 - j0) and block_label[i0 * w + j0] == c:
                continue
        e2 = 0.0
        for q in range(3):
            dx = (tri[i, q, 0] - tri[i, (q + 1) % 3, 0]) * width
            dy = (tri[i, q, 1] - tri[i, (q + 1) % 3, 1]) * height
            e2 = max(e2, dx * dx + dy * dy)
        stack[0] = tri[i]
        depth[0], size[0] = 0, np.sqrt(e2)
        sp = 1
        while sp > 0:  # the sub-triangles, depth first; the face fails at its first failing one
            sp -= 1
            a0, a1 = stack[sp, 0, 0], stack[sp, 0, 1]
            b0, b1 = stack[sp, 1, 0], stack[sp, 1, 1]
            c0, c1 = stack[sp, 2, 0], stack[sp, 2, 1]
            level, edge = depth[sp], size[sp]
            inside = True
            least = np.iinfo(np.int64).max
            for j in range(grid.shape[0]):
                u = (grid[j, 0] * a0 + grid[j, 1] * b0) + grid[j, 2] * c0
                v = (grid[j, 0] * a1 + grid[j, 1] * b1) + grid[j, 2] * c1
                t = _first_texel(u, v, height, width)
                if block_label[t] != c:
                    inside = False
                least = min(least, np.int64(block_room[t]))
            if not inside:
                ok[i] = False
                break
            if least >= np.ceil(edge / 2):
                continue
            if edge <= leaf or level >= max_level:  # at the rim, or not settled within max_level splits
                ok[i] = False
                break
            ab0, ab1 = (a0 + b0) / 2, (a1 + b1) / 2
            bc0, bc1 = (b0 + c0) / 2, (b1 + c1) / 2
            ca0, ca1 = (c0 + a0) / 2, (c1 + a1) / 2
            for child in range(4):  # uvlookup._subdivide's children
                if child == 0:
                    p = (a0, a1, ab0, ab1, ca0, ca1)
                elif child == 1:
                    p = (ab0, ab1, b0, b1, bc0, bc1)
                elif child == 2:
                    p = (ca0, ca1, bc0, bc1, c0, c1)
                else:
                    p = (ab0, ab1, bc0, bc1, ca0, ca1)
                stack[sp, 0, 0], stack[sp, 0, 1], stack[sp, 1, 0], stack[sp, 1, 1], stack[sp, 2, 0], stack[sp, 2, 1] = p
                depth[sp], size[sp] = level + 1, edge / 2
                sp += 1
    return ok


def inside_chart(
    corner_uv: np.ndarray, chart: np.ndarray, block_label: np.ndarray, block_room: np.ndarray, block_count: np.ndarray | None, grid: np.ndarray, height: int, width: int, leaf: float, max_level: int
) -> np.ndarray:
    """(k,) bool: :func:`proctex.transfer.uvlookup._inside_chart` of faces with finite UVs
    ``corner_uv (k, 3, 2)`` and charts ``chart (k,)`` over a :class:`~proctex.transfer.uvlookup.ChartLookup`'s
    arrays, in one pass: each face's box test, then its sub-triangles depth first (the array form
    goes level by level; a face fails when any of its sub-triangles fails either way), the probes
    ``grid (p, 3)`` barycentric, summed in the same order."""
    count = np.zeros((1, 1), np.int32) if block_count is None else np.ascontiguousarray(block_count, dtype=np.int32)
    return _chart_inside(
        np.ascontiguousarray(corner_uv, dtype=np.float64),
        np.ascontiguousarray(chart, dtype=np.int64),
        np.ascontiguousarray(block_label, dtype=np.int32),
        np.ascontiguousarray(block_room, dtype=np.int32),
        count,
        block_count is not None,
        np.ascontiguousarray(grid, dtype=np.float64),
        float(height),
        float(width),
        float(leaf),
        int(max_level),
    )


@njit(cache=True, nogil=True)
def _disoccluded(corner_uv, face_group, group, observed):
    h, w = observed.shape
    n = 0
    for i in range(corner_uv.shape[0]):
        if face_group[i] != group:
            continue
        u = (corner_uv[i, 0, 0] + corner_uv[i, 1, 0] + corner_uv[i, 2, 0]) / 3
        v = (corner_uv[i, 0, 1] + corner_uv[i, 1, 1] + corner_uv[i, 2, 1]) / 3
        t = _first_texel(u, v, float(h), float(w))
        i0, j0 = t // w, t % w
        i1, j1 = min(i0 + 1, h - 1), min(j0 + 1, w - 1)
        if not (observed[i0, j0] and observed[i0, j1] and observed[i1, j0] and observed[i1, j1]):
            n += 1
    return n


def disoccluded_faces(corner_uv: np.ndarray, face_group: np.ndarray, group: int, observed: np.ndarray) -> int:
    """How many faces of ``group`` (``face_group (k,)``) read, at the centre of their UVs
    ``corner_uv (k, 3, 2)`` (finite), a texel outside ``observed (H, W)`` bool: the count of
    :func:`proctex.transfer.apply.disoccluded_texels` over those faces' corner means, in one pass."""
    return int(_disoccluded(np.ascontiguousarray(corner_uv, dtype=np.float64), np.ascontiguousarray(face_group, dtype=np.int64), int(group), np.ascontiguousarray(observed, dtype=np.bool_)))


def affine_corner_uvs(mapped: np.ndarray, faces: np.ndarray, vertices: np.ndarray, template_faces: np.ndarray, corner_uv: np.ndarray, near: np.ndarray) -> np.ndarray:
    """(k, 3, 2) corner UVs of a part's faces: see :func:`proctex.transfer.uvlookup.affine_corner_uvs_arrays`."""
    return _corner_uvs(
        np.ascontiguousarray(mapped, dtype=np.float64),
        np.ascontiguousarray(faces, dtype=np.int64),
        np.ascontiguousarray(vertices, dtype=np.float64),
        np.ascontiguousarray(template_faces, dtype=np.int64),
        np.ascontiguousarray(corner_uv, dtype=np.float64),
        np.ascontiguousarray(near, dtype=np.int64),
    )


def warm() -> None:
    """Compile (or load from numba's cache) the kernel on one triangle (see :func:`proctex.geometry.bvh.warm`)."""
    v = np.array([[0.0, 0, 0], [1, 0, 0], [0, 1, 0]])
    f = np.array([[0, 1, 2]])
    affine_corner_uvs(v, f, v, f, np.array([[[0.0, 0.0], [1.0, 0.0], [0.0, 1.0]]]), np.zeros(1, np.int64))
    face_centroids(v, f)
    disoccluded_faces(np.zeros((1, 3, 2)), np.zeros(1, np.int64), 0, np.ones((2, 2), bool))
    inside_rooms(np.zeros((1, 3, 2)), np.zeros((1, 4)), np.zeros(1, np.int64), np.zeros(1, np.int64), 4, 4)
    tri = np.array([[[0.1, 0.1], [0.9, 0.1], [0.1, 0.9]]])
    for count in (None, np.zeros((5, 5), np.int32)):
        inside_chart(tri, np.ones(1, np.int64), np.ones(16, np.int32), np.zeros(16, np.int32), count, np.full((1, 3), 1.0 / 3.0), 4, 4, 2.0, 2)
