"""What a mesh file says it holds, read from its header alone (PLY and binary STL headers, OBJ's
vertex and face lines, a glTF's accessors and node tree), so limits are checked before any parse:
a 2M-face PLY or an OBJ face of 100,000 corners is refused in milliseconds, not after seconds of
parsing and gigabytes of memory. glTF node trees are walked here, linearly, and refused past
:data:`MAX_NODE_DEPTH` (a library that multiplies transforms along every chain is cubic in depth)."""

from __future__ import annotations

import json
import re
import struct
from dataclasses import dataclass

import numpy as np

#: The most corners one polygon of a file may have (a cylinder cap of 256 segments has 256), the
#: deepest glTF node hierarchy and the most nodes a file may have.
MAX_CORNERS = 4096
MAX_NODE_DEPTH = 32
MAX_NODES = 10_000
MAX_JSON = 16 * 2**20  # bytes of a glTF's JSON


@dataclass(frozen=True)
class DeclaredCounts:
    """``vertices`` and ``triangles`` a file declares (None where its header cannot say), and for
    glTF its node count and depth."""

    vertices: int | None
    triangles: int | None
    nodes: int = 0
    depth: int = 0
    corners: int = 3  # of the largest polygon


def declared_counts(data: bytes, fmt: str, name: str = "mesh") -> DeclaredCounts:
    """The counts of ``data`` (a file of format ``fmt``: obj, ply, stl, glb, gltf) from its header;
    ``ValueError`` naming ``name`` for a header that cannot be read, a polygon of more than
    :data:`MAX_CORNERS` corners, a node cycle, or a node tree past :data:`MAX_NODE_DEPTH` /
    :data:`MAX_NODES`."""
    if fmt == "obj":
        vertices, triangles, largest = _obj_counts(data)
        if largest > MAX_CORNERS:
            raise ValueError(f"{name}: a face of {largest} corners (at most {MAX_CORNERS})")
        return DeclaredCounts(vertices, triangles, corners=largest)
    if fmt == "ply":
        end = data.find(b"end_header", 0, 65536)
        if not data.startswith(b"ply") or end < 0:
            raise ValueError(f"{name}: cannot read PLY file: no PLY header")
        counts = dict(re.findall(rb"(?m)^element[ \t]+(\w+)[ \t]+(\d+)", data[:end]))
        v, f = counts.get(b"vertex"), counts.get(b"face")
        return DeclaredCounts(int(v) if v is not None else None, int(f) if f is not None else None)
    if fmt == "stl":
        if len(data) >= 84:
            (n,) = struct.unpack("<I", data[80:84])
            if 84 + 50 * n == len(data):  # binary: the count is the header's
                return DeclaredCounts(None, n)
        return DeclaredCounts(None, data.count(b"endfacet"))
    if fmt in ("glb", "gltf"):
        return _gltf_counts(_gltf_json(data, fmt, name), name)
    return DeclaredCounts(None, None)


def _obj_counts(data: bytes) -> tuple[int, int, int]:
    """``(vertex lines, triangles, corners of the largest face (3 without faces))`` of an OBJ: by
    the compiled scan of a plain file (:func:`proctex.geometry.obj_kernels.plain_counts`), else by
    array passes or lines."""
    try:
        from .obj_kernels import plain_counts

        fast = plain_counts(data)
    except ImportError:
        fast = None
    if fast is not None:
        return fast
    counted = _obj_counts_by_columns(data)
    vertices, corners = counted if counted is not None else _obj_counts_by_lines(data)
    corners = np.asarray(corners, dtype=np.int64)
    return vertices, int(np.maximum(corners - 2, 0).sum()), int(corners.max()) if len(corners) else 3


def _obj_counts_by_lines(data: bytes) -> tuple[int, list[int]]:
    """``(vertex lines, corners of each face line)`` of an OBJ: lines (from the start or a ``\n``)
    starting, after spaces or tabs, with ``v`` or ``f`` and a space or tab."""
    vertices = len(re.findall(rb"(?m)^[ \t]*v[ \t]", data))
    return vertices, [len(line.split()) for line in re.findall(rb"(?m)^[ \t]*f[ \t]+([^\r\n]*)", data)]


def _obj_counts_by_columns(data: bytes) -> "tuple[int, np.ndarray] | None":
    """:func:`_obj_counts_by_lines` by array passes over the bytes, for the usual OBJ: lines end in
    ``\n`` or ``\r\n`` and none starts with a space or tab; a face's corners are its runs of bytes
    other than the blanks ``bytes.split()`` splits at (space, tab, ``\x0b``, ``\x0c``). None for any
    other file (the line reading then answers)."""
    if not data or (b"\r" in data and data.count(b"\r") != data.count(b"\r\n")):
        return None
    a = np.frombuffer(data, dtype=np.uint8)
    starts = np.concatenate([[0], np.flatnonzero(a == 10) + 1])
    starts = starts[starts < len(a)]
    first = a[starts]
    if ((first == 32) | (first == 9)).any():
        return None
    second = np.append(a, 10)[starts + 1]
    tagged = (second == 32) | (second == 9)
    vertices = int((tagged & (first == ord("v"))).sum())
    face = starts[tagged & (first == ord("f"))]
    if not len(face):
        return vertices, np.zeros(0, dtype=np.int64)
    blank = (a == 32) | (a == 9) | (a == 11) | (a == 12)
    brk = (a == 10) | (a == 13)
    ends = np.flatnonzero(brk)
    end = np.append(ends, len(a))[np.searchsorted(ends, face)]
    # a corner starts where a byte that is neither blank nor a break follows a blank
    corner = np.flatnonzero(~blank[1:] & ~brk[1:] & blank[:-1]) + 1
    return vertices, np.searchsorted(corner, end) - np.searchsorted(corner, face + 1)


def _gltf_json(data: bytes, fmt: str, name: str) -> dict:
    if fmt == "glb":
        if len(data) < 20 or data[:4] != b"glTF":
            raise ValueError(f"{name}: cannot read GLB file: no GLB header")
        length, kind = struct.unpack("<I4s", data[12:20])
        if kind != b"JSON" or length > min(MAX_JSON, len(data) - 20):
            raise ValueError(f"{name}: cannot read GLB file: its first chunk is not its JSON")
        text = data[20 : 20 + length]
    else:
        if len(data) > MAX_JSON:
            raise ValueError(f"{name}: a glTF's JSON of over {MAX_JSON} bytes")
        text = data
    try:
        doc = json.loads(text)
    except (ValueError, RecursionError) as exc:
        raise ValueError(f"{name}: cannot read the glTF's JSON ({type(exc).__name__})") from exc
    if not isinstance(doc, dict):
        raise ValueError(f"{name}: the glTF's JSON is not an object")
    return doc


#: bytes per component of each glTF componentType, and components per element of each type
_COMPONENT = {5120: 1, 5121: 1, 5122: 2, 5123: 2, 5125: 4, 5126: 4}
_ELEMENT = {"SCALAR": 1, "VEC2": 2, "VEC3": 3, "VEC4": 4, "MAT2": 4, "MAT3": 9, "MAT4": 16}


def _shown(value) -> str:
    """A JSON value as the file wrote it, cut to 20 characters (for messages)."""
    try:
        return json.dumps(value)[:20]
    except (TypeError, ValueError):
        return type(value).__name__


def check_accessors(doc: dict, name: str) -> None:
    """``ValueError`` naming the first accessor of a glTF ``doc`` that a reader could misread: a
    count that is not a whole number of at least 1 (the spec's; -3 was read as "all but the last
    three"), an unknown componentType or type, a negative offset, or elements past the end of their
    bufferView (its stride counted)."""
    accessors = doc.get("accessors") or []
    views = doc.get("bufferViews") or []
    if not isinstance(views, list):
        raise ValueError(f"{name}: the glTF's bufferViews must be a list")
    for i, a in enumerate(accessors):
        if not isinstance(a, dict):
            raise ValueError(f"{name}: accessor {i} is not an object")
        count, ctype, kind, offset = a.get("count"), a.get("componentType"), a.get("type"), a.get("byteOffset", 0)
        if isinstance(count, bool) or not isinstance(count, int) or count < 1:
            raise ValueError(f"{name}: accessor {i} has count {_shown(count)} (a whole number of at least 1)")
        if ctype not in _COMPONENT or kind not in _ELEMENT:
            raise ValueError(f"{name}: accessor {i} has componentType {_shown(ctype)} and type {_shown(kind)}, not a glTF pair")
        if isinstance(offset, bool) or not isinstance(offset, int) or offset < 0:
            raise ValueError(f"{name}: accessor {i} has byteOffset {_shown(offset)} (a whole number of at least 0)")
        v = a.get("bufferView")
        if v is None:
            continue  # all zeros (or sparse): nothing to read past
        if isinstance(v, bool) or not isinstance(v, int) or not 0 <= v < len(views) or not isinstance(views[v], dict):
            raise ValueError(f"{name}: accessor {i} names bufferView {_shown(v)}, which does not exist")
        view = views[v]
        length, stride = view.get("byteLength"), view.get("byteStride") or 0
        if isinstance(length, bool) or not isinstance(length, int) or length < 0 or isinstance(stride, bool) or not isinstance(stride, int) or stride < 0:
            raise ValueError(f"{name}: bufferView {v} has byteLength {_shown(length)} and byteStride {_shown(stride)}")
        size = _COMPONENT[ctype] * _ELEMENT[kind]
        if offset + (count - 1) * max(stride, size) + size > length:
            raise ValueError(f"{name}: accessor {i} reads {count} elements past the end of bufferView {v} ({length} bytes)")


def _gltf_counts(doc: dict, name: str) -> DeclaredCounts:
    nodes = doc.get("nodes") or []
    accessors = doc.get("accessors") or []
    meshes = doc.get("meshes") or []
    if not isinstance(nodes, list) or not isinstance(accessors, list) or not isinstance(meshes, list):
        raise ValueError(f"{name}: the glTF's nodes, meshes and accessors must be lists")
    if len(nodes) > MAX_NODES:
        raise ValueError(f"{name}: {len(nodes)} nodes (at most {MAX_NODES})")
    check_accessors(doc, name)

    def count(i) -> int:
        a = accessors[i] if isinstance(i, int) and 0 <= i < len(accessors) and isinstance(accessors[i], dict) else {}
        c = a.get("count", 0)
        return c if isinstance(c, int) and c >= 0 else 0

    per_mesh = []
    for m in meshes:
        v = t = 0
        for p in (m.get("primitives") or []) if isinstance(m, dict) else []:
            if not isinstance(p, dict):
                continue
            pos = count((p.get("attributes") or {}).get("POSITION")) if isinstance(p.get("attributes"), dict) else 0
            v += pos
            t += (count(p["indices"]) if "indices" in p else pos) // 3
        per_mesh.append((v, t))
    children = [[c for c in (n.get("children") or []) if isinstance(c, int)] if isinstance(n, dict) else [] for n in nodes]
    is_child = {c for cs in children for c in cs}
    roots = [i for i in range(len(nodes)) if i not in is_child]
    depth, vertices, triangles, seen = 0, 0, 0, set()
    stack = [(r, 1) for r in roots]
    while stack:  # every node once, by its own depth: linear in the tree
        i, d = stack.pop()
        if not 0 <= i < len(nodes):
            raise ValueError(f"{name}: a node names child {i}, which does not exist")
        if i in seen:
            raise ValueError(f"{name}: node {i} is reached twice (a cycle or a shared child)")
        seen.add(i)
        depth = max(depth, d)
        if depth > MAX_NODE_DEPTH:
            raise ValueError(f"{name}: a node hierarchy {MAX_NODE_DEPTH + 1} or more deep (at most {MAX_NODE_DEPTH}); flatten it")
        m = nodes[i].get("mesh") if isinstance(nodes[i], dict) else None
        if isinstance(m, int) and 0 <= m < len(per_mesh):
            vertices += per_mesh[m][0]
            triangles += per_mesh[m][1]
        stack.extend((c, d + 1) for c in children[i])
    if len(seen) < len(nodes):
        raise ValueError(f"{name}: nodes in a cycle (no root reaches them)")
    if not nodes:  # meshes without a scene graph
        vertices, triangles = sum(v for v, _ in per_mesh), sum(t for _, t in per_mesh)
    return DeclaredCounts(vertices, triangles, len(nodes), depth)
