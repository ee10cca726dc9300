"""Textured mesh export: GLB (glTF 2.0 binary) and OBJ + MTL + PNG.

A *textured shape* is

- ``vertices``: (n, 3) float64 positions;
- ``faces``: (m, 3) int64 vertex indices, m >= 1;
- ``corner_uv``: (m, 3, 2) float64 per face-corner UV in the OpenGL/OBJ convention: u to the right,
  v **up**, (0, 0) is the bottom-left corner of the image;
- ``face_group``: (m,) int64, the texture used by each face, in [0, G), or -1 for a face without
  texture (it gets a plain grey material);
- ``textures``: G images, each (H, W, 3) or (H, W, 4) uint8 (or the bytes of an already encoded PNG, so a server can reuse them) with row 0 at the **top**, so texel
  (i, j) has its centre at u = (j + 0.5) / W, v = 1 - (i + 0.5) / H;
- ``names``: optional G group names (material names);
- ``pbr``: optional G PBR maps (:class:`proctex.texture.pbr.PbrMaps`, arrays or PNG bytes), or None
  per group for a colour-only material.

glTF puts the texcoord origin at the top-left with v pointing down, so the GLB stores (u, 1 - v);
OBJ ``vt`` lines use the convention above unchanged. Positions, normals and texcoords are stored as
float32 (GLB) or printed with 9 significant digits (OBJ, float32-exact).

Texture wrap mode is CLAMP_TO_EDGE: each group texture is a UV atlas whose charts lie inside
[0, 1]^2, so REPEAT would let bilinear filtering and coarse mip levels blend texels from the opposite
image border into charts touching an edge. Alpha channels are written to the images but materials
stay ``OPAQUE`` (atlas backgrounds are often transparent and must not make the surface see-through).
"""

from __future__ import annotations

import io
import json
import math
import re
import shutil
import subprocess
import sys
from pathlib import Path
from typing import Sequence

import numpy as np

from proctex.fileio import atomic_write, encode_png
from proctex.geometry.rowmath import bounds

ARRAY_BUFFER, ELEMENT_ARRAY_BUFFER = 34962, 34963
GREY = [0.5, 0.5, 0.5, 1.0]
ROUGHNESS = 0.8
UNTEXTURED_NAME = "untextured"


# --------------------------------------------------------------------------- validation


def _check_shape(vertices, faces, corner_uv, face_group, textures, names):
    """Validate and normalise inputs; returns (V float64, F int64, UV float64, G int64, texs, names),
    the caller's arrays themselves where they have those dtypes (the GLB and OBJ writers only read
    them)."""
    V = np.asarray(vertices)
    if V.ndim != 2 or V.shape[1] != 3 or V.shape[0] == 0 or V.dtype.kind not in "iuf":
        raise ValueError(f"vertices: expected a non-empty (n, 3) float array, got {V.dtype} {V.shape}")
    V = V.astype(np.float64, copy=False)  # read only below: no copy of a float64 array
    if not np.isfinite(V).all():
        raise ValueError("vertices: contains NaN or inf")
    F = np.asarray(faces)
    if F.ndim != 2 or F.shape[1] != 3 or F.shape[0] == 0 or F.dtype.kind not in "iu":
        raise ValueError(f"faces: expected a non-empty (m, 3) integer array, got {F.dtype} {F.shape}")
    F = F.astype(np.int64, copy=False)
    if F.min() < 0 or F.max() >= len(V):
        raise ValueError(f"faces: indices must be in [0, {len(V)}), got [{F.min()}, {F.max()}]")
    m = len(F)
    UV = np.asarray(corner_uv)
    if UV.shape != (m, 3, 2) or UV.dtype.kind not in "iuf":
        raise ValueError(f"corner_uv: expected a ({m}, 3, 2) float array, got {UV.dtype} {UV.shape}")
    UV = UV.astype(np.float64, copy=False)
    if not np.isfinite(UV).all():
        raise ValueError("corner_uv: contains NaN or inf")
    if isinstance(textures, np.ndarray) or not isinstance(textures, Sequence):
        raise ValueError(f"textures: expected a list of images, got {type(textures).__name__}")
    texs = [_checked_image(t, f"textures[{g}]", "u") for g, t in enumerate(textures)]
    G = np.asarray(face_group)
    if G.shape != (m,) or G.dtype.kind not in "iu":
        raise ValueError(f"face_group: expected a ({m},) integer array, got {G.dtype} {G.shape}")
    G = G.astype(np.int64, copy=False)
    if G.min() < -1 or G.max() >= len(texs):
        raise ValueError(f"face_group: values must be -1 or in [0, {len(texs)}), got [{G.min()}, {G.max()}]")
    if names is None:
        names = [f"group_{g}" for g in range(len(texs))]
    else:
        names = [names] if isinstance(names, str) else list(names)
        if len(names) != len(texs) or not all(isinstance(s, str) for s in names):
            raise ValueError(f"names: expected {len(texs)} strings (one per texture), got {names!r}")
    return V, F, UV, G, texs, names


def _checked_image(image, where: str, kinds: str) -> np.ndarray | bytes:
    """An image as given: PNG bytes (checked by signature) or an (H, W, 3|4) array of dtype kind in
    ``kinds`` ("u": uint8 only; "uf": uint8 or float); ``ValueError`` naming ``where`` otherwise."""
    if isinstance(image, (bytes, bytearray)):  # an already encoded PNG (reused across requests)
        if bytes(image[:8]) != b"\x89PNG\r\n\x1a\n":
            raise ValueError(f"{where}: bytes given, but not a PNG file")
        return bytes(image)
    a = np.asarray(image)
    ok_dtype = a.dtype == np.uint8 if kinds == "u" else a.dtype.kind in kinds
    if not ok_dtype or a.ndim != 3 or a.shape[2] not in (3, 4) or min(a.shape[:2]) == 0:
        want = "a (H, W, 3|4) uint8 image" if kinds == "u" else "an (H, W, 3) image (or 4 channels), uint8 or float"
        raise ValueError(f"{where}: expected {want}, got {a.dtype} {a.shape}")
    return np.ascontiguousarray(a)


def _check_pbr(pbr, n: int) -> list:
    """Per texture its PBR maps or None (``pbr`` None: none at all)."""
    if pbr is None:
        return [None] * n
    if isinstance(pbr, (str, bytes)) or not isinstance(pbr, Sequence) or len(pbr) != n:
        raise ValueError(f"pbr: expected one entry (maps or None) per texture ({n})")
    out = []
    for g, m in enumerate(pbr):
        if m is None:
            out.append(None)
            continue
        if not all(hasattr(m, a) for a in ("orm", "normal", "occlusion")):
            raise ValueError(f"pbr[{g}]: expected PbrMaps (orm, normal, occlusion), got {type(m).__name__}")
        for name in ("orm", "normal"):
            _checked_image(getattr(m, name), f"pbr[{g}].{name}", "uf")
        out.append(m)
    return out


def _groups(face_group: np.ndarray, n_groups: int) -> list[tuple[int, np.ndarray]]:
    """[(group, face indices)] for each non-empty group, the untextured group -1 last."""
    order = np.argsort(face_group, kind="stable")
    bounds = np.concatenate([[0], np.cumsum(np.bincount(face_group + 1, minlength=n_groups + 1))])
    out = [(g - 1, order[bounds[g] : bounds[g + 1]]) for g in range(n_groups + 1)]
    out = [x for x in out if len(x[1])]
    return out[1:] + out[:1] if out[0][0] == -1 else out


# --------------------------------------------------------------------------- geometry


def _split_vertices(faces: np.ndarray, st: np.ndarray | None):
    """Split vertices per unique (vertex index, texcoord) pair.

    faces: (k, 3) int64; st: (k, 3, 2) float32 stored texcoords or None.
    Returns (vid (s,) int64 source vertex per split vertex, st_split (s, 2) float32 or None,
    indices (k, 3) uint32).
    """
    vid = faces.reshape(-1)
    if st is None:
        keys, inv = np.unique(vid, return_inverse=True)
        return keys, None, inv.reshape(-1, 3).astype(np.uint32)
    st = np.ascontiguousarray(st.reshape(-1, 2) + np.float32(0))  # -0.0 -> +0.0
    st_keys, st_inv = np.unique(st.view(np.int64).ravel(), return_inverse=True)
    n_st = len(st_keys)
    keys, inv = np.unique(vid * n_st + st_inv.ravel(), return_inverse=True)
    st_split = st_keys[keys % n_st].view(np.float32).reshape(-1, 2)
    return keys // n_st, st_split, inv.reshape(-1, 3).astype(np.uint32)


def _smooth_normals(vertices: np.ndarray, faces: np.ndarray, vid: np.ndarray, normals: np.ndarray | None = None) -> np.ndarray:
    """Area-weighted unit vertex normals (s, 3) float32 for the split vertices of one primitive
    (``vid``: each split vertex's source vertex).

    Normals are accumulated per *source* vertex over the primitive's faces
    (:func:`proctex.texture.pbr.vertex_normals`), so texture seams do not become shading seams.
    Vertices whose faces are all degenerate (or cancel) get +z. ``normals``: the faces'
    :func:`proctex.texture.pbr.area_normals` when the caller has them.
    """
    from .pbr import vertex_normals

    return vertex_normals(vertices, faces, normals)[vid].astype(np.float32)


#: :func:`_primitive_arrays` combines (primitive, vertex, texcoord) into one int64 key below this.
_KEY_LIMIT = 2.0**62


def _primitive_arrays(V: np.ndarray, F: np.ndarray, UV: np.ndarray, groups: list[tuple[int, np.ndarray]], tangents: list[bool]) -> list[tuple]:
    """The vertex data of every primitive of a GLB, computed for all of them at once (a handful of
    array passes, not a handful per primitive): per ``groups`` entry ``(g, face indices)``,
    ``(vid (s,) int64, st (s, 2) float32 or None, indices (k, 3) uint32, normals (s, 3) float32,
    tangents (s, 4) float32 or None)`` as :func:`_split_vertices`, :func:`_smooth_normals` and
    :func:`_split_tangents` give them one primitive at a time, the same bits (each vertex's sums
    take its primitive's corners in the same order); ``tangents``: per entry whether it needs them.
    Shapes too large for one combined key are done one primitive at a time."""
    from .pbr import area_normals, key_tangents, vertex_normals

    fn_all = area_normals(V, F)
    n, n_rows = len(V), len(groups)
    order = np.concatenate([idx for _, idx in groups])
    gathered = _gather_corners(F, UV, fn_all, order, [(len(idx), g >= 0) for g, idx in groups], n)
    if gathered is not None:  # compiled: the gathers, keys and texcoords below in one pass
        f_o, uv_o, fn_o, keys, st = gathered
    else:
        f_o, uv_o, fn_o = F[order], UV[order], fn_all[order]  # the faces in primitive order, gathered once
        keys = np.repeat(np.arange(n_rows), [3 * len(idx) for _, idx in groups]) * n + f_o.reshape(-1)  # primitive * n + vertex
        st = np.empty((len(order), 3, 2), np.float32)
        st[:, :, 0] = uv_o[:, :, 0]
        st[:, :, 1] = 1.0 - uv_o[:, :, 1]
        textured = np.concatenate([np.full(len(idx), g >= 0) for g, idx in groups])
        if not textured.all():
            st[~textured] = 0.0  # the untextured primitive: no texcoords (split by vertex alone)
        st = np.ascontiguousarray(st.reshape(-1, 2) + np.float32(0))  # -0.0 -> +0.0
    pairs = _split_pairs(keys, st.view(np.int64).ravel(), n_rows * n)
    if pairs is not None:  # compiled: the pairs sorted by (primitive, vertex, texcoord bits) without a full sort
        source, st_bits, inv = pairs
    else:
        st_keys, st_inv = np.unique(st.view(np.int64).ravel(), return_inverse=True)
        n_st = len(st_keys)
    if pairs is None and float(n_rows) * n * n_st >= _KEY_LIMIT:  # one key would overflow: primitive by primitive
        out, c0 = [], 0
        for (g, idx), want in zip(groups, tangents):
            f = F[idx]
            vid, st_split, indices = _split_vertices(f, st[c0 : c0 + 3 * len(idx)].reshape(-1, 3, 2) if g >= 0 else None)
            c0 += 3 * len(idx)
            normals = _smooth_normals(V, f, vid, fn_all[idx])
            out.append((vid, st_split, indices, normals, _split_tangents(V, f, UV[idx], indices, normals, fn_all[idx]) if want else None))
        return out
    if pairs is None:  # split vertices: the unique (primitive, vertex, texcoord) triples, sorted as each primitive's own
        triples, inv = np.unique(keys * n_st + st_inv.ravel(), return_inverse=True)
        inv = inv.ravel()
        source, st_bits = triples // n_st, st_keys[triples % n_st]  # primitive * n + vertex; texcoord bits
    vid = source % n
    # smooth normals per (primitive, source vertex): its corners' face normals in face order
    bin_of_split = np.concatenate([[0], np.cumsum(source[1:] != source[:-1])])
    sums = vertex_normals(np.zeros((int(bin_of_split[-1]) + 1 if len(source) else 0, 3)), bin_of_split[inv].reshape(-1, 3), fn_o)
    normals = sums[bin_of_split].astype(np.float32)
    starts = np.searchsorted(source // n, np.arange(n_rows + 1))
    frames = None
    if any(tangents):
        if all(tangents):  # every face: the gathered arrays as they are
            frames = key_tangents(V, f_o, uv_o, inv, normals.astype(np.float64), fn_o).astype(np.float32)
        else:
            rows_t = np.flatnonzero(np.concatenate([np.full(len(idx), want) for (_, idx), want in zip(groups, tangents)]))
            split_t = inv.reshape(-1, 3)[rows_t]
            frames = key_tangents(V, f_o[rows_t], uv_o[rows_t], split_t.reshape(-1), normals.astype(np.float64), fn_o[rows_t]).astype(np.float32)
    out, c0 = [], 0
    for row, ((g, idx), want) in enumerate(zip(groups, tangents)):
        a, b = starts[row], starts[row + 1]
        indices = (inv[c0 : c0 + 3 * len(idx)] - a).reshape(-1, 3).astype(np.uint32)
        c0 += 3 * len(idx)
        st_split = st_bits[a:b].view(np.float32).reshape(-1, 2) if g >= 0 else None
        out.append((vid[a:b], st_split, indices, normals[a:b], frames[a:b] if want else None))
    return out


def _gather_corners(F: np.ndarray, UV: np.ndarray, fn: np.ndarray, order: np.ndarray, rows: list[tuple[int, bool]], n: int) -> tuple | None:
    """:func:`proctex.texture.vertex_kernels.gather_corners` of the faces ``order`` (the primitives'
    faces one after the other, ``rows``: per primitive its face count and whether it is textured),
    or None where numba does not import (:func:`_primitive_arrays` gathers them in arrays then)."""
    try:
        from .vertex_kernels import gather_corners
    except ImportError:
        return None
    return gather_corners(F, UV, fn, order, np.array([r[0] for r in rows], np.int64), np.array([r[1] for r in rows], np.bool_), n)


def _split_pairs(source: np.ndarray, bits: np.ndarray, n_sources: int) -> tuple[np.ndarray, np.ndarray, np.ndarray] | None:
    """:func:`proctex.texture.vertex_kernels.split_pairs` of the corners' ``(primitive * n + vertex,
    texcoord bits)``, or None where numba does not import or the sources far outnumber the corners
    (a counting sort's table of every (primitive, vertex) would then cost more than sorting the
    corners): :func:`_primitive_arrays` then sorts combined keys with ``np.unique``, the same pairs
    in the same order."""
    if n_sources > 8 * len(source) + 4096:
        return None
    try:
        from .vertex_kernels import split_pairs
    except ImportError:
        return None
    return split_pairs(source, bits, n_sources)


# --------------------------------------------------------------------------- GLB


class _Blob:
    """The GLB under construction as plain JSON dicts, with a binary buffer of 4-byte aligned
    bufferViews (written directly: building pygltflib objects cost more than the rest of a GLB)."""

    def __init__(self, doc: dict):
        self.doc, self.parts, self.offset = doc, [], 0

    def view(self, data: bytes | memoryview, target: int | None = None) -> int:
        """A bufferView of ``data`` (bytes, or a byte view of an array the blob then keeps, copied
        once, into the file, by :meth:`to_bytes`)."""
        view = {"buffer": 0, "byteOffset": self.offset, "byteLength": len(data)}
        if target is not None:
            view["target"] = target
        self.doc["bufferViews"].append(view)
        pad = -len(data) % 4
        self.parts += [data, b"\0" * pad]
        self.offset += len(data) + pad
        return len(self.doc["bufferViews"]) - 1

    def accessor(self, array: np.ndarray, kind: str, target: int, minmax: bool = False) -> int:
        ctype = 5125 if array.dtype == np.uint32 else 5126  # UNSIGNED_INT, FLOAT
        data = memoryview(np.ascontiguousarray(array).reshape(-1).view(np.uint8))  # the array's bytes, not a copy of them (empty too)
        acc = {"bufferView": self.view(data, target), "componentType": ctype, "count": len(array), "type": kind}
        if minmax:
            lo, hi = bounds(array)
            acc["min"], acc["max"] = lo.tolist(), hi.tolist()
        self.doc["accessors"].append(acc)
        return len(self.doc["accessors"]) - 1

    def to_bytes(self) -> bytes:
        """The GLB file: header, JSON chunk (space-padded), BIN chunk (zero-padded)."""
        doc = {k: v for k, v in self.doc.items() if v != []}
        n_binary = self.offset  # every view is padded to 4 bytes: the BIN chunk needs no more
        doc["buffers"] = [{"byteLength": n_binary}]
        text = json.dumps(doc, separators=(",", ":")).encode()
        text += b" " * (-len(text) % 4)
        total = 12 + 8 + len(text) + 8 + n_binary
        header = b"glTF" + (2).to_bytes(4, "little") + total.to_bytes(4, "little")
        return b"".join([header, len(text).to_bytes(4, "little"), b"JSON", text, n_binary.to_bytes(4, "little"), b"BIN\0", *self.parts])  # one copy of the data


def png_bytes(image: np.ndarray | bytes) -> bytes:
    """PNG bytes of a texture, or the bytes themselves when already encoded."""
    return bytes(image) if isinstance(image, (bytes, bytearray)) else encode_png(image)


def _split_tangents(vertices: np.ndarray, faces: np.ndarray, corner_uv: np.ndarray, indices: np.ndarray, normals: np.ndarray, area_normals: np.ndarray | None = None) -> np.ndarray:
    """(s, 4) float32 TANGENT of each split vertex (one per (vertex, texcoord) pair, the pairs
    :func:`proctex.texture.pbr.corner_tangents` averages over), orthogonal to its NORMAL (``normals`` (s, 3));
    ``area_normals``: the faces' :func:`proctex.texture.pbr.area_normals` when the caller has them."""
    from .pbr import key_tangents

    return key_tangents(vertices, faces, corner_uv, indices.reshape(-1).astype(np.int64), normals.astype(np.float64), area_normals).astype(np.float32)


#: Node rotations (glTF quaternions x, y, z, w) that stand a shape with the given up axis upright in
#: glTF's +Y-up world; the vertex data stays in the shape's own frame.
UP_ROTATIONS = {"y": None, "z": [-math.sqrt(0.5), 0.0, 0.0, math.sqrt(0.5)], "x": [0.0, 0.0, math.sqrt(0.5), math.sqrt(0.5)]}


def glb_bytes(
    vertices,
    faces,
    corner_uv,
    face_group,
    textures,
    names=None,
    double_sided: bool = True,
    up: str = "y",
    image_uris: list[str | None] | None = None,
    pbr=None,
    pbr_uris: list[tuple[str, str] | None] | None = None,
) -> bytes:
    """Encode a textured shape as a GLB (glTF 2.0 binary) file.

    Args: see the module docstring (vertices (n, 3) float64, faces (m, 3) int64, corner_uv
    (m, 3, 2) float64 with v up, face_group (m,) int64 in [-1, G), G uint8 textures (H, W, 3|4),
    optional G names); ``double_sided`` sets the materials' doubleSided flag; ``up`` is the
    shape's up axis ("x", "y" or "z"): glTF is +Y up, so a z-up or x-up shape gets a node rotation
    (:data:`UP_ROTATIONS`) and stands upright in every viewer, with its vertex data unchanged.

    The file holds one node and one mesh with one triangle primitive per non-empty group (faces of
    group -1 form a last primitive with a grey untextured material). Each primitive has its own
    vertices, split per unique (vertex, texcoord) pair, with POSITION (min/max), area-weighted smooth
    NORMAL, TEXCOORD_0 = (u, 1 - v) and uint32 indices. Each group has a material (its ``extras``
    ``{"group": g}``) named after it
    (baseColorTexture, metallic 0, roughness 0.8) and a PNG image embedded in the buffer; all
    textures share one LINEAR / LINEAR_MIPMAP_LINEAR, CLAMP_TO_EDGE sampler. Textures of empty
    groups are left out. ``image_uris``: per group a URI (relative to the GLB's own URL, or absolute)
    that the image is read from instead of being embedded, or None to embed it (so a client that
    caches the textures is sent only the geometry and UVs).

    ``pbr``: per texture its :class:`~proctex.texture.pbr.PbrMaps` (or None). A group with maps gets
    metallic and roughness factors 1 with ``metallicRoughnessTexture`` on the ORM image (and
    ``occlusionTexture`` on the same image when it holds occlusion), a ``normalTexture``, and a
    TANGENT attribute (:func:`proctex.texture.pbr.corner_tangents`, the frame the normal map was
    baked in). ``pbr_uris``: per group ``(orm URI, normal URI)`` to refer to instead of embedding.
    Raises ValueError on malformed input.
    """
    V, F, UV, FG, texs, names = _check_shape(vertices, faces, corner_uv, face_group, textures, names)
    maps = _check_pbr(pbr, len(texs))
    map_uris = list(pbr_uris) if pbr_uris is not None else [None] * len(texs)
    if len(map_uris) != len(texs):
        raise ValueError(f"pbr_uris needs one entry per texture ({len(texs)}), got {len(map_uris)}")
    if up not in UP_ROTATIONS:
        raise ValueError(f"up must be x, y or z, got {up!r}")
    uris = list(image_uris) if image_uris is not None else [None] * len(texs)
    if len(uris) != len(texs):
        raise ValueError(f"image_uris needs one entry per texture ({len(texs)}), got {len(uris)}")
    node = {"mesh": 0}
    if UP_ROTATIONS[up] is not None:
        node["rotation"] = UP_ROTATIONS[up]
    doc: dict = {
        "asset": {"generator": "proctex.texture.export", "version": "2.0"},
        "scene": 0,
        "scenes": [{"nodes": [0]}],
        "nodes": [node],
        "meshes": [],
        "accessors": [],
        "bufferViews": [],
        "images": [],
        "textures": [],
        "samplers": [],
        "materials": [],
    }
    blob = _Blob(doc)
    primitives = []
    groups = _groups(FG, len(texs))
    arrays = _primitive_arrays(V, F, UV, groups, [g >= 0 and maps[g] is not None for g, _ in groups])
    for (g, idx), (vid, st_split, indices, normals, frames) in zip(groups, arrays):
        attrs = {"POSITION": blob.accessor(V[vid].astype(np.float32), "VEC3", ARRAY_BUFFER, minmax=True), "NORMAL": blob.accessor(normals, "VEC3", ARRAY_BUFFER)}
        pbr: dict = {"metallicFactor": 0.0, "roughnessFactor": ROUGHNESS}
        material: dict = {}
        if g >= 0:
            attrs["TEXCOORD_0"] = blob.accessor(st_split, "VEC2", ARRAY_BUFFER)

            def texture(image, uri, suffix: str = "") -> int:
                if uri:
                    doc["images"].append({"uri": uri, "mimeType": "image/png", "name": names[g] + suffix})
                else:
                    doc["images"].append({"bufferView": blob.view(png_bytes(image)), "mimeType": "image/png", "name": names[g] + suffix})
                doc["textures"].append({"sampler": 0, "source": len(doc["images"]) - 1})
                return len(doc["textures"]) - 1

            pbr["baseColorTexture"] = {"index": texture(texs[g], uris[g])}
            name = names[g]
            material["extras"] = {"group": int(g)}  # which part group (a viewer's picking; names may repeat)
            material_maps = maps[g]
        else:
            material_maps = None
            pbr["baseColorFactor"] = list(GREY)
            name = UNTEXTURED_NAME
        if material_maps is not None:
            mu = map_uris[g] or (None, None)
            orm = texture(material_maps.orm, mu[0], "_orm")
            pbr["metallicFactor"], pbr["roughnessFactor"] = 1.0, 1.0
            pbr["metallicRoughnessTexture"] = {"index": orm}
            material["normalTexture"] = {"index": texture(material_maps.normal, mu[1], "_normal")}
            if material_maps.occlusion:
                material["occlusionTexture"] = {"index": orm}
            attrs["TANGENT"] = blob.accessor(frames, "VEC4", ARRAY_BUFFER)
        doc["materials"].append({"name": name, "pbrMetallicRoughness": pbr, "doubleSided": bool(double_sided), **material})
        primitives.append({"attributes": attrs, "material": len(doc["materials"]) - 1, "mode": 4, "indices": blob.accessor(indices.reshape(-1), "SCALAR", ELEMENT_ARRAY_BUFFER)})
    if doc["textures"]:
        doc["samplers"] = [{"magFilter": 9729, "minFilter": 9987, "wrapS": 33071, "wrapT": 33071}]  # LINEAR, LINEAR_MIPMAP_LINEAR, CLAMP_TO_EDGE
    doc["meshes"] = [{"primitives": primitives}]
    return blob.to_bytes()


# --------------------------------------------------------------------------- files


def write_glb(path, vertices, faces, corner_uv, face_group, textures, names=None, double_sided: bool = True, up: str = "y", pbr=None) -> str:
    """Write :func:`glb_bytes` to ``path`` atomically (temp file + ``os.replace``); returns the path."""
    data = glb_bytes(vertices, faces, corner_uv, face_group, textures, names, double_sided, up=up, pbr=pbr)
    atomic_write(Path(path), data)
    return str(path)


def _obj_material_names(names: list[str]) -> list[str]:
    """OBJ material names: no whitespace, unique, distinct from the untextured material."""
    out, seen = [], {UNTEXTURED_NAME}
    for g, s in enumerate(names):
        s = re.sub(r"\s+", "_", s.strip()) or f"group_{g}"
        if s in seen:
            s = f"{s}_{g}"
        seen.add(s)
        out.append(s)
    return out


def _channel_png(image, channel: int) -> bytes:
    """A grey PNG of one channel of an (H, W, 3) image (array or PNG bytes)."""
    if isinstance(image, (bytes, bytearray)):
        from PIL import Image

        image = np.asarray(Image.open(io.BytesIO(bytes(image))).convert("RGB"))
    from proctex.fileio import to_uint8

    c = to_uint8(np.asarray(image))[..., channel]
    return encode_png(np.repeat(c[..., None], 3, axis=2))


def obj_files(stem: str, vertices, faces, corner_uv, face_group, textures, names=None, pbr=None) -> list[tuple[str, bytes]]:
    """The files of a textured OBJ, in memory: ``[(name, bytes)]`` for ``<stem>_<g>.png`` per
    non-empty group g (with PBR maps also ``<stem>_<g>_roughness.png``, ``_metallic.png``,
    ``_normal.png`` and, with occlusion, ``_ao.png``), ``<stem>.mtl`` and ``<stem>.obj``, in that
    order (the OBJ, which names the others, last). Inputs are as in :func:`glb_bytes`; see
    :func:`write_obj` for the format."""
    if not stem or "/" in stem or "\\" in stem:
        raise ValueError(f"stem must be a plain file name, got {stem!r}")
    V, F, UV, FG, texs, names = _check_shape(vertices, faces, corner_uv, face_group, textures, names)
    maps = _check_pbr(pbr, len(texs))
    mat_names = _obj_material_names(names)
    mtl_name = f"{stem}.mtl"
    uv_unique, uv_inv = np.unique(UV.reshape(-1, 2), axis=0, return_inverse=True)
    fv = np.stack([F + 1, uv_inv.reshape(-1, 3) + 1], axis=2).reshape(-1, 6)

    files, mtl, body = [], [], io.StringIO()
    for g, idx in _groups(FG, len(texs)):
        name = mat_names[g] if g >= 0 else UNTEXTURED_NAME
        kd = "1 1 1" if g >= 0 else " ".join(map(str, GREY[:3]))
        mtl.append(f"newmtl {name}\nKa 1 1 1\nKd {kd}\nKs 0 0 0\nd 1\nillum 1\n")
        if g >= 0:
            png = f"{stem}_{g}.png"
            files.append((png, png_bytes(texs[g])))
            mtl.append(f"map_Kd {png}\n")
        if g >= 0 and maps[g] is not None:  # the PBR extension of MTL (Pr / Pm / norm), read by Blender
            m = maps[g]
            for kind, channel, key in (("roughness", 1, "Pr"), ("metallic", 2, "Pm")) + ((("ao", 0, "Ka"),) if m.occlusion else ()):
                name_k = f"{stem}_{g}_{kind}.png"
                files.append((name_k, _channel_png(m.orm, channel)))
                mtl.append(f"{key} 1\nmap_{key} {name_k}\n" if key != "Ka" else f"map_Ka {name_k}\n")
            name_n = f"{stem}_{g}_normal.png"
            files.append((name_n, png_bytes(m.normal)))
            mtl.append(f"norm {name_n}\nmap_Bump -bm 1 {name_n}\n")
        mtl.append("\n")
        body.write(f"usemtl {name}\n")
        np.savetxt(body, fv[idx], fmt="f %d/%d %d/%d %d/%d")
    files.append((mtl_name, "".join(mtl).encode()))
    text = io.StringIO()
    text.write(f"# proctex.texture.export\nmtllib {mtl_name}\n")
    np.savetxt(text, V, fmt="v %.9g %.9g %.9g")
    np.savetxt(text, uv_unique, fmt="vt %.9g %.9g")
    text.write(body.getvalue())
    files.append((f"{stem}.obj", text.getvalue().encode()))
    return files


def write_obj(path, vertices, faces, corner_uv, face_group, textures, names=None, pbr=None) -> list[str]:
    """Write ``<stem>.obj``, ``<stem>.mtl`` and ``<stem>_<g>.png`` per non-empty group g.

    ``path`` must end in ``.obj``. Inputs are as in :func:`glb_bytes`. ``vt`` lines use the OBJ
    convention (v up, equal to ``corner_uv``); faces are ``f v/vt`` grouped by ``usemtl``; faces of
    group -1 use a grey material without a texture map. Material names are the group names with
    whitespace replaced by ``_`` (made unique). Every file is written atomically, the PNGs and MTL
    before the OBJ (:func:`obj_files`). Returns the written paths: [obj, mtl, png...].
    """
    path = Path(path)
    if path.suffix.lower() != ".obj":
        raise ValueError(f"path: expected a file name ending in .obj, got {str(path)!r}")
    written = []
    for name, data in obj_files(path.stem, vertices, faces, corner_uv, face_group, textures, names, pbr):
        atomic_write(path.parent / name, data)
        written.append(str(path.parent / name))
    return [written[-1], written[-2]] + written[:-2]


# --------------------------------------------------------------------------- validator


def _validator_dir() -> Path:
    return Path(sys.prefix) / "node" / "node_modules" / "gltf-validator"


def validator_available() -> bool:
    """True when ``node`` is on PATH and the gltf-validator npm package is inside the venv."""
    return shutil.which("node") is not None and (_validator_dir() / "package.json").is_file()


_VALIDATE_JS = """
const validator = require(%s);
const fs = require('fs');
const path = require('path');
const data = fs.readFileSync(0);
const base = %s;
const options = {uri: %s, maxIssues: 1000};
if (base !== null) {  // external images resolved next to the file
  options.externalResourceFunction = (uri) => new Promise((resolve, reject) => {
    fs.readFile(path.resolve(base, decodeURIComponent(uri.split('?')[0])), (err, d) => err ? reject(err.toString()) : resolve(new Uint8Array(d)));
  });
}
validator.validateBytes(new Uint8Array(data), options)
  .then(r => process.stdout.write(JSON.stringify(r)),
        e => { process.stderr.write(String(e)); process.exit(2); });
"""


def validate_glb(path_or_bytes, timeout: float = 120.0) -> dict:
    """Run the Khronos glTF validator on a GLB file path or GLB bytes; returns its report dict.
    Given a path, images the file refers to by URI are read relative to its folder.

    The report has ``issues`` with ``numErrors``, ``numWarnings``, ``numInfos``, ``numHints`` and
    ``messages`` (each with ``code``, ``message``, ``severity`` 0=error..3=hint, ``pointer``).
    Raises RuntimeError when node or the validator is missing or the validator cannot run.
    """
    if not validator_available():
        raise RuntimeError(f"glTF validator unavailable: need node on PATH and {_validator_dir()}")
    if isinstance(path_or_bytes, (bytes, bytearray, memoryview)):
        data, uri, base = bytes(path_or_bytes), "asset.glb", None
    else:
        data, uri, base = Path(path_or_bytes).read_bytes(), Path(path_or_bytes).name, str(Path(path_or_bytes).resolve().parent)
    script = _VALIDATE_JS % (json.dumps(str(_validator_dir())), json.dumps(base), json.dumps(uri))
    proc = subprocess.run(["node", "-e", script], input=data, capture_output=True, timeout=timeout)
    if proc.returncode != 0:
        raise RuntimeError(f"glTF validator failed (rc {proc.returncode}): {proc.stderr.decode(errors='replace')[-2000:]}")
    return json.loads(proc.stdout)


# --------------------------------------------------------------------------- reader
