"""Template texturing: surface painting, the multi-view paint loop, coverage, outputs and the CLI."""

import json

import numpy as np
import pytest

from proctex.cli import main
from proctex.geometry.meshio import load_mesh
from proctex.geometry.parts import analyse
from proctex.models import get_model, list_models
from proctex.store.template import write_textured
from proctex.texture.metrics import coverage
from proctex.texture.paint import SolidViewPainter, paint_surface, resolve_group_prompts
from proctex.texture.paint_loop import fill_unseen, paint_template, paint_views
from proctex.texture.painters import GENERATE, KEEP, SurfacePainter
from proctex.texture.render import Tracer, bounding_sphere, orbit_path, render_buffers
from proctex.texture.uv import sample_texture

from .conftest import require_validator


class Analytic:
    """A smooth surface painter with a closed form (for exact checks)."""

    def paint(self, points, normals, group=None, label=""):
        return (0.5 + 0.4 * np.sin(5 * points + np.array([0.0, 1.0, 2.0]) * (1 + (group or 0)))).astype(np.float32)


def psnr(a, b):
    mse = float(((np.asarray(a, float) - np.asarray(b, float)) ** 2).mean())
    return 10 * np.log10(1 / max(mse, 1e-12))


@pytest.fixture(scope="module")
def sofa(sofa_dir):
    shape, _ = load_mesh(sofa_dir / "train" / "0.obj")
    return shape, analyse(shape)


@pytest.fixture(scope="module")
def chair():
    shape = get_model("chair").generate()
    return shape, analyse(shape)


# --------------------------------------------------------------------------------------- prompts
def test_group_prompts_resolve_by_label_then_index(chair):
    shape, g = chair
    labels = {x.label for x in g.groups}
    assert "leg" in labels
    leg = next(x.index for x in g.groups if x.label == "leg")
    other = next(x.index for x in g.groups if x.label != "leg")
    p = resolve_group_prompts(g, "oak", {"leg": "steel", str(other): "red velvet"})
    assert p[leg] == "steel" and p[other] == "red velvet"
    assert all(v == "oak" for k, v in p.items() if k not in (leg, other))
    p = resolve_group_prompts(g, "oak", {"leg": "steel", str(leg): "gold"})
    assert p[leg] == "gold"  # an explicit index beats the label
    with pytest.raises(ValueError, match="unknown group 'cushion'.*leg"):
        resolve_group_prompts(g, "oak", {"cushion": "silk"})
    with pytest.raises(ValueError):
        resolve_group_prompts(g, 3, None)


# --------------------------------------------------------------------------------- surface paint
def test_surface_paint_puts_the_painter_colour_on_every_covered_texel(chair):
    shape, g = chair
    tex = paint_surface(shape, g, Analytic(), size=128)
    assert len(tex.groups) == len(g.groups)
    from proctex.texture.paint import shape_frame

    center, scale = shape_frame(shape)
    for gt in tex.groups:
        got = gt.image[gt.texels.ij[:, 0], gt.texels.ij[:, 1]]
        want = Analytic().paint((gt.texels.points - center) / scale, gt.texels.normals, group=gt.group)
        assert np.allclose(got, want, atol=1e-6)
        assert gt.painted[gt.texels.ij[:, 0], gt.texels.ij[:, 1]].all()
        assert gt.image.dtype == np.float32 and np.isfinite(gt.image).all()


@pytest.mark.slow
@pytest.mark.parametrize("name", list_models())
def test_coverage_is_zero_on_every_builtin_template(name):
    shape = get_model(name).generate()
    g = analyse(shape)
    tex = paint_surface(shape, g, SurfacePainter("speckled green ceramic", seed=1), size=256)
    cov = coverage(shape.vertices, shape.faces, tex.uv.corner_uv, tex.uv.face_group, tex.painted_masks, size=256)
    assert cov.pixels > 1000 and cov.share == 0.0, cov
    tv = paint_views(shape, g, SolidViewPainter(SurfacePainter("oak"), g), "oak", n_views=6, view_size=128, size=128, uv=None)
    cov = coverage(shape.vertices, shape.faces, tv.uv.corner_uv, tv.uv.face_group, tv.painted_masks, size=256)
    assert cov.share == 0.0, cov


def test_coverage_is_zero_on_a_sofa_sample_and_counts_holes(sofa):
    shape, g = sofa
    tex = paint_surface(shape, g, SurfacePainter("red velvet"), size=256)
    cov = coverage(shape.vertices, shape.faces, tex.uv.corner_uv, tex.uv.face_group, tex.painted_masks, up="y", size=256)
    assert cov.pixels > 10000 and cov.share == 0.0
    # Knock out the painted texels of one group: the metric sees it.
    holes = [m.copy() for m in tex.painted_masks]
    holes[1][:] = False
    cov = coverage(shape.vertices, shape.faces, tex.uv.corner_uv, tex.uv.face_group, holes, up="y", size=256)
    assert cov.share > 0.01


# ------------------------------------------------------------------------------ multi-view loop
@pytest.mark.slow  # over 15 s: not in make test's second pass (tests/suite.py)
@pytest.mark.parametrize("prompt", ["oak wood", "red velvet", "white marble"])
def test_view_loop_reproduces_the_surface_painter(chair, prompt):
    shape, g = chair
    surface = SurfacePainter(prompt, seed=3)
    ref = paint_surface(shape, g, surface, size=256)
    tv = paint_views(shape, g, SolidViewPainter(surface, g), prompt, view_size=384, size=256, uv=ref.uv, complete_hidden=False)
    for a, b in zip(ref.groups, tv.groups):
        # Only texels a view actually painted (fill_unseen invents the others).
        ij = a.texels.ij[b.direct]
        assert b.direct.mean() > 0.8
        assert psnr(a.image[ij[:, 0], ij[:, 1]], b.image[ij[:, 0], ij[:, 1]]) >= 30, (prompt, a.group)


def test_view_loop_trimap_generates_then_keeps(chair):
    shape, g = chair
    surface = SurfacePainter("gold")
    c, r = bounding_sphere(shape.vertices)
    cam = orbit_path(c, r, "z", 11, 96)[0]
    calls = []

    class Recorder(SolidViewPainter):
        def paint_view(self, request):
            calls.append(request.trimap.copy())
            assert request.rgb.shape == (96, 96, 3) and request.group.shape == (96, 96)
            assert request.depth[request.trimap == 0].min() == np.inf
            return super().paint_view(request)

    paint_views(shape, g, Recorder(surface, g), "gold", cameras=[cam, cam], size=128, complete_hidden=False)
    first, second = calls
    fg = first > 0
    assert (first[fg] == GENERATE).all()
    assert (second[fg] == KEEP).mean() > 0.97  # the same view again: nothing to do


def test_view_loop_rejects_bad_painters(chair):
    shape, g = chair

    class Wrong:
        def paint_view(self, request):
            return np.zeros((3, 3, 3))

    with pytest.raises(ValueError, match="expected"):
        paint_views(shape, g, Wrong(), n_views=3, view_size=32, size=32)
    with pytest.raises(ValueError, match="paint_view"):
        paint_views(shape, g, object(), n_views=3, view_size=32, size=32)


def test_fill_unseen_interpolates_on_the_surface():
    pts = np.array([[0, 0, 0], [1, 0, 0], [0.5, 0, 0], [10, 0, 0]], float)
    col = np.array([[1, 0, 0], [0, 0, 1], [9, 9, 9], [9, 9, 9]], float)
    seen = np.array([True, True, False, False])
    out = fill_unseen(pts, col, seen, k=2)
    assert np.allclose(out[2], [0.5, 0, 0.5])
    w = np.array([1 / 10**2, 1 / 9**2])  # inverse squared distances to the two seen texels
    assert np.allclose(out[3], (w[0] * col[0] + w[1] * col[1]) / w.sum())
    assert np.array_equal(out[:2], col[:2])


@pytest.mark.slow  # over 15 s: not in make test's second pass (tests/suite.py)
def test_diffusion_painter_runs_the_whole_loop(tmp_path, chair):
    pytest.importorskip("diffusers")
    import torch

    from proctex.texture.painters.diffusion import DiffusionViewPainter
    from proctex.texture.painters.tiny_pipeline import build_tiny_pipeline

    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    try:
        shape, g = chair
        painter = DiffusionViewPainter(build_tiny_pipeline(tmp_path / "tiny"), steps=2)
        tv = paint_views(shape, g, painter, "a wooden chair", n_views=4, view_size=64, size=64, complete_hidden=False)
    finally:
        torch.set_num_threads(threads)
    cov = coverage(shape.vertices, shape.faces, tv.uv.corner_uv, tv.uv.face_group, tv.painted_masks, size=128)
    assert cov.share == 0.0
    for gt in tv.groups:
        assert np.isfinite(gt.image).all() and gt.image.min() >= 0 and gt.image.max() <= 1
    assert sum(v["texels_updated"] for v in tv.stats["views"]) > 0


# --------------------------------------------------------------------------------------- outputs
def _glb_colour_at(path, point, material, expect_tol=2e-3):
    """Colour of the loaded GLB at a surface point of the primitive with ``material``: find the face,
    interpolate its UVs, sample its texture. (Touching parts share surface, hence the material.)"""
    import trimesh

    from proctex.geometry.surface import SurfaceIndex

    scene = trimesh.load(path, force="scene")
    best = None
    for geom in scene.geometry.values():
        if geom.visual.material.name != material:
            continue
        idx = SurfaceIndex(np.asarray(geom.vertices), np.asarray(geom.faces))
        res = idx.query(point[None])
        if best is None or res.distance[0] < best[0]:
            best = (res.distance[0], geom, res)
    d, geom, res = best
    assert d < expect_tol
    uv = np.einsum("j,jk->k", res.bary[0], np.asarray(geom.visual.uv)[geom.faces[res.faces[0]]])
    img = np.asarray(geom.visual.material.baseColorTexture.convert("RGB"))
    return sample_texture(img, uv[None])[0], geom


def test_write_textured_glb_has_the_right_colours_at_known_points(tmp_path, sofa):
    shape, g = sofa
    tex = paint_surface(shape, g, SurfacePainter("blue and white striped fabric"), size=128)
    summary = write_textured(tex, tmp_path, up="y", obj=True)
    for name in ["textured.glb", "textured.obj", "textured.mtl", "preview.png", "paint.json"]:
        assert (tmp_path / name).is_file()
    assert summary["coverage"]["share"] == 0.0
    rng = np.random.default_rng(0)
    for gt in tex.groups:
        if g.groups[gt.group].degenerate:
            continue
        rep_uv = tex.uv.corner_uv[g.parts[g.groups[gt.group].representative].faces]
        interior = np.flatnonzero(gt.texels.bary.min(axis=1) > 0.05)  # away from chart seams
        for k in rng.choice(interior, 5, replace=False):
            got, _ = _glb_colour_at(tmp_path / "textured.glb", gt.texels.points[k], gt.label or f"group_{gt.group}")
            uv = gt.texels.bary[k] @ rep_uv[gt.texels.face[k]]
            want = sample_texture(gt.uint8(), uv[None])[0]
            assert np.abs(got - want).max() < 1.5 / 255
    from proctex.texture.export import validate_glb

    if require_validator():
        report = validate_glb(tmp_path / "textured.glb")
        assert report["issues"]["numErrors"] == 0


# ------------------------------------------------------------------------------------------- CLI
def test_cli_paint_writes_everything(tmp_path, capsys):
    out = tmp_path / "mug"
    rc = main(["paint", "mug", "--prompt", "glazed blue ceramic", "--group-prompts", '{"handle": "gold"}', "--size", "128", "--out", str(out), "--json"])
    assert rc == 0
    data = json.loads(capsys.readouterr().out)
    assert data["coverage"]["share"] == 0.0
    prompts = {gr["label"]: gr["prompt"] for gr in data["groups"]}
    assert prompts["handle"] == "gold" and prompts["body"] == "glazed blue ceramic"
    pngs = sorted(p.name for p in out.glob("group_*.png"))
    assert len(pngs) == 3 * len(data["groups"])  # base colour, ORM and normal map per group
    assert {p.split(".")[-2] for p in pngs} == {"group_0_body", "group_1_handle", "orm", "normal"}
    assert (out / "textured.glb").is_file() and (out / "preview.png").is_file()


def test_cli_paint_views_painter(tmp_path, capsys):
    rc = main(["paint", "vase", "--prompt", "white marble", "--painter", "views", "--views", "4", "--view-size", "96", "--size", "64", "--out", str(tmp_path / "v"), "--quiet"])
    assert rc == 0
    assert "painted" in capsys.readouterr().out


@pytest.mark.parametrize(
    "argv, message",
    [
        (["paint", "nosuchmodel", "--prompt", "x"], "neither a mesh file nor a built-in model"),
        (["paint", "mug", "--prompt", "x", "--group-prompts", "{bad json"], "not valid JSON"),
        (["paint", "mug", "--prompt", "x", "--group-prompts", '{"cushion": "silk"}'], "unknown group"),
        (["paint", "mug", "--prompt", "x", "--group-prompts", '["a"]'], "JSON object"),
        (["paint", "mug", "--prompt", "x", "--size", "4"], "--size"),
        (["paint", "mug", "--prompt", "x", "--painter", "diffusion"], "--model-dir"),
        (["paint", "mug", "--prompt", "x", "--painter", "diffusion", "--model-dir", "/nonexistent"], "nonexistent"),
    ],
)
def test_cli_paint_bad_input(tmp_path, capsys, argv, message):
    out = tmp_path / "o"
    assert main(argv + ["--out", str(out)]) == 2
    assert message in capsys.readouterr().err
    assert not out.exists()


def test_backproject_matches_the_reference(chair):
    from proctex._reference.paint import backproject_reference
    from proctex.texture.paint_loop import backproject

    shape, g = chair
    c, r = bounding_sphere(shape.vertices)
    cam = orbit_path(c, r, "z", 11, 48)[2]
    b = render_buffers(Tracer(shape.vertices, shape.faces), cam, g.segmentation.face_part)
    rng = np.random.default_rng(0)
    view = rng.uniform(0, 1, (48, 48, 3))
    tri = np.where(b.mask, rng.choice([1, 2, 3], size=b.mask.shape), 0).astype(np.uint8)
    total = 0
    for part in g.parts[:4]:
        pts = shape.vertices[part.vertices]
        pts = np.vstack([pts, (pts[:-1] + pts[1:]) / 2])
        idx, col, cos = backproject(pts, part.index, b, tri, view)
        ref = backproject_reference(pts, part.index, b, tri, view)
        assert set(idx.tolist()) == set(ref)
        for k, cc, cs in zip(idx, col, cos):
            assert np.allclose(cc, ref[k][0]) and np.isclose(cs, ref[k][1])
        total += len(ref)
    assert total > 20


def test_unseen_texels_are_filled_without_repainting_seen_ones(chair):
    """Dis-occlusion: one view leaves most of the chair unseen; the fill never touches painted texels."""
    from scipy.spatial import cKDTree

    shape, g = chair
    surface = SurfacePainter("red and white striped fabric", seed=2)
    c, r = bounding_sphere(shape.vertices)
    cams = orbit_path(c, r, "z", 11, 128)[:1]
    runs = {fill: paint_views(shape, g, SolidViewPainter(surface, g), cameras=cams, size=128, complete_hidden=False, fill=fill) for fill in ("patchmatch", "surface")}
    some_unseen = False
    for a, b in zip(runs["patchmatch"].groups, runs["surface"].groups):
        ij = a.texels.ij
        assert np.array_equal(a.direct, b.direct)
        seen, hidden = ij[a.direct], ij[~a.direct]
        # Painted texels are identical whatever fills the rest.
        assert np.array_equal(a.image[seen[:, 0], seen[:, 1]], b.image[seen[:, 0], seen[:, 1]])
        if len(seen) and len(hidden):
            some_unseen = True
            filled = a.image[hidden[:, 0], hidden[:, 1]]
            assert np.isfinite(filled).all()
            # PatchMatch copies the group's own painted colours (exemplars), not the unpainted grey.
            d, _ = cKDTree(a.image[seen[:, 0], seen[:, 1]]).query(filled)
            assert np.quantile(d, 0.9) < 0.1
    assert some_unseen
    for tv in runs.values():
        cov = coverage(shape.vertices, shape.faces, tv.uv.corner_uv, tv.uv.face_group, tv.painted_masks, size=128)
        assert cov.share == 0.0


def test_painters_come_from_one_registry(tmp_path):
    from proctex.texture.paint import SolidViewPainter
    from proctex.texture.painters import SurfacePainter
    from proctex.texture.painters.diffusion import DiffusionViewPainter
    from proctex.texture.painters.tiny_pipeline import build_tiny_pipeline
    from proctex.texture.painting import make_painter, painter_names

    shape = get_model("mug").generate()
    grouping = analyse(shape)
    assert isinstance(make_painter("surface", grouping, "red"), SurfacePainter)
    views = make_painter("views", grouping, "red", {1: "gold"})
    assert isinstance(views, SolidViewPainter) and isinstance(views.surface, SurfacePainter)
    build_tiny_pipeline(tmp_path / "tiny")
    assert isinstance(make_painter("diffusion", grouping, "red", model_dir=str(tmp_path / "tiny")), DiffusionViewPainter)
    assert painter_names()[:3] == ("surface", "views", "diffusion")
    with pytest.raises(ValueError, match="painter must be one of"):
        make_painter("crayon", grouping, "red")


TOY_PAINTER = '''"""A painter in one file: the surface painter's materials, every texel crimson."""
import numpy as np

from proctex.texture.painting import Painter, register_painter
from proctex.texture.painters import SurfacePainter


class Crimson(SurfacePainter):
    def paint(self, points, normals, group=0, label=""):
        return np.tile(np.array([0.86, 0.08, 0.24], np.float32), (len(points), 1))


register_painter(Painter("toy_crimson", lambda ctx: Crimson(ctx.prompt, {}, seed=ctx.seed), summary="crimson, whatever the prompt"))
'''


def test_a_painter_from_one_file_paints_a_build_and_is_offered_by_the_cli(tmp_path, monkeypatch):
    """One new file registers a painter (issue 33): ``--painter`` offers it, a build config names
    it, and the paint stage paints with it (red where the family's prompt says blue: the registry's
    painter ran, not a default)."""
    from proctex import plugins
    from proctex.build.pipeline import stage_paint
    from proctex.build.pipeline import stage_sample
    from proctex.build.pipeline import stage_template
    from proctex.cli.app import build_parser
    from proctex.store.config import BuildConfig
    from proctex.store.layout import FamilyStore
    from proctex.store.state import write_config
    from proctex.store.template import load_template
    from proctex.texture.painting import unregister_painter

    path = tmp_path / "toy_painter.py"
    path.write_text(TOY_PAINTER)
    monkeypatch.setenv("PROCTEX_PLUGINS", str(path))
    try:
        assert build_parser().parse_args(["paint", "mug", "--prompt", "x", "--out", "o", "--painter", "toy_crimson"]).painter == "toy_crimson"
        cfg = BuildConfig.from_dict({"source": {"model": "mug", "n_train": 2, "n_test": 0}, "paint": {"prompt": "pale blue ceramic", "painter": "toy_crimson", "texture_size": 32}})
        st = FamilyStore(tmp_path / "mug")
        write_config(st, cfg)
        for stage in (stage_sample, stage_template, stage_paint):
            stage(st, cfg, log=lambda *_: None)
        record = load_template(st)
        tex = np.asarray(record.textures[0], dtype=float)
        r, g, b = tex[record.painted[0]].mean(axis=0)
        assert r > b + 40 and r > g + 40, (r, g, b)
    finally:
        unregister_painter("toy_crimson")
        plugins._LOADED.pop(str(path), None)


def test_a_plugin_painter_sees_the_builds_paint_settings_whole(tmp_path):
    """A registered painter is made with the paint settings the build holds, every field (issue 55:
    they went whole -> keywords -> a new PaintConfig of 5 of them, so a plugin saw the default
    texture_size, views, fill, occlusion and group prompts); painting from keywords (the `paint`
    command's path) hands it settings made of every keyword."""
    from dataclasses import asdict

    from proctex.build.pipeline import stage_paint
    from proctex.build.pipeline import stage_sample
    from proctex.build.pipeline import stage_template
    from proctex.store.config import BuildConfig
    from proctex.store.layout import FamilyStore
    from proctex.store.state import write_config
    from proctex.texture.painters import SurfacePainter
    from proctex.texture.painting import Painter, register_painter, unregister_painter

    seen = []

    def make(ctx):
        seen.append(ctx.settings)
        return SurfacePainter(ctx.prompt, {str(k): v for k, v in ctx.prompts.items()}, seed=ctx.seed)

    register_painter(Painter("toy_settings", make, summary="records what it was made with"))
    try:
        paint = {
            "prompt": "pale blue ceramic",
            "painter": "toy_settings",
            "texture_size": 32,
            "views": 5,
            "view_size": 64,
            "paint_hidden": False,
            "fill": "surface",
            "occlusion": True,
            "steps": 7,
            "group_prompts": {"0": "red glaze"},
        }
        cfg = BuildConfig.from_dict({"source": {"model": "mug", "n_train": 2, "n_test": 0}, "paint": paint})
        st = FamilyStore(tmp_path / "mug")
        write_config(st, cfg)
        for stage in (stage_sample, stage_template, stage_paint):
            stage(st, cfg, log=lambda *_: None)
        assert len(seen) == 1 and asdict(seen[0]) == asdict(cfg.paint) and seen[0].texture_size == 32 and seen[0].occlusion
        shape = get_model("mug").generate({})
        paint_template(shape, analyse(shape), "oak", {"0": "red"}, painter="toy_settings", size=32, views=4, view_size=48, fill="surface", occlusion=True, steps=3, maps=False)
        got = seen[1]
        assert (got.texture_size, got.views, got.view_size, got.fill, got.occlusion, got.steps, got.group_prompts, got.painter) == (32, 4, 48, "surface", True, 3, {"0": "red"}, "toy_settings")
    finally:
        unregister_painter("toy_settings")


def test_a_painter_installed_as_a_package_is_found_by_its_entry_point_once_per_import_path(tmp_path, monkeypatch):
    """An installed package's ``proctex.plugins`` entry point registers its painter; the installed
    packages are read once per import path (a lookup reads none again), and a package on a path added
    later is found."""
    import importlib.metadata
    import sys

    from proctex import plugins
    from proctex.texture.painting import get_painter, unregister_painter

    site = tmp_path / "site"
    (site / "toy_pkg-1.0.dist-info").mkdir(parents=True)
    (site / "toy_pkg-1.0.dist-info" / "METADATA").write_text("Metadata-Version: 2.1\nName: toy-pkg\nVersion: 1.0\n")
    (site / "toy_pkg-1.0.dist-info" / "entry_points.txt").write_text("[proctex.plugins]\ntoy = toy_pkg_painter\n")
    (site / "toy_pkg_painter.py").write_text(TOY_PAINTER)
    reads = []
    real = importlib.metadata.entry_points
    monkeypatch.setattr(importlib.metadata, "entry_points", lambda **kw: reads.append(kw) or real(**kw))
    try:
        plugins.load_plugins()
        before = len(reads)
        plugins.load_plugins()
        assert len(reads) == before  # the same import path: nothing read again
        with pytest.raises(ValueError):
            get_painter("toy_crimson")  # not on the path yet
        monkeypatch.syspath_prepend(str(site))
        assert get_painter("toy_crimson").name == "toy_crimson" and "entry point toy" in plugins.load_plugins()
        assert len(reads) == before + 1
    finally:
        unregister_painter("toy_crimson")
        plugins._LOADED.pop("entry point toy", None)
        sys.modules.pop("toy_pkg_painter", None)
