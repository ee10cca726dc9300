"""Truth beside a folder family's files (issue 52's thin, seam-split family): files split at UV seams
load back to the model's mesh, their sidecars carry its canonical coordinates to the stored shape, and
the evaluation measures such a folder on that truth (and calls a wrong truth wrong)."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest

from proctex.geometry.meshio import load_mesh
from proctex.geometry.parts import segment
from proctex.geometry.shape import Shape
from proctex.models import get_model
from proctex.sources.truthfiles import attach_file_truth, folder_truth, read_truth, truth_path, write_truth

sys.path.insert(0, str(Path(__file__).resolve().parent / "bench"))

import seamsplit as S  # noqa: E402


def cube() -> tuple[np.ndarray, np.ndarray]:
    v = np.array([[x, y, z] for x in (0.0, 1.0) for y in (0.0, 1.0) for z in (0.0, 1.0)])
    f = np.array([[0, 2, 6], [0, 6, 4], [1, 5, 7], [1, 7, 3], [0, 4, 5], [0, 5, 1], [2, 3, 7], [2, 7, 6], [0, 1, 3], [0, 3, 2], [4, 6, 7], [4, 7, 5]])
    return v, f


def test_a_cube_split_at_its_box_seams_has_three_vertices_per_corner():
    v, f = cube()
    chart = S.box_charts(v, f)
    assert sorted(np.bincount(chart).tolist()) == [2] * 6  # two triangles per side, one chart each
    faces, source = S.split_at_seams(f, chart, len(v))
    assert len(source) == 24 and np.bincount(source).tolist() == [3] * 8  # each corner in 3 charts
    assert np.array_equal(source[faces], f)  # the same corners, re-indexed
    with pytest.raises(ValueError, match="chart must be"):
        S.split_at_seams(f, chart[:-1], len(v))


def test_seam_split_files_load_back_to_the_model_and_carry_its_truth(tmp_path):
    """A fork (thin parts, adaptive tessellation) written split at seams and +y up: the load path
    stitches it back to the model's vertex and part counts, and the sidecar's truth lands on the
    right vertices (each stored vertex's canonical coordinates are the model's at that point)."""
    model = get_model("fork")
    shape = model.generate()
    path = tmp_path / "0.glb"
    counts = S.export_shape(shape, path)
    assert counts["file_vertices"] > 1.3 * counts["vertices"]  # the seams split many vertices
    loaded, report = load_mesh(path)
    assert loaded.n_vertices == shape.n_vertices and report.stitched_edges > 0
    assert segment(loaded).n_parts == segment(shape).n_parts
    told = attach_file_truth(loaded, path)
    back = told.vertices @ S.Z_TO_Y  # the model's z-up frame again
    order = np.lexsort(np.round(back, 9).T)
    ref = np.lexsort(np.round(shape.vertices, 9).T)
    assert np.abs(back[order] - shape.vertices[ref]).max() < 1e-6
    assert np.abs(told.canonical[order] - shape.canonical[ref]).max() < 1e-6
    assert [told.label_names[i] for i in told.labels[order]] == [shape.label_names[i] for i in shape.labels[ref]]


def test_damaged_or_mismatched_truth_files_are_refused_by_name(tmp_path):
    v, f = cube()
    path = tmp_path / "c.obj"
    path.write_text("".join(f"v {a} {b} {c}\n" for a, b, c in v) + "".join(f"f {a + 1} {b + 1} {c + 1}\n" for a, b, c in f))
    with pytest.raises(ValueError, match="no truth file"):
        attach_file_truth(load_mesh(path)[0], path)
    truth_path(path).write_bytes(b"not an npz")
    with pytest.raises(ValueError, match="not a readable truth file"):
        read_truth(truth_path(path), 8)
    write_truth(truth_path(path), np.zeros((7, 3)), np.zeros(7, int), ["box"])  # a vertex short of the file's 8
    with pytest.raises(ValueError, match=r"canonical must be \(8, 3\)"):
        read_truth(truth_path(path), 8)
    with pytest.raises(ValueError, match="NaN"):
        write_truth(truth_path(path), np.full((8, 3), np.nan), np.zeros(8, int), ["box"])
    with pytest.raises(ValueError, match="labels must index"):
        write_truth(truth_path(path), np.zeros((8, 3)), np.full(8, 2), ["box"])
    with pytest.raises(ValueError, match="label_names"):
        write_truth(truth_path(path), np.zeros((8, 3)), np.zeros(8, int), ["x" * 500])
    write_truth(truth_path(path), v, np.zeros(8, int), ["box"])
    shape = load_mesh(path)[0]
    assert np.array_equal(attach_file_truth(shape, path).canonical, v)
    moved = Shape(shape.vertices + 0.5, shape.faces)
    with pytest.raises(ValueError, match="changed since the build"):
        attach_file_truth(moved, path)
    with pytest.raises(ValueError, match="changed since the build"):
        attach_file_truth(Shape(shape.vertices[:7], shape.faces[:2]), path)


@pytest.fixture(scope="module")
def seam_family(tmp_path_factory):
    """A mug family of seam-split files whose every shape is the default mug (pinned), painted."""
    from proctex.build.pipeline import stage_paint
    from proctex.build.pipeline import stage_sample
    from proctex.build.pipeline import stage_template
    from proctex.store.config import BuildConfig
    from proctex.store.layout import FamilyStore
    from proctex.store.state import write_config

    root = tmp_path_factory.mktemp("seams")
    shape = get_model("mug").generate()
    for split, names in (("train", ("0", "1")), ("test", ("2", "3"))):
        (root / "files" / split).mkdir(parents=True)
        for name in names:
            S.export_shape(shape, root / "files" / split / f"{name}.glb")
            (root / "files" / split / f"{name}.json").write_text('{"width": 1.0}\n')
    cfg = BuildConfig.from_dict(dict(source={"folder": str(root / "files"), "up": "y"}, texture_size=32, prompt="blue ceramic"))
    st = FamilyStore(root / "mug")
    write_config(st, cfg)
    for stage in (stage_sample, stage_template, stage_paint):
        stage(st, cfg, log=lambda *_: None)
    return root


def test_a_folder_with_truth_files_is_measured_on_them_and_a_wrong_truth_is_caught(seam_family):
    """Every shape is the template, so the identity is exact on the files' truth (GT max ~0); the
    same family with one test file's truth mirrored in x (a wrong truth) scores the identity far
    off: the figure can fail. Without every sidecar the folder has no canonical truth."""
    from proctex.measure.evaluate import evaluate
    from proctex.store.layout import FamilyStore

    run = dict(methods=("identity",), tracked=300, view_size=48, bake_size=64, log=lambda *_: None, quiet=True)
    m = evaluate(FamilyStore(seam_family / "mug"), **run)
    assert m["truth"] == "canonical" and m["tracker"] == "canonical"
    assert m["methods"]["identity"]["gt_error"]["max"] < 1e-6  # measured 3e-15 (AVX-512 and AVX2 kernels)

    side = truth_path(seam_family / "files" / "test" / "3.glb")
    kept = side.read_bytes()
    st = FamilyStore(seam_family / "mug")
    try:
        can, lab, names = read_truth(side, len(np.load(side)["labels"]))
        write_truth(side, can * np.array([-1.0, 1.0, 1.0]), lab, names)
        bad = evaluate(st, **run)["methods"]["identity"]["gt_error"]
        # measured: mean 0.48, max 1.72 (one of two test shapes mirrored); the exact truth: 1e-16
        assert bad["mean"] > 0.1 and bad["max"] > 0.5
        side.unlink()
        assert folder_truth(seam_family / "files") is False
        assert evaluate(st, **run)["truth"] is None  # auto: no canonical truth without every sidecar
        with pytest.raises(ValueError, match="truth file beside it"):
            evaluate(st, truth="canonical", **run)
    finally:
        side.write_bytes(kept)
    assert folder_truth(seam_family / "files") is True


def test_the_methods_never_see_the_files_truth(seam_family, monkeypatch):
    """Truth is for measuring only: every shape a method transfers in the evaluation of a folder with
    truth files has no labels and no canonical coordinates (the locating and scoring shape has both)."""
    import proctex.measure.evaluate as evaluation
    from proctex.measure.evaluate import evaluate
    from proctex.store.layout import FamilyStore

    seen = []
    real = evaluation.shape_to_glb  # what the evaluation transfers with
    monkeypatch.setattr(evaluation, "shape_to_glb", lambda shape, *a, **k: seen.append((shape.labels, shape.canonical)) or real(shape, *a, **k))
    m = evaluate(FamilyStore(seam_family / "mug"), methods=("identity", "nearest"), tracked=100, view_size=32, bake_size=32, log=lambda *_: None, quiet=True)
    assert m["truth"] == "canonical" and len(seen) == 4  # 2 test shapes x 2 methods
    assert all(labels is None and canonical is None for labels, canonical in seen)
