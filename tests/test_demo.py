"""The main job (``proctex demo``): sweeps, images, the report, and a whole small run in one process."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from proctex.demo import (
    caption,
    contact_sheet,
    crop_to_content,
    parameter_effects,
    report_html,
    row_values,
    run_demo,
    sweep_settings,
    turntable_path,
)
from proctex.models import get_model
from proctex.params import choice, continuous, integer, ParamSpace
from proctex.texture.gltf_read import read_textured_glb

SPACE = ParamSpace((continuous("width", 1.0, 2.0, 1.5), integer("legs", 3, 6, 4), choice("arms", [True, False], True)))
# A tiny build: every stage runs, in seconds.
TINY = {"corr_points": 200, "cage_iterations": 30, "texture_size": 64, "train": {"iterations": 30, "eval_every": 10, "context_points": 128, "query_points": 64, "shapes_per_batch": 2}}


def test_row_values_span_each_kind_of_parameter():
    assert row_values(SPACE["width"], 5) == [1.0, 1.25, 1.5, 1.75, 2.0]
    assert row_values(SPACE["legs"], 5) == [3, 4, 5, 6]  # every integer when there are few
    assert row_values(integer("n", 0, 100, 5), 3) == [0, 50, 100]
    assert row_values(SPACE["arms"], 5) == [True, False]
    with pytest.raises(ValueError):
        row_values(SPACE["width"], 0)


def test_sweep_rows_follow_the_effects_and_vary_one_parameter_each():
    base = {"width": 1.2, "legs": 5, "arms": False}
    rows = sweep_settings(SPACE, base, {"width": 0.1, "legs": 10.5, "arms": 0.0}, rows=2, per_row=3, seed=4)
    assert [r.name for r in rows] == ["legs", "width", "random"]
    legs, width, rnd = rows
    assert [p["legs"] for p in legs.settings] == [3, 4, 6]  # three distinct integers over the range
    assert all(p["width"] == 1.2 and p["arms"] is False for p in legs.settings)
    assert [p["width"] for p in width.settings] == [1.0, 1.5, 2.0] and all(p["legs"] == 5 for p in width.settings)
    assert len(rnd.settings) == 3 and all(SPACE.validate(p) == p for p in rnd.settings)
    again = sweep_settings(SPACE, base, {"width": 0.1, "legs": 10.5, "arms": 0.0}, rows=2, per_row=3, seed=4)
    assert again[-1].settings == rnd.settings  # seeded
    assert [r.name for r in sweep_settings(SPACE, base, {}, names=["arms"], random_row=False)] == ["arms"]
    with pytest.raises(KeyError):
        sweep_settings(SPACE, base, {}, names=["nope"])


def test_parameter_effects_rank_topology_changes_first():
    model = get_model("chair")
    effects = parameter_effects(model.space, model.space.defaults(), model.generate)
    assert effects["slats"] >= 10 and effects["arms"] >= 10  # the part count changes
    assert effects["seat_width"] < 10 and effects["seat_width"] > effects["arm_height"] >= 0


def test_turntable_path_sweeps_each_parameter_over_its_range():
    path = turntable_path(SPACE, SPACE.defaults(), ["width", "legs"], 40)
    assert len(path) == 40 and all(SPACE.validate(p) == p for p in path)
    widths = [p["width"] for p in path]
    assert min(widths) == pytest.approx(1.0) and max(widths) == pytest.approx(2.0)
    assert {p["legs"] for p in path} == {3, 4, 5, 6}
    assert all(p["arms"] is True for p in path)  # not swept: the base value


def test_crop_keeps_one_box_for_every_image_and_the_sheet_has_every_cell():
    a = np.full((40, 50, 3), 255, np.uint8)
    b = a.copy()
    a[10:12, 5:8] = 0
    b[30:31, 40:45] = 0
    ca, cb = crop_to_content([a, b], margin=1)
    assert ca.shape == cb.shape == (23, 42, 3)  # rows 9..31, cols 4..45
    sheet = contact_sheet([[ca, cb], [ca]], [[["x = 1"], ["x = 2"]], [["a = 1", "b = 2"]]], ["sweep of x", "random"], title="t")
    assert sheet.dtype == np.uint8 and sheet.shape[1] >= 2 * 42 and sheet.shape[0] > 2 * 23
    assert (sheet < 128).any()  # text and images drawn
    with pytest.raises(ValueError):
        contact_sheet([], [], [])
    assert caption({"w": 1.23456, "n": 3}, "w") == ["w = 1.23"]
    assert caption({"w": 1.5, "n": 3}, None) == ["w = 1.5", "n = 3"]


def test_report_escapes_user_text():
    summary = {
        "model": "mug",
        "prompt": "<script>alert(1)</script>",
        "family": "families/mug",
        "serve_root": "families",
        "seed": 0,
        "n_train": 2,
        "n_test": 0,
        "ray": False,
        "groups": [{"group": 0, "label": "<b>", "prompt": "a & b", "texture": "t.png", "network": "none"}],
        "metrics": None,
        "stage_seconds": {"sample": 1.0},
        "total_seconds": 1.0,
        "variants": [],
        "transfer_median_seconds": 0.01,
        "contact_sheet": "c.png",
        "turntable": "t.gif",
        "notes": [],
    }
    page = report_html(summary)
    assert "<script>" not in page and "&lt;script&gt;" in page and "a &amp; b" in page and "&lt;b&gt;" in page


@pytest.fixture(scope="module")
def demo_run(tmp_path_factory):
    out = tmp_path_factory.mktemp("demo")
    result = run_demo(out, model="mug", prompt="blue and white striped ceramic", n_train=3, n_test=2, rows=2, per_row=3, frames=6, log=lambda *_: None, quiet=True, overrides=TINY)
    return out, result


@pytest.mark.slow
def test_demo_writes_every_output(demo_run):
    out, result = demo_run
    s = json.loads((out / "demo.json").read_text())
    assert s["prompt"] == "blue and white striped ceramic" and s["model"] == "mug"
    # Two swept rows of up to three values, plus three random settings: a GLB each, readable, textured.
    rows = [r["row"] for r in s["sweep"]]
    assert len(rows) == 3 and rows[-1] == "random"
    assert len(result.variants) == sum(r["n"] for r in s["sweep"]) == len(s["variants"])
    for path in result.variants:
        mesh = read_textured_glb(path)
        assert len(mesh.faces) > 100 and len(mesh.textures) >= 2 and mesh.notes == []
    sheet = np.asarray(Image.open(out / "contact_sheet.png"))
    assert sheet.ndim == 3 and sheet.shape[0] > 300
    gif = Image.open(out / "turntable.gif")
    assert gif.n_frames == 6
    page = (out / "report.html").read_text()
    for needle in ("blue and white striped ceramic", "contact_sheet.png", "turntable.gif", "Metrics", "pairs", "train"):
        assert needle in page
    for g in s["groups"]:  # the report links every group's texture, which exists
        assert (out / g["texture"]).is_file()
    assert set(s["stage_seconds"]) >= {"sample", "template", "paint", "pairs", "train", "evaluate"}
    assert s["metrics"] is not None and "corrnet" in s["metrics"]["methods"]


@pytest.mark.slow
def test_a_second_run_reuses_the_family_and_other_settings_need_fresh(demo_run):
    out, first = demo_run
    logs: list[str] = []
    again = run_demo(out, model="mug", prompt="blue and white striped ceramic", n_train=3, n_test=2, rows=1, per_row=2, frames=2, log=logs.append, quiet=True, overrides=TINY)
    for stage in ("sample", "template", "paint", "pairs", "evaluate"):  # every stage skipped, nothing redone
        assert f"{stage}: done already" in logs, (stage, logs)
    assert len(again.variants) == 2 + 2
    with pytest.raises(ValueError, match="--fresh"):
        run_demo(out, model="mug", prompt="red velvet", n_train=3, n_test=2, quiet=True, log=lambda *_: None, overrides=TINY)


def test_bad_demo_input_fails_before_any_work(tmp_path):
    with pytest.raises(ValueError, match="unknown model"):
        run_demo(tmp_path / "x", model="spaceship", log=lambda *_: None)
    with pytest.raises(ValueError, match="prompt"):
        run_demo(tmp_path / "x", prompt="  ", log=lambda *_: None)
    assert not (tmp_path / "x").exists()


def test_demo_cli_rejects_bad_flags(capsys, tmp_path):
    from proctex.cli import main

    assert main(["demo", "--out", str(tmp_path / "d"), "--n-train", "1"]) == 2
    assert "--n-train" in capsys.readouterr().err
    assert main(["demo", "--out", str(tmp_path / "d"), "--model", "spaceship"]) == 2
    assert "unknown model" in capsys.readouterr().err
    assert not (tmp_path / "d").exists()


@pytest.mark.slow
def test_sheet_renders_a_built_family_and_refuses_what_it_cannot_sweep(demo_run, capsys, tmp_path):
    from proctex.cli import main

    out, _ = demo_run
    family = out / "families" / "mug"
    sheet = tmp_path / "sheet"
    assert main(["sheet", str(family), "--out", str(sheet), "--rows", "1", "--per-row", "2", "--frames", "2", "--size", "96", "--quiet"]) == 0
    s = json.loads((sheet / "demo.json").read_text())
    assert s["model"] == "mug" and len(s["variants"]) == 2 + 2  # one swept row and the random row
    for v in s["variants"]:
        assert read_textured_glb(sheet / v["glb"]).notes == []
    assert Image.open(sheet / "turntable.gif").n_frames == 2
    assert "contact sheet" in capsys.readouterr().out
    # Bad input: an error line and exit 2, nothing written.
    (tmp_path / "empty").mkdir()
    for argv, needle in (
        (["sheet", str(tmp_path / "nothing")], "no such folder"),
        (["sheet", str(tmp_path / "empty")], "family"),
        (["sheet", str(family), "--per-row", "0"], "--per-row"),
        (["sheet", str(family), "--size", "9999"], "--size"),
    ):
        assert main(argv + ["--out", str(tmp_path / "bad"), "--quiet"]) == 2, argv
        assert needle in capsys.readouterr().err, argv
    assert not (tmp_path / "bad").exists()
    # The in-process transfer benchmark runs on the same family (random settings of its model).
    import subprocess
    import sys

    bench = Path(__file__).parent / "bench" / "bench_family_transfer.py"
    done = subprocess.run([sys.executable, str(bench), str(family), "--settings", "2", "--repeats", "1", "--out", str(tmp_path / "t.json")], capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr[-2000:]
    figures = json.loads((tmp_path / "t.json").read_text())
    assert figures["max_ms"] >= figures["median_ms"] >= figures["min_ms"] > 0 and sum(figures["parts"].values()) > 0
