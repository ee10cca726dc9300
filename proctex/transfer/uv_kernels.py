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
def _disoccluded(corner_uv, face_group, group, observed):
    h, w = observed.shape
    n = 0
    for i in range(corner_uv.shape[0]):
        if face_group[i] != group:
            continue
        u = (corner_uv[i, 0, 0] + corner_uv[i, 1, 0] + corner_uv[i, 2, 0]) / 3
        v = (corner_uv[i, 0, 1] + corner_uv[i, 1, 1] + corner_uv[i, 2, 1]) / 3
        i0 = min(max(int(np.floor((1.0 - v) * h - 0.5)), 0), h - 1)
        j0 = min(max(int(np.floor(u * w - 0.5)), 0), w - 1)
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
