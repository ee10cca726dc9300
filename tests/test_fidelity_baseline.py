"""The fidelity baseline and its compare step (issue 52, tests/bench/fidelity_baseline.py): figures
read from an evaluation, their noise over seeds, and a comparison that calls a family worse only
beyond that noise; a wrong method (the identity in place of the network) is caught."""

from __future__ import annotations

import copy
import json
from pathlib import Path

import pytest

from tests.bench import fidelity_baseline as B

ROOT = Path(__file__).resolve().parents[1]


def methods(gt_mean=0.01, pgt=0.002, var=0.004, var_id=0.01, var_near=0.02, flipped=0.001):
    return {
        "corrnet": {
            "gt_error": {"mean": gt_mean, "p99": 5 * gt_mean, "max": 10 * gt_mean, "flipped": flipped},
            "pgt_error": {"mean": pgt, "flipped": 0.0},
            "tracked_point_variance": var,
            "coverage": 0.0,
            "coverage_baked": 0.0,
        },
        "identity": {"tracked_point_variance": var_id},
        "nearest": {"tracked_point_variance": var_near},
    }


def record(runs: dict[str, list[dict]]) -> dict:
    fams = {}
    for fam, ms in runs.items():
        per = {str(s): B.headline(m) for s, m in enumerate(ms)}
        fams[fam] = {"seeds": list(range(len(ms))), "per_seed": per, "figures": B.summarise(per)}
    return {"code": "x", "families": fams}


def test_figures_are_read_and_summarised_per_seed():
    h = B.headline(methods())
    assert h["gt_mean"] == 0.01 and h["x_identity"] == pytest.approx(0.4) and h["x_nearest"] == pytest.approx(0.2)
    no_truth = methods()
    del no_truth["corrnet"]["gt_error"]
    assert B.headline(no_truth)["gt_mean"] is None and "gt_mean" not in B.summarise({"0": B.headline(no_truth)})
    s = B.summarise({"0": B.headline(methods(gt_mean=0.010)), "1": B.headline(methods(gt_mean=0.013)), "2": B.headline(methods(gt_mean=0.011))})
    assert s["gt_mean"]["values"] == [0.01, 0.013, 0.011] and s["gt_mean"]["mean"] == pytest.approx(0.011333, abs=1e-6)
    assert s["gt_mean"]["spread"] == pytest.approx(0.003)


def test_compare_calls_worse_only_beyond_the_noise_and_catches_a_wrong_method():
    base = record({"sofa": [methods(gt_mean=g) for g in (0.010, 0.012, 0.011)], "mug": [methods(var=v) for v in (0.004, 0.0041, 0.0039)]})
    same = B.compare(base, copy.deepcopy(base))
    assert {r["verdict"] for r in same} == {"same"} and B.worse_families(same) == []
    # within the seeds' spread (0.002): the same; beyond it: worse, and only that family
    within = record({"sofa": [methods(gt_mean=g) for g in (0.0115, 0.0125, 0.0120)], "mug": [methods(var=v) for v in (0.004, 0.0041, 0.0039)]})
    assert B.worse_families(B.compare(base, within)) == []
    worse = record({"sofa": [methods(gt_mean=g) for g in (0.016, 0.017, 0.016)], "mug": [methods(var=v) for v in (0.004, 0.0041, 0.0039)]})
    rows = B.compare(base, worse)
    assert B.worse_families(rows) == ["sofa"] and next(r for r in rows if r["figure"] == "gt_mean")["verdict"] == "worse"
    better = record({"sofa": [methods(gt_mean=g) for g in (0.004, 0.005, 0.004)], "mug": [methods(var=v) for v in (0.004, 0.0041, 0.0039)]})
    assert B.worse_families(B.compare(base, better)) == [] and "better" in {r["verdict"] for r in B.compare(base, better)}
    # a wrong method: the identity mapper's variance in place of the network's -> worse on variance and its ratios
    wrong = record({"sofa": [methods(gt_mean=g) for g in (0.010, 0.012, 0.011)], "mug": [methods(var=0.01) for _ in range(3)]})
    rows = [r for r in B.compare(base, wrong) if r["family"] == "mug" and r["verdict"] == "worse"]
    assert {r["figure"] for r in rows} >= {"variance", "x_identity", "x_nearest"}
    # a family not measured again is not silently passed
    gone = copy.deepcopy(base)
    del gone["families"]["mug"]
    assert B.worse_families(B.compare(base, gone)) == ["mug"]
    # a difference under the figure's floor is never "moved", even with no spread at all
    flat = record({"sofa": [methods(gt_mean=0.01)] * 3, "mug": [methods()] * 3})
    nudged = record({"sofa": [methods(gt_mean=0.01 + 1e-5)] * 3, "mug": [methods()] * 3})
    assert B.worse_families(B.compare(flat, nudged)) == []


def test_the_compare_cli_exits_1_when_a_family_got_worse(tmp_path, capsys):
    base = record({"sofa": [methods(gt_mean=g) for g in (0.010, 0.012, 0.011)]})
    worse = record({"sofa": [methods(gt_mean=g) for g in (0.02, 0.021, 0.02)]})
    (tmp_path / "base.json").write_text(json.dumps(base))
    (tmp_path / "today.json").write_text(json.dumps(worse))
    (tmp_path / "same.json").write_text(json.dumps(base))
    assert B.main(["--compare", str(tmp_path / "base.json"), "--against", str(tmp_path / "today.json")]) == 1
    assert "WORSE: sofa" in capsys.readouterr().out
    assert B.main(["--compare", str(tmp_path / "base.json"), "--against", str(tmp_path / "same.json")]) == 0
    assert "no family got worse" in capsys.readouterr().out
    with pytest.raises(SystemExit, match="not in the baseline"):
        B.main(["--compare", str(tmp_path / "base.json"), "--against", str(tmp_path / "same.json"), "--families", "nope"])
    with pytest.raises(SystemExit, match="at least 3 seeds"):
        B.main(["--record", str(tmp_path / "x.json"), "--families", "sofa", "--seeds", "0,1"])
    with pytest.raises(ValueError, match="unknown family"):
        B.main(["--record", str(tmp_path / "x.json"), "--families", "nope"])


def test_the_committed_baseline_is_whole_and_the_readme_shows_it():
    """``tests/bench/fidelity_baseline.json``: every family measured at 3 or more seeds, each figure's
    mean and spread those of its seeds' values; the README's results table is this baseline's
    (``fidelity_baseline.py --table``), line for line."""
    path = ROOT / "tests" / "bench" / "fidelity_baseline.json"
    data = json.loads(path.read_text())
    assert data["families"], "the baseline has families"
    for fam, entry in data["families"].items():
        assert len(entry["seeds"]) >= 3 and sorted(entry["per_seed"], key=int) == [str(s) for s in entry["seeds"]], fam
        assert entry["figures"] == B.summarise(entry["per_seed"]), fam
        assert B.portable_config(B.family_config(fam, 0)) == entry["config"], f"{fam}: the baseline was recorded with another config"
    readme = (ROOT / "README.md").read_text()
    missing = [line for line in B.readme_table(data).splitlines() if line not in readme]
    assert not missing, f"the README's results table is not the baseline's (fidelity_baseline.py --table): {missing[:2]}"


def test_a_seams_family_is_written_once_as_the_builtin_family_and_read_with_its_truth(tmp_path, monkeypatch):
    """``fork.seams``: the built-in fork family's shapes at the seed (the same sample jobs), written
    as seam-split files under ROOT/files once, and a folder config with canonical truth from them."""
    from proctex.store.config import BuildConfig

    monkeypatch.setitem(B.BUILTIN_SCALE, "n_train", 2)
    monkeypatch.setitem(B.BUILTIN_SCALE, "n_test", 1)
    cfg = B.family_config("fork.seams", 1)
    assert "${FILES}" in json.dumps(B.portable_config(cfg))  # the record names no machine's folder
    ready = B.materialise("fork.seams", 1, cfg, tmp_path)
    folder = Path(ready["source"]["folder"])
    assert folder == tmp_path / "files" / "fork.seams" / "s1"
    built = BuildConfig.from_dict(ready).validate()
    assert built.truth == "canonical" and built.source.up == "y"
    assert sorted(str(p.relative_to(folder)) for p in folder.rglob("*.glb")) == ["test/2.glb", "train/0.glb", "train/1.glb"]
    builtin = BuildConfig.from_dict({"model": "fork", "n_train": 2, "n_test": 1, "seed": 1, "tessellation": "adaptive"})
    jobs = builtin.shapes().sample_jobs(builtin.source, 1)
    assert [json.loads((folder / j.split / f"{j.index}.json").read_text()) for j in jobs] == [json.loads(json.dumps(j.params)) for j in jobs]
    stamp = (folder / "export.json").stat().st_mtime_ns
    assert B.materialise("fork.seams", 1, cfg, tmp_path) == ready and (folder / "export.json").stat().st_mtime_ns == stamp
    with pytest.raises(ValueError, match="unknown family"):
        B.family_config("vase.seams", 0)
