"""Compiled (numba) kernels of the GLB's vertex data: :func:`key_tangents`, :func:`area_normals`,
:func:`vertex_normals`, :func:`split_pairs` (the split vertices) and :func:`gather_corners` in a
pass or two over the faces instead of some forty array passes or two sorts, the same bits as their
array forms in :mod:`proctex.texture.pbr` and :mod:`proctex.texture.export` (the references
``tests/test_pbr.py`` compares them with): the same operations in the same order, each sum taking
its corners in corner order as ``np.bincount`` does. Imported on first use (numba's import and, on
a machine's first run, its compilation, which it caches on disk, are not paid by commands that
write no GLB).
"""

from __future__ import annotations

import numpy as np
from numba import njit

from proctex.geometry.mesh_kernels import checked_mesh


@njit(cache=True, nogil=True)
def _key_tangents(v, f, uv, keys, key_normals, normals, has_normals):
    m = f.shape[0]
    n_keys = key_normals.shape[0]
    T = np.zeros((n_keys, 3))
    B = np.zeros((n_keys, 3))
    for i in range(m):
        i0, i1, i2 = f[i, 0], f[i, 1], f[i, 2]
        e1x, e1y, e1z = v[i1, 0] - v[i0, 0], v[i1, 1] - v[i0, 1], v[i1, 2] - v[i0, 2]
        e2x, e2y, e2z = v[i2, 0] - v[i0, 0], v[i2, 1] - v[i0, 1], v[i2, 2] - v[i0, 2]
        d1u, d1v = uv[i, 1, 0] - uv[i, 0, 0], uv[i, 1, 1] - uv[i, 0, 1]
        d2u, d2v = uv[i, 2, 0] - uv[i, 0, 0], uv[i, 2, 1] - uv[i, 0, 1]
        det = d1u * d2v - d2u * d1v
        r = 1.0 / det if abs(det) > 1e-20 else 0.0
        tx, ty, tz = (e1x * d2v - e2x * d1v) * r, (e1y * d2v - e2y * d1v) * r, (e1z * d2v - e2z * d1v) * r
        bx, by, bz = (e2x * d1u - e1x * d2u) * r, (e2y * d1u - e1y * d2u) * r, (e2z * d1u - e1z * d2u) * r
        if has_normals:
            nx, ny, nz = normals[i, 0], normals[i, 1], normals[i, 2]
        else:
            nx, ny, nz = e1y * e2z - e1z * e2y, e1z * e2x - e1x * e2z, e1x * e2y - e1y * e2x
        area = 0.5 * np.sqrt(nx * nx + ny * ny + nz * nz)
        length = np.sqrt(tx * tx + ty * ty + tz * tz)
        s = area / (length if length > 1e-30 else 1.0)
        tx, ty, tz = tx * s, ty * s, tz * s
        length = np.sqrt(bx * bx + by * by + bz * bz)
        s = area / (length if length > 1e-30 else 1.0)
        bx, by, bz = bx * s, by * s, bz * s
        for c in range(3):
            k = keys[3 * i + c]
            T[k, 0] += tx
            T[k, 1] += ty
            T[k, 2] += tz
            B[k, 0] += bx
            B[k, 1] += by
            B[k, 2] += bz
    out = np.empty((n_keys, 4))
    for k in range(n_keys):
        nx, ny, nz = key_normals[k, 0], key_normals[k, 1], key_normals[k, 2]
        d = T[k, 0] * nx + T[k, 1] * ny + T[k, 2] * nz
        tx, ty, tz = T[k, 0] - nx * d, T[k, 1] - ny * d, T[k, 2] - nz * d
        length = np.sqrt(tx * tx + ty * ty + tz * tz)
        if length < 1e-12:  # no UV extent: any direction in the tangent plane
            if abs(nx) < 0.9:
                hx, hy, hz = 1.0, 0.0, 0.0
            else:
                hx, hy, hz = 0.0, 1.0, 0.0
            d = hx * nx + hy * ny + hz * nz
            tx, ty, tz = hx - nx * d, hy - ny * d, hz - nz * d
            length = np.sqrt(tx * tx + ty * ty + tz * tz)
        length = max(length, 1e-300)
        tx, ty, tz = tx / length, ty / length, tz / length
        cx, cy, cz = ny * tz - nz * ty, nz * tx - nx * tz, nx * ty - ny * tx
        out[k, 0], out[k, 1], out[k, 2] = tx, ty, tz
        out[k, 3] = -1.0 if cx * B[k, 0] + cy * B[k, 1] + cz * B[k, 2] < 0 else 1.0
    return out


def key_tangents(vertices: np.ndarray, faces: np.ndarray, corner_uv: np.ndarray, keys: np.ndarray, key_normals: np.ndarray, normals: np.ndarray | None = None) -> np.ndarray:
    """:func:`proctex.texture.pbr.key_tangents` compiled: ``(k, 4)`` float64 tangent frames of the
    (vertex, UV) pairs, the same bits as the array form. Checked inputs: ``vertices (n, 3)``,
    ``faces (m, 3)`` indexing them, ``corner_uv (m, 3, 2)``, ``keys (3m,)`` in ``[0, k)``,
    ``key_normals (k, 3)``, ``normals (m, 3)`` or None."""
    v = np.ascontiguousarray(vertices, dtype=np.float64)
    f = np.ascontiguousarray(faces, dtype=np.int64)
    uv = np.ascontiguousarray(corner_uv, dtype=np.float64)
    key = np.ascontiguousarray(keys, dtype=np.int64).reshape(-1)
    kn = np.ascontiguousarray(key_normals, dtype=np.float64)
    fn = np.zeros((0, 3)) if normals is None else np.ascontiguousarray(normals, dtype=np.float64)
    m = len(f)
    if v.ndim != 2 or v.shape[1] != 3 or f.ndim != 2 or f.shape[1] != 3 or uv.shape != (m, 3, 2) or kn.ndim != 2 or kn.shape[1] != 3:
        raise ValueError(f"vertices (n, 3), faces (m, 3), corner_uv (m, 3, 2), key_normals (k, 3) expected, got {v.shape}, {f.shape}, {uv.shape}, {kn.shape}")
    if key.shape != (3 * m,) or (normals is not None and fn.shape != (m, 3)):
        raise ValueError(f"keys ({3 * m},) and normals ({m}, 3) expected, got {key.shape} and {fn.shape}")
    if m and (f.min() < 0 or f.max() >= len(v) or key.min() < 0 or key.max() >= len(kn)):
        raise ValueError("faces must index the vertices and keys the key normals")
    return _key_tangents(v, f, uv, key, kn, fn, normals is not None)


@njit(cache=True, nogil=True)
def _area_normals(v, f):
    m = f.shape[0]
    out = np.empty((m, 3))
    for i in range(m):
        i0, i1, i2 = f[i, 0], f[i, 1], f[i, 2]
        e1x, e1y, e1z = v[i1, 0] - v[i0, 0], v[i1, 1] - v[i0, 1], v[i1, 2] - v[i0, 2]
        e2x, e2y, e2z = v[i2, 0] - v[i0, 0], v[i2, 1] - v[i0, 1], v[i2, 2] - v[i0, 2]
        out[i, 0], out[i, 1], out[i, 2] = e1y * e2z - e1z * e2y, e1z * e2x - e1x * e2z, e1x * e2y - e1y * e2x
    return out


@njit(cache=True, nogil=True)
def _vertex_normals(n, f, fn):
    acc = np.zeros((n, 3))
    for i in range(f.shape[0]):
        for c in range(3):
            k = f[i, c]
            acc[k, 0] += fn[i, 0]
            acc[k, 1] += fn[i, 1]
            acc[k, 2] += fn[i, 2]
    for k in range(n):
        length = np.sqrt(acc[k, 0] * acc[k, 0] + acc[k, 1] * acc[k, 1] + acc[k, 2] * acc[k, 2])
        if length > 0:
            acc[k, 0], acc[k, 1], acc[k, 2] = acc[k, 0] / length, acc[k, 1] / length, acc[k, 2] / length
        else:
            acc[k, 0], acc[k, 1], acc[k, 2] = 0.0, 0.0, 1.0
    return acc


def area_normals(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """:func:`proctex.texture.pbr.area_normals` compiled: (m, 3) float64, the same bits."""
    return _area_normals(*checked_mesh(vertices, faces))


def vertex_normals(vertices: np.ndarray, faces: np.ndarray, normals: np.ndarray | None = None) -> np.ndarray:
    """:func:`proctex.texture.pbr.vertex_normals` compiled: (n, 3) float64, the same bits."""
    v, f = checked_mesh(vertices, faces)
    fn = _area_normals(v, f) if normals is None else np.ascontiguousarray(normals, dtype=np.float64)
    if fn.shape != (len(f), 3):
        raise ValueError(f"normals ({len(f)}, 3) expected, got {fn.shape}")
    return _vertex_normals(len(v), f, fn)


@njit(cache=True, nogil=True)
def _gather_corners(F, UV, fn, order, row_faces, row_textured, n):
    k = order.shape[0]
    f_o = np.empty((k, 3), np.int64)
    uv_o = np.empty((k, 3, 2))
    fn_o = np.empty((k, 3))
    keys = np.empty(3 * k, np.int64)
    st = np.empty((3 * k, 2), np.float32)
    zero = np.float32(0.0)
    i = 0
    for row in range(row_faces.shape[0]):
        for _ in range(row_faces[row]):
            o = order[i]
            for c in range(3):
                v = F[o, c]
                f_o[i, c] = v
                keys[3 * i + c] = row * n + v
                u, w = UV[o, c, 0], UV[o, c, 1]
                uv_o[i, c, 0], uv_o[i, c, 1] = u, w
                if row_textured[row]:  # stored texcoords: v flipped, in float32, -0.0 made +0.0
                    st[3 * i + c, 0], st[3 * i + c, 1] = np.float32(u) + zero, np.float32(1.0 - w) + zero
                else:
                    st[3 * i + c, 0], st[3 * i + c, 1] = zero, zero
            fn_o[i, 0], fn_o[i, 1], fn_o[i, 2] = fn[o, 0], fn[o, 1], fn[o, 2]
            i += 1
    return f_o, uv_o, fn_o, keys, st


def gather_corners(faces: np.ndarray, corner_uv: np.ndarray, normals: np.ndarray, order: np.ndarray, row_faces: np.ndarray, row_textured: np.ndarray, n: int) -> tuple[np.ndarray, ...]:
    """The faces ``order (k,)`` of a GLB's primitives one after the other (``row_faces (r,)`` of
    them per primitive, ``row_textured (r,)`` whether it has texcoords), in one pass:
    ``(faces (k, 3) int64, corner_uv (k, 3, 2), normals (k, 3), keys (3k,) int64, st (3k, 2)
    float32)``, the first three gathered from ``faces``, ``corner_uv`` and ``normals``, ``keys``
    each corner's ``primitive * n + vertex`` and ``st`` its stored texcoord ``(u, 1 - v)`` (+0.0 for
    an untextured primitive's corners, and for -0.0): the same values as the array form in
    :func:`proctex.texture.export._primitive_arrays`. Checked inputs (``sum(row_faces) == k``)."""
    if int(np.sum(row_faces)) != len(order):
        raise ValueError(f"row_faces must add up to the {len(order)} faces, got {int(np.sum(row_faces))}")
    return _gather_corners(
        np.ascontiguousarray(faces, dtype=np.int64),
        np.ascontiguousarray(corner_uv, dtype=np.float64),
        np.ascontiguousarray(normals, dtype=np.float64),
        np.ascontiguousarray(order, dtype=np.int64),
        np.ascontiguousarray(row_faces, dtype=np.int64),
        np.ascontiguousarray(row_textured, dtype=np.bool_),
        int(n),
    )


@njit(cache=True, nogil=True)
def _split_pairs(source, value, n_sources):
    n = len(source)
    start = np.zeros(n_sources + 1, np.int64)
    for i in range(n):
        start[source[i] + 1] += 1
    for s in range(n_sources):
        start[s + 1] += start[s]
    fill = start[:-1].copy()
    order = np.empty(n, np.int64)
    for i in range(n):  # corners bucketed by source, in corner order within a bucket
        order[fill[source[i]]] = i
        fill[source[i]] += 1
    inv = np.empty(n, np.int64)
    pair_source = np.empty(n, np.int64)
    pair_value = np.empty(n, np.int64)
    u = 0
    for s in range(n_sources):
        a, b = start[s], start[s + 1]
        if b - a > 16:  # a vertex on many faces of one primitive: a real sort
            rows = order[a:b]
            order[a:b] = rows[np.argsort(value[rows], kind="mergesort")]
        else:  # the usual handful of corners: insertion sort by value
            for j in range(a + 1, b):
                c = order[j]
                k = j - 1
                while k >= a and value[order[k]] > value[c]:
                    order[k + 1] = order[k]
                    k -= 1
                order[k + 1] = c
        for j in range(a, b):
            c = order[j]
            if j == a or value[c] != value[order[j - 1]]:
                pair_source[u] = s
                pair_value[u] = value[c]
                u += 1
            inv[c] = u - 1
    return pair_source[:u].copy(), pair_value[:u].copy(), inv


def split_pairs(source: np.ndarray, value: np.ndarray, n_sources: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The distinct ``(source, value)`` pairs of the corners, sorted by source then value (as
    ``np.unique`` sorts them), and each corner's pair: a counting sort by ``source`` and a few
    comparisons per source instead of two full sorts.

    Args: source (N,) int64 in ``[0, n_sources)``; value (N,) int64 (compared as signed integers:
    the bits of a texcoord pair). Returns ``(pair_source (U,), pair_value (U,), inverse (N,))``,
    all int64; ``ValueError`` for a source out of range or arrays of other lengths."""
    src = np.ascontiguousarray(source, dtype=np.int64).reshape(-1)
    val = np.ascontiguousarray(value, dtype=np.int64).reshape(-1)
    if len(src) != len(val):
        raise ValueError(f"source and value must have one entry per corner, got {len(src)} and {len(val)}")
    if len(src) and (src.min() < 0 or src.max() >= n_sources):
        raise ValueError(f"sources must lie in [0, {n_sources}), got [{src.min()}, {src.max()}]")
    return _split_pairs(src, val, int(n_sources))


def warm() -> None:
    """Compile (or load from numba's cache) these kernels on a tetrahedron (see
    :func:`proctex.geometry.bvh.warm`)."""
    v = np.array([[0.0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]])
    f = np.array([[0, 1, 2], [0, 1, 3], [0, 2, 3], [1, 2, 3]])
    uv = np.tile(np.array([[0.0, 0.0], [1.0, 0.0], [0.0, 1.0]]), (4, 1, 1))
    fn = area_normals(v, f)
    vn = vertex_normals(v, f, fn)
    key_tangents(v, f, uv, f.reshape(-1), vn, fn)  # one signature with the faces' normals given or not
    split_pairs(f.reshape(-1), np.zeros(12, np.int64), 4)
    gather_corners(f, uv, fn, np.arange(4), np.array([3, 1]), np.array([True, False]), 4)
