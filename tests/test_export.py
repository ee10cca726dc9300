"""Tests for proctex.texture.export: GLB / OBJ textured export, texcoord conventions, validator cleanliness."""

from __future__ import annotations

import io
import os

import numpy as np
import pygltflib as gl
import pytest
import trimesh
from PIL import Image

from proctex.texture import export as ex

# Quadrant colours per group: PALETTE[g][top/bottom][left/right]; texture row 0 is the top.
PALETTE = np.array(
    [
        [[(255, 0, 0), (0, 255, 0)], [(0, 0, 255), (255, 255, 0)]],
        [[(0, 255, 255), (255, 0, 255)], [(40, 80, 120), (200, 150, 100)]],
        [[(10, 20, 30), (60, 70, 80)], [(110, 120, 130), (160, 170, 180)]],
    ],
    dtype=np.uint8,
)
CENTRES = np.array([[0.25, 0.25], [0.75, 0.25], [0.75, 0.75], [0.25, 0.75]])


def quadrant_texture(g: int, channels: int = 3, size: int = 64) -> np.ndarray:
    img = np.full((size, size, channels), 255, np.uint8)
    h = size // 2
    for r in range(2):
        for c in range(2):
            img[r * h : (r + 1) * h, c * h : (c + 1) * h, :3] = PALETTE[g, r, c]
    return img


def expected_colour(g: int, uv: np.ndarray) -> np.ndarray:
    """Quadrant colour at uv (v up): top half of the image is v >= 0.5."""
    top = (uv[..., 1] >= 0.5).astype(int)
    right = (uv[..., 0] >= 0.5).astype(int)
    return PALETTE[g, 1 - top, right]


def sample_v_up(img: np.ndarray, uv: np.ndarray) -> np.ndarray:
    """Nearest texel, ProcTex/OBJ convention: (0, 0) bottom-left, row 0 at the top."""
    h, w = img.shape[:2]
    j = np.clip(np.floor(uv[..., 0] * w).astype(int), 0, w - 1)
    i = np.clip(np.floor((1.0 - uv[..., 1]) * h).astype(int), 0, h - 1)
    return img[i, j, :3]


def sample_v_down(img: np.ndarray, st: np.ndarray) -> np.ndarray:
    """Nearest texel, glTF convention: (0, 0) top-left, t grows downwards."""
    h, w = img.shape[:2]
    j = np.clip(np.floor(st[..., 0] * w).astype(int), 0, w - 1)
    i = np.clip(np.floor(st[..., 1] * h).astype(int), 0, h - 1)
    return img[i, j, :3]


def make_shape():
    """A quad (2 faces, group 0, jittered UVs) and a unit cube at x=3 (12 faces, group 1, UV seams)."""
    rng = np.random.default_rng(0)
    quad_v = np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0]], float)
    quad_f = np.array([[0, 1, 2], [0, 2, 3]])
    quad_uv = CENTRES[quad_f] + rng.uniform(-0.2, 0.2, (2, 3, 2))
    box = trimesh.creation.box()
    cube_v = box.vertices + [3.0, 0.0, 0.0]
    cube_f = box.faces + 4
    cube_uv = CENTRES[rng.integers(0, 4, (12, 3))]  # shared vertices get different UVs -> split
    V = np.vstack([quad_v, cube_v])
    F = np.vstack([quad_f, cube_f]).astype(np.int64)
    UV = np.concatenate([quad_uv, cube_uv])
    G = np.array([0, 0] + [1] * 12, np.int64)
    textures = [quadrant_texture(0), quadrant_texture(1, channels=4)]
    return V, F, UV, G, textures, ["quad top", "cube"]


def tricky_shape():
    """Three textures with group 1 empty, a zero-area face, a repeated-index face and grey faces."""
    V, F, UV, G, tex, _ = make_shape()
    V = np.vstack([V, [[0, 0, 5], [1, 0, 5], [2, 0, 5]]])  # collinear -> zero area
    n = len(V)
    F = np.vstack([F, [[n - 3, n - 2, n - 1], [0, 0, 1]]])
    UV = np.concatenate([UV, CENTRES[None, :3], CENTRES[None, 1:]])
    G = np.concatenate([np.where(G == 1, 2, G), [0, -1]])
    G[3:5] = -1  # two cube faces without texture
    tex = [tex[0], quadrant_texture(1), quadrant_texture(2)]
    return V, F, UV, G, tex, ["a", "unused", "c"]


def grey_only_shape():
    """No textures at all: every face is untextured."""
    V, F, UV, G, _, _ = make_shape()
    return V, F, UV, np.full_like(G, -1), [], None


# --------------------------------------------------------------------------- pygltflib reading


def parse(data: bytes):
    gltf = gl.GLTF2.load_from_bytes(data)
    return gltf, gltf.binary_blob()


def accessor(gltf, blob, i) -> np.ndarray:
    a = gltf.accessors[i]
    bv = gltf.bufferViews[a.bufferView]
    dtype = {gl.FLOAT: np.float32, gl.UNSIGNED_INT: np.uint32}[a.componentType]
    k = {"SCALAR": 1, "VEC2": 2, "VEC3": 3}[a.type]
    arr = np.frombuffer(blob, dtype, a.count * k, bv.byteOffset + (a.byteOffset or 0))
    return arr.reshape(a.count, k) if k > 1 else arr


def image_of(gltf, blob, material) -> np.ndarray:
    tex = gltf.textures[material.pbrMetallicRoughness.baseColorTexture.index]
    bv = gltf.bufferViews[gltf.images[tex.source].bufferView]
    return np.asarray(Image.open(io.BytesIO(blob[bv.byteOffset : bv.byteOffset + bv.byteLength])))


def primitives_by_group(gltf, names):
    out = {}
    for p in gltf.meshes[0].primitives:
        name = gltf.materials[p.material].name
        out[-1 if name == ex.UNTEXTURED_NAME else names.index(name)] = p
    return out


# --------------------------------------------------------------------------- GLB


def test_sampler_helpers_agree_with_convention():
    img = quadrant_texture(0)
    uv = np.array([[0.25, 0.75], [0.75, 0.75], [0.25, 0.25], [0.75, 0.25], [0.01, 0.99]])
    assert (sample_v_up(img, uv) == PALETTE[0][[0, 0, 1, 1, 0], [0, 1, 0, 1, 0]]).all()
    assert (sample_v_up(img, uv) == expected_colour(0, uv)).all()
    # texel (i, j) centre is u=(j+.5)/W, v=1-(i+.5)/H
    assert (sample_v_up(img, np.array([[0.5 / 64, 1 - 0.5 / 64]])) == img[0, 0, :3]).all()


def test_glb_stores_flipped_v_and_samples_known_colours():
    V, F, UV, G, tex, names = make_shape()
    gltf, blob = parse(ex.glb_bytes(V, F, UV, G, tex, names))
    prims = primitives_by_group(gltf, names)
    assert sorted(prims) == [0, 1]
    for g, p in prims.items():
        idx = np.flatnonzero(G == g)
        ind = accessor(gltf, blob, p.indices).reshape(-1, 3)
        pos = accessor(gltf, blob, p.attributes.POSITION)[ind]
        st = accessor(gltf, blob, p.attributes.TEXCOORD_0)[ind]
        np.testing.assert_allclose(pos, V[F[idx]], atol=1e-6)  # face order is kept
        np.testing.assert_allclose(st[..., 0], UV[idx, :, 0], atol=1e-6)
        np.testing.assert_allclose(st[..., 1], 1.0 - UV[idx, :, 1], atol=1e-6)
        img = image_of(gltf, blob, gltf.materials[p.material])
        assert (img == tex[g]).all()
        # sampled in glTF's own convention, the stored texcoords hit the intended colours
        assert (sample_v_down(img, st) == expected_colour(g, UV[idx])).all()
        assert (sample_v_down(img, st) == sample_v_up(tex[g], UV[idx])).all()


def test_glb_structure():
    V, F, UV, G, tex, names = make_shape()
    data = ex.glb_bytes(V, F, UV, G, tex, names, double_sided=False)
    gltf, blob = parse(data)
    assert len(data) % 4 == 0 and len(blob) % 4 == 0
    assert gltf.buffers[0].byteLength == len(blob)
    assert len(gltf.meshes) == 1 and gltf.scenes[gltf.scene].nodes == [0]
    assert gltf.nodes[0].mesh == 0
    assert all(bv.byteOffset % 4 == 0 for bv in gltf.bufferViews)
    assert [im.mimeType for im in gltf.images] == ["image/png"] * 2
    assert [m.name for m in gltf.materials] == names
    (s,) = gltf.samplers
    assert (s.magFilter, s.minFilter) == (gl.LINEAR, gl.LINEAR_MIPMAP_LINEAR)
    assert s.wrapS == s.wrapT == gl.CLAMP_TO_EDGE
    for m in gltf.materials:
        pbr = m.pbrMetallicRoughness
        assert pbr.metallicFactor == 0.0 and pbr.roughnessFactor == pytest.approx(0.8)
        assert m.doubleSided is False and m.alphaMode == "OPAQUE"
    for g, p in primitives_by_group(gltf, names).items():
        k = int((G == g).sum())
        acc = {a: gltf.accessors[getattr(p.attributes, a)] for a in ("POSITION", "NORMAL", "TEXCOORD_0")}
        ind = gltf.accessors[p.indices]
        assert ind.count == 3 * k and ind.componentType == gl.UNSIGNED_INT
        assert gltf.bufferViews[ind.bufferView].target == ex.ELEMENT_ARRAY_BUFFER
        assert len({a.count for a in acc.values()}) == 1
        pos = accessor(gltf, blob, p.attributes.POSITION)
        assert acc["POSITION"].min == pos.min(axis=0).tolist()
        assert acc["POSITION"].max == pos.max(axis=0).tolist()
        nrm = accessor(gltf, blob, p.attributes.NORMAL)
        np.testing.assert_allclose(np.linalg.norm(nrm, axis=1), 1.0, atol=1e-6)
        assert accessor(gltf, blob, p.indices).max() == acc["POSITION"].count - 1
    quad = primitives_by_group(gltf, names)[0]
    quad_normals = accessor(gltf, blob, quad.attributes.NORMAL)
    assert len(quad_normals) == 6  # jittered UVs: no corner shares a texcoord
    np.testing.assert_allclose(quad_normals, np.broadcast_to([0, 0, 1], (6, 3)), atol=1e-6)


def test_glb_vertex_split_and_normals_match_slow_reference():
    V, F, UV, G, tex, names = tricky_shape()
    gltf, blob = parse(ex.glb_bytes(V, F, UV, G, tex, names))
    tri = V[F]
    face_n = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    for g, p in primitives_by_group(gltf, names).items():
        idx = np.flatnonzero(G == g)
        keys, acc = set(), {}
        for fi in idx:  # slow reference: one loop per face corner
            for c in range(3):
                vid = int(F[fi, c])
                st = (np.float32(UV[fi, c, 0]), np.float32(1.0 - UV[fi, c, 1])) if g >= 0 else ()
                keys.add((vid,) + st)
                acc[vid] = acc.get(vid, 0.0) + face_n[fi]
        pos = accessor(gltf, blob, p.attributes.POSITION)
        assert len(pos) == len(keys)
        ind = accessor(gltf, blob, p.indices).reshape(-1, 3)
        nrm = accessor(gltf, blob, p.attributes.NORMAL)[ind]
        for k, fi in enumerate(idx):
            for c in range(3):
                a = acc[int(F[fi, c])]
                ref = a / np.linalg.norm(a) if np.linalg.norm(a) > 0 else np.array([0.0, 0.0, 1.0])
                np.testing.assert_allclose(nrm[k, c], ref, atol=1e-6)
        assert (p.attributes.TEXCOORD_0 is None) == (g == -1)


def test_glb_empty_group_degenerate_and_untextured_faces():
    V, F, UV, G, tex, names = tricky_shape()
    gltf, blob = parse(ex.glb_bytes(V, F, UV, G, tex, names))
    prims = primitives_by_group(gltf, names)
    assert list(prims) == [0, 2, -1]  # empty group 1 skipped, grey primitive last
    assert [m.name for m in gltf.materials] == ["a", "c", ex.UNTEXTURED_NAME]
    assert len(gltf.images) == len(gltf.textures) == 2
    assert (image_of(gltf, blob, gltf.materials[1]) == tex[2]).all()
    grey = gltf.materials[2].pbrMetallicRoughness
    assert grey.baseColorTexture is None and grey.baseColorFactor == ex.GREY
    assert gltf.accessors[prims[-1].indices].count == 3 * int((G == -1).sum())


def test_trimesh_glb_round_trip(tmp_path):
    V, F, UV, G, tex, names = tricky_shape()
    path = ex.write_glb(tmp_path / "shape.glb", V, F, UV, G, tex, names)
    scene = trimesh.load(path, force="scene")
    geoms = {gm.visual.material.name: gm for gm in scene.geometry.values()}
    assert sorted(geoms) == sorted(["a", "c", ex.UNTEXTURED_NAME])
    for g, name in ((0, "a"), (2, "c")):
        gm, idx = geoms[name], np.flatnonzero(G == g)
        assert len(gm.faces) == len(idx)
        np.testing.assert_allclose(gm.vertices[gm.faces], V[F[idx]], atol=1e-6)
        # trimesh flips glTF texcoords back (v = 1 - t), so its UVs equal ours
        np.testing.assert_allclose(gm.visual.uv[gm.faces], UV[idx], atol=1e-6)
        img = np.asarray(gm.visual.material.baseColorTexture)
        assert (sample_v_up(img, gm.visual.uv[gm.faces]) == sample_v_up(tex[g], UV[idx])).all()
        assert (sample_v_up(img, gm.visual.uv[gm.faces]) == expected_colour(g, UV[idx])).all()
    grey = geoms[ex.UNTEXTURED_NAME]
    assert len(grey.faces) == int((G == -1).sum())
    assert list(grey.visual.material.baseColorFactor[:3]) == [128, 128, 128]


# --------------------------------------------------------------------------- OBJ


def test_obj_round_trip(tmp_path):
    V, F, UV, G, tex, names = tricky_shape()
    names = ["a x", "unused", "c"]
    paths = ex.write_obj(tmp_path / "shape.obj", V, F, UV, G, tex, names)
    assert paths == [str(tmp_path / n) for n in ("shape.obj", "shape.mtl", "shape_0.png", "shape_2.png")]
    assert sorted(os.listdir(tmp_path)) == sorted(os.path.basename(p) for p in paths)  # no temp files
    mtl = (tmp_path / "shape.mtl").read_text()
    assert "map_Kd shape_0.png" in mtl and "map_Kd shape_2.png" in mtl and "newmtl a_x" in mtl
    for g in (0, 2):
        assert (np.asarray(Image.open(tmp_path / f"shape_{g}.png")) == tex[g]).all()
    scene = trimesh.load(paths[0], force="scene", process=False)
    geoms = {gm.visual.material.name: gm for gm in scene.geometry.values()}
    assert sorted(geoms) == sorted(["a_x", "c", ex.UNTEXTURED_NAME])
    for g, name in ((0, "a_x"), (2, "c")):
        gm, idx = geoms[name], np.flatnonzero(G == g)
        np.testing.assert_allclose(gm.vertices[gm.faces], V[F[idx]], atol=1e-6)
        np.testing.assert_allclose(gm.visual.uv[gm.faces], UV[idx], atol=1e-7)  # vt: v up, unflipped
        img = np.asarray(gm.visual.material.image)
        assert (sample_v_up(img, gm.visual.uv[gm.faces]) == expected_colour(g, UV[idx])).all()
    assert len(geoms[ex.UNTEXTURED_NAME].faces) == int((G == -1).sum())
    assert geoms[ex.UNTEXTURED_NAME].visual.material.image is None


def test_writes_are_atomic_and_overwrite(tmp_path):
    V, F, UV, G, tex, names = make_shape()
    target = tmp_path / "a.glb"
    target.write_bytes(b"old")
    ex.write_glb(target, V, F, UV, G, tex, names)
    assert target.read_bytes() == ex.glb_bytes(V, F, UV, G, tex, names)
    with pytest.raises(ValueError):
        ex.write_glb(target, V, F, UV, G + 5, tex, names)
    assert target.read_bytes()[:4] == b"glTF"
    assert os.listdir(tmp_path) == ["a.glb"]
    with pytest.raises(ValueError, match=r"\.obj"):
        ex.write_obj(tmp_path / "a.txt", V, F, UV, G, tex, names)


# --------------------------------------------------------------------------- validator


@pytest.fixture()
def validator():
    """The Khronos validator: required where npm exists (``conftest.require_validator``), skipped elsewhere."""
    from .conftest import require_validator

    if not require_validator():
        pytest.skip("no npm here: the Khronos glTF validator cannot be installed")


@pytest.mark.usefixtures("validator")
@pytest.mark.parametrize("shape", [make_shape, tricky_shape, grey_only_shape])
def test_validator_clean(shape, tmp_path):
    V, F, UV, G, tex, names = shape()
    path = ex.write_glb(tmp_path / "x.glb", V, F, UV, G, tex, names)
    report = ex.validate_glb(path)
    issues = report["issues"]
    assert issues["numErrors"] == 0 and issues["numWarnings"] == 0, issues["messages"]
    assert report["validatorVersion"]


@pytest.mark.usefixtures("validator")
def test_validator_detects_errors():
    V, F, UV, G, tex, names = make_shape()
    gltf, _ = parse(ex.glb_bytes(V, F, UV, G, tex, names))
    gltf.accessors[gltf.meshes[0].primitives[0].attributes.POSITION].max = [9.0, 9.0, 9.0]
    report = ex.validate_glb(b"".join(gltf.save_to_bytes()))
    codes = {m["code"] for m in report["issues"]["messages"]}
    assert report["issues"]["numErrors"] > 0 and "ACCESSOR_MAX_MISMATCH" in codes


# --------------------------------------------------------------------------- bad input and scale


def _bad(**kw):
    V, F, UV, G, tex, names = make_shape()
    args = dict(vertices=V, faces=F, corner_uv=UV, face_group=G, textures=tex, names=names)
    args.update(kw)
    return args


@pytest.mark.parametrize(
    "kw, match",
    [
        (dict(vertices=np.zeros((12, 2))), "vertices"),
        (dict(vertices=np.full((12, 3), np.nan)), "vertices"),
        (dict(faces=np.zeros((14, 4), np.int64)), "faces"),
        (dict(faces=np.zeros((14, 3))), "faces"),
        (dict(faces=np.full((14, 3), 12)), "faces"),
        (dict(faces=np.zeros((0, 3), np.int64)), "faces"),
        (dict(corner_uv=np.zeros((14, 3))), "corner_uv"),
        (dict(corner_uv=np.full((14, 3, 2), np.nan)), "corner_uv"),
        (dict(face_group=np.full(14, 2)), "face_group"),
        (dict(face_group=np.full(14, -2)), "face_group"),
        (dict(face_group=np.zeros(13, np.int64)), "face_group"),
        (dict(textures=[np.zeros((4, 4, 3), np.float32)] * 2), "textures"),
        (dict(textures=[np.zeros((4, 4), np.uint8)] * 2), "textures"),
        (dict(textures=[np.zeros((4, 4, 2), np.uint8)] * 2), "textures"),
        (dict(textures=np.zeros((2, 4, 4, 3), np.uint8)), "textures"),
        (dict(names=["only one"]), "names"),
        (dict(names="ab"), "names"),
    ],
)
def test_bad_input_raises(kw, match, tmp_path):
    args = _bad(**kw)
    with pytest.raises(ValueError, match=match):
        ex.glb_bytes(**args)
    with pytest.raises(ValueError, match=match):
        ex.write_obj(tmp_path / "x.obj", **args)
    assert os.listdir(tmp_path) == []


def test_large_mesh_is_vectorised():
    n = 317  # (n-1)^2 * 2 = 199,712 faces on an n x n grid
    x, y = np.meshgrid(np.linspace(0, 1, n), np.linspace(0, 1, n))
    V = np.stack([x.ravel(), y.ravel(), np.sin(3 * x).ravel()], axis=1)
    i = (np.arange(n - 1)[:, None] * n + np.arange(n - 1)[None, :]).ravel()
    F = np.concatenate([np.stack([i, i + 1, i + n + 1], 1), np.stack([i, i + n + 1, i + n], 1)])
    UV = V[F][..., :2]
    G = np.arange(len(F)) % 4
    tex = [np.zeros((2, 2, 3), np.uint8)] * 4
    gltf, _ = parse(ex.glb_bytes(V, F, UV, G, tex))  # its time is a benchmark figure (README), not asserted here
    assert sum(gltf.accessors[p.indices].count for p in gltf.meshes[0].primitives) == 3 * len(F)


def test_the_glb_blob_copies_array_bytes_once_and_exactly():
    """``_Blob`` keeps a byte view of each accessor's array (no copy of its own) and writes the file
    in one join: the binary chunk is each array's ``tobytes()`` in order, 4-byte aligned, for empty,
    non-contiguous and uint32 arrays alike (a view of a strided array's memory would give other
    bytes for the second)."""
    blob = ex._Blob({"bufferViews": [], "accessors": []})
    arrays = [np.zeros((0, 3), np.float32), np.arange(12, dtype=np.float32).reshape(4, 3)[:, ::2], np.arange(9, dtype=np.uint32).reshape(3, 3), np.arange(3, dtype=np.float32)]
    for a in arrays:
        blob.accessor(a, "VEC3", 34962)
    data = blob.to_bytes()
    doc = gl.GLTF2.load_from_bytes(data)
    binary = doc.binary_blob()
    assert len(binary) == blob.offset and blob.offset % 4 == 0
    for a, view in zip(arrays, doc.bufferViews):
        assert binary[view.byteOffset : view.byteOffset + view.byteLength] == np.ascontiguousarray(a).tobytes()
    assert [v.byteLength for v in doc.bufferViews] == [0, 32, 36, 12]
