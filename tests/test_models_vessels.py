"""Tests for the round built-in models: mug, pumpkin, mushroom, cake, shell."""

from __future__ import annotations

import numpy as np
import pytest

import trimesh
from .meshes import part_label, split_parts

from proctex.geometry.sweeps import sphere_canonical
from proctex.models import get_model, list_models
from proctex.models.food import tier_label

MODELS = ["mug", "pumpkin", "mushroom", "cake", "shell"]


def rigid_signature(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """(5,) float64 quantities invariant under rotation, translation and reflection:
    surface area, volume and the sorted principal standard deviations of the vertices."""
    mesh = trimesh.Trimesh(vertices, faces, process=False)
    centred = vertices - vertices.mean(axis=0)
    spread = np.sqrt(np.sort(np.linalg.eigvalsh(centred.T @ centred / len(centred))))
    return np.concatenate([[mesh.area, abs(mesh.volume)], spread])


def nearest_canonical(shape, ids: np.ndarray, s: float, phi: float) -> np.ndarray:
    """(3,) position of the vertex among ``ids`` whose canonical point is closest to (s, phi)."""
    target = sphere_canonical(s, phi)
    return shape.vertices[ids[np.argmin(np.linalg.norm(shape.canonical[ids] - target, axis=1))]]


def parts_by_label(shape) -> dict[str, list[tuple[np.ndarray, np.ndarray]]]:
    out: dict[str, list] = {}
    for ids, faces in split_parts(shape):
        out.setdefault(part_label(shape, ids), []).append((ids, faces))
    return out


def test_models_are_registered():
    assert set(MODELS) <= set(list_models())


@pytest.mark.parametrize("name", MODELS)
def test_deterministic(name):
    model = get_model(name)
    params = model.space.sample(1, seed=3)[0]
    a, b = model.generate(params), model.generate(dict(params))
    for attr in ("vertices", "faces", "canonical", "labels"):
        np.testing.assert_array_equal(getattr(a, attr), getattr(b, attr))
    assert a.label_names == b.label_names


@pytest.mark.parametrize("name", MODELS)
def test_parts_are_closed_and_match_expected_counts(name):
    model = get_model(name)
    for params in model.space.sample(20, seed=0) + [model.space.defaults()]:
        shape = model.generate(params)
        assert np.all(np.isfinite(shape.vertices)) and np.all(np.isfinite(shape.canonical))
        assert shape.n_faces < 20000
        n_parts, n_groups = model.expected_counts(params)
        parts = split_parts(shape)
        assert len(parts) == n_parts, params
        assert len(shape.label_names) == n_groups, params
        for ids, faces in parts:
            part_label(shape, ids)
            mesh = trimesh.Trimesh(shape.vertices[ids], faces, process=False)
            assert mesh.is_watertight and mesh.is_winding_consistent, params
            assert mesh.volume > 0, params
        # Standing on the ground.
        assert abs(shape.vertices[:, 2].min()) < 1e-9


@pytest.mark.parametrize("name", MODELS)
def test_expected_counts_validate_params(name):
    model = get_model(name)
    with pytest.raises(ValueError):
        model.expected_counts({"no_such_param": 1})


@pytest.mark.parametrize("name", ["mushroom", "cake"])
def test_same_label_parts_are_congruent(name):
    model = get_model(name)
    for params in model.space.sample(10, seed=4):
        shape = model.generate(params)
        for label, parts in parts_by_label(shape).items():
            ref_ids, ref_faces = parts[0]
            ref_d = np.linalg.norm(shape.vertices[ref_ids][:, None] - shape.vertices[ref_ids][None], axis=-1)
            for ids, faces in parts[1:]:
                np.testing.assert_array_equal(faces, ref_faces)
                d = np.linalg.norm(shape.vertices[ids][:, None] - shape.vertices[ids][None], axis=-1)
                np.testing.assert_allclose(d, ref_d, atol=1e-9, err_msg=label)


@pytest.mark.parametrize("name", MODELS)
def test_different_labels_are_not_congruent(name):
    model = get_model(name)
    for params in model.space.sample(20, seed=5):
        shape = model.generate(params)
        sigs = {label: rigid_signature(shape.vertices[parts[0][0]], parts[0][1]) for label, parts in parts_by_label(shape).items()}
        labels = sorted(sigs)
        for i, a in enumerate(labels):
            for b in labels[i + 1 :]:
                rel = np.abs(sigs[a] - sigs[b]) / np.maximum(np.abs(sigs[a]), np.abs(sigs[b]))
                assert rel.max() > 0.1, (a, b, params)


def test_pumpkin_rib_count_changes_topology():
    model = get_model("pumpkin")
    sizes = {ribs: model.generate({"ribs": ribs}).n_vertices for ribs in (5, 8, 12)}
    assert len(set(sizes.values())) == 3
    assert sizes[5] < sizes[8] < sizes[12]


def test_mushroom_counts_follow_n_small():
    model = get_model("mushroom")
    for n_small in range(4):
        shape = model.generate({"n_small": n_small})
        expected = (2 + 2 * n_small, 2 + (2 if n_small else 0))
        assert model.expected_counts({"n_small": n_small}) == expected
        assert len(split_parts(shape)) == expected[0]
        assert len(shape.label_names) == expected[1]
    assert set(model.generate({"n_small": 3}).label_names) == {"cap", "stem", "small_cap", "small_stem"}


def test_cake_counts_follow_tiers_and_candles():
    model = get_model("cake")
    for tiers, candles in [(1, 0), (1, 3), (2, 8), (3, 1), (3, 0)]:
        shape = model.generate({"tiers": tiers, "candles": candles})
        n_parts, n_groups = model.expected_counts({"tiers": tiers, "candles": candles})
        assert n_parts == 1 + tiers + candles
        assert n_groups == 1 + tiers + (candles > 0)
        assert len(split_parts(shape)) == n_parts
        assert sorted(shape.label_names) == sorted(["plate", *(tier_label(i, tiers) for i in range(tiers))] + (["candle"] if candles else []))


def test_mug_canonical_anchor_is_outer_top_rim():
    model = get_model("mug")
    for params in model.space.sample(10, seed=6):
        shape = model.generate(params)
        ((ids, _),) = parts_by_label(shape)["body"]
        rim = nearest_canonical(shape, ids, 0.45, 0.0)
        top_radius = params["radius"] * (1 + params["taper"])
        np.testing.assert_allclose(rim, [top_radius, 0.0, params["height"]], atol=1e-9)


def test_canonical_coordinates_do_not_depend_on_params():
    model = get_model("mug")
    a, b = (model.generate(p) for p in model.space.sample(2, seed=7))
    np.testing.assert_array_equal(a.canonical, b.canonical)


def test_shell_canonical_counts_whorls_back_from_the_aperture():
    """Shells grow or lose whorls at the apex (the body whorl keeps its place), so the canonical
    profile parameter counts turns back from the lip: it depends on ``turns`` only, and the ring
    one turn behind the lip has the same canonical value on a 3-turn and a 5-turn shell."""
    model = get_model("shell")
    p, q = model.space.sample(2, seed=7)
    a = model.generate({**p, "turns": 4.0})
    b = model.generate({**q, "turns": 4.0})
    np.testing.assert_array_equal(a.canonical, b.canonical)
    s3 = model._canonical_s({"turns": 3.0}, np.array([1.0 - 1.0 / 3.0, 1.0]))
    s5 = model._canonical_s({"turns": 5.0}, np.array([1.0 - 1.0 / 5.0, 1.0]))
    np.testing.assert_allclose(s3, s5)
    assert 0.0 < s3[0] < s3[1] < 1.0


def test_pumpkin_canonical_anchors():
    model = get_model("pumpkin")
    for params in model.space.sample(10, seed=8):
        shape = model.generate(params)
        ((ids, _),) = parts_by_label(shape)["body"]
        # The equator at angle 0 is the middle of a lobe, at the full radius.
        equator = nearest_canonical(shape, ids, 0.5, 0.0)
        np.testing.assert_allclose(equator[:2], [params["radius"], 0.0], atol=1e-9)
        # The stem's start pole sits in the body's top dimple.
        ((stem_ids, _),) = parts_by_label(shape)["stem"]
        foot = nearest_canonical(shape, stem_ids, 0.0, 0.0)
        top = nearest_canonical(shape, ids, 1.0, 0.0)
        np.testing.assert_allclose(foot[:2], [0.0, 0.0], atol=1e-9)
        assert top[2] - 0.01 < foot[2] < top[2]


def test_mushroom_cap_top_pole_is_highest_point_of_main_cap():
    model = get_model("mushroom")
    for params in model.space.sample(10, seed=9):
        shape = model.generate(params)
        ((ids, _),) = parts_by_label(shape)["cap"]
        top = nearest_canonical(shape, ids, 1.0, 0.0)
        np.testing.assert_allclose(top[:2], [0.0, 0.0], atol=1e-9)
        assert top[2] == pytest.approx(shape.vertices[ids, 2].max())


def test_cake_tier_top_centre_anchor():
    model = get_model("cake")
    for params in model.space.sample(10, seed=10):
        shape = model.generate(params)
        ((ids, _),) = parts_by_label(shape)[tier_label(0, params["tiers"])]
        centre = nearest_canonical(shape, ids, 1.0, 0.0)
        np.testing.assert_allclose(centre[:2], [0.0, 0.0], atol=1e-9)
        assert centre[2] == pytest.approx(shape.vertices[ids, 2].max())
        assert centre[2] - shape.vertices[ids, 2].min() == pytest.approx(params["tier_height"])


def test_shell_anchors_apex_on_axis_and_aperture_outside():
    model = get_model("shell")
    for params in model.space.sample(10, seed=11):
        shape = model.generate(params)
        all_ids = np.arange(shape.n_vertices)
        apex = nearest_canonical(shape, all_ids, 0.0, 0.0)
        aperture = nearest_canonical(shape, all_ids, 1.0, 0.0)
        assert np.ptp(shape.vertices, axis=0).max() == pytest.approx(params["length"], rel=0.1)
        # The whorl radius shrinks by growth ** -turns from the aperture to the apex.
        assert np.hypot(*aperture[:2]) > 0.25 * params["length"]
        assert np.hypot(*apex[:2]) < 0.4 * np.hypot(*aperture[:2])


def test_shell_canonical_angle_zero_faces_away_from_the_axis():
    model = get_model("shell")
    for params in model.space.sample(10, seed=12):
        shape = model.generate(params)
        all_ids = np.arange(shape.n_vertices)
        for s in (0.5, 0.8, 0.95):
            outside = nearest_canonical(shape, all_ids, s, 0.0)
            inside = nearest_canonical(shape, all_ids, s, np.pi)
            assert np.hypot(*outside[:2]) > np.hypot(*inside[:2])
