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
- ``names``: optional G group names (material names).

glTF puts the texcoord origin at the top-left with v pointing down, so the GLB stores (u, 1 - v);
OBJ ``vt`` lines use the convention above unchanged. Positions, normals and texcoords are stored as
float32 (GLB) or printed with 9 significant digits (OBJ, float32-exact).

Texture wrap mode is CLAMP_TO_EDGE: each group texture is a UV atlas whose charts lie inside
[0, 1]^2, so REPEAT would let bilinear filtering and coarse mip levels blend texels from the opposite
image border into charts touching an edge. Alpha channels are written to the images but materials
stay ``OPAQUE`` (atlas backgrounds are often transparent and must not make the surface see-through).
"""

from __future__ import annotations

import base64
import binascii
import io
import json
import math
import re
import shutil
import subprocess
import sys
import urllib.parse
from dataclasses import dataclass, field
from pathlib import Path
from typing import Sequence

import numpy as np
import pygltflib as gl
from PIL import Image

from proctex.fileio import atomic_write, encode_png

ARRAY_BUFFER, ELEMENT_ARRAY_BUFFER = 34962, 34963
GREY = [0.5, 0.5, 0.5, 1.0]
ROUGHNESS = 0.8
UNTEXTURED_NAME = "untextured"


# --------------------------------------------------------------------------- validation

def _check_shape(vertices, faces, corner_uv, face_group, textures, names):
    """Validate and normalise inputs; returns (V float64, F int64, UV float64, G int64, texs, names)."""
    V = np.asarray(vertices)
    if V.ndim != 2 or V.shape[1] != 3 or V.shape[0] == 0 or V.dtype.kind not in "iuf":
        raise ValueError(f"vertices: expected a non-empty (n, 3) float array, got {V.dtype} {V.shape}")
    V = V.astype(np.float64)
    if not np.isfinite(V).all():
        raise ValueError("vertices: contains NaN or inf")
    F = np.asarray(faces)
    if F.ndim != 2 or F.shape[1] != 3 or F.shape[0] == 0 or F.dtype.kind not in "iu":
        raise ValueError(f"faces: expected a non-empty (m, 3) integer array, got {F.dtype} {F.shape}")
    F = F.astype(np.int64)
    if F.min() < 0 or F.max() >= len(V):
        raise ValueError(f"faces: indices must be in [0, {len(V)}), got [{F.min()}, {F.max()}]")
    m = len(F)
    UV = np.asarray(corner_uv)
    if UV.shape != (m, 3, 2) or UV.dtype.kind not in "iuf":
        raise ValueError(f"corner_uv: expected a ({m}, 3, 2) float array, got {UV.dtype} {UV.shape}")
    UV = UV.astype(np.float64)
    if not np.isfinite(UV).all():
        raise ValueError("corner_uv: contains NaN or inf")
    if isinstance(textures, np.ndarray) or not isinstance(textures, Sequence):
        raise ValueError(f"textures: expected a list of images, got {type(textures).__name__}")
    texs = []
    for g, t in enumerate(textures):
        if isinstance(t, (bytes, bytearray)):  # an already encoded PNG (reused across requests)
            if not bytes(t[:8]) == b"\x89PNG\r\n\x1a\n":
                raise ValueError(f"textures[{g}]: bytes given, but not a PNG file")
            texs.append(bytes(t))
            continue
        t = np.asarray(t)
        if t.dtype != np.uint8 or t.ndim != 3 or t.shape[2] not in (3, 4) or min(t.shape[:2]) == 0:
            raise ValueError(f"textures[{g}]: expected a (H, W, 3|4) uint8 image, got {t.dtype} {t.shape}")
        texs.append(np.ascontiguousarray(t))
    G = np.asarray(face_group)
    if G.shape != (m,) or G.dtype.kind not in "iu":
        raise ValueError(f"face_group: expected a ({m},) integer array, got {G.dtype} {G.shape}")
    G = G.astype(np.int64)
    if G.min() < -1 or G.max() >= len(texs):
        raise ValueError(f"face_group: values must be -1 or in [0, {len(texs)}), "
                         f"got [{G.min()}, {G.max()}]")
    if names is None:
        names = [f"group_{g}" for g in range(len(texs))]
    else:
        names = [names] if isinstance(names, str) else list(names)
        if len(names) != len(texs) or not all(isinstance(s, str) for s in names):
            raise ValueError(f"names: expected {len(texs)} strings (one per texture), got {names!r}")
    return V, F, UV, G, texs, names


def _groups(face_group: np.ndarray, n_groups: int) -> list[tuple[int, np.ndarray]]:
    """[(group, face indices)] for each non-empty group, the untextured group -1 last."""
    order = np.argsort(face_group, kind="stable")
    bounds = np.concatenate([[0], np.cumsum(np.bincount(face_group + 1, minlength=n_groups + 1))])
    out = [(g - 1, order[bounds[g]:bounds[g + 1]]) for g in range(n_groups + 1)]
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


def _smooth_normals(vertices: np.ndarray, faces: np.ndarray, vid: np.ndarray,
                    indices: np.ndarray) -> np.ndarray:
    """Area-weighted unit vertex normals (s, 3) float32 for the split vertices of one primitive.

    Normals are accumulated per *source* vertex over the primitive's faces, so texture seams do not
    become shading seams. Vertices whose faces are all degenerate (or cancel) get +z.
    """
    tri = vertices[faces]
    fn = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])  # length = 2 * area
    _, local = np.unique(vid, return_inverse=True)  # vid is sorted: local id per split vertex
    corner_local = local.ravel()[indices.astype(np.int64)].ravel()
    n_local = int(corner_local.max()) + 1
    acc = np.stack([np.bincount(corner_local, weights=np.repeat(fn[:, k], 3), minlength=n_local)
                    for k in range(3)], axis=1)
    length = np.linalg.norm(acc, axis=1)
    ok = length > 0
    acc[ok] /= length[ok, None]
    acc[~ok] = (0.0, 0.0, 1.0)
    return acc[local.ravel()].astype(np.float32)


# --------------------------------------------------------------------------- GLB

class _Blob:
    """Binary buffer with 4-byte aligned bufferViews."""

    def __init__(self, gltf: gl.GLTF2):
        self.gltf, self.parts, self.offset = gltf, [], 0

    def view(self, data: bytes, target: int | None = None) -> int:
        self.gltf.bufferViews.append(gl.BufferView(buffer=0, byteOffset=self.offset,
                                                   byteLength=len(data), target=target))
        pad = -len(data) % 4
        self.parts += [data, b"\0" * pad]
        self.offset += len(data) + pad
        return len(self.gltf.bufferViews) - 1

    def accessor(self, array: np.ndarray, kind: str, target: int, minmax: bool = False) -> int:
        ctype = gl.UNSIGNED_INT if array.dtype == np.uint32 else gl.FLOAT
        acc = gl.Accessor(bufferView=self.view(array.tobytes(), target), componentType=ctype,
                          count=len(array), type=kind, min=None, max=None, byteOffset=None)
        if minmax:
            acc.min, acc.max = array.min(axis=0).tolist(), array.max(axis=0).tolist()
        self.gltf.accessors.append(acc)
        return len(self.gltf.accessors) - 1


def _png(image: np.ndarray | bytes) -> bytes:
    """PNG bytes of a texture, or the bytes themselves when already encoded."""
    return image if isinstance(image, bytes) else encode_png(image)


#: Node rotations (glTF quaternions x, y, z, w) that stand a shape with the given up axis upright in
#: glTF's +Y-up world; the vertex data stays in the shape's own frame.
UP_ROTATIONS = {"y": None, "z": [-math.sqrt(0.5), 0.0, 0.0, math.sqrt(0.5)], "x": [0.0, 0.0, math.sqrt(0.5), math.sqrt(0.5)]}


def glb_bytes(vertices, faces, corner_uv, face_group, textures, names=None,
              double_sided: bool = True, up: str = "y") -> bytes:
    """Encode a textured shape as a GLB (glTF 2.0 binary) file.

    Args: see the module docstring (vertices (n, 3) float64, faces (m, 3) int64, corner_uv
    (m, 3, 2) float64 with v up, face_group (m,) int64 in [-1, G), G uint8 textures (H, W, 3|4),
    optional G names); ``double_sided`` sets the materials' doubleSided flag; ``up`` is the
    shape's up axis ("x", "y" or "z"): glTF is +Y up, so a z-up or x-up shape gets a node rotation
    (:data:`UP_ROTATIONS`) and stands upright in every viewer, with its vertex data unchanged.

    The file holds one node and one mesh with one triangle primitive per non-empty group (faces of
    group -1 form a last primitive with a grey untextured material). Each primitive has its own
    vertices, split per unique (vertex, texcoord) pair, with POSITION (min/max), area-weighted smooth
    NORMAL, TEXCOORD_0 = (u, 1 - v) and uint32 indices. Each group has a material named after it
    (baseColorTexture, metallic 0, roughness 0.8) and a PNG image embedded in the buffer; all
    textures share one LINEAR / LINEAR_MIPMAP_LINEAR, CLAMP_TO_EDGE sampler. Textures of empty
    groups are left out. Raises ValueError on malformed input.
    """
    V, F, UV, FG, texs, names = _check_shape(vertices, faces, corner_uv, face_group, textures, names)
    if up not in UP_ROTATIONS:
        raise ValueError(f"up must be x, y or z, got {up!r}")
    gltf = gl.GLTF2(asset=gl.Asset(generator="proctex.export", version="2.0"), scene=0,
                    scenes=[gl.Scene(nodes=[0])], nodes=[gl.Node(mesh=0, rotation=UP_ROTATIONS[up])], buffers=[gl.Buffer()])
    blob = _Blob(gltf)
    primitives = []
    for g, idx in _groups(FG, len(texs)):
        f = F[idx]
        st = None
        if g >= 0:
            st = np.empty((len(idx), 3, 2), np.float32)
            st[..., 0] = UV[idx, :, 0]
            st[..., 1] = 1.0 - UV[idx, :, 1]
        vid, st_split, indices = _split_vertices(f, st)
        attrs = gl.Attributes(
            POSITION=blob.accessor(V[vid].astype(np.float32), gl.VEC3, ARRAY_BUFFER, minmax=True),
            NORMAL=blob.accessor(_smooth_normals(V, f, vid, indices), gl.VEC3, ARRAY_BUFFER))
        pbr = gl.PbrMetallicRoughness(metallicFactor=0.0, roughnessFactor=ROUGHNESS)
        if g >= 0:
            attrs.TEXCOORD_0 = blob.accessor(st_split, gl.VEC2, ARRAY_BUFFER)
            gltf.images.append(gl.Image(bufferView=blob.view(_png(texs[g])), mimeType="image/png",
                                        name=names[g]))
            gltf.textures.append(gl.Texture(sampler=0, source=len(gltf.images) - 1))
            pbr.baseColorTexture = gl.TextureInfo(index=len(gltf.textures) - 1)
            name = names[g]
        else:
            pbr.baseColorFactor = list(GREY)
            name = UNTEXTURED_NAME
        gltf.materials.append(gl.Material(pbrMetallicRoughness=pbr, doubleSided=bool(double_sided),
                                          name=name, emissiveFactor=None))
        primitives.append(gl.Primitive(
            attributes=attrs, material=len(gltf.materials) - 1, mode=gl.TRIANGLES,
            indices=blob.accessor(indices.reshape(-1), gl.SCALAR, ELEMENT_ARRAY_BUFFER)))
    if gltf.textures:
        gltf.samplers = [gl.Sampler(magFilter=gl.LINEAR, minFilter=gl.LINEAR_MIPMAP_LINEAR,
                                    wrapS=gl.CLAMP_TO_EDGE, wrapT=gl.CLAMP_TO_EDGE)]
    gltf.meshes = [gl.Mesh(primitives=primitives)]
    gltf.set_binary_blob(b"".join(blob.parts))
    return b"".join(gltf.save_to_bytes())


# --------------------------------------------------------------------------- files

def write_glb(path, vertices, faces, corner_uv, face_group, textures, names=None,
              double_sided: bool = True, up: str = "y") -> str:
    """Write :func:`glb_bytes` to ``path`` atomically (temp file + ``os.replace``); returns the path."""
    data = glb_bytes(vertices, faces, corner_uv, face_group, textures, names, double_sided, up=up)
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


def write_obj(path, vertices, faces, corner_uv, face_group, textures, names=None) -> list[str]:
    """Write ``<stem>.obj``, ``<stem>.mtl`` and ``<stem>_<g>.png`` per non-empty group g.

    ``path`` must end in ``.obj``. Inputs are as in :func:`glb_bytes`. ``vt`` lines use the OBJ
    convention (v up, equal to ``corner_uv``); faces are ``f v/vt`` grouped by ``usemtl``; faces of
    group -1 use a grey material without a texture map. Material names are the group names with
    whitespace replaced by ``_`` (made unique). Every file is written atomically, the PNGs and MTL
    before the OBJ. Returns the written paths: [obj, mtl, png...].
    """
    path = Path(path)
    if path.suffix.lower() != ".obj":
        raise ValueError(f"path: expected a file name ending in .obj, got {str(path)!r}")
    V, F, UV, FG, texs, names = _check_shape(vertices, faces, corner_uv, face_group, textures, names)
    mat_names = _obj_material_names(names)
    stem = path.with_suffix("")
    mtl_path = stem.with_suffix(".mtl")
    uv_unique, uv_inv = np.unique(UV.reshape(-1, 2), axis=0, return_inverse=True)
    fv = np.stack([F + 1, uv_inv.reshape(-1, 3) + 1], axis=2).reshape(-1, 6)

    written, mtl, body = [], [], io.StringIO()
    for g, idx in _groups(FG, len(texs)):
        name = mat_names[g] if g >= 0 else UNTEXTURED_NAME
        kd = "1 1 1" if g >= 0 else " ".join(map(str, GREY[:3]))
        mtl.append(f"newmtl {name}\nKa 1 1 1\nKd {kd}\nKs 0 0 0\nd 1\nillum 1\n")
        if g >= 0:
            png = stem.parent / f"{stem.name}_{g}.png"
            atomic_write(png, _png(texs[g]))
            written.append(str(png))
            mtl.append(f"map_Kd {png.name}\n")
        mtl.append("\n")
        body.write(f"usemtl {name}\n")
        np.savetxt(body, fv[idx], fmt="f %d/%d %d/%d %d/%d")
    atomic_write(mtl_path, "".join(mtl).encode())

    text = io.StringIO()
    text.write(f"# proctex.export\nmtllib {mtl_path.name}\n")
    np.savetxt(text, V, fmt="v %.9g %.9g %.9g")
    np.savetxt(text, uv_unique, fmt="vt %.9g %.9g")
    text.write(body.getvalue())
    atomic_write(path, text.getvalue().encode())
    return [str(path), str(mtl_path)] + written


# --------------------------------------------------------------------------- validator

def _validator_dir() -> Path:
    return Path(sys.prefix) / "node" / "node_modules" / "gltf-validator"


def validator_available() -> bool:
    """True when ``node`` is on PATH and the gltf-validator npm package is inside the venv."""
    return shutil.which("node") is not None and (_validator_dir() / "package.json").is_file()


_VALIDATE_JS = """
const validator = require(%s);
const data = require('fs').readFileSync(0);
validator.validateBytes(new Uint8Array(data), {uri: %s, maxIssues: 1000})
  .then(r => process.stdout.write(JSON.stringify(r)),
        e => { process.stderr.write(String(e)); process.exit(2); });
"""


def validate_glb(path_or_bytes, timeout: float = 120.0) -> dict:
    """Run the Khronos glTF validator on a GLB file path or GLB bytes; returns its report dict.

    The report has ``issues`` with ``numErrors``, ``numWarnings``, ``numInfos``, ``numHints`` and
    ``messages`` (each with ``code``, ``message``, ``severity`` 0=error..3=hint, ``pointer``).
    Raises RuntimeError when node or the validator is missing or the validator cannot run.
    """
    if not validator_available():
        raise RuntimeError(f"glTF validator unavailable: need node on PATH and {_validator_dir()}")
    if isinstance(path_or_bytes, (bytes, bytearray, memoryview)):
        data, uri = bytes(path_or_bytes), "asset.glb"
    else:
        data, uri = Path(path_or_bytes).read_bytes(), Path(path_or_bytes).name
    script = _VALIDATE_JS % (json.dumps(str(_validator_dir())), json.dumps(uri))
    proc = subprocess.run(["node", "-e", script], input=data, capture_output=True, timeout=timeout)
    if proc.returncode != 0:
        raise RuntimeError(f"glTF validator failed (rc {proc.returncode}): "
                           f"{proc.stderr.decode(errors='replace')[-2000:]}")
    return json.loads(proc.stdout)


# --------------------------------------------------------------------------- reader

_COMPONENT_DTYPES = {5120: np.int8, 5121: np.uint8, 5122: np.int16, 5123: np.uint16, 5125: np.uint32,
                     5126: np.float32}
_TYPE_SIZES = {"SCALAR": 1, "VEC2": 2, "VEC3": 3, "VEC4": 4, "MAT2": 4, "MAT3": 9, "MAT4": 16}
_MODE_NAMES = {0: "POINTS", 1: "LINES", 2: "LINE_LOOP", 3: "LINE_STRIP", 4: "TRIANGLES",
               5: "TRIANGLE_STRIP", 6: "TRIANGLE_FAN"}


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
    """

    vertices: np.ndarray
    faces: np.ndarray
    corner_uv: np.ndarray
    face_group: np.ndarray
    textures: list[np.ndarray]
    names: list[str]
    notes: list[str] = field(default_factory=list)


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
        return data[start:start + length], bv.byteStride or 0

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
            with Image.open(io.BytesIO(data)) as pil:
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
        r[:3, :3] = [[1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
                     [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
                     [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)]]
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
    V, F, UV, G = [], [], [], []
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
        groups[mat] = len(textures)
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
                    notes.append(f"{where}: material {names[g]!r} has a texture but the primitive has no "
                                 f"TEXCOORD_{tc}; it samples the texture's bottom-left texel")
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
            if not np.array_equal(world, np.eye(4)):
                pos = pos @ world[:3, :3].T + world[:3, 3]
                if np.linalg.det(world[:3, :3]) < 0:  # mirrored: keep the faces' front side
                    tri = tri[:, [0, 2, 1]]
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
    return TexturedMesh(vertices, np.concatenate(F), np.concatenate(UV), np.concatenate(G), textures, names, notes)
