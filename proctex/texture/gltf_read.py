"""Reading textured glTF / GLB back (:func:`read_textured_glb`): node transforms applied, triangles from every
primitive mode, per-material base-colour textures and factors. The tests and the evaluation read our own
exports (and users' files) with it."""

from __future__ import annotations

import base64
import binascii
import io
import urllib.parse
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pygltflib as gl
from PIL import Image

from .export import GREY, UNTEXTURED_NAME

_COMPONENT_DTYPES = {5120: np.int8, 5121: np.uint8, 5122: np.int16, 5123: np.uint16, 5125: np.uint32, 5126: np.float32}
_TYPE_SIZES = {"SCALAR": 1, "VEC2": 2, "VEC3": 3, "VEC4": 4, "MAT2": 4, "MAT3": 9, "MAT4": 16}
#: the most pixels a texture of a read glTF may have (checked from its header before decoding): an
#: 8192 x 8192 atlas, the largest a family paints.
MAX_IMAGE_PIXELS = 8192 * 8192
_MODE_NAMES = {0: "POINTS", 1: "LINES", 2: "LINE_LOOP", 3: "LINE_STRIP", 4: "TRIANGLES", 5: "TRIANGLE_STRIP", 6: "TRIANGLE_FAN"}


@dataclass
class TexturedMesh:
    """A textured shape read back from a glTF file (conventions of the module docstring).

    Attributes:
        vertices: (n, 3) float64 world positions (node transforms applied).
        faces: (m, 3) int64 vertex indices, m >= 1 (vertices are not shared between primitives).
        corner_uv: (m, 3, 2) float64 per-corner UVs, **v up** (glTF's (s, t) read back as (s, 1 - t)).
        face_group: (m,) int64 in [0, G): one group per material (primitives without a material
            share one grey group).
        textures: G (H, W, 3) uint8 images, row 0 at the top; untextured materials get a 1x1 image
            of their base colour factor.
        names: G group (material) names.
        notes: what was skipped or approximated (non-triangle primitives, missing texcoords, ...).
        pbr: per group its :class:`proctex.texture.pbr.PbrMaps` (ORM from ``metallicRoughnessTexture``
            times its factors, normal from ``normalTexture``), or None for a material with neither
            texture (colour only).
        corner_normals: (m, 3, 3) float64 unit normals per face corner from the file's NORMAL
            attributes (world frame), or None when a primitive has none.
    """

    vertices: np.ndarray
    faces: np.ndarray
    corner_uv: np.ndarray
    face_group: np.ndarray
    textures: list[np.ndarray]
    names: list[str]
    notes: list[str] = field(default_factory=list)
    pbr: list = field(default_factory=list)
    corner_normals: np.ndarray | None = None


def _data_uri(uri: str) -> bytes:
    head, _, payload = uri.partition(",")
    try:
        return base64.b64decode(payload) if head.endswith(";base64") else urllib.parse.unquote_to_bytes(payload)
    except (ValueError, binascii.Error) as exc:
        raise ValueError(f"bad data: URI ({exc})") from exc


class _GltfReader:
    """Decodes buffers, accessors and images of a loaded glTF (``base``: folder for external URIs)."""

    def __init__(self, gltf: gl.GLTF2, base: Path | None):
        self.gltf, self.base, self._buffers = gltf, base, {}

    def _uri(self, uri: str, what: str) -> bytes:
        if uri.startswith("data:"):
            return _data_uri(uri)
        if self.base is None:
            raise ValueError(f"{what} refers to an external file {uri!r}: read the file from a path")
        path = self.base / urllib.parse.unquote(uri)
        if not path.is_file():
            raise ValueError(f"{what} refers to {uri!r}, which does not exist next to the file")
        return path.read_bytes()

    def buffer(self, i: int) -> bytes:
        if i not in self._buffers:
            if not 0 <= i < len(self.gltf.buffers):
                raise ValueError(f"buffer {i} does not exist")
            uri = self.gltf.buffers[i].uri
            if uri:
                self._buffers[i] = self._uri(uri, f"buffer {i}")
            else:
                blob = self.gltf.binary_blob()
                if i != 0 or blob is None:
                    raise ValueError(f"buffer {i} has no data (no URI and no GLB binary chunk)")
                self._buffers[i] = bytes(blob)
        return self._buffers[i]

    def view(self, i: int) -> tuple[bytes, int]:
        """(bytes of bufferView i, its byteStride or 0)."""
        if i is None or not 0 <= i < len(self.gltf.bufferViews):
            raise ValueError(f"bufferView {i} does not exist")
        bv = self.gltf.bufferViews[i]
        data = self.buffer(bv.buffer or 0)
        start, length = bv.byteOffset or 0, bv.byteLength or 0
        if start + length > len(data):
            raise ValueError(f"bufferView {i} ends at byte {start + length}, past its buffer ({len(data)} bytes)")
        return data[start : start + length], bv.byteStride or 0

    def accessor(self, i: int) -> np.ndarray:
        """Accessor i as a (count, components) array (float64 when ``normalized``)."""
        if i is None or not 0 <= i < len(self.gltf.accessors):
            raise ValueError(f"accessor {i} does not exist")
        acc = self.gltf.accessors[i]
        if acc.componentType not in _COMPONENT_DTYPES or acc.type not in _TYPE_SIZES:
            raise ValueError(f"accessor {i}: unsupported component type {acc.componentType} / type {acc.type}")
        dtype = np.dtype(_COMPONENT_DTYPES[acc.componentType]).newbyteorder("<")
        k, count = _TYPE_SIZES[acc.type], int(acc.count or 0)
        if acc.bufferView is None:
            out = np.zeros((count, k), dtype)
        else:
            raw, stride = self.view(acc.bufferView)
            offset, elem = acc.byteOffset or 0, k * dtype.itemsize
            stride = stride or elem
            if count and offset + stride * (count - 1) + elem > len(raw):
                raise ValueError(f"accessor {i}: {count} elements do not fit in bufferView {acc.bufferView}")
            out = np.ndarray((count, k), dtype, buffer=raw, offset=offset, strides=(stride, dtype.itemsize)).copy()
        if acc.sparse is not None and acc.sparse.count:
            sp = acc.sparse
            idx_dtype = np.dtype(_COMPONENT_DTYPES[sp.indices.componentType]).newbyteorder("<")
            raw, _ = self.view(sp.indices.bufferView)
            idx = np.frombuffer(raw, idx_dtype, sp.count, sp.indices.byteOffset or 0).astype(np.int64)
            raw, _ = self.view(sp.values.bufferView)
            vals = np.frombuffer(raw, dtype, sp.count * k, sp.values.byteOffset or 0).reshape(-1, k)
            if idx.size and (idx.min() < 0 or idx.max() >= count):
                raise ValueError(f"accessor {i}: sparse indices out of range")
            out[idx] = vals
        if acc.normalized and dtype.kind in "iu":
            info = np.iinfo(dtype)
            out = np.maximum(out.astype(np.float64) / info.max, -1.0)
        return out

    def image(self, i: int) -> np.ndarray:
        """Image i decoded to (H, W, 3) uint8 (alpha dropped)."""
        if i is None or not 0 <= i < len(self.gltf.images):
            raise ValueError(f"image {i} does not exist")
        im = self.gltf.images[i]
        if im.bufferView is not None:
            data, _ = self.view(im.bufferView)
        elif im.uri:
            data = self._uri(im.uri, f"image {i}")
        else:
            raise ValueError(f"image {i} has neither a bufferView nor a URI")
        try:
            with Image.open(io.BytesIO(data), formats=["PNG", "JPEG", "WEBP"]) as pil:
                w, h = pil.size
                if w * h > MAX_IMAGE_PIXELS:  # read from the header: never decoded
                    raise ValueError(f"{w} x {h} pixels, over the limit of {MAX_IMAGE_PIXELS:,}")
                return np.asarray(pil.convert("RGB"), dtype=np.uint8).copy()
        except Exception as exc:  # PIL raises several types for undecodable data
            raise ValueError(f"image {i} ({im.mimeType or 'unknown type'}) cannot be decoded: {exc}") from exc


def _node_matrix(node: gl.Node) -> np.ndarray:
    """The node's local 4x4 transform (``matrix``, column-major, or T * R * S)."""
    if node.matrix is not None and len(node.matrix) == 16:
        return np.asarray(node.matrix, dtype=np.float64).reshape(4, 4).T
    m = np.eye(4)
    if node.scale is not None:
        m = np.diag([*np.asarray(node.scale, dtype=np.float64), 1.0])
    if node.rotation is not None:
        x, y, z, w = np.asarray(node.rotation, dtype=np.float64) / (np.linalg.norm(node.rotation) or 1.0)
        r = np.eye(4)
        r[:3, :3] = [
            [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
            [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
            [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
        ]
        m = r @ m
    if node.translation is not None:
        t = np.eye(4)
        t[:3, 3] = node.translation
        m = t @ m
    return m


def _scene_meshes(gltf: gl.GLTF2) -> list[tuple[int, np.ndarray]]:
    """[(mesh index, world matrix)] of every node with a mesh in the default scene, depth first."""
    nodes = gltf.nodes or []
    if gltf.scenes:
        s = gltf.scene if gltf.scene is not None else 0
        if not 0 <= s < len(gltf.scenes):
            raise ValueError(f"the default scene {s} does not exist")
        roots = list(gltf.scenes[s].nodes or [])
    else:  # no scenes: every node that is nobody's child
        children = {c for n in nodes for c in (n.children or [])}
        roots = [i for i in range(len(nodes)) if i not in children]
    out: list[tuple[int, np.ndarray]] = []
    stack = [(i, np.eye(4), ()) for i in reversed(roots)]
    while stack:
        i, parent, path = stack.pop()
        if not 0 <= i < len(nodes):
            raise ValueError(f"node {i} does not exist")
        if i in path:
            raise ValueError(f"node {i} is its own ancestor (cyclic node hierarchy)")
        world = parent @ _node_matrix(nodes[i])
        if nodes[i].mesh is not None:
            out.append((nodes[i].mesh, world))
        stack += [(c, world, path + (i,)) for c in reversed(nodes[i].children or [])]
    return out


def _triangles(idx: np.ndarray, mode: int) -> np.ndarray:
    """(k, 3) int64 triangles from a TRIANGLES / TRIANGLE_STRIP / TRIANGLE_FAN index list."""
    n = len(idx)
    if mode == 4:
        return idx[: n // 3 * 3].reshape(-1, 3)
    if n < 3:
        return np.zeros((0, 3), np.int64)
    k = np.arange(n - 2)
    if mode == 5:  # glTF: triangle k = (k, k + 1 + k % 2, k + 2 - k % 2)
        return np.stack([idx[k], idx[k + 1 + k % 2], idx[k + 2 - k % 2]], axis=1)
    return np.stack([idx[k + 1], idx[k + 2], np.full(n - 2, idx[0])], axis=1)  # fan


def read_textured_glb(path_or_bytes) -> TexturedMesh:
    """Read a textured GLB (or a .gltf JSON file given by path) into a :class:`TexturedMesh`.

    ``path_or_bytes``: a file path, or the bytes of a GLB file.

    Every mesh primitive of every node of the default scene is read with its node's world matrix
    (parent chains included; mirroring transforms flip the winding back). Indices may be absent or
    u8/u16/u32; TRIANGLES, TRIANGLE_STRIP and TRIANGLE_FAN are read, POINTS/LINES primitives are
    skipped with a note. Each material becomes one group: its baseColorTexture (embedded
    bufferView PNG/JPEG, data: URI or, for files on disk, a relative URI) multiplied by its
    baseColorFactor, addressed by the TEXCOORD_<texCoord> of the primitive converted to v up
    (``v = 1 - t``). A material without a texture gets a 1x1 texture of its factor colour
    (``round(255 * factor)``, no sRGB conversion); primitives without a material share one grey
    group. Texture transforms (KHR_texture_transform), vertex colours, morph targets and skins are
    ignored.

    A GLB written by :func:`glb_bytes` reads back to the arrays it was written from, up to vertex
    splitting, face order (grouped by material), float32 rounding of positions and UVs, and
    textures of empty groups (left out); a group -1 comes back as a 1x1 (128, 128, 128) texture.
    Raises ValueError for a missing or unreadable file, non-glTF data, or no triangles.
    """
    base: Path | None = None
    if isinstance(path_or_bytes, (bytes, bytearray, memoryview)):
        data, what = bytes(path_or_bytes), "GLB data"
    else:
        path = Path(path_or_bytes)
        if not path.is_file():
            raise ValueError(f"{path}: no such file")
        try:
            data = path.read_bytes()
        except OSError as exc:
            raise ValueError(f"{path}: cannot be read ({exc})") from exc
        base, what = path.parent, str(path)
    is_json = base is not None and data.lstrip()[:1] == b"{"
    if data[:4] != b"glTF" and not is_json:
        raise ValueError(f"{what} is not a GLB file (it does not start with the 'glTF' magic)")
    try:
        gltf = gl.GLTF2.from_json(data.decode("utf-8"), infer_missing=True) if is_json else gl.GLTF2.load_from_bytes(data)
    except Exception as exc:  # pygltflib raises struct/IO/JSON/key errors on corrupt files
        raise ValueError(f"{what} cannot be read as glTF: {type(exc).__name__}: {exc}") from exc
    if gltf is None:
        raise ValueError(f"{what} cannot be read as glTF: no JSON chunk")
    try:
        return _read_gltf(gltf, _GltfReader(gltf, base))
    except ValueError as exc:
        raise ValueError(f"{what}: {exc}") from exc
    except (TypeError, AttributeError, IndexError, KeyError) as exc:  # malformed JSON structure
        raise ValueError(f"{what}: malformed glTF ({type(exc).__name__}: {exc})") from exc


def _read_gltf(gltf: gl.GLTF2, rd: _GltfReader) -> TexturedMesh:
    notes: list[str] = []
    groups: dict[int | None, int] = {}  # material index (None: no material) -> group
    textures: list[np.ndarray] = []
    names: list[str] = []
    texcoord_of_group: list[int | None] = []
    pbr_maps: list = []
    V, F, UV, G, NRM = [], [], [], [], []
    n_vertices = 0

    def group_of(mat: int | None) -> int:
        if mat in groups:
            return groups[mat]
        if mat is None:
            tex, name, tc = np.full((1, 1, 3), round(GREY[0] * 255), np.uint8), UNTEXTURED_NAME, None
        else:
            if not 0 <= mat < len(gltf.materials):
                raise ValueError(f"material {mat} does not exist")
            m = gltf.materials[mat]
            pbr = m.pbrMetallicRoughness or gl.PbrMetallicRoughness()
            factor = np.clip(np.asarray(pbr.baseColorFactor or [1.0] * 4, dtype=np.float64)[:3], 0, 1)
            name, tc, tex = m.name or f"material_{mat}", None, None
            info = pbr.baseColorTexture
            if info is not None and info.index is not None:
                if not 0 <= info.index < len(gltf.textures):
                    raise ValueError(f"material {mat}: texture {info.index} does not exist")
                source = gltf.textures[info.index].source
                if source is None:
                    notes.append(f"material {name!r}: texture {info.index} has no PNG/JPEG source; using its colour factor")
                else:
                    tex, tc = rd.image(source), int(info.texCoord or 0)
                    if (factor != 1).any():
                        tex = np.round(tex * factor).astype(np.uint8)
                    if "KHR_texture_transform" in (info.extensions or {}):
                        notes.append(f"material {name!r}: KHR_texture_transform ignored")
            if tex is None:
                tex = np.round(factor * 255).astype(np.uint8).reshape(1, 1, 3)
            maps = _material_maps(gltf, rd, m, pbr, name, notes)
        groups[mat] = len(textures)
        pbr_maps.append(maps if mat is not None else None)
        textures.append(tex)
        names.append(name)
        texcoord_of_group.append(tc)
        return groups[mat]

    for mesh_index, world in _scene_meshes(gltf):
        if not 0 <= mesh_index < len(gltf.meshes):
            raise ValueError(f"mesh {mesh_index} does not exist")
        for p, prim in enumerate(gltf.meshes[mesh_index].primitives or []):
            where = f"mesh {mesh_index} primitive {p}"
            mode = 4 if prim.mode is None else prim.mode
            if mode not in (4, 5, 6):
                notes.append(f"{where}: skipped {_MODE_NAMES.get(mode, f'mode {mode}')} (only triangles are read)")
                continue
            attrs = prim.attributes
            if attrs is None or attrs.POSITION is None:
                notes.append(f"{where}: skipped (no POSITION)")
                continue
            pos = rd.accessor(attrs.POSITION).astype(np.float64)
            if pos.shape[1] != 3:
                raise ValueError(f"{where}: POSITION must be VEC3")
            if prim.indices is not None:
                idx = rd.accessor(prim.indices)
                if idx.shape[1] != 1 or idx.dtype.kind != "u":
                    raise ValueError(f"{where}: indices must be unsigned integer scalars")
                idx = idx[:, 0].astype(np.int64)
                if idx.size and idx.max() >= len(pos):
                    raise ValueError(f"{where}: index {idx.max()} out of range for {len(pos)} vertices")
            else:
                idx = np.arange(len(pos), dtype=np.int64)
            tri = _triangles(idx, mode)
            if not len(tri):
                notes.append(f"{where}: no triangles")
                continue
            g = group_of(prim.material)
            tc = texcoord_of_group[g]
            if tc is not None:
                acc = getattr(attrs, f"TEXCOORD_{tc}", None)
                if acc is None:
                    notes.append(f"{where}: material {names[g]!r} has a texture but the primitive has no TEXCOORD_{tc}; it samples the texture's bottom-left texel")
                    uv = np.zeros((len(pos), 2))
                else:
                    st = rd.accessor(acc)
                    if st.shape != (len(pos), 2):
                        raise ValueError(f"{where}: TEXCOORD_{tc} must be VEC2 with one value per vertex")
                    uv = np.empty((len(pos), 2))
                    uv[:, 0] = st[:, 0]
                    uv[:, 1] = 1.0 - st[:, 1].astype(np.float64)
            else:
                uv = np.zeros((len(pos), 2))
            nrm = None
            if getattr(attrs, "NORMAL", None) is not None:
                nrm = rd.accessor(attrs.NORMAL).astype(np.float64)
                nrm = nrm if nrm.shape == (len(pos), 3) and np.isfinite(nrm).all() else None
            if not np.array_equal(world, np.eye(4)):
                pos = pos @ world[:3, :3].T + world[:3, 3]
                if nrm is not None:  # normals follow the inverse transpose
                    inv_t = np.linalg.inv(world[:3, :3]).T if abs(np.linalg.det(world[:3, :3])) > 1e-30 else world[:3, :3]
                    nrm = nrm @ inv_t.T
                if np.linalg.det(world[:3, :3]) < 0:  # mirrored: keep the faces' front side
                    tri = tri[:, [0, 2, 1]]
            if nrm is not None:
                length = np.linalg.norm(nrm, axis=1, keepdims=True)
                nrm = np.where(length > 1e-12, nrm / np.where(length > 1e-12, length, 1.0), np.array([0.0, 0.0, 1.0]))
            NRM.append(None if nrm is None else nrm[tri])
            V.append(pos)
            F.append(tri + n_vertices)
            UV.append(uv[tri])
            G.append(np.full(len(tri), g, np.int64))
            n_vertices += len(pos)
    if not F:
        detail = f" ({'; '.join(notes)})" if notes else ""
        raise ValueError(f"no triangles in the default scene{detail}")
    vertices = np.concatenate(V)
    if not np.isfinite(vertices).all():
        raise ValueError("vertex positions contain NaN or inf")
    # Groups are made only for primitives with triangles, so every group is used.
    normals = np.concatenate(NRM) if all(n is not None for n in NRM) else None
    return TexturedMesh(vertices, np.concatenate(F), np.concatenate(UV), np.concatenate(G), textures, names, notes, pbr_maps, normals)


def _material_maps(gltf: gl.GLTF2, rd: "_GltfReader", m: gl.Material, pbr: gl.PbrMetallicRoughness, name: str, notes: list[str]):
    """A material's :class:`~proctex.texture.pbr.PbrMaps`, or None without a metallic-roughness or normal texture."""
    from .pbr import FLAT_NORMAL, PbrMaps

    def image(info, what: str):
        if info is None or info.index is None:
            return None
        if not 0 <= info.index < len(gltf.textures) or gltf.textures[info.index].source is None:
            notes.append(f"material {name!r}: its {what} texture cannot be read; ignored")
            return None
        if int(getattr(info, "texCoord", 0) or 0) != 0:
            notes.append(f"material {name!r}: its {what} texture uses another texcoord set; read with TEXCOORD_0")
        return rd.image(gltf.textures[info.index].source)

    mr = image(pbr.metallicRoughnessTexture, "metallic-roughness")
    nt = image(m.normalTexture, "normal")
    occlusion = False
    if m.occlusionTexture is not None and m.occlusionTexture.index is not None and pbr.metallicRoughnessTexture is not None:
        occlusion = m.occlusionTexture.index == pbr.metallicRoughnessTexture.index  # packed ORM: R is occlusion
        if not occlusion:
            notes.append(f"material {name!r}: an occlusion texture apart from the metallic-roughness one is ignored")
    if mr is None and nt is None:
        return None
    rough_f = 1.0 if pbr.roughnessFactor is None else float(pbr.roughnessFactor)
    metal_f = 1.0 if pbr.metallicFactor is None else float(pbr.metallicFactor)
    if mr is None:
        orm = np.empty((1, 1, 3), np.float32)
        orm[:] = (1.0, rough_f, metal_f)
    else:
        orm = mr.astype(np.float32) / 255.0
        if not occlusion:
            orm[..., 0] = 1.0
        orm[..., 1] *= rough_f
        orm[..., 2] *= metal_f
    if nt is None:
        normal = np.empty((1, 1, 3), np.float32)
        normal[:] = FLAT_NORMAL
    else:
        normal = nt
    return PbrMaps(np.clip(orm, 0, 1), normal, occlusion)
