"""Mesh I/O (OBJ, PLY, STL, GLB/glTF) that keeps the source's connectivity (docs/correspondence.md).

Parts are connected components by *shared vertex indices*, so the loader never welds by position
unless the file gives it no choice:

- OBJ is parsed here by vertex (``v``) index only; ``vt``/``vn`` indices are ignored, so an OBJ with
  texture or normal seams still comes out as whole parts, and touching parts (coincident vertices
  with different indices) stay apart.
- Files whose loader or format splits vertices (glTF primitives split along UV seams, STL is a pure
  triangle soup, any file whose faces share no vertex) are *stitched*: two faces are joined across
  an edge when exactly two boundary half-edges coincide in position there (a manifold seam).
  Parts that merely touch keep their own closed surfaces, whose edges are never boundary edges, so
  they are not merged; a soup of unwelded triangles comes out as its real parts.
- ``connectivity="weld"`` welds every coincident vertex (for files where even that is wanted).

Other repairs: polygons with more than three corners are fan-triangulated; faces repeating a
vertex index are dropped; faces that use a NaN/inf vertex are dropped (or an error with
``nonfinite="error"``); unreferenced vertices are dropped. Out-of-range indices, empty files and
unparsable lines raise ``ValueError`` naming the file and line.
"""

from __future__ import annotations

import io
import itertools
import json
import os
import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components
from scipy.spatial import cKDTree

from proctex.fileio import atomic_write
from .shape import Shape, split_by_face_parts

FORMATS = {".obj": "obj", ".ply": "ply", ".stl": "stl", ".glb": "glb", ".gltf": "gltf"}
CONNECTIVITY = ("auto", "index", "stitch", "weld")


@dataclass
class LoadReport:
    """What the loader found and repaired.

    ``vertex_map`` is (n_source_vertices,) int64: the output vertex of each source vertex, -1 when
    it was dropped.
    """

    path: str
    format: str
    connectivity: str
    source_vertices: int = 0
    source_polygons: int = 0
    triangulated_polygons: int = 0
    dropped_repeated_index_faces: int = 0
    dropped_nonfinite_faces: int = 0
    dropped_unreferenced_vertices: int = 0
    stitched_edges: int = 0
    welded_vertices: int = 0
    vertex_map: np.ndarray | None = field(default=None, repr=False)

    def notes(self) -> list[str]:
        out = []
        if self.triangulated_polygons:
            out.append(f"triangulated {self.triangulated_polygons} polygons with more than 3 corners")
        if self.dropped_repeated_index_faces:
            out.append(f"dropped {self.dropped_repeated_index_faces} faces that repeat a vertex")
        if self.dropped_nonfinite_faces:
            out.append(f"dropped {self.dropped_nonfinite_faces} faces using NaN/inf vertices")
        if self.dropped_unreferenced_vertices:
            out.append(f"dropped {self.dropped_unreferenced_vertices} unreferenced vertices")
        if self.stitched_edges:
            out.append(f"stitched {self.stitched_edges} split edges ({self.welded_vertices} vertices welded)")
        return out

    def to_dict(self) -> dict[str, Any]:
        d = {k: v for k, v in self.__dict__.items() if k != "vertex_map"}
        d["notes"] = self.notes()
        return d


# ------------------------------------------------------------------------------------------ readers
def _parse_obj_index(token: str, n_vertices: int, path: str, lineno: int) -> int:
    head = token.split("/", 1)[0]
    try:
        idx = int(head)
    except ValueError:
        raise ValueError(f"{path}:{lineno}: bad face index {token!r}") from None
    if abs(idx) >= 2**62:
        raise ValueError(f"{path}:{lineno}: face index {token!r} is out of range")
    if idx > 0:
        return idx - 1
    if idx < 0:
        return n_vertices + idx  # relative index (OBJ spec)
    raise ValueError(f"{path}:{lineno}: face index 0 is invalid in OBJ (indices start at 1)")


_OBJ_OTHER_V = ("vt", "vn", "vp")


def _read_obj_columns(data: str) -> tuple[np.ndarray, np.ndarray] | None:
    """The common OBJ read as space-separated columns by Arrow's CSV reader (C++, about 4x faster
    than :func:`_read_obj_triangles` on a sofa export): every ``v`` line ``v x y z`` and every ``f``
    line ``f a b c`` (``a``, ``a/b``, ``a//c`` or ``a/b/c``, positive), one space apart. ``None``
    for anything else (another column count on a ``v`` / ``f`` line, a tab, a quad, a relative
    index, a malformed number), which the next reader then takes; lines of other kinds are ignored."""
    import pyarrow as pa
    import pyarrow.compute as pc
    import pyarrow.csv as pacsv

    odd: list[int] = []

    def other_shape(row) -> str:
        tag = (row.text or "").lstrip().split(" ", 1)[0]
        if tag[:1] in ("v", "f") and tag not in _OBJ_OTHER_V:
            odd.append(row.number)  # a vertex or face line this reader does not take
        return "skip"

    names = ["t", "a", "b", "c"]
    try:
        table = pacsv.read_csv(
            pa.py_buffer(data.encode()),
            read_options=pacsv.ReadOptions(column_names=names, use_threads=False, block_size=1 << 22),
            parse_options=pacsv.ParseOptions(delimiter=" ", quote_char=False, invalid_row_handler=other_shape),
            convert_options=pacsv.ConvertOptions(column_types={n: pa.string() for n in names}, strings_can_be_null=False),
        )
    except (pa.ArrowInvalid, pa.ArrowNotImplementedError, ValueError):
        return None
    tags = table["t"]
    if odd or any(t[:1] in ("v", "f") and t not in ("v", "f") + _OBJ_OTHER_V for t in pc.unique(tags).to_pylist()):
        return None
    v_rows = table.filter(pc.equal(tags, "v"))
    f_rows = table.filter(pc.equal(tags, "f"))
    try:
        v = np.stack([pc.cast(v_rows[n], pa.float64()).to_numpy(zero_copy_only=False) for n in "abc"], axis=1) if len(v_rows) else np.zeros((0, 3))
        cols = []
        for n in "abc":
            col = f_rows[n]
            if len(col) and pc.any(pc.match_substring(col, "/")).as_py():
                col = pc.list_element(pc.split_pattern(col, "/"), 0)
            cols.append(pc.cast(col, pa.int64()).to_numpy(zero_copy_only=False))
        f = np.stack(cols, axis=1) if len(f_rows) else np.zeros((0, 3), np.int64)
    except (pa.ArrowInvalid, pa.ArrowNotImplementedError, ValueError):
        return None
    if len(f) and (f.min() < 1 or f.max() >= 2**62):
        return None
    return v.astype(np.float64), f.astype(np.int64) - 1


def _read_obj_triangles(data: str) -> tuple[np.ndarray, np.ndarray] | None:
    """The common OBJ in one pass of numpy parsing: every ``v`` line three coordinates, every ``f``
    line three positive indices (``v``, ``v/vt``, ``v//vn`` or ``v/vt/vn``). ``None`` for anything
    else (quads, relative indices, extra columns, a malformed token), which the line-by-line reader
    then parses with its precise errors."""
    import re
    import warnings

    if re.search(r"^[vf](?![ tnp])", data, re.MULTILINE):
        return None  # a "v"/"f" line with a tab or nothing after it, or a tag this path does not know
    lines = data.splitlines()
    vs = [ln[2:] for ln in lines if ln[:2] == "v "]
    fs = [ln[2:] for ln in lines if ln[:2] == "f "]
    ft = " ".join(fs)
    if "/" in ft:
        ft = re.sub(r"/\S*", "", ft)
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # numpy warns (not raises) on a token it cannot read
        try:
            v = np.fromstring(" ".join(vs), sep=" ") if vs else np.zeros(0)
            f = np.fromstring(ft, sep=" ", dtype=np.int64) if fs else np.zeros(0, np.int64)
        except (ValueError, DeprecationWarning):
            return None
    if len(v) != 3 * len(vs) or len(f) != 3 * len(fs) or (len(f) and (f.min() < 1 or f.max() >= 2**62)):  # 2**62: saturated
        return None
    return v.reshape(-1, 3), f.reshape(-1, 3) - 1


def read_obj(data: str, path: str = "<obj>") -> tuple[np.ndarray, list[list[int]] | np.ndarray]:
    """Parse OBJ text into ``(vertices (n, 3) float64, polygons)`` using ``v`` indices only.

    Negative (relative) indices are resolved; lines other than ``v`` and ``f`` are ignored.
    Triangle-only files with plain vertices take a vectorised path (polygons then an (m, 3) int64
    array); anything else is read line by line (a list of index lists).
    """
    fast = _read_obj_columns(data)
    if fast is None:
        fast = _read_obj_triangles(data)
    if fast is not None:
        return fast
    verts: list[tuple[float, float, float]] = []
    polys: list[list[int]] = []
    for lineno, line in enumerate(data.splitlines(), start=1):
        if not line or line[0] not in "vf":
            continue
        parts = line.split()
        tag = parts[0]
        if tag == "v":
            if len(parts) < 4:
                raise ValueError(f"{path}:{lineno}: vertex needs 3 coordinates: {line.strip()!r}")
            try:
                verts.append((float(parts[1]), float(parts[2]), float(parts[3])))
            except ValueError:
                raise ValueError(f"{path}:{lineno}: bad vertex coordinates: {line.strip()!r}") from None
        elif tag == "f":
            if len(parts) < 4:
                raise ValueError(f"{path}:{lineno}: face needs at least 3 corners: {line.strip()!r}")
            polys.append([_parse_obj_index(t, len(verts), path, lineno) for t in parts[1:]])
    return np.array(verts, dtype=np.float64).reshape(-1, 3), polys


def read_obj_groups(data: str, n_polygons: int) -> np.ndarray | None:
    """The OBJ group (``g`` or ``o`` line) of each of the file's ``n_polygons`` faces, as (p,) int64
    ids in order of first use, or None when the file names fewer than two groups. Faces before the
    first group line are group 0's "default" group."""
    text = "\n" + data
    if "\ng " not in text and "\no " not in text:
        return None
    if _plain_breaks(data):  # lines end in \n or \r\n: whole runs of faces at once
        counted, groups = _obj_groups_by_runs(text, n_polygons)
        if counted:
            return groups
    return _obj_groups_by_line(data, n_polygons)


#: Line breaks other than ``\n`` and ``\r\n`` (``str.splitlines`` breaks at these too).
_OTHER_BREAKS = re.compile("\r(?!\n)|[\x0b\x0c\x1c\x1d\x1e\x85\u2028\u2029]")


def _plain_breaks(data: str) -> bool:
    """Whether every line break of ``data`` is ``\n`` or ``\r\n`` (a scan per character kind for
    ASCII text, the usual OBJ; :data:`_OTHER_BREAKS` otherwise)."""
    if not data.isascii():
        return not _OTHER_BREAKS.search(data)
    return data.count("\r") == data.count("\r\n") and not any(c in data for c in "\x0b\x0c\x1c\x1d\x1e")


def _group_lines(text: str) -> list[tuple[int, str]]:
    """``(position, name)`` of every line of ``text`` (which starts with ``\n``) that starts with
    ``g `` or ``o ``, in order; the name is the rest of the line, stripped."""
    out = []
    for tag in ("\ng ", "\no "):
        at = text.find(tag)
        while at >= 0:
            end = text.find("\n", at + 1)
            end = len(text) if end < 0 else end
            out.append((at + 1, text[at + 3 : end].strip()))
            at = text.find(tag, end)
    return sorted(out)


def _obj_groups_by_runs(text: str, n_polygons: int) -> tuple[bool, np.ndarray | None]:
    """:func:`_obj_groups_by_line` for a file ``text`` (with a ``\n`` put before it) whose lines
    end in ``\n`` or ``\r\n``: the faces between two group lines counted in one pass each
    (``str.count``), not line by line. Returns ``(False, None)`` when the file's face lines are not
    ``n_polygons`` (for the line-by-line reading to answer), else ``(True, its answer)``."""
    marks = _group_lines(text)
    bounds = [0] + [pos for pos, _ in marks] + [len(text)]
    names = [""] + [name for _, name in marks]
    counts = [text.count("\nf ", bounds[i], bounds[i + 1]) for i in range(len(names))]
    if sum(counts) != n_polygons:
        return False, None
    ids: dict[str, int] = {}
    runs = [ids.setdefault(name, len(ids)) for name, c in zip(names, counts) if c]
    if len(ids) < 2:
        return True, None
    return True, np.repeat(np.asarray(runs, dtype=np.int64), [c for c in counts if c])


def _obj_groups_by_line(data: str, n_polygons: int) -> np.ndarray | None:
    """:func:`read_obj_groups` line by line (any line breaks ``str.splitlines`` knows)."""
    ids: dict[str, int] = {}
    out = np.empty(n_polygons, dtype=np.int64)
    current, k = "", 0
    for line in data.splitlines():
        if line.startswith(("g ", "o ")):
            current = line[2:].strip()
        elif line.startswith("f ") and k < n_polygons:
            out[k] = ids.setdefault(current, len(ids))
            k += 1
    if k != n_polygons or len(ids) < 2:
        return None
    return out


def _read_plain_obj(data: bytes) -> tuple[np.ndarray, np.ndarray, np.ndarray, list[str]] | None:
    """:func:`proctex.geometry.obj_kernels.read_plain` of an OBJ's bytes (the compiled reader of the
    plain OBJ exporters write), None for any other file or where numba does not import (the
    readers here answer then)."""
    try:
        from .obj_kernels import read_plain
    except ImportError:
        return None
    return read_plain(data)


def plain_obj_groups(face_group: np.ndarray, names: list[str]) -> np.ndarray | None:
    """:func:`read_obj_groups` from what the compiled reader found: ``face_group (m,) int64`` the
    ordinal of the ``o`` / ``g`` line before each face (-1 before the first, non-decreasing: faces
    are in file order) and ``names`` those lines' names. Group ids in order of first use, faces
    before any group line in the "" group; None when fewer than two are used."""
    segment = np.asarray(face_group, dtype=np.int64) + 1
    used = np.unique(segment)
    every = [""] + list(names)
    ids: dict[str, int] = {}
    lut = np.array([ids.setdefault(every[s], len(ids)) for s in used.tolist()], dtype=np.int64)
    if len(ids) < 2:
        return None
    return lut[np.searchsorted(used, segment)]


def _read_with_trimesh(data: bytes, fmt: str, path: str) -> tuple[np.ndarray, list[np.ndarray]]:
    """Vertices and triangle blocks of a file's bytes via trimesh, without any processing (no
    merging/reordering); ``path`` names it in errors."""
    import trimesh

    if fmt in ("glb", "gltf"):
        from .meshcounts import declared_counts

        declared_counts(data, fmt, path)  # a node tree past the depth a library can walk is refused here
    try:
        loaded = trimesh.load(io.BytesIO(data), file_type=fmt, process=False, force=None)
    except Exception as exc:  # trimesh raises many types for malformed files
        raise ValueError(f"{path}: cannot read {fmt.upper()} file: {exc}") from exc
    if isinstance(loaded, trimesh.Scene):
        meshes = []
        for node in loaded.graph.nodes_geometry:
            transform, name = loaded.graph[node]
            geom = loaded.geometry[name]
            if isinstance(geom, trimesh.Trimesh):
                m = geom.copy()
                m.apply_transform(transform)
                meshes.append(m)
    elif isinstance(loaded, trimesh.Trimesh):
        meshes = [loaded]
    else:
        meshes = []
    verts, faces, offset = [], [], 0
    for m in meshes:
        v = np.asarray(m.vertices, dtype=np.float64)
        verts.append(v)
        faces.append(np.asarray(m.faces, dtype=np.int64) + offset)
        offset += len(v)
    if not verts:
        return np.zeros((0, 3)), []
    return np.concatenate(verts), faces


def detect_format(path: str | os.PathLike) -> str:
    ext = Path(path).suffix.lower()
    if ext not in FORMATS:
        raise ValueError(f"{path}: unsupported mesh format {ext!r}; expected one of {sorted(FORMATS)}")
    return FORMATS[ext]


# --------------------------------------------------------------------------------------- clean-up
def triangulate(polygons: list) -> tuple[np.ndarray, int]:
    """Fan-triangulate polygons, keeping their order.

    Args:
        polygons: list of index sequences with >= 3 corners each.

    Returns:
        ``(faces (m, 3) int64, number of polygons that had more than 3 corners)``.
    """
    lengths = np.fromiter(map(len, polygons), dtype=np.int64, count=len(polygons))
    if len(lengths) == 0:
        return np.zeros((0, 3), np.int64), 0
    if np.all(lengths == 3):
        return np.asarray(polygons, dtype=np.int64).reshape(-1, 3), 0
    flat = np.fromiter(itertools.chain.from_iterable(polygons), dtype=np.int64, count=int(lengths.sum()))
    starts = np.cumsum(lengths) - lengths
    n_tri = lengths - 2
    poly_of_tri = np.repeat(np.arange(len(lengths)), n_tri)
    k = np.arange(int(n_tri.sum())) - np.repeat(np.cumsum(n_tri) - n_tri, n_tri)
    s = starts[poly_of_tri]
    faces = np.stack([flat[s], flat[s + k + 1], flat[s + k + 2]], axis=1)
    return faces, int((lengths > 3).sum())


def _union_find(n: int, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Labels (n,) int64 of the connected components of the graph with edges (a[i], b[i])."""
    graph = coo_matrix((np.ones(len(a)), (a, b)), shape=(n, n))
    return connected_components(graph, directed=False)[1].astype(np.int64)


#: Most vertex pairs within the weld tolerance per distinct position before a mesh is refused: a real
#: mesh has a few near-duplicates per position (seams, soups), an attack crams thousands into one spot.
MAX_NEAR_PAIRS_PER_VERTEX = 64


def unique_rows(a: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``(distinct rows (d, c) in lexicographic order, inverse (n,) int64)`` of ``a (n, c)``, like
    ``np.unique(a, axis=0, return_inverse=True)`` but by a column-wise ``lexsort`` (about 5x faster
    on float rows than sorting them as opaque bytes). Rows compare by value: 0.0 equals -0.0."""
    a = np.asarray(a)
    if a.ndim != 2:
        raise ValueError(f"unique_rows needs a 2-D array, got shape {a.shape}")
    if len(a) == 0:
        return a.copy(), np.zeros(0, np.int64)
    order = np.lexsort(a.T[::-1])
    ordered = a[order]
    new = np.empty(len(a), dtype=bool)
    new[0] = True
    np.any(ordered[1:] != ordered[:-1], axis=1, out=new[1:])
    inverse = np.empty(len(a), dtype=np.int64)
    inverse[order] = np.cumsum(new) - 1
    return ordered[new], inverse


def position_ids(vertices: np.ndarray, tol: float) -> np.ndarray:
    """(n,) int64 id per vertex, equal for vertices within ``tol`` of each other (transitively).

    Exact duplicates are merged first (memory linear in ``n`` however many share a position); the
    near pairs among the distinct positions are counted before they are listed, and more than
    :data:`MAX_NEAR_PAIRS_PER_VERTEX` per position is a ``ValueError`` (a cluster of thousands of
    vertices within ``tol`` would need memory quadratic in its size)."""
    n = len(vertices)
    if n == 0:
        return np.zeros(0, np.int64)
    distinct, inverse = unique_rows(np.asarray(vertices, dtype=np.float64))
    tree = cKDTree(distinct)
    near = (int(tree.count_neighbors(tree, tol)) - len(distinct)) // 2  # unordered pairs, self-pairs left out
    if near > MAX_NEAR_PAIRS_PER_VERTEX * len(distinct) + 1000:
        raise ValueError(f"{near} pairs of distinct vertices lie within {tol:g} of each other ({len(distinct)} positions): too many coincident vertices to weld")
    pairs = tree.query_pairs(tol, output_type="ndarray")
    if len(pairs) == 0:
        labels = np.arange(len(distinct), dtype=np.int64)
    else:
        labels = _union_find(len(distinct), pairs[:, 0], pairs[:, 1])
    # Components numbered as before (first vertex order does not matter to callers: ids are labels).
    return labels[inverse].astype(np.int64)


def _pair_around_edge(vertices: np.ndarray, faces: np.ndarray, he_face: np.ndarray, pa: int, pb: int) -> list[tuple[int, int]]:
    """Pair the faces meeting at one non-manifold geometric edge so each pair encloses one solid.

    Faces are ordered by their angle around the edge; from each face we turn towards its inside
    (against its normal) and pair it with the first face whose inside faces back. Coincident faces
    of two touching solids have opposite normals, so each pairs with its own solid.

    Args:
        vertices, faces: the mesh; he_face: (h,) faces of the coincident half-edges;
        pa, pb: two vertex indices giving the edge's end positions.

    Returns:
        list of pairs of positions into ``he_face``.
    """
    a, b = vertices[pa], vertices[pb]
    e = b - a
    e = e / max(np.linalg.norm(e), 1e-300)
    tri = vertices[faces[he_face]]
    # Direction from the edge into each face (via its centroid), perpendicular to the edge.
    w = tri.mean(axis=1) - a
    w -= np.outer(w @ e, e)
    w /= np.maximum(np.linalg.norm(w, axis=1, keepdims=True), 1e-300)
    u0 = w[0]
    v0 = np.cross(e, u0)
    theta = np.arctan2(w @ v0, w @ u0) % (2 * np.pi)
    n = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    ccw_inside = np.einsum("ij,ij->i", -n, np.cross(e, w)) > 0
    pairs, taken = [], set()
    for i in np.argsort(theta, kind="stable"):
        if i in taken or not ccw_inside[i]:
            continue
        offset = (theta - theta[i]) % (2 * np.pi)
        offset[offset <= 1e-9] = 2 * np.pi  # a coincident face lies a full turn away
        ok = [j for j in np.argsort(offset, kind="stable") if j != i and j not in taken and not ccw_inside[j]]
        if ok:
            pairs.append((int(i), int(ok[0])))
            taken.update((int(i), int(ok[0])))
    return pairs


def _has_single(keys: np.ndarray) -> bool:
    """Whether some value occurs exactly once in ``keys (h,)`` (a boundary edge among the
    half-edges' keys): one sort, without the inverse and counts that stitching itself needs."""
    s = np.sort(keys)
    if len(s) < 2:
        return len(s) == 1
    differs = s[1:] != s[:-1]
    alone = np.ones(len(s), dtype=bool)
    alone[1:] &= differs
    alone[:-1] &= differs
    return bool(alone.any())


def stitch_split_edges(vertices: np.ndarray, faces: np.ndarray, tol: float) -> tuple[np.ndarray, int]:
    """Weld map for vertices split along seams (or a triangle soup).

    Only *boundary* half-edges (index edges used by one face) are stitched. Where exactly two
    half-edges coincide in position they pair up; where more coincide (solids touching along an
    edge), all faces there are paired around the edge by angle and orientation
    (:func:`_pair_around_edge`) and the pairs of two boundary half-edges are stitched. Stitched
    edges weld their endpoint vertices.

    Args:
        vertices: (n, 3) float64; faces: (m, 3) int64.
        tol: distance under which two positions are the same.

    Returns:
        ``(weld (n,) int64, stitched_edge_count)``: ``weld[i]`` is the representative vertex of i.
    """
    n = len(vertices)
    he_a = faces.reshape(-1)
    he_b = np.roll(faces, -1, axis=1).reshape(-1)
    lo, hi = np.minimum(he_a, he_b), np.maximum(he_a, he_b)
    edge_key = lo * n + hi
    if not _has_single(edge_key):  # closed by index already (most exports): nothing to stitch, no position search
        return np.arange(n, dtype=np.int64), 0
    _, inv, counts = np.unique(edge_key, return_inverse=True, return_counts=True)
    boundary = counts[inv] == 1
    pid = position_ids(vertices, tol)
    he_f = np.repeat(np.arange(len(faces)), 3)
    pa, pb = pid[he_a], pid[he_b]
    pos_key = np.minimum(pa, pb) * n + np.maximum(pa, pb)
    # Every half-edge at a geometric edge that has at least one boundary half-edge takes part in
    # the pairing; interior ones only so that a closed part touching there keeps its own faces.
    involved = np.flatnonzero(np.isin(pos_key, np.unique(pos_key[boundary])) & (pa != pb))
    order = involved[np.argsort(pos_key[involved], kind="stable")]
    keys = pos_key[order]
    starts = np.flatnonzero(np.r_[True, keys[1:] != keys[:-1]])
    sizes = np.diff(np.r_[starts, len(keys)])
    pairs: list[tuple[int, int]] = [(int(order[s]), int(order[s + 1])) for s in starts[sizes == 2]]
    for s, k in zip(starts[sizes > 2], sizes[sizes > 2]):
        hes = order[s : s + k]
        for i, j in _pair_around_edge(vertices, faces, he_f[hes], int(he_a[hes[0]]), int(he_b[hes[0]])):
            pairs.append((int(hes[i]), int(hes[j])))
    pairs = [(i, j) for i, j in pairs if boundary[i] and boundary[j]]
    if not pairs:
        return np.arange(n, dtype=np.int64), 0
    h = np.array(pairs, dtype=np.int64)
    # Match endpoints by position: (a0, b0) against (a1, b1) or (b1, a1).
    a0, b0, a1, b1 = he_a[h[:, 0]], he_b[h[:, 0]], he_a[h[:, 1]], he_b[h[:, 1]]
    same = pid[a0] == pid[a1]
    u = np.concatenate([a0, b0])
    v = np.concatenate([np.where(same, a1, b1), np.where(same, b1, a1)])
    labels = _union_find(n, u, v)
    rep = np.full(labels.max() + 1, n, dtype=np.int64)
    np.minimum.at(rep, labels, np.arange(n))
    return rep[labels], len(h)


def weld_all(vertices: np.ndarray, tol: float) -> np.ndarray:
    """Weld map merging every pair of vertices within ``tol`` (representative = smallest index)."""
    n = len(vertices)
    labels = position_ids(vertices, tol)
    rep = np.full(labels.max() + 1 if n else 0, n, dtype=np.int64)
    np.minimum.at(rep, labels, np.arange(n))
    return rep[labels]


def clean_mesh(
    vertices: np.ndarray,
    polygons: list,
    connectivity: str = "auto",
    nonfinite: str = "drop",
    weld_tol: float = 1e-7,
    report: LoadReport | None = None,
) -> tuple[np.ndarray, np.ndarray, LoadReport]:
    """Turn raw vertices and polygons into a clean triangle mesh whose components are the parts.

    Args:
        vertices: (n, 3) float64 source vertices.
        polygons: list of index sequences (>= 3 corners each), or an (m, 3) int array.
        connectivity: ``"index"`` (shared indices only), ``"stitch"`` (also join faces across
            manifold seams split by position), ``"weld"`` (merge all coincident vertices) or
            ``"auto"`` (= ``"stitch"``: a no-op on well-indexed files with closed or separate parts).
        nonfinite: ``"drop"`` faces using NaN/inf vertices, or ``"error"``.
        weld_tol: weld distance relative to the bounding-box diagonal.

    Returns:
        ``(vertices (k, 3) float64, faces (m, 3) int64, report)``.
    """
    if connectivity not in CONNECTIVITY:
        raise ValueError(f"connectivity must be one of {CONNECTIVITY}, got {connectivity!r}")
    if nonfinite not in ("drop", "error"):
        raise ValueError(f"nonfinite must be 'drop' or 'error', got {nonfinite!r}")
    rep = report or LoadReport(path="<arrays>", format="arrays", connectivity=connectivity)
    vertices = np.asarray(vertices, dtype=np.float64).reshape(-1, 3)
    n = len(vertices)
    rep.source_vertices = n
    if isinstance(polygons, np.ndarray):
        faces = np.asarray(polygons, dtype=np.int64).reshape(-1, 3)
        rep.source_polygons = len(faces)
    else:
        rep.source_polygons = len(polygons)
        faces, rep.triangulated_polygons = triangulate(polygons)
    if len(faces) == 0:
        raise ValueError(f"{rep.path}: the mesh has no faces")
    if faces.min() < 0 or faces.max() >= n:
        bad = int(faces.max()) if faces.max() >= n else int(faces.min())
        raise ValueError(f"{rep.path}: face references vertex {bad}, but there are {n} vertices (valid: 0..{n - 1})")
    repeated = (faces[:, 0] == faces[:, 1]) | (faces[:, 1] == faces[:, 2]) | (faces[:, 0] == faces[:, 2])
    rep.dropped_repeated_index_faces = int(repeated.sum())
    faces = faces[~repeated]
    finite_v = np.all(np.isfinite(vertices), axis=1)
    bad_faces = ~np.all(finite_v[faces], axis=1)
    if bad_faces.any():
        if nonfinite == "error":
            raise ValueError(f"{rep.path}: {int(bad_faces.sum())} faces use vertices with NaN/inf coordinates")
        rep.dropped_nonfinite_faces = int(bad_faces.sum())
        faces = faces[~bad_faces]
    if len(faces) == 0:
        raise ValueError(f"{rep.path}: no valid faces left after dropping degenerate and non-finite ones")
    used = np.zeros(n, dtype=bool)
    used[faces.reshape(-1)] = True
    rep.dropped_unreferenced_vertices = int((~used).sum())
    mode = "stitch" if connectivity == "auto" else connectivity
    rep.connectivity = mode
    weld = np.arange(n)
    if mode != "index":
        sub = np.flatnonzero(used)
        pts = vertices[sub]
        tol = weld_tol * max(float(np.linalg.norm(pts.max(0) - pts.min(0))), 1e-12)
        remap = -np.ones(n, dtype=np.int64)
        remap[sub] = np.arange(len(sub))
        if mode == "stitch":
            local, rep.stitched_edges = stitch_split_edges(pts, remap[faces], tol)
        else:
            local = weld_all(pts, tol)
        weld[sub] = sub[local]
        rep.welded_vertices = int((weld != np.arange(n)).sum())
        faces = weld[faces]
        repeated = (faces[:, 0] == faces[:, 1]) | (faces[:, 1] == faces[:, 2]) | (faces[:, 0] == faces[:, 2])
        rep.dropped_repeated_index_faces += int(repeated.sum())
        faces = faces[~repeated]
        used = np.zeros(n, dtype=bool)
        used[faces.reshape(-1)] = True
    new_index = -np.ones(n, dtype=np.int64)
    new_index[used] = np.arange(int(used.sum()))
    rep.vertex_map = new_index[weld]
    return vertices[used], new_index[faces], rep


# ------------------------------------------------------------------------------------------- public
def load_mesh(
    path: str | os.PathLike,
    connectivity: str = "auto",
    nonfinite: str = "drop",
) -> tuple[Shape, LoadReport]:
    """Load a mesh file as a :class:`Shape` whose connected components are its parts.

    See the module docstring for the connectivity rules and repairs. Raises ``ValueError`` for
    missing, empty, malformed or unsupported files.
    """
    path = str(path)
    detect_format(path)
    if not os.path.isfile(path):
        raise ValueError(f"{path}: no such file")
    with open(path, "rb") as fh:
        data = fh.read()
    return load_mesh_bytes(data, path, connectivity, nonfinite)


def load_mesh_bytes(
    data: bytes,
    name: str,
    connectivity: str = "auto",
    nonfinite: str = "drop",
    groups: bool = False,
) -> tuple[Shape, LoadReport]:
    """:func:`load_mesh` of a file's bytes (an upload, a store object): the format comes from
    ``name``'s extension, which also names the mesh in errors and as the shape's source.

    ``groups``: an OBJ naming two or more groups (``g`` / ``o``) has one part per group at least:
    faces of different groups get their own vertices and nothing is stitched or welded across them
    (connectivity by index; the Blender add-on sends a family's part attribute this way)."""
    name = str(name)
    fmt = detect_format(name)
    if not len(data):
        raise ValueError(f"{name}: the file is empty")
    report = LoadReport(path=name, format=fmt, connectivity=connectivity)
    if fmt == "obj":
        plain = _read_plain_obj(data)
        if plain is not None:
            vertices, polygons, face_group, names = plain
        else:
            text = bytes(data).decode("utf-8", errors="replace")
            vertices, polygons = read_obj(text, name)
        if len(vertices) == 0:
            raise ValueError(f"{name}: the file has no vertices")
        if len(polygons) == 0:
            raise ValueError(f"{name}: the file has no faces")
        faces: Any = polygons
        if not groups:
            group = None
        elif plain is not None:
            group = plain_obj_groups(face_group, names)
        else:
            group = read_obj_groups(text, len(polygons))
        if group is not None:
            tri, _ = triangulate(list(polygons)) if not isinstance(polygons, np.ndarray) else (polygons, 0)
            lengths = np.full(len(polygons), 3) if isinstance(polygons, np.ndarray) else np.fromiter(map(len, polygons), np.int64, len(polygons))
            tri_group = np.repeat(group, lengths - 2)
            if tri.size and (tri.min() < 0 or tri.max() >= len(vertices)):
                raise ValueError(f"{name}: a face references a vertex that does not exist")
            faces, source = split_by_face_parts(tri, tri_group, len(vertices))
            vertices = vertices[source]
            connectivity = "index"
            report.connectivity = "index"
    else:
        vertices, blocks = _read_with_trimesh(bytes(data), fmt, name)
        if len(vertices) == 0 or not blocks or sum(len(b) for b in blocks) == 0:
            raise ValueError(f"{name}: the file has no triangles")
        faces = np.concatenate(blocks)
    v, f, report = clean_mesh(vertices, faces, connectivity, nonfinite, report=report)
    return Shape(v, f, source=name), report


def read_params(path: str | os.PathLike) -> dict[str, Any]:
    """Parameters from a sample's JSON file (a flat object of name -> value)."""
    try:
        with open(path, "r", encoding="utf-8") as fh:
            data = json.load(fh)
    except (OSError, json.JSONDecodeError) as exc:
        raise ValueError(f"{path}: cannot read parameters: {exc}") from exc
    if not isinstance(data, dict):
        raise ValueError(f"{path}: parameters must be a JSON object, got {type(data).__name__}")
    return data


def obj_text(vertices: np.ndarray, faces: np.ndarray) -> str:
    """OBJ text of a triangle mesh (1-based ``v``/``f`` lines, full float precision)."""
    buf = io.StringIO()
    buf.write("# written by proctex\n")
    np.savetxt(buf, vertices, fmt="v %.9g %.9g %.9g")
    np.savetxt(buf, faces + 1, fmt="f %d %d %d")
    return buf.getvalue()


def save_mesh(shape: Shape, path: str | os.PathLike) -> None:
    """Write a shape's geometry as OBJ, PLY, STL or GLB (format from the extension), atomically.

    STL has no shared vertices; loading it back stitches the parts together again.
    """
    path = str(path)
    fmt = detect_format(path)
    if fmt == "obj":
        data = obj_text(shape.vertices, shape.faces).encode()
    else:
        import trimesh

        mesh = trimesh.Trimesh(shape.vertices, shape.faces, process=False)
        file_type = "glb" if fmt == "gltf" else fmt
        if fmt == "gltf":
            raise ValueError(f"{path}: write binary glTF (.glb) instead of .gltf")
        data = mesh.export(file_type=file_type)
        if isinstance(data, str):
            data = data.encode()
    atomic_write(path, data)


def save_params(params: dict[str, Any], path: str | os.PathLike) -> None:
    atomic_write(path, json.dumps(params, indent=2) + "\n")
