"""Properties every built-in model must have, checked through the real segmentation and grouping."""

import numpy as np
import pytest
from scipy.spatial import cKDTree

from proctex.geometry.matching import match_groups
from proctex.geometry.parts import analyse
from proctex.models import get_model, list_models

MODELS = list_models()


def test_library_size_and_coverage():
    assert len(MODELS) >= 10
    changing = 0
    for name in MODELS:
        m = get_model(name)
        counts = {(s.n_vertices, s.n_faces) for s in map(m.generate, m.space.sample(12, seed=0, method="lhs"))}
        changing += len(counts) > 1
    assert changing >= 4


def _labels_of_groups(grouping):
    return [{grouping.parts[i].label for i in g.members} for g in grouping.groups]


@pytest.mark.parametrize("name", MODELS)
def test_segmentation_and_grouping_follow_the_parameters(name):
    model = get_model(name)
    for params in [model.space.defaults()] + model.space.sample(2, seed=11, method="lhs"):
        shape = model.generate(params)
        g = analyse(shape)
        assert (len(g.parts), len(g.groups)) == model.expected_counts(params), params
        # Every part carries one label, and groups are exactly the label classes.
        labels = _labels_of_groups(g)
        assert all(len(s) == 1 for s in labels), labels
        assert len({next(iter(s)) for s in labels}) == len(labels)
        assert not any(p.degenerate for p in g.parts)


@pytest.mark.parametrize("name", MODELS)
def test_determinism_and_finite(name):
    model = get_model(name)
    p = model.space.sample(1, seed=5)[0]
    a, b = model.generate(p), model.generate(dict(p))
    np.testing.assert_array_equal(a.vertices, b.vertices)
    np.testing.assert_array_equal(a.faces, b.faces)
    np.testing.assert_array_equal(a.canonical, b.canonical)
    assert np.all(np.isfinite(a.vertices)) and np.all(np.isfinite(a.canonical))


def _part_points(shape, label):
    """Canonical coords, per-axis normalised positions and vertex areas of the first part with a label."""
    from proctex.geometry.parts import part_mesh, segment
    from proctex.geometry.surface import triangle_areas

    seg = segment(shape)
    part = next(p for p in seg.parts if p.label == label)
    v, f = part_mesh(shape, part)
    lo, hi = v.min(0), v.max(0)
    norm = (v - (lo + hi) / 2) / np.maximum((hi - lo) / 2, 1e-12)
    area = np.bincount(f.reshape(-1), weights=np.repeat(triangle_areas(v, f), 3), minlength=len(v))
    return shape.canonical[part.vertices], norm, area / area.sum()


@pytest.mark.parametrize("name", MODELS)
def test_canonical_coordinates_mean_the_same_place(name):
    """Same canonical point <-> same semantic location, across parameter settings.

    For each label in two shapes, every vertex of A finds the vertex of B with the nearest canonical
    coordinates; their positions in the per-axis normalised part frame must agree far better than
    random pairs do (means weighted by vertex area, i.e. over the surface).
    """
    model = get_model(name)
    pa, pb = model.space.sample(2, seed=21, method="lhs")
    a, b = model.generate(pa), model.generate(pb)
    common = sorted(set(a.label_names) & set(b.label_names))
    assert common
    rng = np.random.default_rng(0)
    for label in common:
        ca, na, wa = _part_points(a, label)
        cb, nb, _ = _part_points(b, label)
        dcan, j = cKDTree(cb).query(ca)
        assert np.median(dcan) < 0.2, (label, np.median(dcan))  # B covers A's canonical domain
        matched = np.linalg.norm(na - nb[j], axis=1) @ wa
        random = np.linalg.norm(na - nb[rng.integers(0, len(nb), len(na))], axis=1) @ wa
        assert matched < 0.4 and matched < 0.4 * random, (label, matched, random)


@pytest.mark.parametrize("name", MODELS)
def test_group_matching_pairs_the_same_labels(name):
    model = get_model(name)
    samples = model.space.sample(3, seed=3, method="lhs")
    template = model.generate(model.space.defaults())
    tg = analyse(template)
    t_labels = [next(iter(s)) for s in _labels_of_groups(tg)]
    for p in samples:
        shape = model.generate(p)
        sg = analyse(shape)
        m = match_groups(shape, sg, template, tg)
        s_labels = [next(iter(s)) for s in _labels_of_groups(sg)]
        for a, b in m.pairs:
            assert s_labels[a] == t_labels[b], (p, s_labels[a], t_labels[b])
        assert sorted(s_labels[a] for a in m.added) == sorted(set(s_labels) - set(t_labels)), p
        assert sorted(t_labels[b] for b in m.missing) == sorted(set(t_labels) - set(s_labels)), p
