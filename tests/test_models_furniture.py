"""Tests of the furniture and utensil models: desk, sofa, chair, stair, table, fork."""

from __future__ import annotations

import itertools

import numpy as np
import pytest
import trimesh

from .meshes import labelled_parts
from scipy.spatial import cKDTree

from proctex.models import get_model, list_models

MODELS = ("desk", "sofa", "chair", "stair", "table", "fork")


# ------------------------------------------------------------------------------------------- helpers
def kabsch_residual(a: np.ndarray, b: np.ndarray, proper: bool) -> float:
    """RMS residual of the best rotation (``proper``) or best reflection mapping rows of a onto b."""
    a = a - a.mean(axis=0)
    b = b - b.mean(axis=0)
    u, _, vt = np.linalg.svd(a.T @ b)
    d = np.sign(np.linalg.det(u @ vt))
    flip = np.diag([1.0, 1.0, d if proper else -d])
    r = u @ flip @ vt
    return float(np.sqrt(np.mean(np.sum((a @ r - b) ** 2, axis=1))))


def principal_extents(v: np.ndarray) -> np.ndarray:
    """(3,) sorted extents of a point set along its principal axes (a congruence invariant)."""
    c = v - v.mean(axis=0)
    _, axes = np.linalg.eigh(c.T @ c)
    proj = c @ axes
    return np.sort(proj.max(axis=0) - proj.min(axis=0))


def best_orthogonal_fit(a: np.ndarray, b: np.ndarray) -> tuple[float, float]:
    """Correspondence-free fit of point set a onto b by rotations and by reflections.

    Aligns the principal frames with every choice of axis signs and measures the symmetric mean
    nearest-neighbour distance; returns (best proper, best improper).
    """
    a = a - a.mean(axis=0)
    b = b - b.mean(axis=0)
    _, ea = np.linalg.eigh(a.T @ a)
    _, eb = np.linalg.eigh(b.T @ b)
    tree_b = cKDTree(b)
    best = {True: np.inf, False: np.inf}
    for signs in itertools.product((-1.0, 1.0), repeat=3):
        q = eb @ np.diag(signs) @ ea.T
        mapped = a @ q.T
        dist = 0.5 * (tree_b.query(mapped)[0].mean() + cKDTree(mapped).query(b)[0].mean())
        proper = bool(np.linalg.det(q) > 0)
        best[proper] = min(best[proper], dist)
    return best[True], best[False]


def samples(name: str, n: int = 20) -> list[dict]:
    return get_model(name).space.sample(n, seed=0)


# --------------------------------------------------------------------------------------------- tests
def test_models_registered():
    assert set(MODELS) <= set(list_models())


@pytest.mark.parametrize("name", MODELS)
def test_deterministic(name):
    model = get_model(name)
    for p in samples(name, 3):
        a, b = model.generate(p), model.generate(p)
        assert np.array_equal(a.vertices, b.vertices)
        assert np.array_equal(a.faces, b.faces)
        assert np.array_equal(a.canonical, b.canonical)
        assert np.array_equal(a.labels, b.labels)


@pytest.mark.parametrize("name", MODELS)
def test_counts_match_components(name):
    model = get_model(name)
    for p in samples(name):
        shape = model.generate(p)
        assert np.all(np.isfinite(shape.vertices)) and np.all(np.isfinite(shape.canonical))
        assert shape.n_faces < 20000
        parts = labelled_parts(shape)
        n_parts, n_groups = model.expected_counts(p)
        assert len(parts) == n_parts, p
        assert len({label for _, _, label in parts}) == n_groups == len(shape.label_names), p


@pytest.mark.parametrize("name", MODELS)
def test_parts_are_closed_and_outward(name):
    model = get_model(name)
    for p in samples(name, 8):
        shape = model.generate(p)
        for vid, faces, label in labelled_parts(shape):
            mesh = trimesh.Trimesh(shape.vertices[vid], faces, process=False)
            assert mesh.is_watertight, (label, p)
            assert mesh.is_winding_consistent, (label, p)
            assert mesh.volume > 0, (label, p)


@pytest.mark.parametrize("name", MODELS)
def test_stands_on_floor_and_centred(name):
    shape = get_model(name).generate()
    lo, hi = shape.vertices.min(axis=0), shape.vertices.max(axis=0)
    assert lo[2] == pytest.approx(0.0, abs=1e-9)
    assert np.all(np.abs((lo + hi)[:2] / 2) < 0.25 * (hi - lo)[:2])


@pytest.mark.parametrize("name", MODELS)
def test_same_label_parts_congruent(name):
    model = get_model(name)
    for p in samples(name, 10):
        shape = model.generate(p)
        by_label: dict[str, list] = {}
        for vid, faces, label in labelled_parts(shape):
            by_label.setdefault(label, []).append((shape.vertices[vid], faces))
        for label, parts in by_label.items():
            v0, f0 = parts[0]
            for v, f in parts[1:]:
                assert v.shape == v0.shape, (label, p)
                assert np.array_equal(f, f0) or np.array_equal(f, f0[:, ::-1]), (label, p)
                residual = min(kabsch_residual(v0, v, True), kabsch_residual(v0, v, False))
                assert residual < 1e-9, (label, p)


@pytest.mark.parametrize("name", MODELS)
def test_different_labels_differ_in_size(name):
    """Parts with different labels differ by more than 10% in some principal extent."""
    model = get_model(name)
    for p in model.space.sample(40, seed=1, method="lhs"):
        shape = model.generate(p)
        firsts: dict[str, np.ndarray] = {}
        for vid, _, label in labelled_parts(shape):
            firsts.setdefault(label, principal_extents(shape.vertices[vid]))
        for (la, ea), (lb, eb) in itertools.combinations(firsts.items(), 2):
            assert np.max(np.abs(ea - eb) / np.maximum(ea, eb)) > 0.1, (la, lb, p)


@pytest.mark.parametrize(
    "name, param, low, high",
    [
        ("desk", "drawers", 0, 4),
        ("desk", "drawers", 1, 3),
        ("stair", "steps", 3, 12),
        ("stair", "handrail", False, True),
        ("chair", "slats", 2, 6),
        ("chair", "arms", False, True),
        ("table", "legs", 3, 6),
        ("table", "top_shape", "rect", "round"),
        ("table", "apron", False, True),
        ("fork", "tines", 2, 5),
        ("sofa", "seats", 1, 3),
    ],
)
def test_topology_varies(name, param, low, high):
    model = get_model(name)
    a, b = model.generate({param: low}), model.generate({param: high})
    assert a.n_vertices != b.n_vertices
    assert a.n_faces != b.n_faces
    if name != "table" or param != "top_shape":
        assert model.expected_counts({param: low})[0] < model.expected_counts({param: high})[0]
    assert len(labelled_parts(a)) == model.expected_counts({param: low})[0]
    assert len(labelled_parts(b)) == model.expected_counts({param: high})[0]


def test_expected_counts_formulas():
    assert get_model("desk").expected_counts({"drawers": 0}) == (5, 2)
    assert get_model("desk").expected_counts({"drawers": 3}) == (12, 5)
    assert get_model("sofa").expected_counts({"seats": 2}) == (12, 6)
    assert get_model("chair").expected_counts({"slats": 4, "arms": True}) == (13, 5)
    assert get_model("chair").expected_counts({"slats": 4, "arms": False}) == (11, 4)
    assert get_model("stair").expected_counts({"steps": 5, "handrail": True}) == (18, 5)
    assert get_model("stair").expected_counts({"steps": 5, "handrail": False}) == (12, 3)
    assert get_model("table").expected_counts({"legs": 5, "apron": True}) == (7, 3)
    assert get_model("fork").expected_counts({"tines": 3}) == (5, 3)
    with pytest.raises(ValueError):
        get_model("desk").expected_counts({"drawers": 5})


@pytest.mark.parametrize("name", ["sofa", "chair"])
def test_armrests_are_mirror_images_not_rotations(name):
    model = get_model(name)
    for p in samples(name, 5) + [model.space.defaults()]:
        if name == "chair" and not p["arms"]:
            continue
        shape = model.generate(p)
        arms = [shape.vertices[vid] for vid, _, label in labelled_parts(shape) if label == "armrest"]
        assert len(arms) == 2
        left, right = arms
        size = np.linalg.norm(np.ptp(left, axis=0))
        # Same vertex order: a reflection maps one onto the other, no rotation does.
        assert kabsch_residual(left, right, proper=False) < 1e-9 * size
        assert kabsch_residual(left, right, proper=True) > 0.05 * size
        # Without correspondences too: the part is chiral, so no rotation superimposes them.
        rotated, reflected = best_orthogonal_fit(left, right)
        assert reflected < 1e-6 * size
        assert rotated > 0.003 * size
        assert np.sign(left[:, 0].mean()) != np.sign(right[:, 0].mean())


def first_part_with(shape, label: str, canonical: tuple[float, float, float]) -> np.ndarray:
    """(3,) position of the vertex with the given canonical coordinates on the first ``label`` part."""
    vid, _, _ = next(part for part in labelled_parts(shape) if part[2] == label)
    hit = vid[np.all(np.isclose(shape.canonical[vid], canonical), axis=1)]
    assert len(hit) == 1
    return shape.vertices[hit[0]]


def test_canonical_anchor_desk_top_front_edge():
    model = get_model("desk")
    for p in samples("desk"):
        point = first_part_with(model.generate(p), "top", (0.5, 0.0, 1.0))
        assert np.allclose(point, (0.0, -p["depth"] / 2, p["height"]))


def test_canonical_anchor_stair_first_nosing():
    model = get_model("stair")
    for p in samples("stair"):
        point = first_part_with(model.generate(p), "step", (0.5, 0.0, 1.0))
        assert point[2] == pytest.approx(p["rise"])
        assert point[1] < -p["steps"] * p["run"] / 2 + 1e-9  # the nosing overhangs the first riser


def test_canonical_anchor_table_rect_corner():
    model = get_model("table")
    for p in samples("table"):
        p = {**p, "top_shape": "rect"}
        point = first_part_with(model.generate(p), "top", (1.0, 1.0, 1.0))
        assert np.allclose(point, (p["width"] / 2, p["depth"] / 2, p["height"]))


def test_fork_tines_touch_head():
    model = get_model("fork")
    for p in samples("fork", 5):
        shape = model.generate(p)
        parts = labelled_parts(shape)
        head = next(shape.vertices[vid] for vid, _, label in parts if label == "head")
        lo, hi = head.min(axis=0), head.max(axis=0)
        for vid, _, label in parts:
            if label == "tine":
                tine = shape.vertices[vid]
                base = tine[tine[:, 1] < tine[:, 1].min() + 1e-9]
                assert np.all((base >= lo - 1e-9) & (base <= hi + 1e-9)), p  # base inside the head
                assert np.ptp(tine[:, 1]) > 5 * np.ptp(tine[:, 0])  # long and thin
