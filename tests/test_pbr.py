"""PBR maps: tangent frames, normal-map baking, material values, and the maps through GLB, OBJ and the store."""

from __future__ import annotations

import io
import json

import numpy as np
import pygltflib as gl
import pytest
from PIL import Image

from proctex.geometry.parts import analyse
from proctex.models import get_model
from proctex.texture.export import glb_bytes, obj_files, validate_glb
from proctex.texture.paint_loop import paint_template
from proctex.texture.painters import SurfacePainter, parse_prompt
from proctex.texture.painters.pbr import base_props
from proctex.texture.pbr import (
    PbrMaps,
    bake_maps,
    corner_normals,
    corner_tangents,
    decode_normal,
    encode_normal,
    texel_frames,
)
from proctex.texture.uv import texel_map

from .conftest import require_validator


# ---------------------------------------------------------------------------------------- helpers
def grid(n: int = 12, angle: float = 0.0, mirror: bool = False) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A unit square in z = 0 as 2 n^2 triangles, with UVs rotated by ``angle`` (and mirrored in u)
    and fitted into [0.1, 0.9]^2. Returns (vertices, faces, corner_uv)."""
    xs = np.linspace(0.0, 1.0, n + 1)
    X, Y = np.meshgrid(xs, xs, indexing="ij")
    V = np.stack([X.ravel(), Y.ravel(), np.zeros(X.size)], axis=1)
    idx = np.arange(V.shape[0]).reshape(n + 1, n + 1)
    a, b, c, d = idx[:-1, :-1].ravel(), idx[1:, :-1].ravel(), idx[1:, 1:].ravel(), idx[:-1, 1:].ravel()
    F = np.concatenate([np.stack([a, b, c], 1), np.stack([a, c, d], 1)])
    R = np.array([[np.cos(angle), -np.sin(angle)], [np.sin(angle), np.cos(angle)]])
    uv = (V[:, :2] - 0.5) @ R.T
    if mirror:
        uv[:, 0] *= -1
    uv = 0.5 + 0.55 * uv  # rotated square stays inside [0, 1]^2
    return V, F, uv[F]


def glb_material_images(data: bytes) -> list[dict[str, np.ndarray]]:
    """Per material of a GLB: its images by role (base, orm, normal, occlusion), as uint8 arrays."""
    g = gl.GLTF2.load_from_bytes(data)
    blob = g.binary_blob()

    def image(tex_index: int) -> np.ndarray:
        img = g.images[g.textures[tex_index].source]
        view = g.bufferViews[img.bufferView]
        raw = blob[view.byteOffset : view.byteOffset + view.byteLength]
        return np.asarray(Image.open(io.BytesIO(raw)).convert("RGB"))

    out = []
    for m in g.materials:
        roles = {}
        pbr = m.pbrMetallicRoughness
        if pbr.baseColorTexture is not None:
            roles["base"] = image(pbr.baseColorTexture.index)
        if pbr.metallicRoughnessTexture is not None:
            roles["orm"] = image(pbr.metallicRoughnessTexture.index)
        if m.normalTexture is not None:
            roles["normal"] = image(m.normalTexture.index)
        if m.occlusionTexture is not None:
            roles["occlusion"] = image(m.occlusionTexture.index)
        out.append(roles)
    return out


def glb_attribute(data: bytes, prim: int, name: str) -> np.ndarray:
    g = gl.GLTF2.load_from_bytes(data)
    p = g.meshes[0].primitives[prim]
    acc = g.accessors[p.indices if name == "indices" else getattr(p.attributes, name)]
    view = g.bufferViews[acc.bufferView]
    comps = {"SCALAR": 1, "VEC2": 2, "VEC3": 3, "VEC4": 4}[acc.type]
    dtype = np.uint32 if acc.componentType == gl.UNSIGNED_INT else np.float32
    raw = g.binary_blob()[view.byteOffset : view.byteOffset + view.byteLength]
    return np.frombuffer(raw, dtype=dtype).reshape(acc.count, comps) if comps > 1 else np.frombuffer(raw, dtype=dtype)


# ---------------------------------------------------------------------------------------- tangents
@pytest.mark.parametrize("angle", [0.0, 0.7, np.pi / 2, 2.5])
@pytest.mark.parametrize("mirror", [False, True])
def test_corner_tangents_follow_the_uv_directions(angle, mirror):
    V, F, UV = grid(6, angle, mirror)
    T = corner_tangents(V, F, UV)
    assert T.shape == (len(F), 3, 4)
    # On the plane, u = 0.5 + 0.55 * s (R p)_0 with s = -1 when mirrored: dP/du is the first row of R, times s.
    s = -1.0 if mirror else 1.0
    du = s * np.array([np.cos(angle), -np.sin(angle), 0.0])
    dv = np.array([np.sin(angle), np.cos(angle), 0.0])
    np.testing.assert_allclose(T[..., :3].reshape(-1, 3), np.tile(du, (3 * len(F), 1)), atol=1e-9)
    # The bitangent a viewer builds, w * cross(N, T), is dP/dv.
    B = np.cross(np.array([0.0, 0.0, 1.0]), T[..., :3].reshape(-1, 3)) * T[..., 3].reshape(-1, 1)
    np.testing.assert_allclose(B, np.tile(dv, (3 * len(F), 1)), atol=1e-9)


def test_corner_tangents_degenerate_uvs_and_curved_surfaces():
    V, F, UV = grid(4)
    UV[:] = 0.5  # no UV extent at all
    T = corner_tangents(V, F, UV)
    assert np.isfinite(T).all() and np.allclose(np.linalg.norm(T[..., :3], axis=-1), 1.0)
    assert np.allclose((T[..., :3] * corner_normals(V, F)).sum(-1), 0.0)
    # On a sphere the tangents stay orthogonal to the smooth normals.
    import trimesh

    m = trimesh.creation.uv_sphere(radius=2.0, count=(12, 16))
    uv = np.stack([np.arctan2(m.vertices[:, 1], m.vertices[:, 0]) / (2 * np.pi) + 0.5, m.vertices[:, 2] / 4 + 0.5], 1)[m.faces]
    T = corner_tangents(m.vertices, m.faces, uv)
    N = corner_normals(m.vertices, m.faces)
    assert np.abs((T[..., :3] * N).sum(-1)).max() < 1e-9
    assert set(np.unique(T[..., 3])) <= {-1.0, 1.0}


def test_normal_encoding_round_trip():
    rng = np.random.default_rng(0)
    n = rng.normal(size=(500, 3))
    n[:, 2] = np.abs(n[:, 2]) + 0.2
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    back = decode_normal((encode_normal(n) * 255).round().astype(np.uint8))
    assert np.degrees(np.arccos(np.clip((back * n).sum(1), -1, 1))).max() < 0.8  # 8-bit quantisation


# ------------------------------------------------------------------------- baking a known relief
@pytest.mark.parametrize("angle, mirror", [(0.0, False), (0.9, False), (2.2, True)])
def test_baked_normal_map_decodes_to_the_analytic_relief(angle, mirror):
    """A height h = A sin(k x) on a plane, baked with UVs rotated (and mirrored), read back the way a
    glTF viewer does (the GLB's TANGENT, bitangent w * cross(N, T), the 8-bit map) gives the analytic
    perturbed normal normalize(-dh/dx, 0, 1) everywhere."""
    A, k = 0.02, 2 * np.pi * 3
    V, F, UV = grid(16, angle, mirror)

    def props(p, n, t, b):
        grad = np.stack([A * k * np.cos(k * p[:, 0]), np.zeros(len(p)), np.zeros(len(p))], 1)
        nts = np.stack([-(grad * t).sum(1), -(grad * b).sum(1), np.ones(len(p))], 1)
        return np.full(len(p), 0.5), np.zeros(len(p)), nts / np.linalg.norm(nts, axis=1, keepdims=True)

    texels = texel_map(V, F, UV, 128)
    maps = bake_maps(texels, V, F, UV, props, center=np.zeros(3), scale=1.0)
    # Through the GLB: tangents per split vertex, and the encoded map.
    data = glb_bytes(V, F, UV, np.zeros(len(F), np.int64), [np.full((128, 128, 3), 200, np.uint8)], pbr=[maps])
    images = glb_material_images(data)[0]
    tangent = glb_attribute(data, 0, "TANGENT")
    corners = glb_attribute(data, 0, "indices").reshape(-1, 3)  # one primitive: the faces in order
    corner_t = tangent[corners].astype(np.float64)
    T, B, N = texel_frames(texels, corner_t, corner_normals(V, F))
    nts = decode_normal(images["normal"][texels.ij[:, 0], texels.ij[:, 1]])
    world = nts[:, :1] * T + nts[:, 1:2] * B + nts[:, 2:] * N
    x = texels.points[:, 0]
    expected = np.stack([-A * k * np.cos(k * x), np.zeros_like(x), np.ones_like(x)], 1)
    expected /= np.linalg.norm(expected, axis=1, keepdims=True)
    err = np.degrees(np.arccos(np.clip((world * expected).sum(1), -1, 1)))
    assert np.median(err) < 0.5 and np.percentile(err, 99) < 1.5, (np.median(err), err.max())
    # A map baked with the wrong handedness (bitangent flipped) decodes far from the relief on a mirrored or rotated layout.
    wrong = nts[:, :1] * T - nts[:, 1:2] * B + nts[:, 2:] * N
    tilt = np.degrees(np.arctan(A * k))
    if abs(np.sin(angle)) > 0.5:
        assert np.median(np.degrees(np.arccos(np.clip((wrong * expected).sum(1), -1, 1)))) > tilt / 2


# ------------------------------------------------------------------------------- material values
PLAUSIBLE = [
    # prompt, roughness range, metallic
    ("brushed brass", (0.3, 0.5), 1.0),
    ("polished chrome", (0.0, 0.12), 1.0),
    ("hammered copper", (0.2, 0.45), 1.0),
    ("gold", (0.1, 0.35), 1.0),
    ("red velvet", (0.85, 1.0), 0.0),
    ("blue denim", (0.85, 1.0), 0.0),
    ("wool", (0.85, 1.0), 0.0),
    ("glazed ceramic", (0.0, 0.12), 0.0),
    ("white porcelain", (0.0, 0.15), 0.0),
    ("terracotta", (0.75, 1.0), 0.0),
    ("oak", (0.5, 0.85), 0.0),
    ("varnished walnut", (0.1, 0.35), 0.0),
    ("black rubber", (0.8, 1.0), 0.0),
    ("polished marble", (0.0, 0.2), 0.0),
    ("grey concrete", (0.8, 1.0), 0.0),
    ("glossy red plastic", (0.1, 0.3), 0.0),
]


def _sphere_points(n=4000, seed=0):
    rng = np.random.default_rng(seed)
    p = rng.normal(size=(n, 3))
    p /= np.linalg.norm(p, axis=1, keepdims=True)
    t = np.cross(p, [0.0, 0.0, 1.0]) + np.cross(p, [1.0, 0.0, 0.0]) * 1e-3
    t /= np.linalg.norm(t, axis=1, keepdims=True)
    return 0.9 * p, p, t, np.cross(p, t)


@pytest.mark.parametrize("prompt, rough, metal", PLAUSIBLE)
def test_materials_have_physically_plausible_values(prompt, rough, metal):
    p, n, t, b = _sphere_points()
    r, m, nts = SurfacePainter(prompt).material(p, n, t, b)
    assert rough[0] <= np.median(r) <= rough[1], (prompt, np.median(r))
    assert np.allclose(m, metal), prompt
    assert np.allclose(np.linalg.norm(nts, axis=1), 1.0, atol=1e-5) and (nts[:, 2] > 0.5).all()
    assert base_props(parse_prompt(prompt))[1] == metal


def test_relief_follows_the_material():
    """Fabric weave, leather creases, brick mortar and hammered dimples tilt the normal; glazed
    ceramic and polished chrome stay flat; a rusty patch on steel is not metal."""
    p, n, t, b = _sphere_points()

    def tilt(prompt):
        nts = SurfacePainter(prompt).material(p, n, t, b)[2]
        return np.degrees(np.arccos(np.clip(nts[:, 2], -1, 1)))

    for prompt in ("denim", "worn leather", "red brick", "hammered copper", "oak", "tree bark"):
        assert np.percentile(tilt(prompt), 90) > 2.0, prompt
    for prompt in ("glazed ceramic", "polished chrome", "white porcelain"):
        assert np.percentile(tilt(prompt), 90) < 0.5, prompt
    r, m, _ = SurfacePainter("rusty steel").material(p, n, t, b)
    assert (m < 0.1).mean() > 0.2 and (m > 0.9).mean() > 0.2
    assert np.corrcoef(r, m)[0, 1] < -0.8  # rust is rough where the steel is gone


def test_material_is_pointwise_and_frame_covariant():
    p, n, t, b = _sphere_points(3000)
    sp = SurfacePainter("denim", seed=3)
    r, m, nts = sp.material(p, n, t, b)
    r2, m2, nts2 = sp.material(p[::-1], n[::-1], t[::-1], b[::-1])  # another batch order: same values
    np.testing.assert_array_equal(r, r2[::-1])
    np.testing.assert_array_equal(nts, nts2[::-1])
    # A frame turned by 90 degrees (T' = B, B' = -T) turns the tangent-space normal the same way.
    _, _, nts3 = sp.material(p, n, b, -t)
    np.testing.assert_allclose(nts3[:, 0], nts[:, 1], atol=0.02)
    np.testing.assert_allclose(nts3[:, 1], -nts[:, 0], atol=0.02)
    with pytest.raises(ValueError, match="same length"):
        sp.material(p, n, t[:5], b)
    with pytest.raises(ValueError, match="NaN"):
        sp.material(p, n, np.full_like(t, np.nan), b)


# ------------------------------------------------------------------------- GLB, OBJ, validator
@pytest.fixture(scope="module")
def painted():
    """The mug painted with a metal and with a fabric prompt (64 px textures)."""
    shape = get_model("mug").generate(None)
    grouping = analyse(shape)
    return {prompt: paint_template(shape, grouping, prompt, size=64) for prompt in ("brushed brass", "red velvet")}


def _glb(tex) -> bytes:
    return glb_bytes(tex.shape.vertices, tex.shape.faces, tex.uv.corner_uv, tex.uv.face_group, [g.uint8() for g in tex.groups], names=[g.label for g in tex.groups], up="z", pbr=tex.pbr)


def test_glb_vertex_data_of_all_primitives_at_once_is_each_primitives_own(painted, monkeypatch):
    """The GLB's split vertices, normals and tangents, computed for every primitive in one pass, are
    the bytes of the same GLB computed primitive by primitive (the path for shapes too large for one
    key): a textured group with maps, one without, and untextured faces (group -1)."""
    import proctex.texture.export as ex

    tex = painted["brushed brass"]
    fg = tex.uv.face_group.copy()
    fg[::7] = -1
    args = (tex.shape.vertices, tex.shape.faces, tex.uv.corner_uv, fg, [g.uint8() for g in tex.groups])
    maps = [tex.pbr[0], None]
    together = glb_bytes(*args, up="z", pbr=maps)
    monkeypatch.setattr(ex, "_KEY_LIMIT", 0.0)
    apart = glb_bytes(*args, up="z", pbr=maps)
    assert together == apart
    assert glb_attribute(together, 0, "TANGENT").shape[1] == 4 and glb_attribute(together, 2, "NORMAL").shape[1] == 3


def test_glb_carries_every_map_and_is_validator_clean(painted):
    for prompt, tex in painted.items():
        data = _glb(tex)
        g = gl.GLTF2.load_from_bytes(data)
        for mat in g.materials:
            assert mat.pbrMetallicRoughness.metallicRoughnessTexture is not None and mat.normalTexture is not None
            assert mat.pbrMetallicRoughness.metallicFactor == 1.0 and mat.pbrMetallicRoughness.roughnessFactor == 1.0
        for prim in g.meshes[0].primitives:
            assert prim.attributes.TANGENT is not None
        if require_validator():
            report = validate_glb(data)
            assert report["issues"]["numErrors"] == 0 and report["issues"]["numWarnings"] == 0, report["issues"]["messages"][:5]


def test_glb_metallic_and_roughness_at_known_texels(painted):
    """Read back with pygltflib: at every covered texel, the brass is metal and the velvet is rough
    and not metal (and each check fails on the other prompt's file)."""
    values = {}
    for prompt, tex in painted.items():
        images = glb_material_images(_glb(tex))
        values[prompt] = [(img["orm"][gt.texels.ij[:, 0], gt.texels.ij[:, 1]] / 255.0) for img, gt in zip(images, tex.groups)]
    for orm in values["brushed brass"]:
        assert (orm[:, 2] > 0.98).all() and np.median(orm[:, 1]) < 0.5
    for orm in values["red velvet"]:
        assert (orm[:, 2] < 0.02).all() and (orm[:, 1] > 0.85).all()


def test_obj_mtl_names_the_pbr_maps(painted):
    tex = painted["brushed brass"]
    files = dict(obj_files("mug", tex.shape.vertices, tex.shape.faces, tex.uv.corner_uv, tex.uv.face_group, [g.uint8() for g in tex.groups], names=["body", "handle"], pbr=tex.pbr))
    mtl = files["mug.mtl"].decode()
    for g in (0, 1):
        for line in (f"map_Pr mug_{g}_roughness.png", f"map_Pm mug_{g}_metallic.png", f"norm mug_{g}_normal.png"):
            assert line in mtl
        metal = np.asarray(Image.open(io.BytesIO(files[f"mug_{g}_metallic.png"])))
        ij = tex.groups[g].texels.ij
        assert (metal[ij[:, 0], ij[:, 1]] > 250).all()


def test_bad_pbr_input_is_a_clear_error(painted):
    tex = painted["red velvet"]
    args = (tex.shape.vertices, tex.shape.faces, tex.uv.corner_uv, tex.uv.face_group, [g.uint8() for g in tex.groups])
    with pytest.raises(ValueError, match="one entry"):
        glb_bytes(*args, pbr=[tex.pbr[0]])
    with pytest.raises(ValueError, match="not a PNG"):
        glb_bytes(*args, pbr=[PbrMaps(b"nope", b"nope"), None])
    with pytest.raises(ValueError, match=r"\(H, W, 3\)"):
        glb_bytes(*args, pbr=[PbrMaps(np.zeros((4, 4)), np.zeros((4, 4, 3))), None])
    with pytest.raises(ValueError, match="expected PbrMaps"):
        glb_bytes(*args, pbr=["orm", None])


# ------------------------------------------------------------------------------------ the store
def test_template_store_keeps_the_maps(tmp_path):
    from proctex.build.pipeline import stage_paint
    from proctex.build.pipeline import stage_sample
    from proctex.build.pipeline import stage_template
    from proctex.store.config import BuildConfig
    from proctex.store.layout import FamilyStore, StoreLayout
    from proctex.store.state import write_config
    from proctex.store.template import Template, load_template_shape

    cfg = BuildConfig.from_dict(dict(model="mug", n_train=2, n_test=0, texture_size=32, prompt="hammered copper", group_prompts={"handle": "black rubber"}))
    st = FamilyStore(tmp_path / "mug")
    write_config(st, cfg)
    for stage in (stage_sample, stage_template, stage_paint):
        stage(st, cfg, log=lambda *_: None)
    t = Template.load(st, load_template_shape(st, cfg))
    assert t.pbr is not None and len(t.pbr) == 2
    body, handle = t.pbr
    assert body.orm[..., 2].max() == 255 and handle.orm[..., 2].max() == 0
    summary = json.loads((tmp_path / "mug" / StoreLayout.PAINT).read_text())
    assert all(g["orm_sha256"] and g["normal_sha256"] for g in summary["groups"])
    # The stored GLB is validator-clean with every map.
    data = (tmp_path / "mug" / StoreLayout.TEMPLATE_GLB).read_bytes()
    assert all("normal" in m and "orm" in m for m in glb_material_images(data))
    if require_validator():
        assert validate_glb(data)["issues"]["numErrors"] == 0
    # A damaged map is named, not read.
    path = tmp_path / "mug" / StoreLayout.texture(0, "body", "orm")
    raw = bytearray(path.read_bytes())
    raw[-20] ^= 0xFF
    path.write_bytes(bytes(raw))
    with pytest.raises(ValueError, match="checksum mismatch"):
        Template.load(st, load_template_shape(st, cfg))


# ------------------------------------------------------------------------------ edits and serving
def test_edits_carry_the_maps(painted_mug_root, tmp_path):
    """A hue shift leaves roughness alone; a re-paint makes every map again; roughness / metallic
    edits move those channels; undo brings the maps back; the service answers with them, linked."""
    import shutil

    from proctex.serve.edits import adjust_orm, edit_group, undo_edit
    from proctex.serve.service import FamilyService, GroupEdit
    from proctex.store.layout import FamilyStore, StoreLayout
    from proctex.store.state import build_stamp

    root = tmp_path / "fams"
    shutil.copytree(painted_mug_root, root)
    st = FamilyStore(root / "mug")
    orm_path = root / "mug" / StoreLayout.texture(0, "body", "orm")
    normal_path = root / "mug" / StoreLayout.texture(0, "body", "normal")
    orm0, normal0 = orm_path.read_bytes(), normal_path.read_bytes()
    edit_group(st, 0, hue=120.0)
    assert orm_path.read_bytes() == orm0 and normal_path.read_bytes() == normal0
    edit_group(st, 0, prompt="brushed steel")
    metal = np.asarray(Image.open(orm_path))[..., 2]
    assert metal.max() == 255 and np.asarray(Image.open(io.BytesIO(orm0)))[..., 2].max() == 0
    edit_group(st, "body", roughness=0.9, metallic=0.0)
    orm = np.asarray(Image.open(orm_path)) / 255.0
    painted = np.asarray(st.read_arrays(StoreLayout.PAINTED)["g0"], bool)  # the means are over the painted texels
    assert abs(orm[..., 1][painted].mean() - 0.9) < 0.01 and orm[..., 2].max() == 0
    summary = json.loads((root / "mug" / StoreLayout.PAINT).read_text())
    assert summary["edits"][-1]["material"] == {"roughness": 0.9, "metallic": 0.0}
    glb = (root / "mug" / StoreLayout.TEMPLATE_GLB).read_bytes()
    assert np.array_equal(glb_material_images(glb)[0]["orm"], np.asarray(Image.open(orm_path).convert("RGB")))
    for _ in range(3):
        undo_edit(st, expect_stamp=build_stamp(st))
    assert orm_path.read_bytes() == orm0 and normal_path.read_bytes() == normal0
    with pytest.raises(ValueError, match="roughness must be"):
        adjust_orm(np.zeros((2, 2, 3)), roughness=1.5)
    # The service: linked answers name the maps' URIs and serve them; an edit that changes the maps embeds them.
    from proctex.store.state import stored_config
    from proctex.store.template import load_template_shape

    svc = FamilyService(st)
    shape = load_template_shape(st, stored_config(st))
    data, _ = svc.transfer(shape, linked=True)
    g = gl.GLTF2.load_from_bytes(data)
    uris = sorted(img.uri for img in g.images if img.uri)
    assert any(".orm.png?v=" in u for u in uris) and any(".normal.png?v=" in u for u in uris)
    png, dig = svc.texture_png("0.orm")
    assert png == orm0 and dig.startswith(uris[[".orm." in u for u in uris].index(True)].split("v=")[1])
    data, _ = svc.transfer(shape, linked=True, edits={0: GroupEdit(roughness=0.2)})
    g = gl.GLTF2.load_from_bytes(data)
    assert not any(img.uri and img.uri.startswith("textures/0.orm") for img in g.images)
    assert any(img.uri and img.uri.startswith("textures/0.normal") for img in g.images)  # the normal map stays linked
    assert any(img.uri and img.uri.startswith("textures/0.png") for img in g.images)  # and so does the colour
    roles = glb_material_images(svc.transfer(shape, edits={0: GroupEdit(roughness=0.2)})[0])
    assert abs(roles[0]["orm"][..., 1][painted].mean() / 255 - 0.2) < 0.01


def test_bake_re_expresses_the_relief_in_the_new_atlas():
    """Baking a transferred shape into its own atlas keeps the relief: the baked normal map, decoded
    in the atlas's tangent frame, matches the painter's relief evaluated afresh in that frame (the
    template itself, mapped by the identity and baked, so every surface point is known)."""
    from proctex.texture.paint import shape_frame
    from proctex.texture.pbr import corner_tangents as ct
    from proctex.transfer.apply import bake, shape_to_glb, transfer
    from proctex.transfer.assets import prepare_template
    from proctex.transfer.methods import make_mapper

    shape = get_model("mug").generate(None)
    grouping = analyse(shape)
    tex = paint_template(shape, grouping, "hammered copper", size=512)  # dimples span several texels
    assets = prepare_template(shape, grouping, tex.uv.corner_uv, [g.uint8() for g in tex.groups], pbr=tex.pbr)
    mapper = make_mapper("identity", assets)
    result = transfer(shape, assets, mapper, shortcut=False)
    baked = bake(shape, result, assets, size=512)
    assert baked.pbr is not None and not any(baked.direct)
    sel = baked.face_group == 0
    faces = np.flatnonzero(sel)
    used = np.unique(shape.faces[faces])
    local = np.searchsorted(used, shape.faces[faces])
    tm = texel_map(shape.vertices[used], local, baked.corner_uv[faces], 512)
    cn = corner_normals(shape.vertices[used], local)
    T, B, N = texel_frames(tm, ct(shape.vertices[used], local, baked.corner_uv[faces], cn), cn)
    center, scale = shape_frame(shape)
    _, metal, fresh = SurfacePainter("hammered copper").bind(shape, grouping).material((tm.points - center) / scale, N, T, B, group=0, label="body")
    got = decode_normal(baked.pbr[0].normal_uint8()[tm.ij[:, 0], tm.ij[:, 1]])
    err = np.degrees(np.arccos(np.clip((got * fresh).sum(1), -1, 1)))
    tilt = np.degrees(np.arccos(np.clip(fresh[:, 2], -1, 1)))
    assert np.median(tilt) > 3.0  # there is relief to keep
    # Resampling costs some detail (a half-texel shift of the template's own map costs 1.7 degrees here).
    assert np.median(err) < 0.35 * np.median(tilt), (np.median(err), np.median(tilt))
    # Copied without re-expressing (the template map's texels as they are) would be far worse.
    raw = decode_normal(tex.groups[0].pbr.normal_uint8()[tm.ij[:, 0], tm.ij[:, 1]])
    assert np.median(np.degrees(np.arccos(np.clip((raw * fresh).sum(1), -1, 1)))) > np.median(err) * 1.5
    # Deliberately wrong frames score clearly worse: the baked map turned by 90 degrees, or mirrored.
    for wrong in (np.stack([-got[:, 1], got[:, 0], got[:, 2]], 1), got * np.array([1.0, -1.0, 1.0])):
        assert np.median(np.degrees(np.arccos(np.clip((wrong * fresh).sum(1), -1, 1)))) > np.median(err) * 1.5
    assert (baked.pbr[0].orm_uint8()[tm.ij[:, 0], tm.ij[:, 1], 2] > 250).all()
    # The baked GLB carries the maps and stays validator-clean.
    answer = shape_to_glb(shape, assets, mapper, up="z", bake_size=128, shortcut=False)
    assert all("normal" in m and "orm" in m for m in glb_material_images(answer.data))
    if require_validator():
        assert validate_glb(answer.data)["issues"]["numErrors"] == 0


# ------------------------------------------------------------------------------------ PBR shading
def _sphere_scene(rough: float, metal: float, colour=(200, 150, 60), normal=None):
    import trimesh

    from proctex.texture.pbr import flat_maps
    from proctex.texture.render import orbit_camera

    m = trimesh.creation.uv_sphere(radius=1.0, count=(48, 64))
    V, F = m.vertices, m.faces
    uv = np.stack([np.arctan2(V[:, 1], V[:, 0]) / (2 * np.pi) + 0.5, np.arccos(np.clip(V[:, 2], -1, 1)) / np.pi], 1)[F]
    uv[..., 1] = 1 - uv[..., 1]
    maps = flat_maps(64, 64, rough, metal)
    if normal is not None:
        maps.normal[:] = normal
    tex = np.zeros((64, 64, 3), np.uint8)
    tex[:] = colour
    cam = orbit_camera(np.zeros(3), 1.0, "z", 20.0, 15.0, size=160)
    from proctex.texture.render import render_textured

    return render_textured(V, F, uv, np.zeros(len(F), np.int64), [tex], cam, maps=[maps])


def test_pbr_shading_tells_materials_apart():
    """Metal reflects in its own colour and has no diffuse; smooth surfaces have small bright
    highlights and rough ones broad dim ones; a flat normal map changes nothing, a tilted one does."""
    luma = lambda img: img.astype(float) @ [0.2126, 0.7152, 0.0722]  # noqa: E731
    obj = lambda img: (img < 250).any(axis=2)  # noqa: E731
    smooth_metal, rough_metal = _sphere_scene(0.1, 1.0), _sphere_scene(0.8, 1.0)
    smooth_plastic = _sphere_scene(0.1, 0.0)
    # Highlights: the smooth metal's brightest pixels are brighter than the rough metal's, and there are fewer of them.
    top_s, top_r = np.percentile(luma(smooth_metal)[obj(smooth_metal)], 99.5), np.percentile(luma(rough_metal)[obj(rough_metal)], 99.5)
    assert top_s > top_r + 10
    # A dielectric's highlight is white, a metal's is tinted by its base colour (orange: red > blue).
    hi_p = smooth_plastic[luma(smooth_plastic) >= np.percentile(luma(smooth_plastic)[obj(smooth_plastic)], 99.8)].astype(float)
    hi_m = smooth_metal[luma(smooth_metal) >= np.percentile(luma(smooth_metal)[obj(smooth_metal)], 99.8)].astype(float)
    assert (hi_p[:, 0] - hi_p[:, 2]).mean() < 0.5 * (hi_m[:, 0] - hi_m[:, 2]).mean()
    # The flat normal map is the unbent surface; a tilted map changes the shading.
    flat = _sphere_scene(0.5, 0.0)
    same = _sphere_scene(0.5, 0.0, normal=(0.5, 0.5, 1.0))
    tilted = _sphere_scene(0.5, 0.0, normal=(0.85, 0.5, 0.85))
    assert np.abs(flat.astype(int) - same.astype(int)).max() <= 1
    assert np.abs(flat.astype(int) - tilted.astype(int))[obj(flat)].mean() > 5


def test_glb_read_back_gives_the_maps_and_render_lights_them(painted, tmp_path):
    from proctex.cli import main
    from proctex.texture.gltf_read import read_textured_glb

    tex = painted["brushed brass"]
    path = tmp_path / "brass.glb"
    path.write_bytes(_glb(tex))
    mesh = read_textured_glb(path)
    assert len(mesh.pbr) == 2 and all(m is not None for m in mesh.pbr)
    for got, want in zip(mesh.pbr, tex.pbr):
        np.testing.assert_array_equal((got.orm[..., 1:] * 255).round().astype(np.uint8), want.orm_uint8()[..., 1:])
        np.testing.assert_array_equal(got.normal, want.normal_uint8())
    # `proctex render` lights a PBR file physically: it differs from the same file without its maps.
    assert main(["render", str(path), "--size", "96", "--out", str(tmp_path / "pbr.png")]) == 0
    plain = tmp_path / "plain.glb"
    plain.write_bytes(glb_bytes(tex.shape.vertices, tex.shape.faces, tex.uv.corner_uv, tex.uv.face_group, [g.uint8() for g in tex.groups], up="z"))
    assert read_textured_glb(plain).pbr == [None, None]
    assert main(["render", str(plain), "--size", "96", "--out", str(tmp_path / "plain.png")]) == 0
    a = np.asarray(Image.open(tmp_path / "pbr.png")).astype(int)
    b = np.asarray(Image.open(tmp_path / "plain.png")).astype(int)
    assert np.abs(a - b).mean() > 3


def test_ambient_occlusion_darkens_crevices():
    """Inside a box open at the top, the floor's corners see less sky than its middle and the outside
    sees it all; painted with --occlusion, the mug's maps hold it in R and the GLB names it."""
    from proctex.texture.lighting import vertex_occlusion
    from proctex.texture.render import embree_available

    if not embree_available():
        pytest.skip("no Embree here")
    # An open box (no lid) from five quads, subdivided.
    import trimesh

    box = trimesh.creation.box(extents=(2, 2, 2))
    box = box.subdivide().subdivide().subdivide()
    keep = box.triangles_center[:, 2] < 0.99  # drop the lid
    V, F = box.vertices, box.faces[keep]
    flip = F[:, [0, 2, 1]]  # the inside: faces turned inwards
    ao_in = vertex_occlusion(V, flip, rays=64)
    used = np.unique(flip)
    floor = used[V[used, 2] < -0.99]
    corner = floor[np.linalg.norm(V[floor, :2], axis=1) > 1.3]
    middle = floor[np.linalg.norm(V[floor, :2], axis=1) < 0.3]
    assert ao_in[corner].mean() < ao_in[middle].mean() - 0.1
    assert vertex_occlusion(V, F, rays=64)[used].min() > 0.95  # the outside of the same box is open
    shape = get_model("mug").generate(None)
    tex = paint_template(shape, analyse(shape), "white ceramic", size=64, occlusion=True)
    body = tex.groups[0]
    occ = body.pbr.orm[body.texels.ij[:, 0], body.texels.ij[:, 1], 0]
    assert body.pbr.occlusion and occ.min() < 0.6 and occ.max() > 0.95
    g = gl.GLTF2.load_from_bytes(_glb(tex))
    assert g.materials[0].occlusionTexture.index == g.materials[0].pbrMetallicRoughness.metallicRoughnessTexture.index
    with pytest.raises(ValueError, match="rays"):
        vertex_occlusion(V, F, rays=0)


def test_occlusion_setting_is_validated():
    from proctex.store.config import BuildConfig

    assert BuildConfig.from_dict(dict(model="mug", occlusion=True)).validate().paint.occlusion is True
    with pytest.raises(ValueError, match="occlusion must be true or false"):
        BuildConfig.from_dict(dict(model="mug", occlusion="yes")).validate()


def test_http_serves_the_maps_and_refuses_bad_material_edits(painted_mug_root, tmp_path):
    import shutil

    from fastapi.testclient import TestClient

    from proctex.serve.catalog import Catalog
    from proctex.serve.service import BadInput, parse_edit
    from workers.http import create_app

    root = tmp_path / "fams"
    shutil.copytree(painted_mug_root, root)
    c = TestClient(create_app(lambda: Catalog(str(root))))
    described = c.get("/v1/families/mug").json()["groups"]
    assert all(g["pbr"] and 0 <= g["roughness"] <= 1 and 0 <= g["metallic"] <= 1 for g in described)
    r = c.get("/v1/families/mug/textures/0.orm.png")
    assert r.status_code == 200 and r.headers["content-type"] == "image/png" and r.headers["etag"]
    assert c.get("/v1/families/mug/textures/1.normal.png").status_code == 200
    for bad in ("0.bogus.png", "9.orm.png", "0.orm", "..%2F0.png"):
        r = c.get(f"/v1/families/mug/textures/{bad}")
        assert r.status_code == 404 and "error" in r.json(), bad
    for raw, message in (({"roughness": "nan"}, "finite"), ({"metallic": 2}, r"\[0, 1\]"), ({"roughness": True}, "number"), ({"roughness": [0.5]}, "number")):
        with pytest.raises(BadInput, match=message):
            parse_edit(raw)
        r = c.post("/v1/families/mug/transfer", json={"params": {}, "edits": {"0": raw}})
        assert r.status_code == 422 and "error" in r.json()
    ok = c.post("/v1/families/mug/transfer", json={"params": {}, "edits": {"body": {"roughness": 0.3, "metallic": 1}}})
    assert ok.status_code == 200
    orm = glb_material_images(ok.content)[0]["orm"]
    assert orm[..., 2].mean() > 250


def _messy_mesh(seed: int = 0):
    """A sphere's faces plus degenerate ones (a point, a line), a face with no UV extent, a face
    used twice and vertices no face uses; corner UVs with seams (per-face jitter)."""
    import trimesh

    rng = np.random.default_rng(seed)
    s = trimesh.creation.icosphere(subdivisions=2)
    v = np.concatenate([np.asarray(s.vertices) * rng.uniform(0.8, 1.2, (len(s.vertices), 1)), rng.normal(size=(5, 3))])
    f = np.concatenate([np.asarray(s.faces), [[0, 0, 0], [0, 1, 1], [2, 3, 4], [2, 3, 4]]])
    uv = rng.uniform(0, 1, (len(f), 3, 2))
    uv[-2] = 0.5  # no UV extent
    return v, f, uv


@pytest.mark.parametrize("seed", [0, 1])
@pytest.mark.parametrize("given_normals", [False, True])
def test_compiled_vertex_data_is_the_array_forms_bit_for_bit(seed, given_normals):
    """The GLB's normals and tangents (:mod:`proctex.texture.vertex_kernels`) against their array
    forms, bit for bit, on a messy mesh: corner keys by (vertex, UV) pair and by vertex alone."""
    from proctex.texture.pbr import area_normals, area_normals_arrays, key_tangents, key_tangents_arrays, vertex_normals, vertex_normals_arrays

    v, f, uv = _messy_mesh(seed)
    fn = area_normals_arrays(v, f)
    assert np.array_equal(area_normals(v, f).view(np.int64), fn.view(np.int64))
    given = fn if given_normals else None
    vn = vertex_normals_arrays(v, f, given)
    assert np.array_equal(vertex_normals(v, f, given).view(np.int64), vn.view(np.int64))
    for keys in (np.unique(f.reshape(-1) * 10_000 + np.arange(f.size) // 3 % 7, return_inverse=True)[1].ravel(), f.reshape(-1)):
        key_normals = np.zeros((int(keys.max()) + 1, 3))
        key_normals[keys] = vn[f.reshape(-1)]
        want = key_tangents_arrays(v, f, uv, keys, key_normals, given)
        got = key_tangents(v, f, uv, keys, key_normals, given)
        assert got.shape == want.shape and np.array_equal(got.view(np.int64), want.view(np.int64))


def test_compiled_vertex_data_refuses_bad_input():
    from proctex.texture import vertex_kernels as vk

    v, f, uv = _messy_mesh()
    keys = f.reshape(-1)
    kn = np.zeros((len(v), 3))
    with pytest.raises(ValueError, match="faces index"):
        vk.area_normals(v, f + len(v))
    with pytest.raises(ValueError, match="normals"):
        vk.vertex_normals(v, f, np.zeros((2, 3)))
    with pytest.raises(ValueError, match="corner_uv"):
        vk.key_tangents(v, f, uv[:, :2], keys, kn)
    with pytest.raises(ValueError, match="keys"):
        vk.key_tangents(v, f, uv, keys[:-1], kn)
    with pytest.raises(ValueError, match="index"):
        vk.key_tangents(v, f, uv, keys, kn[:3])


def test_without_numba_the_array_forms_answer(monkeypatch):
    """Where numba does not import, the GLB's normals and tangents come from the array forms: the
    same bits as the compiled kernels."""
    import sys

    v, f, uv = _messy_mesh(2)
    from proctex.texture.pbr import area_normals, key_tangents, vertex_normals

    want = (area_normals(v, f), vertex_normals(v, f), key_tangents(v, f, uv, f.reshape(-1), vertex_normals(v, f)))
    monkeypatch.setitem(sys.modules, "proctex.texture.vertex_kernels", None)  # its import raises ImportError
    got = (area_normals(v, f), vertex_normals(v, f), key_tangents(v, f, uv, f.reshape(-1), vertex_normals(v, f)))
    for g, w in zip(got, want):
        assert np.array_equal(g.view(np.int64), w.view(np.int64))


def _unique_pairs(source: np.ndarray, value: np.ndarray, n_sources: int):
    """The reference of :func:`proctex.texture.vertex_kernels.split_pairs`: ``np.unique`` of the
    values' ranks combined with the sources into one key, as the GLB's array form sorts them."""
    v_keys, v_inv = np.unique(value, return_inverse=True)
    keys, inv = np.unique(source * len(v_keys) + v_inv.ravel(), return_inverse=True)
    return keys // len(v_keys), v_keys[keys % len(v_keys)], inv.ravel()


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_split_pairs_are_np_unique_of_the_pairs(seed):
    """The GLB's split vertices (the compiled counting sort) against ``np.unique``: the same pairs
    in the same order and the same inverse, on sources with one corner, with dozens (the sort past
    the insertion sort's 16), equal and negative values (texcoord bits compared as signed
    integers), sources no corner uses, and none at all."""
    from proctex.texture.vertex_kernels import split_pairs

    rng = np.random.default_rng(seed)
    n_sources = 50
    source = np.concatenate([rng.integers(0, 40, 300), np.full(40, 45), [49]])  # 45: 40 corners, 49: one
    value = rng.integers(-4, 5, len(source)) * (1 << 40) + rng.integers(0, 2, len(source))  # many ties, both signs
    value[source == 45] = rng.permutation(np.repeat(rng.integers(-(1 << 62), 1 << 62, 8), 5))
    order = rng.permutation(len(source))
    source, value = source[order], value[order]
    got, want = split_pairs(source, value, n_sources), _unique_pairs(source, value, n_sources)
    for g, w in zip(got, want):
        assert g.dtype == np.int64 and np.array_equal(g, w)
    assert len(got[0]) < len(source)  # ties merged: the test has pairs in common
    empty = split_pairs(np.zeros(0, np.int64), np.zeros(0, np.int64), 3)
    assert all(len(x) == 0 for x in empty)
    with pytest.raises(ValueError, match="lie in"):
        split_pairs(np.array([3]), np.array([0]), 3)
    with pytest.raises(ValueError, match="one entry per corner"):
        split_pairs(np.array([0, 1]), np.array([0]), 3)


def test_a_glb_is_the_same_bytes_without_the_compiled_split(monkeypatch):
    """The GLB of a messy shape (seams, degenerate and repeated faces, an untextured group,
    -0.0 texcoords) is the same bytes whether its split vertices come from the compiled kernel
    or from ``np.unique`` (numba hidden, or 50,000 unused vertices); a GLB whose texcoords differ
    is not (the comparison sees the split; and a kernel that kept -0.0 or keyed corners by vertex
    alone gives other bytes)."""
    import sys

    v, f, uv = _messy_mesh(3)
    uv[:4] = -0.0
    group = np.arange(len(f)) % 3 - 1  # groups -1, 0, 1
    tex = [np.full((8, 8, 3), 90 * g, np.uint8) for g in (1, 2)]
    fast = glb_bytes(v, f, uv, group, tex)
    unused = np.concatenate([v, np.ones((50_000, 3))])  # vertices far outnumbering the corners: the sorting path
    from proctex.texture.export import _split_pairs

    assert _split_pairs(np.zeros(3 * len(f), np.int64), np.zeros(3 * len(f), np.int64), 3 * len(unused)) is None  # that path is taken
    assert glb_bytes(unused, f, uv, group, tex) == fast  # bytes compared exactly: no tolerance on any CPU
    monkeypatch.setitem(sys.modules, "proctex.texture.vertex_kernels", None)  # its import raises ImportError
    slow = glb_bytes(v, f, uv, group, tex)
    assert fast == slow
    moved = uv.copy()
    moved[5, 0, 0] += 1e-3
    assert glb_bytes(v, f, moved, group, tex) != slow
