"""Building a family into a store, stage by stage (single process)."""

import json
from pathlib import Path

import numpy as np
import pytest

from proctex.build.pipeline import stage_paint
from proctex.build.pipeline import stage_pairs
from proctex.build.pipeline import stage_sample
from proctex.build.pipeline import stage_template
from proctex.store.config import BuildConfig
from proctex.store.layout import FamilyStore
from proctex.store.samples import read_pair
from proctex.store.state import stage_done, write_config
from proctex.transfer.assets import load_assets


@pytest.fixture(scope="module")
def mug_family(tmp_path_factory):
    root = tmp_path_factory.mktemp("fam") / "mug"
    cfg = BuildConfig.from_dict(dict(model="mug", n_train=2, n_test=1, corr_points=200, cage_iterations=20, texture_size=64, prompt="glazed blue ceramic", group_prompts={"handle": "gold"})).validate()
    st = FamilyStore(root)
    write_config(st, cfg)
    for stage in (stage_sample, stage_template, stage_paint, stage_pairs):
        stage(st, cfg, log=lambda *_: None)
    return st, cfg


def test_build_writes_the_store(mug_family):
    st, cfg = mug_family
    state = st.read_json("family.json")
    assert state["config"]["source"]["model"] == "mug" and "torch" in state["versions"]
    assert state["versions"]["proctex"] == __import__("proctex").__version__ != "0+unknown"  # the version that built it
    for stage in ("sample", "template", "paint", "pairs"):
        assert stage_done(st, stage)
    rows = st.read_table("samples.parquet").to_pylist()
    assert [r["split"] for r in rows] == ["train", "train", "test"]
    assert all(st.exists(r["mesh"]) for r in rows)
    pairs = st.read_table("pairs.parquet").to_pylist()
    assert len(pairs) == 3 * 2 and all(p["status"] == "done" for p in pairs)
    src, dst = read_pair(st, rows[0]["id"], 1)
    assert src.shape == dst.shape == (200, 3) and np.abs(src).max() <= 1.0001 and np.abs(dst).max() <= 1.0001
    summary = st.read_json("template/paint.json")
    assert {g["label"]: g["prompt"] for g in summary["groups"]} == {"body": "glazed blue ceramic", "handle": "gold"}
    assets = load_assets(st)
    assert assets.names == ["body", "handle"] and assets.textures[0].shape == (64, 64, 3)


def test_the_template_record_reads_its_grouping_back_and_round_trips(mug_family, tmp_path, monkeypatch):
    """The stored grouping is read, not analysed again (analysis is switched off here); the record
    saves and loads to the same arrays; a store whose grouping predates the member maps is
    analysed as before."""
    import proctex.store.template as tm
    from proctex.geometry.parts import analyse
    from proctex.store.layout import StoreLayout
    from proctex.store.template import load_template, load_template_shape

    st, cfg = mug_family
    fresh = analyse(load_template_shape(st, cfg), seed=cfg.seed)

    def no_analysis(*a, **k):
        raise AssertionError("the template was analysed again")

    with monkeypatch.context() as m:
        m.setattr(tm, "analyse", no_analysis)
        rec = load_template(st, cfg)
    assert [g.members for g in rec.grouping.groups] == [g.members for g in fresh.groups]
    for a, b in zip(rec.grouping.groups, fresh.groups):
        for ma, mb in zip(a.maps, b.maps):
            np.testing.assert_allclose(ma.R, mb.R, atol=1e-12)
            np.testing.assert_allclose(ma.t, mb.t, atol=1e-12)
    other = FamilyStore(tmp_path / "copy")
    other.write_json(StoreLayout.PAINT, st.read_json(StoreLayout.PAINT))
    rec.save(other)
    back = tm.Template.load(other, rec.shape)
    np.testing.assert_array_equal(back.corner_uv, rec.corner_uv)
    np.testing.assert_array_equal(back.face_group, rec.face_group)
    assert all(np.array_equal(a, b) for a, b in zip(back.textures, rec.textures)) and back.names == rec.names == ["body", "handle"]
    assert all(np.array_equal(a, b) for a, b in zip(back.painted, rec.painted))
    # An older record (no member maps): analysed again, the same groups.
    old = other.read_json(StoreLayout.GROUPING)
    for g in old["groups"]:
        del g["maps"]
    other.write_json(StoreLayout.GROUPING, old)
    assert [g.members for g in tm.Template.load(other, rec.shape, seed=cfg.seed).grouping.groups] == [g.members for g in fresh.groups]
    other.write_bytes(StoreLayout.UV, st.read_bytes(StoreLayout.UV)[:100])
    with pytest.raises(ValueError, match="uv.npz"):
        tm.Template.load(other, rec.shape)


def test_rerun_skips_completed_work(mug_family):
    st, cfg = mug_family
    before = {p.name: p.stat().st_mtime_ns for p in Path(st.base).rglob("*.parquet")}
    logs = []
    for stage in (stage_sample, stage_template, stage_paint, stage_pairs):
        stage(st, cfg, log=logs.append)
    after = {p.name: p.stat().st_mtime_ns for p in Path(st.base).rglob("*.parquet")}
    assert before == after
    assert any("done already" in line for line in logs)


def test_config_files_and_validation(tmp_path):
    (tmp_path / "fam.toml").write_text('model = "chair"\nprompt = "oak"\nn_train = 4\n[params]\nslats = [2, 4]\n')
    cfg = BuildConfig.from_file(tmp_path / "fam.toml")
    assert cfg.source.model == "chair" and cfg.source.params == {"slats": [2, 4]}
    (tmp_path / "data").mkdir()
    (tmp_path / "f.json").write_text(json.dumps({"folder": "data", "prompt": "x"}))
    assert BuildConfig.from_file(tmp_path / "f.json").source.folder == str((tmp_path / "data").resolve())
    for bad in [{"prompt": "x"}, {"model": "mug", "folder": "x"}, {"model": "mug", "n_train": 1}, {"model": "mug", "nonsense": 1}, {"model": "nosuch"}, {"folder": str(tmp_path / "missing")}]:
        with pytest.raises(ValueError):
            BuildConfig.from_dict(bad)
    st = FamilyStore(tmp_path / "x")
    write_config(st, BuildConfig.from_dict(dict(model="mug")).validate())
    with pytest.raises(ValueError, match="other paint settings .*proctex look add"):  # only the prompt differs: a look
        write_config(st, BuildConfig.from_dict(dict(model="mug", prompt="gold")).validate())
    with pytest.raises(ValueError, match="another config"):
        write_config(st, BuildConfig.from_dict(dict(model="mug", n_train=5)).validate())


def test_parameter_bounds_restrict_sampling(tmp_path):
    cfg = BuildConfig.from_dict(dict(model="chair", n_train=6, n_test=0, params={"slats": [2, 3], "seat_width": [0.4, 0.42]})).validate()
    st = FamilyStore(tmp_path / "c")
    write_config(st, cfg)
    stage_sample(st, cfg, log=lambda *_: None)
    for r in st.read_table("samples.parquet").to_pylist():
        p = json.loads(r["params"])
        assert 2 <= p["slats"] <= 3 and 0.4 <= p["seat_width"] <= 0.42
    with pytest.raises(ValueError, match="within"):
        BuildConfig.from_dict(dict(model="chair", params={"slats": [0, 9]})).procedural_model()


def test_edits_change_one_group_and_reach_every_transfer(mug_family, tmp_path):
    import io
    import shutil

    from PIL import Image

    from proctex.models import get_model
    from proctex.serve.edits import edit_group
    from proctex.texture.edit import rgb_to_hsv
    from proctex.transfer.apply import glb, transfer
    from proctex.transfer.mappers import IdentityMapper

    st0, _ = mug_family
    shutil.copytree(st0.base, tmp_path / "fam")
    st = FamilyStore(tmp_path / "fam")

    def png(name):
        return np.asarray(Image.open(io.BytesIO(st.read_bytes(f"template/{name}"))).convert("RGB")).astype(float) / 255

    body0, handle0 = png("group_0_body.png"), png("group_1_handle.png")
    edit_group(st, "handle", hue=120)
    body1, handle1 = png("group_0_body.png"), png("group_1_handle.png")
    assert np.array_equal(body0, body1)
    h0, h1 = rgb_to_hsv(handle0)[..., 0], rgb_to_hsv(handle1)[..., 0]
    sat = rgb_to_hsv(handle0)[..., 1] > 0.2
    dh = (h1[sat] - h0[sat]) * (360 if h0.max() <= 1 else 1) % 360
    assert np.median(dh) == pytest.approx(120, abs=3)
    # A logo at the centre of the body texture.
    logo = np.zeros((8, 8, 4), np.uint8)
    logo[..., 2], logo[..., 3] = 255, 255
    Image.fromarray(logo).save(tmp_path / "logo.png")
    edit_group(st, 0, logo=str(tmp_path / "logo.png"), at=(0.5, 0.5), size=(0.2, 0.2))
    body2 = png("group_0_body.png")
    assert np.allclose(body2[32, 32], [0, 0, 1], atol=1 / 255) and np.array_equal(body2[0, 0], body1[0, 0])
    # Re-paint the body; every later transfer carries the new textures.
    edit_group(st, "body", prompt="white marble")
    assert st.read_json("template/paint.json")["groups"][0]["prompt"] == "white marble"
    assert len(st.read_json("template/paint.json")["edits"]) == 3
    from proctex.transfer.assets import load_assets

    assets = load_assets(st)
    assert np.allclose(assets.textures[1] / 255, handle1, atol=1 / 255)
    shape = get_model("mug").generate({"radius": 0.045})
    data = glb(shape, transfer(shape, assets, IdentityMapper()), assets)
    assert assets.png[0] in data and assets.png[1] in data
    with pytest.raises(ValueError, match="unknown group"):
        edit_group(st, "seat", hue=10)
    with pytest.raises(ValueError, match="no edit"):
        edit_group(st, 0)


def test_cli_transfer_and_edit(mug_family, tmp_path, capsys):
    import shutil

    from proctex.cli import main

    st0, _ = mug_family
    fam = tmp_path / "fam"
    shutil.copytree(st0.base, fam)
    out = tmp_path / "t.glb"
    assert main(["transfer", str(fam), "--params", '{"radius": 0.045}', "--out", str(out), "--mapper", "identity"]) == 0
    assert out.read_bytes()[:4] == b"glTF"
    assert main(["transfer", str(fam), "--params", '{"radius": 0.045}', "--out", str(tmp_path / "b.glb"), "--mapper", "nearest", "--bake", "64", "--json"]) == 0
    assert (tmp_path / "b.glb").is_file()
    assert main(["edit", str(fam), "--group", "handle", "--hue", "90"]) == 0
    for argv, message in [
        (["transfer", str(fam), "--params", '{"radius": 5}', "--out", str(tmp_path / "x.glb")], "radius"),
        (["transfer", str(fam), "--params", "{bad", "--out", str(tmp_path / "x.glb")], "not valid JSON"),
        (["transfer", str(fam), "--out", str(tmp_path / "x.glb")], "exactly one"),
        (["transfer", str(fam), "--params", "{}", "--out", str(tmp_path / "x.obj")], ".glb"),
        (["transfer", str(tmp_path / "nothing"), "--params", "{}", "--out", str(tmp_path / "x.glb")], "not a ProcTex family"),
        (["edit", str(fam), "--group", "seat", "--hue", "3"], "unknown group"),
        (["edit", str(fam), "--group", "0", "--logo", str(tmp_path / "none.png")], "no such file"),
        (["edit", str(fam), "--group", "0", "--at", "a,b", "--logo", str(out)], "numbers"),
        (["build", "--model", "nosuch", "--out", str(tmp_path / "nb")], "nosuch"),
        (["build", "--out", str(tmp_path / "nb2")], "exactly one"),
    ]:
        capsys.readouterr()
        assert main(argv) == 2, argv
        assert message in capsys.readouterr().err, argv
    assert not (tmp_path / "x.glb").exists() and not (tmp_path / "nb").exists()


def test_train_stage_and_network_transfer(mug_family, tmp_path):
    import shutil

    from proctex.build.pipeline import stage_train
    from proctex.models import get_model
    from proctex.store.networks import load_models
    from proctex.transfer.apply import transfer
    from proctex.transfer.mappers import NetworkMapper

    st0, cfg0 = mug_family
    shutil.copytree(st0.base, tmp_path / "fam")
    st = FamilyStore(tmp_path / "fam")
    cfg = BuildConfig.from_dict({**st.read_json("family.json")["config"], "train": {"iterations": 30, "eval_every": 10, "context_points": 128, "query_points": 64, "shapes_per_batch": 2}})
    stage_train(st, cfg, log=lambda *_: None)
    assert stage_done(st, "train")
    models = load_models(st)
    assert sorted(models) == [0, 1]
    shape = get_model("mug").generate({"radius": 0.045})
    assets = load_assets(st)
    r = transfer(shape, assets, NetworkMapper(models, context=128))
    assert np.isfinite(r.corner_uv).all() and (r.face_group >= 0).all()
    # Each network carries what the build chose to serve its group, from held-out pairs, and the
    # train record says the same.
    record = st.read_json("family.json")["stages"]["train"]["groups"]
    for g, m in models.items():
        assert m.serving["serve"] in ("network", "box", "identity") and m.serving == record[str(g)]["serving"]
        assert set(m.serving["errors"]) == {"network", "box", "identity"}
    _serving_is_followed(models, assets, shape)
    # Rerunning skips trained groups.
    logs = []
    stage_train(st, cfg, log=logs.append)
    assert all("done already" in line for line in logs if line.startswith("train: group"))


def _serving_is_followed(models, assets, shape):
    """The run-time mapper maps each group by the stored choice: the box map runs no network, the
    identity is the fallback, and ``follow=False`` (``corrnet_all``) runs the networks anyway."""
    import copy

    from proctex.correspond.training import box_map, part_extent
    from proctex.transfer.mappers import NetworkMapper
    from proctex.transfer.methods import make_mapper

    rng = np.random.default_rng(0)
    v = rng.uniform(-1, 1, (40, 3))
    f = np.array([[0, 1, 2], [2, 3, 0]])
    for serve in ("box", "identity", "network"):
        ms = {g: copy.deepcopy(m) for g, m in models.items()}
        for m in ms.values():
            m.serving = {**m.serving, "serve": serve, "template_extent": [0.9, 0.5, 0.25]}
            if serve != "network":  # the network must not run: a broken one would show
                m.decode = m.encode = None
        mapper = NetworkMapper(ms, context=128)
        assert [mapper.serves(g) for g in ms] == [serve] * len(ms)
        out = mapper.map(0, v, f, v)
        if serve == "box":
            np.testing.assert_allclose(out, box_map(v, part_extent(v), [0.9, 0.5, 0.25]))
        elif serve == "identity":
            np.testing.assert_array_equal(out, v)
        else:
            assert not np.allclose(out, v)
    everywhere = make_mapper("corrnet_all", assets, ms)
    assert not everywhere.follow and make_mapper("corrnet", assets, ms).follow


@pytest.mark.slow  # 10-40 s (issue 49: the fast tests run twice in make test)
def test_evaluate_stage_on_identical_shapes(tmp_path):
    """Bounds pinned to the defaults: every sample is the template, so every method must give a
    tracked-point variance of exactly 0 and full coverage; errors are reported for net and cage."""
    from proctex.build.pipeline import build
    from proctex.models import get_model

    pinned = {s.name: [s.default, s.default] for s in get_model("mug").space.specs}
    cfg = BuildConfig.from_dict(
        dict(
            model="mug",
            n_train=2,
            n_test=2,
            corr_points=200,
            cage_iterations=20,
            texture_size=64,
            params=pinned,
            train={"iterations": 20, "eval_every": 10, "context_points": 128, "query_points": 64, "shapes_per_batch": 2},
        )
    ).validate()
    st = FamilyStore(tmp_path / "fam")
    logs = []
    state = build(st, cfg, log=logs.append)
    assert state["stages"]["evaluate"]["state"] == "done"
    m = st.read_json("metrics.json")
    assert m["shapes"] == 2 and m["split"] == "test" and set(m["methods"]) == {"corrnet", "identity"}
    assert m["tracker"] == "canonical" and m["truth"] == "canonical"
    for name, entry in m["methods"].items():
        # Points tracked by the truth: the shapes show the template's own colours (the bake resamples them).
        assert entry["tracked_point_variance_realtime"] < 1e-6 and entry["tracked_point_variance"] < 0.01, name
        assert entry["coverage"] == 0.0 and entry["coverage_baked"] == 0.0 and entry["shapes_with_holes"] == 0
        assert len(entry["per_shape"]) == 2 and entry["seconds_per_shape"] > 0 and entry["tracker"] == "canonical"
        # Identical shapes: both methods are exact; the cage pairs (pseudo-ground truth) carry the solver's own error.
        assert entry["gt_error"]["max"] < 1e-6 and entry["gt_error"]["failed"] == 0.0, name
        pgt = entry["pgt_error"]
        assert pgt["pairs"] == 4 and 0 < pgt["mean"] <= pgt["p95"] <= pgt["p99"] <= pgt["max"] and set(pgt["per_group"]) == {"0", "1"}
    net = m["methods"]["corrnet"]
    assert net["mapped_share"] == 0.0 and m["methods"]["identity"]["mapped_share"] == 1.0  # the shortcut; identity maps every part
    assert state["stages"]["evaluate"]["tracker"] == "canonical" and state["stages"]["evaluate"]["gt_error"]["max"] < 1e-6
    assert any(line.startswith("evaluate corrnet") for line in logs)
    # Rerun: done already.
    logs.clear()
    build(st, cfg, stages=("evaluate",), log=logs.append)
    assert logs == ["evaluate: done already"]
    from proctex.measure.evaluate import evaluate

    with pytest.raises(ValueError, match="methods"):
        evaluate(st, methods=("bogus",))
    with pytest.raises(ValueError, match="split"):
        evaluate(st, split="inference")


def test_cli_eval(mug_family, tmp_path, capsys):
    import shutil

    from proctex.cli import main

    st0, _ = mug_family
    fam = tmp_path / "fam"
    shutil.copytree(st0.base, fam)
    capsys.readouterr()
    # The fixture family has one test shape; its train split has two.
    assert main(["eval", str(fam), "--shapes", "train", "--methods", "identity", "--json"]) == 0
    m = json.loads(capsys.readouterr().out)
    assert m["shapes"] == 2 and list(m["methods"]) == ["identity"] and "tracked_point_variance" in m["methods"]["identity"]
    assert FamilyStore(fam).read_json("metrics.json") == m
    assert main(["eval", str(fam), "--shapes", "train", "--methods", "identity", "--quiet"]) == 0
    assert "| identity |" in capsys.readouterr().out
    for argv, message in [
        (["eval", str(tmp_path / "nothing")], "not a ProcTex family"),
        (["eval", str(fam), "--methods", "magic"], "--methods"),
        (["eval", str(fam), "--methods", "corrnet"], "no trained models"),
        (["eval", str(fam), "--methods", "identity", "--tracked", "5"], "--tracked"),
        (["eval", str(fam), "--methods", "identity", "--truth", "vertex-index"], "vertex-index truth needs"),
        (["eval", str(fam), "--limit", "0"], "--limit"),
    ]:
        capsys.readouterr()
        assert main(argv) == 2, argv
        assert message in capsys.readouterr().err, argv


def test_view_painted_family_keeps_its_already_painted_mask(tmp_path):
    """A template painted from views of the whole shape only stores which texels no view saw;
    transfer then finds the dis-occluded surface of a shape and the bake fills it."""
    from proctex.transfer.apply import bake, transfer
    from proctex.transfer.mappers import IdentityMapper

    cfg = BuildConfig.from_dict(
        dict(
            model="cake",
            n_train=2,
            n_test=0,
            texture_size=64,
            painter="views",
            views=6,
            view_size=96,
            paint_hidden=False,
            params={"candles": [0, 0], "tiers": [2, 2], "shrink": [0.7, 0.72]},
            prompt="red velvet cake",
        )
    ).validate()
    st = FamilyStore(tmp_path / "cake")
    write_config(st, cfg)
    for stage in (stage_sample, stage_template, stage_paint):
        stage(st, cfg, log=lambda *_: None)
    masks = st.read_arrays("template/painted.npz")
    assert {f"g{k}" for k in range(3)} | {f"o{k}" for k in range(3)} == set(masks)
    assets = load_assets(st)
    for g in range(3):
        assert not (assets.observed[g] & ~assets.painted[g]).any()
    assert sum(int((p & ~o).sum()) for p, o in zip(assets.painted, assets.observed)) > 0
    from proctex.models import get_model

    shape = get_model("cake").generate({"candles": 0, "shrink": 0.6, "tiers": 2})
    r = transfer(shape, assets, IdentityMapper())
    b = bake(shape, r, assets, size=64)
    assert any(d.any() for d in b.disoccluded) and any("PatchMatch" in n for n in b.notes)


def test_build_config_painter_checks(tmp_path):
    with pytest.raises(ValueError, match="model_dir"):
        BuildConfig.from_dict(dict(model="mug", painter="diffusion")).validate()
    with pytest.raises(ValueError, match="painter"):
        BuildConfig.from_dict(dict(model="mug", painter="crayon")).validate()
    with pytest.raises(ValueError, match="fill"):
        BuildConfig.from_dict(dict(model="mug", painter="views", fill="blur")).validate()

    with pytest.raises(ValueError, match="iteratons"):
        BuildConfig.from_dict(dict(model="mug", train={"iteratons": 5}))


def test_cage_settings_reach_the_solver_and_bad_ones_are_refused():
    from proctex.store.config import BuildConfig

    cfg = BuildConfig.from_dict({"model": "mug", "cage_level": 2, "cage_iterations": 40, "cage": {"w_rest": 0.3, "prealign": "box"}})
    cage = cfg.cage
    assert (cage.level, cage.iterations, cage.w_rest, cage.prealign) == (2, 40, 0.3, "box")
    assert BuildConfig.from_dict({"model": "mug"}).cage.prealign == "auto"
    with pytest.raises(ValueError, match="once"):
        BuildConfig.from_dict({"model": "mug", "cage_level": 2, "cage": {"level": 3}})
    for bad, msg in (({"level": 9}, "level"), ({"nope": 1}, "bad cage"), ({"w_rest": -1.0}, "weights"), ({"normal_target": "edge"}, "normal_target"), ("w_rest=1", "object")):
        with pytest.raises(ValueError, match=msg):
            BuildConfig.from_dict({"model": "mug", "cage": bad})


def test_a_store_built_before_the_cage_settings_keeps_its_old_solver(tmp_path):
    """A family.json without ``cage`` was solved by the old cage (ICP start, vertex normals, no rest
    term, last iterate): resuming its pairs must use that solver, not the new defaults."""
    from proctex.store.config import BuildConfig
    from proctex.store.state import stored_config, write_config

    store = FamilyStore(str(tmp_path / "old"))
    settings = {"model": "mug", "prompt": "oak", "seed": 0, "n_train": 24, "cage_level": 1, "cage_iterations": 300, "train": {}}  # flat, no cage
    store.write_json("family.json", {"config": settings, "stages": {}})
    cage = stored_config(store).cage
    assert (cage.prealign, cage.normal_target, cage.keep_best, cage.w_rest) == ("icp", "vertex", False, 0.0)
    with pytest.raises(ValueError, match="another config"):  # resuming with the new defaults is refused
        write_config(store, BuildConfig.from_dict({"model": "mug"}))
    write_config(store, stored_config(store))  # and with its own settings accepted


def test_configs_in_sections_and_flat_keys_are_the_same_config_and_round_trip():
    from proctex.store.config import PRESETS, BuildConfig, resolved_settings

    flat = {"model": "chair", "prompt": "oak", "seed": 3, "n_train": 5, "cage_iterations": 40, "cage": {"w_rest": 0.3}, "train": {"iterations": 50}, "texture_size": 64}
    nested = {"seed": 3, "source": {"model": "chair", "n_train": 5}, "paint": {"prompt": "oak", "texture_size": 64}, "cage": {"iterations": 40, "w_rest": 0.3}, "train": {"iterations": 50}}
    a, b = BuildConfig.from_dict(flat), BuildConfig.from_dict(nested)
    assert a == b and a.cage.iterations == 40 and a.train.iterations == 50 and a.source.n_train == 5
    assert a.train.seed == 3  # the network's seed follows the family seed unless set
    stored = a.to_dict()
    assert BuildConfig.from_dict(stored) == a and resolved_settings(stored) == stored
    assert set(stored) == {"seed", "corr_points", "truth", "source", "paint", "cage", "train"}
    old = resolved_settings({"model": "chair"})  # an old store's flat settings: the values of then filled in
    assert old["source"]["tessellation"] == "fixed" and old["cage"]["prealign"] == "icp"
    demo = BuildConfig.from_dict({}, preset="demo")
    assert demo.source.model == PRESETS["demo"]["source"]["model"] and demo.corr_points == 1000 and demo.train.iterations == 600
    over = BuildConfig.from_dict({"source": {"n_train": 4}, "paint": {"prompt": "red"}}, preset="demo")
    assert (over.source.model, over.source.n_train, over.paint.prompt, over.cage.iterations) == ("sofa", 4, "red", 200)


def test_bad_configs_are_clear_errors():
    from proctex.store.config import BuildConfig

    deep: dict = {}
    for _ in range(3000):
        deep = {"x": deep}
    for bad, msg in (
        ({"source": "mug"}, "source must be an object"),
        ({"source": {"model": "mug", "colour": 1}}, "bad config"),
        ({"model": "mug", "extra": 1}, "unknown config keys"),
        ({"model": "mug", "paint": {"texture_size": 8}}, "texture_size"),
        ({"model": "mug", "train": {"nope": 1}}, "unknown CorrNetConfig"),
        ([1, 2], "object of settings"),
        ({"model": "mug", "source": {"n_train": 1}}, "n_train"),
        ({"model": "mug", "deep": deep}, "unknown config keys"),
        ({"source": {"model": "mug", **{f"k{i}": i for i in range(300)}}}, "at most"),
    ):
        with pytest.raises(ValueError, match=msg):
            BuildConfig.from_dict(bad)
    with pytest.raises(ValueError, match="unknown preset"):
        BuildConfig.from_dict({"model": "mug"}, preset="nope")


@pytest.mark.slow  # 10-40 s (issue 49: the fast tests run twice in make test)
def test_the_same_plans_run_by_another_executor_build_the_same_family(tmp_path):
    """The build is plans run by an executor: one that runs the batches backwards, without the
    in-process context (as a Ray worker does) but with the plan's torch threads, stores the same
    family; a rerun plans nothing."""
    from proctex.build.pipeline import build
    from proctex.build.plan import Placement, run_in_process
    from proctex.pools import torch_threads
    from proctex.store.networks import load_models
    from proctex.store.samples import samples

    cfg = BuildConfig.from_dict(
        dict(
            model="mug",
            n_train=3,
            n_test=1,
            corr_points=200,
            cage_iterations=10,
            texture_size=64,
            train={"iterations": 20, "eval_every": 10, "context_points": 128, "query_points": 64, "plain_below": 0.0},
        )
    )  # both groups trained, whatever their plain maps
    ran = []

    def backwards(plan, store, config, log):
        if plan.skip or plan.placement is Placement.HERE:
            return run_in_process(plan, store, config, log)
        ran.append((plan.stage, plan.n_jobs, plan.placement.value))
        with torch_threads(plan.threads):  # the plan's torch threads, as run_in_process and a Ray task set them: 1 and 2 threads may round apart
            out = {i: plan.run_batch(store, config, plan.batches[i], None) for i in reversed(range(len(plan.batches)))}
        for i in reversed(range(len(plan.batches))):
            plan.collect(plan.batches[i], out[i]) if plan.collect else None
        plan.record = plan.finish([out[i] for i in range(len(plan.batches))])
        return plan

    stages = ("sample", "template", "paint", "pairs", "train")
    a, b = FamilyStore(tmp_path / "a"), FamilyStore(tmp_path / "b")
    build(a, cfg, stages=stages, log=lambda *_: None)
    build(b, cfg, stages=stages, log=lambda *_: None, executor=backwards)
    assert ran == [("sample", 4, "tasks"), ("pairs", 8, "tasks"), ("train", 2, "team")]  # placed by the stage table
    assert samples(a) == samples(b)
    for row in samples(a):
        for g in (0, 1):
            assert all(np.array_equal(x, y) for x, y in zip(read_pair(a, row["id"], g), read_pair(b, row["id"], g)))
    pts = np.random.default_rng(0).uniform(-1, 1, (50, 3)).astype(np.float32)
    from proctex.correspond.corrnet import predict

    ma, mb = load_models(a), load_models(b)
    assert sorted(ma) == sorted(mb) == [0, 1]
    for g in ma:
        assert np.allclose(predict(ma[g], pts, pts), predict(mb[g], pts, pts), atol=1e-6)
        assert ma[g].serving["serve"] == mb[g].serving["serve"]
        assert ma[g].serving["errors"] == pytest.approx(mb[g].serving["errors"], rel=1e-5, abs=1e-7)
    ran.clear()
    logs = []
    build(b, cfg, stages=stages, log=logs.append, executor=backwards)
    assert ran == [] and sum("done already" in line for line in logs) >= 3


def test_a_damaged_serving_choice_is_a_clear_error_and_none_means_the_network():
    from proctex.store.networks import check_serving

    good = {"serve": "box", "template_extent": [1.0, 0.5, 0.25], "errors": {}}
    assert check_serving(good, "m.pt") is good and check_serving(None, "m.pt") is None
    for bad in (
        {"serve": "magic", "template_extent": [1, 1, 1]},
        {"serve": "box", "template_extent": [1, 0, 1]},
        {"serve": "box", "template_extent": [1, float("nan"), 1]},
        {"serve": "box"},
        ["box"],
        "box",
    ):
        with pytest.raises(ValueError, match="m.pt: damaged serving choice"):
            check_serving(bad, "m.pt")


@pytest.mark.slow  # 10-40 s (issue 49: the fast tests run twice in make test)
def test_a_pooled_in_process_build_solves_pairs_side_by_side_and_stores_the_same_family(tmp_path, capsys):
    """``proctex build --workers 2``: the cage pairs run in two worker processes (one thread each),
    every batch collected once, ``finish`` given them in batch order; the pairs are the sequential
    build's (sources exactly, targets to float noise: one thread sums in another order)."""
    from proctex.build.pipeline import build
    from proctex.build.plan import Plan, local_executor, run_in_process
    from proctex.cli import main
    from proctex.store.samples import samples

    # both groups trained, whatever their plain maps (the networks' part of this test is how they are run)
    cfg = BuildConfig.from_dict(dict(model="mug", n_train=3, n_test=1, corr_points=200, cage_iterations=10, texture_size=64, train={"iterations": 20, "plain_below": 0.0}))
    (tmp_path / "train.json").write_text(json.dumps({"train": {"plain_below": 0.0}}))
    stages = ("sample", "template", "paint", "pairs")
    a = FamilyStore(tmp_path / "a")
    build(a, cfg, stages=stages, log=lambda *_: None)
    argv = [
        "build",
        "--model",
        "mug",
        "--n-train",
        "3",
        "--n-test",
        "1",
        "--points",
        "200",
        "--iterations",
        "10",
        "--texture-size",
        "64",
        "--train-iterations",
        "20",
        "--config",
        str(tmp_path / "train.json"),
        "--stages",
        ",".join(stages),
        "--out",
        str(tmp_path / "b"),
        "--workers",
        "2",
        "--quiet",
    ]
    assert main(argv) == 0
    b = FamilyStore(tmp_path / "b")
    assert samples(a) == samples(b) and b.read_json("family.json")["stages"]["pairs"]["pairs"] == 8
    for row in samples(a):
        for g in (0, 1):
            (sa, da), (sb, db) = read_pair(a, row["id"], g), read_pair(b, row["id"], g)
            assert np.array_equal(sa, sb) and np.allclose(da, db, atol=1e-4)
    assert main(argv[:-3] + ["--workers", "-1"]) == 2 and "--workers" in capsys.readouterr().err
    # the networks too, a group per worker: each stored with its record
    assert main([("train" if a == ",".join(stages) else a) for a in argv]) == 0
    trained = b.read_json("family.json")["stages"]["train"]["groups"]
    assert sorted(trained) == ["0", "1"] and all(b.exists(f"models/group_{g}.pt") and trained[g]["sha256"] for g in trained)
    # the executor itself: batches finish out of order, collect sees each once, finish gets batch order
    seen, finished = [], []
    plan = Plan("toy", [[3], [1], [2]], _toy_batch, finish=finished.append, collect=lambda batch, out: seen.append(batch[0]), parallel=True)
    local_executor(2)(plan, a, cfg, lambda *_: None)
    assert sorted(seen) == [1, 2, 3] and finished == [[[30], [10], [20]]]
    plan = Plan("toy", [[3], [1]], _toy_batch, finish=finished.append)  # not parallel: here, in order
    run_in_process(plan, a, cfg, workers=2)
    assert finished[-1] == [[30], [10]]
    # merged plans (the networks): a share of the batches per worker, dealt round robin, results split back per batch
    seen.clear()
    plan = Plan("toy", [[3], [1], [2], [4, 5]], _toy_merged, finish=finished.append, collect=lambda batch, out: seen.append(batch), parallel=True, merge=True)
    local_executor(2)(plan, a, cfg, lambda *_: None)
    assert finished[-1] == [[(30, (3, 2))], [(10, (1, 4, 5))], [(20, (3, 2))], [(40, (1, 4, 5)), (50, (1, 4, 5))]]
    assert sorted(map(tuple, seen)) == [(1,), (2,), (3,), (4, 5)]
    run_in_process(plan, a, cfg)  # one process: every batch in one call
    assert finished[-1][0] == [(30, (3, 1, 2, 4, 5))] and finished[-1][3][1] == (50, (3, 1, 2, 4, 5))
    # trained together in one batched loop (train.together "on"; "auto" does so on a GPU): the same networks as one by one (to rounding)
    cfg.train.together = "on"
    build(a, cfg, stages=("train",), log=lambda *_: None)
    joint = a.read_json("family.json")["stages"]["train"]["groups"]
    assert all(joint[g]["together"] == 2 and trained[g]["together"] == 1 for g in ("0", "1"))
    for g in ("0", "1"):  # (bfloat16 products where the CPU has them: rounding at the third digit, amplified by 20 steps)
        assert joint[g]["iterations"] == trained[g]["iterations"]
        assert joint[g]["best_val"]["mean"] == pytest.approx(trained[g]["best_val"]["mean"], rel=0.1)
    assert abs(joint["0"]["best_val"]["mean"] - trained["1"]["best_val"]["mean"]) > 0.2 * trained["1"]["best_val"]["mean"]


def _toy_merged(store, config, batch, context):
    return [(10 * j, tuple(batch)) for j in batch]


def _toy_batch(store, config, batch, context):
    import time

    time.sleep(0.05 * batch[0])
    return [10 * batch[0]]


def test_the_pairs_stage_skips_the_train_pairs_of_groups_whose_plain_map_fits(tmp_path):
    """Two steps: the test pairs and each group's held-out and probe train pairs first; then the
    other train pairs of a group whose plain map already fits its held-out shapes are skipped (its
    network would not be trained) and every other group's are solved. The train stage settles the
    same groups on the same pairs; a rerun plans nothing; without the settle every skipped pair is
    solved after all."""
    from proctex.build.pairs import pair_jobs, probe_keys
    from proctex.build.pipeline import run_stage
    from proctex.build.plan import run_in_process
    from proctex.build.groupdata import VAL_SHARE, group_training_data, plain_groups
    from proctex.store.samples import held_out_split, samples
    from proctex.store.state import FamilyState

    # 100 cage iterations: the same groups settle natively and on other kernels (python -m tests.portable:
    # identical plain-map errors); the tightest settled group's box map 0.000312 against plain_below 0.0005 (x1.6)
    cfg = BuildConfig.from_dict(dict(model="sofa", n_train=8, n_test=1, corr_points=300, cage_iterations=100, texture_size=64)).validate()
    st = FamilyStore(tmp_path / "sofa")
    write_config(st, cfg)
    for stage in (stage_sample, stage_template, stage_paint):
        stage(st, cfg, log=lambda *_: None)
    ran, logs = [], []

    def execute(plan, *rest):
        ran.append(plan.n_jobs)
        return run_in_process(plan, *rest)

    run_stage(st, cfg, "pairs", logs.append, execute)  # in its two steps, recorded by the pipeline
    rows = {(r["id"], r["group"]): r for r in st.read_table("pairs.parquet").to_pylist()}
    groups = sorted({g for _, g in rows})
    train = sorted(r["id"] for r in samples(st) if r["split"] == "train")
    record = FamilyState.load(st).stage("pairs")
    settled = {int(g) for g in record["settled"]}
    assert record["state"] == "done" and settled and settled != set(groups), record  # some settle, some do not
    probes = probe_keys(cfg, pair_jobs(st, cfg))
    assert len(ran) == 2 and ran[0] == len(probes) == len(groups) * 3  # a group's test pair, 1 held out, 1 probe
    for g in groups:
        held, probe = held_out_split(train, cfg.seed, g, VAL_SHARE)
        for sid in train:
            status = rows[(sid, g)]["status"]
            assert status == ("skipped" if g in settled and sid not in held + probe else "done"), (g, sid, status)
    assert record["skipped"] == sum(r["status"] == "skipped" for r in rows.values()) == len(settled) * (len(train) - 2)
    assert ran[1] == len(rows) - len(probes) - record["skipped"]  # the second step solves the rest of the unsettled groups
    assert sum("train pairs skipped" in line for line in logs) == len(settled)
    # the train stage settles the same groups on the same pairs, holding out the same shapes
    assert set(plain_groups(st, cfg, groups)) == settled
    for g in settled:
        d = group_training_data(st, cfg, g, VAL_SHARE)
        assert d["val_ids"] == held_out_split(train, cfg.seed, g, VAL_SHARE)[0] and len(d["train_ids"]) == 1
    # a rerun plans nothing; a config that never settles solves what was skipped
    ran.clear()
    run_stage(st, cfg, "pairs", logs.append, execute)
    assert ran == [0]
    plain = BuildConfig.from_dict({**cfg.to_dict(), "train": {**cfg.to_dict()["train"], "plain_below": 0.0}})
    ran.clear()
    run_stage(st, plain, "pairs", logs.append, execute)
    assert ran == [record["skipped"]]
    assert all(r["status"] == "done" for r in st.read_table("pairs.parquet").to_pylist())


def test_the_held_out_shapes_are_drawn_before_the_pairs_and_always_leave_shapes_to_train():
    """``held_out_split`` depends only on the train shapes (so the pairs stage can solve them
    first); a group holds out the family's draw where it was solved, its own draw where that holds
    out none or every solved shape (the Blender table's optional part: solved only in the family's
    held-out shapes; below three shapes that holds none out). The draw as it was before: with every pair
    solved, the same shapes as ``rng.choice`` over them."""
    from proctex.store.samples import held_out_ids, held_out_split

    train = [f"s{i:04d}" for i in range(40)]
    held, probes = held_out_split(train, 0, 3, 0.15)
    assert len(held) == len(probes) == 6 and not set(held) & set(probes) and set(held + probes) <= set(train)
    assert held_out_split(list(reversed(train)), 0, 3, 0.15) == (held, probes)  # order does not matter
    assert held_out_split(train, 0, 4, 0.15)[0] != held and held_out_split(train[:2], 0, 3, 0.15) == ([], [])
    rng = np.random.default_rng(0 + 3)
    assert held == sorted(rng.choice(train, size=6, replace=False).tolist())  # what group_training_data drew before
    assert held_out_ids(train, train, 0, 3, 0.15) == held  # every pair solved: the family's draw
    assert held_out_ids(train, held + probes, 0, 3, 0.15) == held  # the first step's pairs: the same shapes
    own = held_out_ids(train, held, 0, 3, 0.15)  # solved only where held out: its own draw, some left to train
    assert own and set(own) < set(held)
    others = [i for i in train if i not in held][:10]
    assert held_out_ids(train, others, 0, 3, 0.15) == held_out_split(others, 0, 3, 0.15)[0] != []  # none of the draw solved
    assert held_out_ids(train, held[:2], 0, 3, 0.15) == []  # two shapes, both in the draw: none held out
    assert held_out_ids(train, [held[0], probes[0]], 0, 3, 0.15) == [held[0]]  # one in the draw, one to train on


def test_a_shape_is_segmented_and_assigned_once_for_all_its_pairs(painted_mug_root, monkeypatch):
    """The pairs of one shape (a batch) share its segmentation and part assignment: computed once,
    not once per template group, with the same inputs for every group as computed afresh; a shape
    whose arrays were replaced is assigned again."""
    import proctex.build.pairs as pairs
    from proctex.build.pairs import pair_input
    from proctex.store.samples import load_sample, samples
    from proctex.transfer.assets import load_assets

    st = FamilyStore(painted_mug_root / "mug")
    cfg = BuildConfig.from_dict(st.read_json("family.json")["config"])
    assets = load_assets(st)
    groups = [g.group for g in assets.groups]
    row = samples(st)[1]
    fresh = {g: pair_input(load_sample(st, row, cfg), assets, g) for g in groups}
    calls = []
    real = pairs.assign_parts
    monkeypatch.setattr(pairs, "assign_parts", lambda *a, **k: calls.append(1) or real(*a, **k))
    shape = load_sample(st, row, cfg)
    for g in groups:
        got = pair_input(shape, assets, g)
        assert got[0] == fresh[g][0] and np.array_equal(got[1], fresh[g][1]) and np.array_equal(got[2], fresh[g][2])
    assert len(groups) == 2 and len(calls) == 1
    shape.vertices = shape.vertices * 1.0  # new arrays: assigned again
    pair_input(shape, assets, groups[0])
    assert len(calls) == 2


def test_the_template_shape_is_read_whole_and_never_made_again(mug_family, tmp_path, monkeypatch):
    """The template stage records the template shape whole (labels, part names, canonical truth,
    parameters): loading the family reads it and makes no shape (a model that raises is never
    called), equal to the shape its parameters make. A damaged or missing record is an error naming
    it; a family built before the record reads its mesh or makes it again, unless making a shape
    starts another program (Blender): then it asks for a rebuild rather than start one."""
    import dataclasses

    import proctex.sources.registry as reg
    from proctex.store.config import BuildConfig as Config
    from proctex.store.layout import StoreDamaged, StoreLayout
    from proctex.store.samples import read_shape_record, shape_record
    from proctex.store.state import FamilyState
    from proctex.store.template import load_template_shape

    st, cfg = mug_family
    made = cfg.procedural_model().generate(FamilyState.load(st).stage("template")["params"])

    def no_shapes(self, *a, **k):
        raise AssertionError("a shape was made while loading the family")

    with monkeypatch.context() as m:
        m.setattr(Config, "procedural_model", no_shapes)
        shape = load_template_shape(st, cfg)
    for k in ("vertices", "faces", "canonical", "labels"):
        np.testing.assert_array_equal(getattr(shape, k), getattr(made, k))
    assert shape.label_names == made.label_names and shape.params == made.params and shape.source == StoreLayout.TEMPLATE_MESH
    assert shape.corner_uv is None and shape.derived == {}

    # the record round-trips any shape (optional arrays present or absent) and refuses other files
    other = FamilyStore(tmp_path / "other")
    odd = dataclasses.replace(made, corner_uv=np.zeros((made.n_faces, 3, 2)), face_source=np.arange(made.n_faces), params={"ü": [1.5]})
    other.write_bytes("s.npz", shape_record(odd))
    back = read_shape_record(other, "s.npz")
    for k in ("vertices", "faces", "canonical", "labels", "corner_uv", "face_source"):
        np.testing.assert_array_equal(getattr(back, k), getattr(odd, k))
        assert getattr(back, k).dtype == getattr(odd, k).dtype
    assert (back.label_names, back.params, back.source) == (odd.label_names, odd.params, odd.source)
    other.write_arrays("bad.npz", vertices=made.vertices, faces=made.faces)
    with pytest.raises(StoreDamaged, match="bad.npz is not a shape record"):
        read_shape_record(other, "bad.npz")

    copy = FamilyStore(tmp_path / "copy")
    for rel in (StoreLayout.STATE, StoreLayout.TEMPLATE_MESH, StoreLayout.TEMPLATE_SHAPE):
        copy.write_bytes(rel, st.read_bytes(rel))
    data = bytearray(copy.read_bytes(StoreLayout.TEMPLATE_SHAPE))
    data[-40] ^= 1
    copy.write_bytes(StoreLayout.TEMPLATE_SHAPE, bytes(data))
    with pytest.raises(StoreDamaged, match="shape.npz: checksum mismatch"):
        load_template_shape(copy)
    copy.delete(StoreLayout.TEMPLATE_SHAPE)
    with pytest.raises(StoreDamaged, match="shape.npz is missing"):
        load_template_shape(copy)
    # built before the record: the stage record has no digest
    state = FamilyState.load(copy)
    del state.stages["template"]["shape"]
    state.save(copy)
    again = load_template_shape(copy)
    np.testing.assert_array_equal(again.labels, made.labels)
    kind = reg.get_source_kind("model")
    with monkeypatch.context() as m:
        import proctex.store.template as tm

        m.setattr(tm, "source_kind", lambda source: dataclasses.replace(kind, starts_program=True))
        m.setattr(Config, "procedural_model", no_shapes)
        with pytest.raises(ValueError, match="built before ProcTex 0.16.*build it again"):
            load_template_shape(copy)


def test_loading_a_family_opens_no_shape_source_and_one_version_value(mug_family, monkeypatch):
    """A service loads and describes a model family from its records alone (the parameter space as
    the sample stage recorded it, the template shape as recorded): its source is opened only by
    the first transfer by parameters (for a ``.blend`` family, that is when Blender starts). The
    family's version is one value: the handle's, the service's and the description's."""
    from proctex.serve.service import FamilyService
    from proctex.store.config import BuildConfig as Config
    from proctex.store.family import Family
    from proctex.store.state import FamilyState

    st, cfg = mug_family
    recorded = FamilyState.load(st).stage("sample")["space"]
    assert recorded == cfg.procedural_model().space.to_list()

    def opened(self, *a, **k):
        raise AssertionError("the shape source was opened")

    with monkeypatch.context() as m:
        m.setattr(Config, "shapes", opened)
        m.setattr(Config, "procedural_model", opened)
        family = Family.open(st)
        assert family.space.to_list() == recorded and family.template_shape.n_faces > 0
        svc = FamilyService(st, "mug")
        described = svc.describe()
        assert described["parameters"] == recorded and described["inputs"] == ["params", "mesh"]
        assert described["source"]["kind"] == "model" and described["parts_attribute"] is None
        assert family.version == svc.stamp == described["stamp"]
        with pytest.raises(AssertionError, match="source was opened"):
            svc.shape_from_params({})
    shape = svc.shape_from_params({})  # opened now
    assert shape.n_faces > 0


def undeclared(before: set[str], after: set[str], declared: tuple[str, ...]) -> list[str]:
    """Files in ``after`` but not in ``before`` (written, or read) that match none of the ``declared`` patterns
    (``family.json``, the pipeline's record, and lock files aside)."""
    import fnmatch

    new = sorted(after - before)
    return [f for f in new if f != "family.json" and not f.startswith(".") and not any(fnmatch.fnmatch(f, p) for p in declared)]


def store_files(root: Path) -> set[str]:
    return {str(p.relative_to(root)) for p in root.rglob("*") if p.is_file()}


def test_each_stage_writes_only_what_it_declares_and_the_pipeline_alone_records_it(tmp_path):
    """The stage table (:data:`proctex.build.pipeline.STAGES_TABLE`) lists the stages in build order
    with their placement; run one by one, each stage writes only files its table entry declares and
    reads only those it declares or wrote (the check finds a file nobody declared), and its record
    in ``family.json`` appears when the pipeline writes it: no module of ``proctex`` but the
    pipeline marks a stage done."""
    import ast

    from proctex.build.pipeline import STAGES_TABLE, run_stage
    from proctex.build.plan import Placement
    from proctex.store.state import STAGES, FamilyState

    assert tuple(STAGES_TABLE) == STAGES
    assert {s.name: s.placement for s in STAGES_TABLE.values()} == {
        "sample": Placement.TASKS,
        "template": Placement.HERE,
        "paint": Placement.HERE,
        "pairs": Placement.TASKS,
        "train": Placement.TEAM,
        "evaluate": Placement.HERE,
    }
    assert undeclared({"a"}, {"a", "models/group_0.pt", "notes.txt"}, ("models/*",)) == ["notes.txt"]

    cfg = BuildConfig.from_dict(
        dict(model="mug", n_train=3, n_test=2, corr_points=200, cage_iterations=10, texture_size=64, train={"iterations": 20, "eval_every": 10, "context_points": 128, "query_points": 64})
    ).validate()
    root = tmp_path / "mug"
    st = FamilyStore(root)
    write_config(st, cfg)
    reads: list[str] = []
    real = FamilyStore.read_bytes
    with pytest.MonkeyPatch.context() as m:  # every store read (JSON, tables, arrays) goes through read_bytes
        m.setattr(FamilyStore, "read_bytes", lambda self, rel: reads.append(rel) or real(self, rel))
        for name in STAGES:
            before = store_files(root)
            reads.clear()
            run_stage(st, cfg, name, log=lambda *_: None)
            after = store_files(root)
            entry = STAGES_TABLE[name]
            assert undeclared(before, after, entry.writes) == [], name
            assert after - before, f"{name} wrote nothing"
            # what it read: its declared reads, what it wrote itself, family.json
            assert undeclared(set(), set(reads), entry.reads + entry.writes) == [], name
            assert FamilyState.load(st).done(name), name

    markers = []
    package = Path(__file__).resolve().parents[1] / "proctex"
    for path in sorted(package.rglob("*.py")):
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.Call):
                fn = node.func
                name = fn.id if isinstance(fn, ast.Name) else fn.attr if isinstance(fn, ast.Attribute) else ""
                if name == "mark_stage" or (name == "mark" and isinstance(fn, ast.Attribute) and "state" in ast.unparse(fn.value).lower()):
                    markers.append(path.relative_to(package).as_posix())
    assert sorted(set(markers)) == ["build/pipeline.py", "store/state.py"], markers


def test_a_build_reads_family_json_once(tmp_path, monkeypatch):
    """A build holds the family's state in memory under its exclusive lock
    (:func:`proctex.store.state.held_state`): its process reads ``family.json`` at most once (none
    for a new folder) whatever its stages ask, writes every record through, and lets the state go
    when it ends, also when a stage fails."""
    import proctex.store.state as state_mod
    from proctex.build.pipeline import build
    from proctex.store.state import FamilyState

    reads = []
    real = FamilyStore.read_bytes
    monkeypatch.setattr(FamilyStore, "read_bytes", lambda self, rel: (reads.append(rel) if rel == "family.json" else None) or real(self, rel))
    cfg = BuildConfig.from_dict(dict(model="mug", n_train=3, n_test=1, corr_points=200, cage_iterations=10, texture_size=64))
    st = FamilyStore(tmp_path / "mug")
    build(st, cfg, stages=("sample", "template", "paint", "pairs"), log=lambda *_: None)
    assert reads == [] and state_mod._HELD == {}
    after = FamilyState.load(st)  # outside a build: read from the file
    assert all(after.done(s) for s in ("sample", "template", "paint", "pairs")) and reads == ["family.json"]
    reads.clear()
    build(st, cfg, stages=("sample", "template", "paint", "pairs"), log=lambda *_: None)  # resumed: everything done
    assert reads == ["family.json"]

    def broken(*a, **k):
        raise RuntimeError("a stage failed")

    monkeypatch.setattr("proctex.build.pipeline._run_stages", broken)
    with pytest.raises(RuntimeError):
        build(st, cfg, stages=("sample",), log=lambda *_: None)
    assert state_mod._HELD == {}


def test_a_pair_batch_keys_its_cached_template_on_the_planned_version(mug_family, monkeypatch):
    """A worker (a pool process, a Ray task) keys its cached template on the family version the jobs
    were planned at: a warm worker reads no ``family.json`` for a batch; a job planned at another
    version loads the template again."""
    import proctex.build.pairs as pairs
    from proctex.build.pairs import pair_jobs, run_pair_batch
    from proctex.store.family import Family

    st, cfg = mug_family
    jobs = pair_jobs(st, cfg)
    assert {j.version for j in jobs} == {Family.open(st).version}
    pairs._ASSETS.clear()
    reads = []
    real = FamilyStore.read_bytes
    monkeypatch.setattr(FamilyStore, "read_bytes", lambda self, rel: (reads.append(rel) if rel == "family.json" else None) or real(self, rel))
    first = run_pair_batch(st, cfg, jobs[:1])
    cold = len(reads)
    second = run_pair_batch(st, cfg, jobs[1:2])
    assert cold == 1 and len(reads) == cold  # cold: the template loaded, family.json read once; warm: nothing read
    assert first[0]["status"] == second[0]["status"] == "done"
    other = pairs.PairJob(jobs[0].index, jobs[0].row, jobs[0].group, "another")
    run_pair_batch(st, cfg, [other])
    assert len(reads) > cold and list(pairs._ASSETS) == [(st.uri, "another")]
