"""Reading textured GLBs back, the view helpers of proctex.texture.render and the visual CLI outputs
(`proctex render`, `transfer --preview`, `paint --preview`)."""

from __future__ import annotations

import base64
import io
import json

import numpy as np
import pygltflib as gl
import pytest
from PIL import Image

from proctex.cli import main
from proctex.geometry.parts import analyse
from proctex.models import get_model
from proctex.texture.export import glb_bytes, write_glb
from proctex.texture.gltf_read import read_textured_glb
from proctex.texture.paint import paint_surface
from proctex.texture.painters import SurfacePainter
from proctex.texture.render import (
    Tracer,
    bounding_sphere,
    canonical_cameras,
    grid_columns,
    render_grid,
    render_six_views,
    render_textured,
    render_three_quarter,
    render_views,
    save_gif,
    three_quarter_camera,
    turntable_frames,
)

from .test_export import make_shape, tricky_shape

WHITE = 255


def f32(x: np.ndarray) -> np.ndarray:
    return np.asarray(x, np.float64).astype(np.float32).astype(np.float64)


def stored_uv(uv: np.ndarray) -> np.ndarray:
    """What a GLB round trip gives back for v-up UVs: glTF stores (u, 1 - v) as float32."""
    return np.stack([f32(uv[..., 0]), 1.0 - f32(1.0 - uv[..., 1])], axis=-1)


def object_pixels(img: np.ndarray) -> np.ndarray:
    return (img != WHITE).any(axis=-1)


def red_share(img: np.ndarray) -> float:
    """Share of the object pixels that are clearly red (the checkered fabric's red squares)."""
    px = img[object_pixels(img)].astype(int)
    return float(((px[:, 0] > px[:, 1] + 80) & (px[:, 0] > px[:, 2] + 80)).mean())


@pytest.fixture(scope="module")
def mug():
    """A mug with a red/white checkered surface texture per group: (V, F, UV, G, textures)."""
    shape = get_model("mug").generate(None)
    tex = paint_surface(shape, analyse(shape), SurfacePainter("red and white checkered fabric"), size=64)
    return shape.vertices, shape.faces, tex.uv.corner_uv, tex.uv.face_group, [g.uint8() for g in tex.groups]


# ------------------------------------------------------------------------------------- reader
@pytest.mark.parametrize("which", ["quad_cube", "tricky", "mug"])
def test_glb_round_trip_is_exact_up_to_float32_and_vertex_splitting(which, mug):
    V, F, UV, G, tex, names = {"quad_cube": make_shape, "tricky": tricky_shape}.get(which, lambda: (*mug, None))()
    m = read_textured_glb(glb_bytes(V, F, UV, G, tex, names))
    # glb_bytes writes one primitive per non-empty group (group -1 last), faces in their order.
    order = np.argsort(np.where(G < 0, len(tex), G), kind="stable")
    present = [g for g in range(len(tex)) if (G == g).any()]
    rank = {g: k for k, g in enumerate(present)}
    rank[-1] = len(present)
    assert m.faces.dtype == np.int64 and m.face_group.dtype == np.int64 and m.vertices.dtype == np.float64
    assert len(m.faces) == len(F) and m.notes == []
    assert np.array_equal(m.vertices[m.faces], f32(V[F[order]]))  # per-corner positions, float32-exact
    assert np.array_equal(m.face_group, np.array([rank[g] for g in G[order]]))
    textured = G[order] >= 0
    assert np.array_equal(m.corner_uv[textured], stored_uv(UV[order])[textured])
    assert np.abs(m.corner_uv[textured] - UV[order][textured]).max() < 1e-7
    for g in present:
        assert np.array_equal(m.textures[rank[g]], np.asarray(tex[g])[..., :3])  # PNG is lossless; alpha dropped
    if names is not None:
        assert m.names[: len(present)] == [names[g] for g in present]
    if (G < 0).any():  # the grey untextured material comes back as a 1x1 texture of its colour
        assert m.names[-1] == "untextured" and m.textures[-1].tolist() == [[[128, 128, 128]]]


def test_render_of_the_glb_equals_render_of_the_arrays(mug):
    V, F, UV, G, tex = mug
    m = read_textured_glb(glb_bytes(V, F, UV, G, tex))
    c, r = bounding_sphere(V)
    cams = [three_quarter_camera(V, "z", 128)] + canonical_cameras(c, r, "z", 96)
    from_glb = render_views(m.vertices, m.faces, m.corner_uv, m.face_group, m.textures, cams)
    # Equal to the arrays rounded as the GLB stores them (float32 positions / UVs) but for rays that
    # hit a shared edge exactly: the GLB's split vertices and per-material face order give the ray
    # tracer another BVH, whose traversal order (its width follows the CPU's SIMD) may hand such a
    # tie to the other triangle (0 pixels here; 1e-4 is 7 of the 71,680) ...
    exact = render_views(f32(V), F, stored_uv(UV), G, tex, cams)
    for a, b in zip(from_glb, exact):
        assert a.shape == b.shape and (np.abs(a.astype(int) - b).max(axis=-1) > 0).mean() <= 1e-4
    # ... and to the float64 originals but for at most 0.2% of the pixels (float32 rounding).
    for a, b, cam in zip(from_glb, render_views(V, F, UV, G, tex, cams), cams):
        d = np.abs(a.astype(int) - b).max(axis=-1)
        assert (d > 0).mean() <= 0.002, cam.name
        assert object_pixels(a).sum() > 0.1 * a.shape[0] * a.shape[1]  # not blank
    assert red_share(from_glb[0]) > 0.15  # shows the texture, not a flat default colour


def _blob_accessor(gltf: gl.GLTF2, blob: bytearray, array: np.ndarray, kind: str, ctype: int) -> int:
    while len(blob) % 4:
        blob.append(0)
    gltf.bufferViews.append(gl.BufferView(buffer=0, byteOffset=len(blob), byteLength=array.nbytes))
    blob += array.tobytes()
    gltf.accessors.append(gl.Accessor(bufferView=len(gltf.bufferViews) - 1, componentType=ctype, count=len(array), type=kind, min=None, max=None))
    return len(gltf.accessors) - 1


TRI = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0]], np.float32)
QUAD = np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0]], np.float32)
QUAD_ST = np.array([[0, 1], [1, 1], [1, 0], [0, 0]], np.float32)  # glTF: t down, so this is v = y
RGBA = np.array([[[255, 0, 0, 255], [0, 255, 0, 128]], [[0, 0, 255, 0], [255, 255, 255, 255]]], np.uint8)


def handmade_glb(lines_only: bool = False) -> bytes:
    """A scene written with pygltflib, the way other tools do it.

    Node 0 (translation (10, 0, 0)) has child node 1 (rotation 90 degrees about z, scale 2) with
    mesh 0: a non-indexed triangle with a colour-only red material, a u16-indexed quad textured
    with a 2x2 RGBA data: URI PNG times a factor (1, 0.5, 1), and a LINES primitive. Node 2
    (mirrored in x by its matrix) has mesh 1: a u8-indexed triangle without material. Node 3, not
    in the scene, has mesh 0 again.
    """
    gltf = gl.GLTF2(scene=0, scenes=[gl.Scene(nodes=[0, 2])], buffers=[gl.Buffer()])
    blob = bytearray()
    s = np.sqrt(0.5)
    gltf.nodes = [
        gl.Node(translation=[10, 0, 0], children=[1]),
        gl.Node(mesh=0, rotation=[0, 0, s, s], scale=[2, 2, 2]),
        gl.Node(mesh=1, matrix=[-1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1]),
        gl.Node(mesh=0),
    ]
    png = io.BytesIO()
    Image.fromarray(RGBA).save(png, format="PNG")
    gltf.images = [gl.Image(uri="data:image/png;base64," + base64.b64encode(png.getvalue()).decode())]
    gltf.textures = [gl.Texture(source=0)]
    gltf.materials = [
        gl.Material(name="red", pbrMetallicRoughness=gl.PbrMetallicRoughness(baseColorFactor=[1, 0, 0, 1])),
        gl.Material(name="tex", pbrMetallicRoughness=gl.PbrMetallicRoughness(baseColorFactor=[1, 0.5, 1, 1], baseColorTexture=gl.TextureInfo(index=0))),
    ]
    lines = gl.Primitive(attributes=gl.Attributes(POSITION=_blob_accessor(gltf, blob, TRI, gl.VEC3, gl.FLOAT)), mode=gl.LINES)
    if lines_only:
        gltf.meshes = [gl.Mesh(primitives=[lines]), gl.Mesh(primitives=[lines])]
    else:
        tri = gl.Primitive(attributes=gl.Attributes(POSITION=_blob_accessor(gltf, blob, TRI, gl.VEC3, gl.FLOAT)), material=0)
        quad = gl.Primitive(
            attributes=gl.Attributes(POSITION=_blob_accessor(gltf, blob, QUAD, gl.VEC3, gl.FLOAT), TEXCOORD_0=_blob_accessor(gltf, blob, QUAD_ST, gl.VEC2, gl.FLOAT)),
            indices=_blob_accessor(gltf, blob, np.array([0, 1, 2, 0, 2, 3], np.uint16), gl.SCALAR, gl.UNSIGNED_SHORT),
            material=1,
        )
        plain = gl.Primitive(
            attributes=gl.Attributes(POSITION=_blob_accessor(gltf, blob, TRI, gl.VEC3, gl.FLOAT)), indices=_blob_accessor(gltf, blob, np.array([0, 1, 2], np.uint8), gl.SCALAR, gl.UNSIGNED_BYTE)
        )
        gltf.meshes = [gl.Mesh(primitives=[tri, quad, lines]), gl.Mesh(primitives=[plain])]
    gltf.set_binary_blob(bytes(blob))
    return b"".join(gltf.save_to_bytes())


def test_reader_applies_node_transforms_materials_and_index_types():
    m = read_textured_glb(handmade_glb())
    assert len(m.faces) == 1 + 2 + 1  # node 3 is not in the scene; LINES skipped
    assert any("LINES" in n for n in m.notes)
    assert m.names == ["red", "tex", "untextured"] and m.face_group.tolist() == [0, 1, 1, 2]
    # World matrix of node 1: translate (10, 0, 0) * rotate 90 deg about z * scale 2.
    world = lambda p: np.stack([10 - 2 * p[:, 1], 2 * p[:, 0], 2 * p[:, 2]], axis=1)  # noqa: E731
    assert np.allclose(m.vertices[m.faces[0]], world(TRI), atol=1e-12)
    assert np.allclose(m.vertices[m.faces[1:3]].reshape(-1, 3), world(QUAD[[0, 1, 2, 0, 2, 3]]), atol=1e-12)
    # The mirrored node flips the winding back: the triangle still faces +z.
    a, b, c = m.vertices[m.faces[3]]
    assert np.allclose(a, [0, 0, 0]) and np.allclose(np.cross(b - a, c - a), [0, 0, 1])
    # Colour-only material: 1x1 texture of its factor; no material: grey; texture times factor, alpha dropped.
    assert m.textures[0].tolist() == [[[255, 0, 0]]] and m.textures[2].tolist() == [[[128, 128, 128]]]
    assert np.array_equal(m.textures[1], np.round(RGBA[..., :3] * [1, 0.5, 1]).astype(np.uint8))
    # glTF (s, t) -> (s, 1 - t): the quad's UVs equal its x, y (v up).
    assert np.array_equal(m.corner_uv[1:3].reshape(-1, 2), QUAD[[0, 1, 2, 0, 2, 3], :2])
    assert np.array_equal(m.corner_uv[[0, 3]], np.zeros((2, 3, 2)))
    # Rendered, the untextured triangles show their material colours, exactly (headlight shading).
    img = render_textured(m.vertices, m.faces, m.corner_uv, m.face_group, m.textures, three_quarter_camera(m.vertices, "z", 96, azimuth=0, elevation=89))
    px = img[object_pixels(img)].astype(int)
    red = (px[:, 1] == 0) & (px[:, 2] == 0) & (px[:, 0] > 0)
    grey = (px[:, 0] == px[:, 1]) & (px[:, 1] == px[:, 2])
    assert red.sum() > 20 and grey.sum() > 20


def test_reader_handles_a_transformed_glb_bytes_output_and_a_gltf_json_file(tmp_path):
    V, F, UV, G, tex, names = make_shape()
    gltf = gl.GLTF2.load_from_bytes(glb_bytes(V, F, UV, G, tex, names))
    gltf.nodes = [gl.Node(children=[1], scale=[1, 1, 3]), gl.Node(mesh=0, translation=[0, 5, 0])]
    gltf.scenes = [gl.Scene(nodes=[0])]
    m = read_textured_glb(b"".join(gltf.save_to_bytes()))
    base = read_textured_glb(glb_bytes(V, F, UV, G, tex, names))
    assert np.array_equal(m.vertices, (base.vertices + [0, 5, 0]) * [1, 1, 3])
    assert np.array_equal(m.faces, base.faces) and np.array_equal(m.corner_uv, base.corner_uv)
    # The same scene as a .gltf JSON file with its buffer in a data: URI.
    gltf.convert_buffers(gl.BufferFormat.DATAURI)
    gltf.save_json(str(tmp_path / "scene.gltf"))
    j = read_textured_glb(tmp_path / "scene.gltf")
    assert np.array_equal(j.vertices, m.vertices) and all(np.array_equal(a, b) for a, b in zip(j.textures, m.textures))


@pytest.mark.parametrize(
    "data, message",
    [
        (b"", "not a GLB"),
        (b"solid cube\nfacet normal 0 0 1\n", "not a GLB"),
        (b"glTF\x02\x00\x00\x00\xff\xff\x00\x00garbage", "cannot be read"),
        (None, "no triangles"),
    ],
)
def test_reader_rejects_bad_input(data, message, tmp_path):
    with pytest.raises(ValueError, match=message):
        read_textured_glb(handmade_glb(lines_only=True) if data is None else data)
    with pytest.raises(ValueError, match="no such file"):
        read_textured_glb(tmp_path / "missing.glb")
    good = glb_bytes(*make_shape())
    with pytest.raises(ValueError, match="cannot be read|bufferView|accessor|past"):
        read_textured_glb(good[: len(good) // 2])  # truncated binary chunk


# ------------------------------------------------------------------------------------- views
def test_view_helpers(mug, tmp_path):
    V, F, UV, G, tex = mug
    tracer = Tracer(V, F)
    single = render_three_quarter(V, F, UV, G, tex, up="z", size=64, tracer=tracer)
    assert single.shape == (64, 64, 3) and single.dtype == np.uint8
    assert np.array_equal(single, render_textured(V, F, UV, G, tex, three_quarter_camera(V, "z", 64), tracer))
    six, names = render_six_views(V, F, UV, G, tex, up="z", size=48, tracer=tracer)
    assert names == ["front", "back", "left", "right", "top", "bottom"] and all(i.shape == (48, 48, 3) for i in six)
    grid = render_grid(six, 3, labels=names, pad=4)
    band = grid.shape[0] - 2 * (48 + 4) - 4
    assert grid.shape[1] == 3 * (48 + 4) + 4 and band > 0 and band % 2 == 0
    assert np.array_equal(grid[4 + band // 2 : 4 + band // 2 + 48, 4:52], six[0])  # tile below its caption
    assert (grid[4 : 4 + band // 2, 4:52] < 128).any()  # the caption is drawn
    assert np.array_equal(render_grid(six, 3)[4:52, 4:52], six[0])
    frames = turntable_frames(V, F, UV, G, tex, up="z", n=4, size=40, tracer=tracer)
    assert len(frames) == 4 and not np.array_equal(frames[0], frames[1])
    assert grid_columns(6) == 3 and grid_columns(24) == 6 and grid_columns(1) == 1
    save_gif(tmp_path / "t.gif", frames, fps=10)  # GIF delays are in 10 ms steps
    with Image.open(tmp_path / "t.gif") as gif:
        assert gif.n_frames == 4 and gif.size == (40, 40) and gif.info["duration"] == 100
    assert [p.name for p in tmp_path.iterdir()] == ["t.gif"]  # no temporary file left
    for bad in ([], [frames[0], frames[1][:20]]):
        with pytest.raises(ValueError):
            save_gif(tmp_path / "bad.gif", bad)
    with pytest.raises(ValueError):
        render_grid([six[0], frames[0]], 2)


# ------------------------------------------------------------------------------------- CLI
@pytest.fixture(scope="module")
def mug_glb(mug, tmp_path_factory):
    path = tmp_path_factory.mktemp("render") / "mug.glb"
    write_glb(path, *mug, names=["body", "handle"])
    return path


def test_cli_render_front_six_and_turntable(mug_glb, capsys):
    d = mug_glb.parent
    assert main(["render", str(mug_glb), "--size", "96", "--up", "z"]) == 0
    assert f"wrote {d / 'mug.png'}" in capsys.readouterr().out  # default: FILE with .png suffix
    img = np.asarray(Image.open(d / "mug.png"))
    m = read_textured_glb(mug_glb)
    assert np.array_equal(img, render_three_quarter(m.vertices, m.faces, m.corner_uv, m.face_group, m.textures, "z", 96))
    assert object_pixels(img).mean() > 0.1 and red_share(img) > 0.15
    # --up auto is y for .glb files: a different view of the same file.
    assert main(["render", str(mug_glb), "--size", "96", "--out", str(d / "auto.png")]) == 0
    assert not np.array_equal(np.asarray(Image.open(d / "auto.png")), img)

    assert main(["render", str(mug_glb), "--views", "six", "--size", "64", "--up", "z", "--out", str(d / "six.png")]) == 0
    six = np.asarray(Image.open(d / "six.png"))
    assert six.shape[1] == 3 * (64 + 4) + 4 and six.shape[0] > 2 * (64 + 4) + 4
    assert main(["render", str(mug_glb), "--views", "turntable", "--frames", "5", "--size", "32", "--up", "z", "--out", str(d / "turn.gif")]) == 0
    with Image.open(d / "turn.gif") as gif:
        assert gif.n_frames == 5 and gif.size == (32, 32)
    assert main(["render", str(mug_glb), "--views", "turntable", "--frames", "6", "--size", "32", "--out", str(d / "sub" / "turn.png")]) == 0
    assert np.asarray(Image.open(d / "sub" / "turn.png")).shape == (2 * 36 + 4, 3 * 36 + 4, 3)


@pytest.mark.parametrize(
    "argv, message",
    [
        (["{missing}"], "no such file"),
        (["{text}"], "not a GLB"),
        (["{lines}"], "no triangles"),
        (["{glb}", "--size", "4"], "--size"),
        (["{glb}", "--frames", "0", "--views", "turntable"], "--frames"),
        (["{glb}", "--views", "six", "--out", "{dir}/x.gif"], "turntable"),
        (["{glb}", "--out", "{dir}/x.jpg"], ".png"),
    ],
)
def test_cli_render_bad_input(argv, message, mug_glb, tmp_path, capsys):
    (tmp_path / "text.glb").write_text("not a glb\n")
    (tmp_path / "lines.glb").write_bytes(handmade_glb(lines_only=True))
    names = {"missing": tmp_path / "missing.glb", "text": tmp_path / "text.glb", "lines": tmp_path / "lines.glb", "glb": mug_glb, "dir": tmp_path}
    before = set(tmp_path.iterdir())
    assert main(["render"] + [a.format(**names) for a in argv]) == 2
    err = capsys.readouterr().err
    assert err.startswith("error: ") and message in err
    assert set(tmp_path.iterdir()) == before


@pytest.fixture(scope="module")
def mug_family(tmp_path_factory):
    """A small built mug family (sample, template, paint; no correspondences needed by --mapper identity/nearest)."""
    from proctex.build.pipeline import stage_paint
    from proctex.build.pipeline import stage_sample
    from proctex.build.pipeline import stage_template
    from proctex.store.config import BuildConfig
    from proctex.store.layout import FamilyStore
    from proctex.store.state import write_config

    root = tmp_path_factory.mktemp("fam") / "mug"
    cfg = BuildConfig.from_dict(dict(model="mug", n_train=2, n_test=0, texture_size=64, prompt="red and white checkered fabric", group_prompts={"handle": "gold"})).validate()
    st = FamilyStore(root)
    write_config(st, cfg)
    for stage in (stage_sample, stage_template, stage_paint):
        stage(st, cfg, log=lambda *_: None)
    return root


def test_cli_transfer_preview(mug_family, tmp_path, capsys):
    out, png = tmp_path / "t.glb", tmp_path / "previews" / "t.png"
    assert main(["transfer", str(mug_family), "--params", '{"radius": 0.045}', "--out", str(out), "--mapper", "identity", "--preview", str(png), "--json"]) == 0
    summary = json.loads(capsys.readouterr().out)
    assert summary["preview"] == str(png) and summary["out"] == str(out)
    img = np.asarray(Image.open(png))
    assert img.shape == (512, 512, 3) and object_pixels(img).mean() > 0.1 and red_share(img) > 0.15
    # The preview shows what the GLB holds: a z-up model family, stood upright in glTF's y-up world.
    m = read_textured_glb(out)
    assert all(p is not None for p in m.pbr)  # with its PBR maps, lit physically in both
    again = render_three_quarter(m.vertices, m.faces, m.corner_uv, m.face_group, m.textures, "y", 512, maps=m.pbr, normals=m.corner_normals)
    assert (np.abs(again.astype(int) - img).max(axis=-1) > 1).mean() <= 0.002

    baked, bpng = tmp_path / "b.glb", tmp_path / "b.png"
    assert main(["transfer", str(mug_family), "--params", '{"radius": 0.045}', "--out", str(baked), "--mapper", "nearest", "--bake", "64", "--preview", str(bpng)]) == 0
    assert f"wrote {bpng}" in capsys.readouterr().out
    bimg = np.asarray(Image.open(bpng))
    assert bimg.shape == (512, 512, 3) and red_share(bimg) > 0.15
    m = read_textured_glb(baked)
    assert all(p is not None for p in m.pbr)  # the bake carries the maps too
    again = render_three_quarter(m.vertices, m.faces, m.corner_uv, m.face_group, m.textures, "y", 512, maps=m.pbr, normals=m.corner_normals)
    assert (np.abs(again.astype(int) - bimg).max(axis=-1) > 1).mean() <= 0.002

    assert main(["transfer", str(mug_family), "--params", "{}", "--out", str(tmp_path / "x.glb"), "--preview", str(tmp_path / "x.jpg")]) == 2
    assert "--preview must name a .png" in capsys.readouterr().err
    assert not (tmp_path / "x.glb").exists()


def test_cli_paint_preview(tmp_path, capsys):
    out, png = tmp_path / "p", tmp_path / "p34.png"
    assert main(["paint", "mug", "--prompt", "red and white checkered fabric", "--size", "64", "--out", str(out), "--preview", str(png), "--json"]) == 0
    summary = json.loads(capsys.readouterr().out)
    assert summary["preview"] == str(png)
    assert (out / "preview.png").is_file() and (out / "textured.glb").is_file()  # unchanged behaviour
    img = np.asarray(Image.open(png))
    assert img.shape == (512, 512, 3) and red_share(img) > 0.15
    m = read_textured_glb(out / "textured.glb")  # the z-up mug stands upright in glTF's y-up world
    assert all(p is not None for p in m.pbr)  # with its PBR maps, lit physically in both
    again = render_three_quarter(m.vertices, m.faces, m.corner_uv, m.face_group, m.textures, "y", 512, maps=m.pbr, normals=m.corner_normals)
    assert (np.abs(again.astype(int) - img).max(axis=-1) > 1).mean() <= 0.002
    assert main(["paint", "mug", "--prompt", "x", "--out", str(tmp_path / "q"), "--preview", str(tmp_path / "q.gif")]) == 2
    assert "--preview must name a .png" in capsys.readouterr().err and not (tmp_path / "q").exists()


@pytest.mark.parametrize("up, axis", [("z", 2), ("x", 0), ("y", 1)])
def test_glb_stands_the_shape_upright_in_gltf_y_up(mug, up, axis):
    """A z-up (or x-up) shape gets a node rotation taking its up axis to glTF's +Y; the vertex data
    is unchanged, so a reader applying node transforms sees the shape's up axis as +Y."""
    V, F, UV, G, tex = mug
    data = glb_bytes(V, F, UV, G, tex, up=up)
    gltf = gl.GLTF2.load_from_bytes(data)
    raw = read_textured_glb(glb_bytes(V, F, UV, G, tex))
    m = read_textured_glb(data)
    assert np.allclose(m.vertices[m.faces][..., 1], raw.vertices[raw.faces][..., axis], atol=1e-6)
    assert (gltf.nodes[0].rotation is None) == (up == "y")
    assert np.allclose(np.linalg.norm(m.vertices[m.faces], axis=-1), np.linalg.norm(raw.vertices[raw.faces], axis=-1), atol=1e-6)
    with pytest.raises(ValueError, match="up must be"):
        glb_bytes(V, F, UV, G, tex, up="w")
