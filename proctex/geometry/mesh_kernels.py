"""Compiled (numba) kernels of a shape's segmentation (:func:`proctex.geometry.parts.segment`, run on
every served shape): :func:`connected_parts` by union-find over the faces in one pass instead of a
sparse graph's components, and :func:`triangle_areas` in one pass over the faces. Each gives the same
answer as its array form (:func:`proctex.geometry.parts.connected_parts_arrays`, the same parts
numbered the same way; :func:`proctex.geometry.surface.triangle_areas_arrays`, the same bits: the
same operations in the same order), which answers where numba does not import and which
``tests/test_parts.py`` compares them with. Imported on first use.
"""

from __future__ import annotations

import numpy as np
from numba import njit


@njit(cache=True, nogil=True)
def _find(parent, i):
    root = i
    while parent[root] != root:
        root = parent[root]
    while parent[i] != root:  # path compression
        parent[i], i = root, parent[i]
    return root


@njit(cache=True, nogil=True)
def _connected_parts(faces, n_vertices):
    m = faces.shape[0]
    parent = np.arange(n_vertices)
    for i in range(m):
        a = _find(parent, faces[i, 0])
        for k in range(1, 3):
            b = _find(parent, faces[i, k])
            if a != b:  # the lower root stays: the result does not depend on it
                if b < a:
                    a, b = b, a
                parent[b] = a
    label = np.full(n_vertices, -1, np.int64)  # per root: its part, numbered by first face
    face_part = np.empty(m, np.int64)
    count = 0
    for i in range(m):
        r = _find(parent, faces[i, 0])
        if label[r] < 0:
            label[r] = count
            count += 1
        face_part[i] = label[r]
    vertex_part = np.full(n_vertices, -1, np.int64)
    for i in range(m):
        for k in range(3):
            vertex_part[faces[i, k]] = face_part[i]
    return face_part, vertex_part, count


def connected_parts(faces: np.ndarray, n_vertices: int) -> tuple[np.ndarray, np.ndarray, int]:
    """``(face_part (m,) int64, vertex_part (n,) int64 with -1 for unreferenced, count)``: the
    components of the face-vertex graph by shared vertex index, numbered in order of their first
    face. ``faces (m, 3)`` int indices in ``[0, n_vertices)`` (``ValueError`` otherwise)."""
    f = np.ascontiguousarray(faces, dtype=np.int64)
    if f.ndim != 2 or f.shape[1] != 3:
        raise ValueError(f"faces must be (m, 3), got {f.shape}")
    if len(f) and (f.min() < 0 or f.max() >= n_vertices):
        raise ValueError(f"faces index vertices in [0, {n_vertices}), got [{f.min()}, {f.max()}]")
    face_part, vertex_part, count = _connected_parts(f, int(n_vertices))
    return face_part, vertex_part, int(count)


@njit(cache=True, nogil=True)
def _triangle_areas(v, f):
    m = f.shape[0]
    out = np.empty(m)
    for i in range(m):
        i0, i1, i2 = f[i, 0], f[i, 1], f[i, 2]
        e1x, e1y, e1z = v[i1, 0] - v[i0, 0], v[i1, 1] - v[i0, 1], v[i1, 2] - v[i0, 2]
        e2x, e2y, e2z = v[i2, 0] - v[i0, 0], v[i2, 1] - v[i0, 1], v[i2, 2] - v[i0, 2]
        nx, ny, nz = e1y * e2z - e1z * e2y, e1z * e2x - e1x * e2z, e1x * e2y - e1y * e2x
        out[i] = 0.5 * np.sqrt(nx * nx + ny * ny + nz * nz)
    return out


def checked_mesh(vertices: np.ndarray, faces: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``(vertices (n, 3) float64, faces (m, 3) int64)``, C-ordered, as the compiled kernels take
    them; ``ValueError`` for other shapes or faces indexing past the vertices."""
    v = np.ascontiguousarray(vertices, dtype=np.float64)
    f = np.ascontiguousarray(faces, dtype=np.int64)
    if v.ndim != 2 or v.shape[1] != 3 or f.ndim != 2 or f.shape[1] != 3:
        raise ValueError(f"vertices (n, 3) and faces (m, 3) expected, got {v.shape} and {f.shape}")
    if len(f) and (f.min() < 0 or f.max() >= len(v)):
        raise ValueError(f"faces index vertices 0..{len(v) - 1}, got {f.min()}..{f.max()}")
    return v, f


def triangle_areas(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """(m,) float64 areas of ``faces (m, 3)`` over ``vertices (n, 3)`` (:func:`checked_mesh`)."""
    return _triangle_areas(*checked_mesh(vertices, faces))


def warm() -> None:
    """Compile (or load from numba's cache) these kernels on a tetrahedron."""
    v = np.array([[0.0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]])
    f = np.array([[0, 1, 2], [0, 1, 3], [0, 2, 3], [1, 2, 3]])
    connected_parts(f, 5)
    triangle_areas(v, f)
