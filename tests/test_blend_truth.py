"""Canonical truth for ``.blend`` families (issue 50): each producing node's own box coordinates, and
the node of every face, read while evaluating. A point's true template point has the same box
coordinates, from the same node, on the template part its group maps to. Shown on the bench fixture
(built in code): the template against itself is exact; a board scaled and moved by parameters has an
exact, known truth the tool recovers; the true map scores near zero and a mirror, a collapse and the
identity clearly worse; points of a node the template part lacks have no truth."""

from __future__ import annotations

from dataclasses import replace
import numpy as np
import pytest

from proctex.build.pipeline import build
from proctex.geometry.parts import part_mesh, segment
from proctex.geometry.surface import interpolate
from proctex.measure.fidelity import (
    FAIL_ERROR,
    gt_errors,
    locate_canonical,
    template_truth,
    tracked_points,
    truth_samples,
)
from proctex.store.config import BuildConfig
from proctex.store.layout import FamilyStore
from proctex.store.samples import load_sample, samples
from proctex.transfer.apply import transfer
from proctex.transfer.assets import load_assets, with_textures
from proctex.transfer.assign import assign_parts, representative_frame
from proctex.transfer.mappers import IdentityMapper

from .test_blender import blends, needs_bpy  # noqa: F401  (blends: the fixture files, built once per module)
from .test_fidelity import Collapse, Mirrored, _smooth_textures
from .test_fidelity import _score as _fidelity_score

pytestmark = needs_bpy


class SourceTruthMapper:
    """The true correspondence of a ``.blend`` shape: each vertex to the template point with the same
    box coordinates from the same node (the node of a face using it)."""

    def __init__(self, assets, truth) -> None:
        self.assets, self.truth, self._parts = assets, truth, []

    def set_shape(self, shape) -> None:
        seg = segment(shape)
        self._parts = []
        for a in assign_parts(shape, seg, self.assets):
            if a.group < 0:
                continue
            part = seg.parts[a.part]
            v, f = part_mesh(shape, part)
            key = np.zeros(len(v), dtype=np.int64)
            key[f.reshape(-1)] = np.repeat(shape.face_source[part.faces], 3)
            self._parts.append((representative_frame(v, a), shape.canonical[part.vertices], key))

    def map(self, group, vertices, faces, query, seed=0):
        for vn, can, key in self._parts:
            if vn.shape == vertices.shape and np.array_equal(vn, vertices):
                ga = self.assets.groups[group]
                out = np.zeros((len(vertices), 3))
                for k in np.unique(key):
                    at = key == k
                    f, b = self.truth.rep_canonical[(group, int(k))].query(can[at])
                    out[at] = interpolate(ga.vertices, ga.faces, f, b)
                return out
        raise AssertionError("SourceTruthMapper: unknown part")


@pytest.fixture(scope="module")
def bench_family(blends, tmp_path_factory):
    cfg = BuildConfig.from_dict(
        {
            "source": {
                "blender": {"file": str(blends / "bench.blend"), "object": "Bench"},
                "n_train": 2,
                "n_test": 4,
                "params": {"Width": [0.8, 2.0], "Legs": [2, 6], "Leg Height": [0.3, 0.6]},
                "listed": ["Has Back"],
            },
            "paint": {"prompt": "oak", "texture_size": 128},
            "seed": 3,
        }
    )
    st = FamilyStore(tmp_path_factory.mktemp("blendtruth") / "bench")
    build(st, cfg, stages=("sample", "template", "paint"), log=lambda *_: None)
    assets = load_assets(st)
    assets = replace(with_textures(assets, _smooth_textures(assets)), painted=None, observed=None)
    uv = st.read_arrays("template/uv.npz")
    shapes = [load_sample(st, r, cfg) for r in samples(st) if r["split"] == "test"]
    return st, cfg, assets, uv, shapes


def _score(family, mapper, n=1500):
    """test_fidelity's scoring (truth-tracked variance, GT error summary) and the share of the
    measured points that have truth (:func:`truth_samples` gives ``n`` points a shape)."""
    tv, gt, _ = _fidelity_score(family, mapper, n)
    return tv, gt, gt["points"] / (n * len(family[4]))


def test_the_shapes_carry_each_nodes_box_and_the_template_against_itself_is_exact(bench_family):
    from proctex.store.state import FamilyState

    st, cfg, assets, uv, shapes = bench_family
    tpl = assets.shape
    assert tpl.face_source is not None and (tpl.face_source > 0).all() and np.isfinite(tpl.canonical).all()
    notes = FamilyState.load(st).stages["sample"]["notes"]  # the build record says which inputs kept the file's values
    assert any("'Seat Size' held at the file's value (0.4)" in n for n in notes)
    assert cfg.truth == "auto" and __import__("proctex.measure.evaluate", fromlist=["x"]).resolve_truth(cfg) == "canonical"
    seg = segment(tpl)
    tp = tracked_points(tpl, assets.grouping, "canonical", n=800, seed=0)
    loc = locate_canonical(tp, tpl, seg, tpl, seg)
    assert (loc.face >= 0).all()
    assert np.allclose(interpolate(tpl.vertices, tpl.faces, loc.face, loc.bary), interpolate(tpl.vertices, tpl.faces, tp.face, tp.bary), atol=1e-6)
    truth = template_truth(tpl, assets.grouping, assets, "canonical")
    sm = truth_samples(tpl, seg, "canonical", n=800)
    for g in assets.grouping.groups:  # on each representative, a point's truth is the point itself
        ga, on = assets.groups[g.index], sm.part == g.representative
        for key in np.unique(tpl.face_source[sm.face[on]]):
            at = np.flatnonzero(on & (tpl.face_source[sm.face] == key))
            faces, bary = truth.rep_canonical[(g.index, int(key))].query(sm.canonical[at])
            points = interpolate(tpl.vertices, tpl.faces, sm.face[at], sm.bary[at])
            assert np.abs(interpolate(ga.vertices, ga.faces, faces, bary) - (points - ga.center) / ga.radius).max() < 1e-9
    result = transfer(tpl, assets, IdentityMapper())
    e, _ = gt_errors(tpl, seg, sm, result, assets, truth)
    # Measured as the transfer reads (projected onto the side a point's face is on), the template's
    # thin 8-sided legs land a few points on a neighbouring side face: near, never far.
    assert not np.isnan(e).any() and np.nanmax(e) < 0.05 and np.mean(e) < 2e-3


def test_a_board_scaled_and_moved_by_parameters_has_the_exact_known_truth(bench_family):
    """The seat board is a cube whose x size is Width and whose height is Leg Height: the truth of a
    point on it is the affine map between the two boards' boxes, recovered to 1e-6."""
    st, cfg, assets, uv, shapes = bench_family
    tpl = assets.shape
    model = cfg.procedural_model()
    board = next(i for i, p in model.producer_names.items() if p.name == "Seat" and p.node.startswith("Cube ("))
    truth = template_truth(tpl, assets.grouping, assets, "canonical")
    tseg = segment(tpl)
    tpart = next(p for p in tseg.parts if (tpl.face_source[p.faces] == board).all())
    group = int(assets.grouping.part_group[tpart.index])
    assert assets.grouping.groups[group].representative == tpart.index
    t_lo, t_hi = tpl.vertices[tpart.vertices].min(0), tpl.vertices[tpart.vertices].max(0)
    shape = model.generate({**model.space.defaults(), "Width": 2.0, "Leg Height": 0.35})
    seg = segment(shape)
    spart = next(p for p in seg.parts if (shape.face_source[p.faces] == board).all())
    s_lo, s_hi = shape.vertices[spart.vertices].min(0), shape.vertices[spart.vertices].max(0)
    assert np.isclose(s_hi[0] - s_lo[0], 2.0) and not np.allclose(s_lo, t_lo)  # scaled and moved
    sm = truth_samples(shape, seg, "canonical", n=2000, seed=4)
    on = sm.part == spart.index
    faces, bary = truth.rep_canonical[(group, board)].query(sm.canonical[on])
    rep_local = np.searchsorted(tpart.vertices, tpl.faces[tpart.faces])
    got = interpolate(tpl.vertices[tpart.vertices], rep_local, faces, bary)
    points = interpolate(shape.vertices, shape.faces, sm.face[on], sm.bary[on])
    expected = (points - s_lo) / (s_hi - s_lo) * (t_hi - t_lo) + t_lo
    # exact in exact arithmetic; Blender stores the box coordinates in float32 (eps 6e-8 of a unit box)
    assert on.sum() > 100 and np.abs(got - expected).max() < 1e-6


@pytest.mark.slow
def test_the_true_map_scores_near_zero_and_wrong_maps_at_least_3x_worse(bench_family):
    """GT error and truth-tracked variance can fail: a mirror, every part collapsed to a point and
    the identity score at least 3x the true map (which scores near zero); every measured point of
    the bench has truth except those of nodes the template lacks (its back when the template has
    none), and the share is reported."""
    assets = bench_family[2]
    truth = template_truth(assets.shape, assets.grouping, assets, "canonical")
    tv, gt, share = _score(bench_family, SourceTruthMapper(assets, truth))
    print(f"truth: tracked {tv.value:.5f}, GT mean {gt['mean']:.5f} p99 {gt['p99']:.5f} max {gt['max']:.5f}, with truth {share:.3f}")
    # measured (AMD EPYC, native and the second pass's kernels): GT mean 0.0002, variance 0.00000,
    # share 1.0; identity 0.013 / 0.0032, collapse 0.60 / 0.050, mirror 0.84 / 0.085: every bound
    # below is 3x or more from what it is compared with
    assert gt["mean"] < 0.01 and gt["failed"] == 0.0 and tv.value < 0.01 and share > 0.5
    for name, mapper in (("mirror", Mirrored(SourceTruthMapper(assets, truth))), ("collapse", Collapse()), ("identity", IdentityMapper())):
        wtv, wgt, wshare = _score(bench_family, mapper)
        print(f"{name}: tracked {wtv.value:.5f}, GT mean {wgt['mean']:.5f} max {wgt['max']:.5f}")
        assert wshare == share and wgt["mean"] >= 3 * gt["mean"] + 0.01 and wtv.value >= 3 * tv.value + 1e-3, (name, wgt, wtv.value)


def test_a_point_of_a_node_the_template_part_lacks_has_no_truth_and_a_wrong_group_fails(bench_family):
    """Lookups never cross nodes: the rail's points measured in the legs' group fail (FAIL_ERROR),
    and with the rail's node removed from the template's truth they have none (NaN)."""
    st, cfg, assets, uv, shapes = bench_family
    tpl = assets.shape
    truth = template_truth(tpl, assets.grouping, assets, "canonical")
    shape = shapes[0]
    seg = segment(shape)
    result = transfer(shape, assets, IdentityMapper())
    sm = truth_samples(shape, seg, "canonical", n=1500, seed=2)
    e, groups = gt_errors(shape, seg, sm, result, assets, truth)
    rail = next(i for i, p in cfg.procedural_model().producer_names.items() if p.name == "Rail" and "Curve to Mesh" in p.node)
    on = shape.face_source[sm.face] == rail
    assert on.any() and not np.isnan(e[on]).any()
    legs_group = next(g.index for g in assets.grouping.groups if g.label == "Legs")
    for a in result.assignment:  # the rail put in the legs' group: a wrong group for its node
        if (shape.face_source[seg.parts[a.part].faces] == rail).all():
            a.group = legs_group
    e2, _ = gt_errors(shape, seg, sm, result, assets, truth)
    assert (e2[on] == FAIL_ERROR).all()
    truth.label_groups.pop(rail)
    e3, _ = gt_errors(shape, seg, sm, result, assets, truth)
    assert np.isnan(e3[on]).all() and np.array_equal(np.isnan(e3[~on]), np.isnan(e[~on]))
