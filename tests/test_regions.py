"""Regions within a part from the prompt: parsing, the region rules, and the built-in fork, mug and vase."""

from __future__ import annotations

import numpy as np
import pytest

from proctex.geometry.parts import analyse
from proctex.models import get_model
from proctex.texture.paint_loop import paint_template
from proctex.texture.painters import SurfacePainter
from proctex.texture.painters.regions import RegionFrame, region_weight, split_regions


# ---------------------------------------------------------------------------------------- parsing
@pytest.mark.parametrize(
    "prompt, labels, base, regions, parts",
    [
        ("a dinner fork with a silver tip and a dark wood handle", [], "dinner fork", [("head", "silver"), ("handle", "dark wood")], []),
        ("a dinner fork with a silver tip and a dark wood handle", ["handle", "head", "tine"], "dinner fork", [("head", "silver")], [("handle", "dark wood")]),
        ("a blue mug with a gold rim", ["body", "handle"], "blue mug", [("rim", "gold")], []),
        ("red top", [], "", [("top", "red")], []),
        ("blue and white striped top, white base", [], "", [("top", "blue and white striped"), ("bottom", "white")], []),
        ("handle in dark wood, steel blade", [], "", [("handle", "dark wood"), ("head", "steel")], []),
        ("handle made of walnut", [], "", [("handle", "walnut")], []),
        ("brown leather with black legs", ["seat", "leg"], "brown leather", [], [("leg", "black")]),
        ("a green vase with a white body and a gold lip", [], "green vase white", [("rim", "gold")], []),
    ],
)
def test_split_regions(prompt, labels, base, regions, parts):
    plan = split_regions(prompt, labels)
    assert plan.base == base and list(plan.regions) == regions and list(plan.parts) == parts


@pytest.mark.parametrize("prompt", ["oak", "red and white stripes", "blue denim with white polka dots", "with", ", , and and", "", "x" * 5000])
def test_prompts_without_regions_are_unchanged(prompt):
    plan = split_regions(prompt)
    assert plan.base == prompt and not plan.has_regions


def test_unknown_regions_are_reported():
    plan = split_regions("red velvet with gold buttons")
    assert plan.unknown == ("buttons",) and plan.base == "red velvet"
    assert any("buttons" in n and "'gold' was not used" in n for n in plan.notes)
    sp = SurfacePainter("red velvet with gold buttons")
    assert any("buttons" in line for line in sp.notes())
    with pytest.raises(ValueError, match="string"):
        split_regions(None)


# ------------------------------------------------------------------------------------------ rules
def _cylinder(n=24, rings=20, radius=0.3, height=2.0, flare=0.0):
    """An open tube along z (radius growing by ``flare`` towards +z): vertices, faces."""
    th = np.linspace(0, 2 * np.pi, n, endpoint=False)
    z = np.linspace(-height / 2, height / 2, rings)
    r = radius * (1 + flare * (z - z[0]) / height)
    V = np.array([(rr * np.cos(t), rr * np.sin(t), zz) for zz, rr in zip(z, r) for t in th])
    F = []
    for i in range(rings - 1):
        for j in range(n):
            a, b, c, d = i * n + j, i * n + (j + 1) % n, (i + 1) * n + (j + 1) % n, (i + 1) * n + j
            F += [(a, b, c), (a, c, d)]
    return V, np.array(F)


def test_region_rules_on_a_flared_tube():
    V, F = _cylinder(flare=1.0)
    frame = RegionFrame.from_mesh(V, F, up=2)
    assert frame.axis[2] > 0.99  # the principal axis points to the wide end (+z)
    assert len(frame.border) > 0  # an open tube has a border
    pts = np.array([[0.3, 0, -0.95], [0.5, 0, 0.0], [0.58, 0, 0.95]])
    out = np.array([[1.0, 0, 0]] * 3)
    w = {r: region_weight(r, frame, pts, out) for r in ("head", "handle", "top", "bottom", "rim", "outside", "inside")}
    np.testing.assert_allclose(w["head"], [0, 0, 1])
    np.testing.assert_allclose(w["handle"] + w["head"], 1.0)
    np.testing.assert_allclose(w["top"], [0, 0, 1])
    np.testing.assert_allclose(w["bottom"], [1, 0, 0])
    assert w["rim"][1] == 0 and w["rim"][0] > 0.9 and w["rim"][2] > 0.9  # both open ends are rims
    np.testing.assert_allclose(w["outside"], 1.0)
    np.testing.assert_allclose(region_weight("inside", frame, pts, -out), 1.0)
    # top and bottom both named meet halfway: every point belongs to exactly one
    t = np.linspace(-1, 1, 201)
    line = np.stack([np.full_like(t, 0.4), np.zeros_like(t), t], 1)
    both = region_weight("top", frame, line, out[:1].repeat(201, 0), named=("top", "bottom")) + region_weight("bottom", frame, line, out[:1].repeat(201, 0), named=("top", "bottom"))
    np.testing.assert_allclose(both, 1.0)
    # the boundary is soft, a few per cent wide
    wt = region_weight("top", frame, line, out[:1].repeat(201, 0))
    soft = (wt > 0.01) & (wt < 0.99)
    assert 0 < soft.sum() <= 16  # 8 % of the extent (2 x 0.04)
    with pytest.raises(ValueError, match="unknown region"):
        region_weight("spout", frame, pts, out)


def test_region_weights_are_pointwise():
    V, F = _cylinder(flare=0.5)
    sp = SurfacePainter("white ceramic with a red top and a gold rim")
    from proctex.geometry.shape import Shape

    shape = Shape(V, F)
    sp.bind(shape, analyse(shape))
    rng = np.random.default_rng(1)
    p = rng.uniform(-1, 1, (5000, 3))
    n = rng.normal(size=(5000, 3))
    whole = sp.paint(p, n, group=0)
    parts = np.concatenate([sp.paint(p[k : k + 777], n[k : k + 777], group=0) for k in range(0, 5000, 777)])
    np.testing.assert_array_equal(whole, parts)


# ------------------------------------------------------------------------- the built-in shapes
def _texel_values(tex, group: int):
    gt = tex.groups[group]
    ij = gt.texels.ij
    return gt.texels.points, gt.image[ij[:, 0], ij[:, 1]], gt.pbr.orm[ij[:, 0], ij[:, 1]]


@pytest.fixture(scope="module")
def shapes():
    out = {}
    for name in ("fork", "mug", "vase"):
        s = get_model(name).generate(None)
        out[name] = (s, analyse(s))
    return out


def test_fork_silver_tip_and_dark_wood_handle(shapes):
    shape, grouping = shapes["fork"]
    labels = [g.label for g in grouping.groups]
    tex = paint_template(shape, grouping, "a dinner fork with a silver tip and a dark wood handle", size=96)
    _, col, orm = _texel_values(tex, labels.index("tine"))
    assert (orm[:, 2] > 0.99).all()  # every tine texel is silver
    assert np.abs(col - col.mean(0)).max() < 0.3 and col.mean() > 0.6
    _, col, orm = _texel_values(tex, labels.index("handle"))
    assert (orm[:, 2] < 0.01).all() and np.median(orm[:, 1]) > 0.5  # wood: not metal, rough
    assert (col[:, 0] > col[:, 2]).mean() > 0.95 and col.mean() < 0.45  # dark and brown
    # the metric fails without the region words: the whole fork is one plastic
    plain = paint_template(shape, grouping, "a dinner fork", size=96)
    assert (_texel_values(plain, labels.index("tine"))[2][:, 2] < 0.01).all()


def test_fork_as_one_part_gets_tip_and_handle_along_its_axis(shapes):
    """The fork's parts joined into one: the tip end (the wide one) is silver and the handle end wood."""
    from proctex.geometry.shape import Shape

    from proctex.geometry.parts import segment

    shape, _ = shapes["fork"]
    parts = segment(Shape(shape.vertices, shape.faces)).parts
    bridge = [[int(parts[0].vertices[0]), int(p.vertices[0]), int(p.vertices[1])] for p in parts[1:]]  # slivers join the parts into one
    one = Shape(shape.vertices, np.concatenate([shape.faces, np.asarray(bridge, dtype=shape.faces.dtype).reshape(-1, 3)]))
    grouping = analyse(one)
    assert len(grouping.groups) == 1
    sp = SurfacePainter("a silver tip and a dark wood handle").bind(one, grouping)
    y = (one.vertices[:, 1] - one.vertices[:, 1].min()) / np.ptp(one.vertices[:, 1])  # measuring only: 0 butt, 1 tines
    center = (one.vertices.max(0) + one.vertices.min(0)) / 2
    scale = np.abs(one.vertices - center).max()
    pts = (one.vertices - center) / scale
    nrm = np.tile([0.0, 0.0, 1.0], (len(pts), 1))
    rough, metal, _ = sp.material(pts, nrm, np.tile([1.0, 0, 0], (len(pts), 1)), np.tile([0, 1.0, 0], (len(pts), 1)), group=grouping.groups[0].index, label=grouping.groups[0].label)
    assert (metal[y > 0.75] > 0.99).all() and (metal[y < 0.55] < 0.01).all()


def test_mug_gold_rim(shapes):
    shape, grouping = shapes["mug"]
    tex = paint_template(shape, grouping, "a blue mug with a gold rim", size=128)
    h = shape.vertices[:, 2].max()
    pts, col, orm = _texel_values(tex, 0)  # the body
    rim, below = pts[:, 2] > 0.975 * h, pts[:, 2] < 0.85 * h
    assert rim.sum() > 20 and (orm[rim, 2] > 0.99).all() and (col[rim, 0] > col[rim, 2]).all()  # gold
    assert (orm[below, 2] < 0.01).all() and (col[below, 2] > col[below, 0] + 0.3).all()  # blue plastic
    _, col_h, orm_h = _texel_values(tex, 1)  # the handle is below the rim: blue
    assert (orm_h[:, 2] < 0.01).all()
    plain = paint_template(shape, grouping, "a blue mug", size=128)
    assert (_texel_values(plain, 0)[2][rim, 2] < 0.01).all()


def test_vase_red_top_white_rest_and_group_prompts_still_work(shapes):
    shape, grouping = shapes["vase"]
    tex = paint_template(shape, grouping, "a white vase with a red top", size=128)
    z = shape.vertices[:, 2]
    t_of = lambda p: (p[:, 2] - z.min()) / np.ptp(z)  # noqa: E731
    pts, col, _ = _texel_values(tex, 0)
    t = t_of(pts)
    top, rest = t > 0.78, t < 0.62
    assert (col[top, 0] > 0.6).all() and (col[top, 1] < 0.3).all()  # red
    assert (col[rest].min(axis=1) > 0.8).all()  # white
    # A group prompt keeps working and may carry its own regions, in the part's own frame.
    tex2 = paint_template(shape, grouping, "oak", {"body": "black rubber with a brass rim"}, size=128)
    pts2, col2, orm2 = _texel_values(tex2, 0)
    assert (orm2[t_of(pts2) > 0.985, 2] > 0.99).all() and (orm2[t_of(pts2) < 0.8, 2] < 0.01).all()


def test_views_painter_places_regions_too(shapes):
    shape, grouping = shapes["vase"]
    tex = paint_template(shape, grouping, "a white vase with a red top", painter="views", views=4, view_size=96, size=64)
    pts, col, _ = _texel_values(tex, 0)
    z = shape.vertices[:, 2]
    t = (pts[:, 2] - z.min()) / np.ptp(z)
    seen = tex.groups[0].direct if tex.groups[0].direct is not None else np.ones(len(t), bool)
    assert (col[seen & (t > 0.8), 0] > 0.6).all() and (col[seen & (t < 0.6)].min(axis=1) > 0.75).all()


def test_hostile_prompts_stay_bounded():
    """Thousands of region clauses: one clause per region (the last), the regions there are at most,
    and one material layer per region to paint; a region named twice keeps its last clause."""
    from proctex.texture.painters.regions import MAX_REGIONS, REGIONS

    plan = split_regions("with red top, " * 5000 + "with blue top")
    assert plan.regions == (("top", "blue"),) and any("again" in n for n in plan.notes)
    every = ", ".join(f"{c} {w}" for c, w in zip(["red", "blue", "green", "gold", "white", "black", "grey", "pink"], ["tip", "handle", "top", "bottom", "rim", "inside", "outside", "top"]))
    assert len(split_regions(every).regions) <= min(MAX_REGIONS, len(REGIONS))
    shape = get_model("vase").generate(None)
    sp = SurfacePainter("with red top, " * 5000).bind(shape, analyse(shape))
    assert len(sp._layers_for(0, "body")) == 2  # the rest and one region layer, not 5,000
    colours = sp.paint(np.random.default_rng(0).uniform(-1, 1, (2000, 3)), np.tile([0.0, 0.0, 1.0], (2000, 1)), group=0, label="body")
    assert np.isfinite(colours).all()
