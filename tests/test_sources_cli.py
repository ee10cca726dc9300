import json
import re

import numpy as np
import pytest

from proctex.cli import main
from proctex.geometry.meshio import load_mesh
from proctex.sources.files import FolderSource, load_generator, resolve_shape

GEN = """
import numpy as np
from proctex.geometry import primitives as P

PARAMS = [{"name": "legs", "kind": "integer", "low": 2, "high": 5, "default": 3}]

def generate(params):
    parts = [P.box((1.0, 1.0, 0.1), center=(0, 0, 1))]
    for k in range(params["legs"]):
        a = 2 * np.pi * k / params["legs"]
        parts.append(P.box((0.05, 0.05, 1.0), center=(0.4 * np.cos(a), 0.4 * np.sin(a), 0.5)))
    verts, faces, off = [], [], 0
    for p in parts:
        verts.append(p.vertices); faces.append(p.faces + off); off += len(p.vertices)
    return np.concatenate(verts), np.concatenate(faces)
"""


@pytest.fixture
def generator_config(tmp_path):
    (tmp_path / "legs_gen.py").write_text(GEN)
    cfg = tmp_path / "family.toml"
    cfg.write_text('[generator]\nname = "stool"\nmodule = "legs_gen.py"\nfunction = "generate"\n')
    return cfg


def test_user_generator_from_config(generator_config):
    model = load_generator(generator_config)
    assert model.name == "stool" and model.space.names == ["legs"]
    shape = model.generate({"legs": 4})
    assert shape.params == {"legs": 4} and shape.canonical is None
    with pytest.raises(ValueError, match=r"\[2, 5\]"):
        model.generate({"legs": 9})


def test_generator_config_errors(tmp_path):
    bad = tmp_path / "bad.toml"
    bad.write_text("[generator]\nmodule = 'nope.py'\nfunction = 'f'\nparams = []\n")
    with pytest.raises(ValueError, match="does not exist"):
        load_generator(bad)
    bad.write_text("[generator\n")
    with pytest.raises(ValueError, match="cannot parse"):
        load_generator(bad)
    bad.write_text("[other]\n")
    with pytest.raises(ValueError, match=r"\[generator\]"):
        load_generator(bad)
    (tmp_path / "g.py").write_text("def f(p):\n    return 42\n")
    bad.write_text("[generator]\nmodule = 'g.py'\nfunction = 'f'\nparams = []\n")
    with pytest.raises(ValueError, match="returned int"):
        load_generator(bad).generate({})
    bad.write_text("[generator]\nmodule = 'g.py'\nfunction = 'missing'\nparams = []\n")
    with pytest.raises(ValueError, match="no function"):
        load_generator(bad)


def test_cli_sample_then_segment_folder(tmp_path, generator_config, capsys):
    out = tmp_path / "samples"
    assert main(["sample", str(generator_config), "--n", "4", "--seed", "1", "--out", str(out), "--quiet"]) == 0
    src = FolderSource(out)
    assert len(src) == 4 and src.space.names == ["legs"]
    for i in range(4):
        src.load(i)  # each sample loads
        legs = src.params(i)["legs"]
        assert main(["segment", src.samples[i].mesh_path, "--json"]) == 0
        data = json.loads(capsys.readouterr().out)
        assert len(data["parts"]) == 1 + legs
        assert sorted(len(g["parts"]) for g in data["groups"]) == [1, legs]
        assert all({"faces", "area", "degenerate", "group"} <= set(p) for p in data["parts"])


@pytest.mark.parametrize("fmt", ["ply", "glb", "stl"])
def test_cli_sample_formats_round_trip(tmp_path, fmt):
    out = tmp_path / fmt
    assert main(["sample", "fork", "--n", "2", "--seed", "0", "--out", str(out), "--format", fmt, "--quiet"]) == 0
    for i, p in enumerate(json.loads((out / f"{i}.json").read_text()) for i in range(2)):
        from proctex.models import get_model

        want_parts, _ = get_model("fork").expected_counts(p)
        shape, _ = load_mesh(out / f"{i}.{fmt}")
        from proctex.geometry.parts import segment

        assert segment(shape).n_parts == want_parts


def test_cli_models_json(capsys):
    assert main(["models", "--json"]) == 0
    models = json.loads(capsys.readouterr().out)["models"]
    assert len(models) >= 10
    sofa = next(m for m in models if m["name"] == "sofa")
    assert {p["kind"] for p in sofa["params"]} <= {"continuous", "integer", "choice"}


def test_cli_segment_model_argument(capsys):
    assert main(["segment", 'desk:{"drawers": 2}', "--json"]) == 0
    data = json.loads(capsys.readouterr().out)
    assert (data["n_parts"], data["n_groups"]) == (5 + 1 + 4, 5)


def test_cli_segment_sofa(sofa_dir, capsys):
    assert main(["segment", str(sofa_dir / "inference" / "0.obj"), "--json"]) == 0
    data = json.loads(capsys.readouterr().out)
    assert len(data["parts"]) == 9 and sum(p["degenerate"] for p in data["parts"]) == 4
    assert [g["parts"] for g in data["groups"]][0] == [0, 1]


def test_cli_match_and_template(sofa_dir, capsys):
    assert main(["template", str(sofa_dir), "--json"]) == 0
    t = json.loads(capsys.readouterr().out)
    assert t["template"].startswith("train/")
    assert main(["match", 'chair:{"arms": false}', "chair", "--json"]) == 0
    m = json.loads(capsys.readouterr().out)
    assert len(m["missing"]) == 1 and not m["added"] and len(m["matched"]) == 4


@pytest.mark.parametrize(
    "argv,match",
    [
        (["segment", "nothing.obj"], "neither a mesh file nor a built-in model"),
        (["segment", 'desk:{"drawers": 9}'], r"\[0, 4\]"),
        (["segment", "desk:{bad json"], "bad parameters"),
        (["sample", "teapot", "--n", "2", "--out", "x"], "unknown model"),
        (["sample", "desk", "--n", "0", "--out", "x"], "--n must be >= 1"),
        (["template", "nowhere_dir_or_model"], "unknown model"),
    ],
)
def test_cli_bad_input(argv, match, capsys, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert err.startswith("error:") and re.search(match, err), err
    assert not (tmp_path / "x").exists()  # nothing written on failure


def test_cli_bad_mesh_file(tmp_path, capsys):
    p = tmp_path / "broken.obj"
    p.write_text("v 0 0 0\nf 1 2 3\n")
    assert main(["segment", str(p)]) == 2
    assert "references vertex" in capsys.readouterr().err


def test_resolve_shape_reads_params_next_to_mesh(tmp_path):
    from proctex.geometry.meshio import save_mesh, save_params
    from proctex.models import get_model

    shape = get_model("vase").generate()
    save_mesh(shape, tmp_path / "v.obj")
    save_params(shape.params, tmp_path / "v.json")
    back = resolve_shape(str(tmp_path / "v.obj"))
    assert back.params == shape.params


def test_folder_source_flat_and_errors(tmp_path):
    with pytest.raises(ValueError, match="not a folder"):
        FolderSource(tmp_path / "missing")
    with pytest.raises(ValueError, match="no mesh files"):
        FolderSource(tmp_path)
    main(["sample", "vase", "--n", "3", "--out", str(tmp_path / "flat"), "--quiet"])
    src = FolderSource(tmp_path / "flat")
    assert [s.id for s in src.samples] == ["0", "1", "2"] and src.indices("test") == []
    assert 0 <= src.template_index() < 3


TOY_SOURCE = '''"""A kind of shape source in one file: the built-in mug, scaled by its settings."""
from proctex.models import get_model
from proctex.sources.registry import ShapeSource, SourceKind, get_source_kind, register_source_kind


class ScaledMug:
    def __init__(self, scale):
        self.inner, self.scale = get_model("mug"), scale
        self.space = self.inner.space

    def generate(self, params=None):
        shape = self.inner.generate(params)
        shape.vertices = shape.vertices * self.scale
        return shape


def check(settings):
    if not isinstance(settings, dict) or not isinstance(settings.get("scale"), (int, float)) or not settings["scale"] > 0:
        raise ValueError("toy_mug settings must be {scale: a positive number}")


register_source_kind(SourceKind("toy_mug", lambda cfg: ShapeSource(get_source_kind("toy_mug"), ScaledMug(cfg.settings["scale"]),
                                                                   get_model("mug").space), check, "the mug, scaled"))
'''


def test_a_source_kind_from_one_file_builds_and_serves_a_family(tmp_path, monkeypatch):
    """One new file registers a kind of shape source (issue 33): a build config names it by
    ``[source] kind`` with its settings, the build samples and paints its shapes, the service makes
    new ones from parameters, and its own check rejects bad settings."""
    from proctex import plugins
    from proctex.build.pipeline import stage_paint
    from proctex.build.pipeline import stage_sample
    from proctex.build.pipeline import stage_template
    from proctex.models import get_model
    from proctex.serve.service import FamilyService
    from proctex.sources.registry import unregister_source_kind
    from proctex.store.config import BuildConfig
    from proctex.store.layout import FamilyStore
    from proctex.store.samples import load_sample, samples
    from proctex.store.state import write_config

    path = tmp_path / "toy_source.py"
    path.write_text(TOY_SOURCE)
    monkeypatch.setenv("PROCTEX_PLUGINS", str(path))
    try:
        cfg = BuildConfig.from_dict({"source": {"kind": "toy_mug", "settings": {"scale": 3.0}, "n_train": 2, "n_test": 0}, "paint": {"prompt": "blue ceramic", "texture_size": 32}})
        st = FamilyStore(tmp_path / "fam")
        write_config(st, cfg)
        for stage in (stage_sample, stage_template, stage_paint):
            stage(st, cfg, log=lambda *_: None)
        row = samples(st)[0]
        mug = get_model("mug").generate(json.loads(row["params"]))
        assert np.allclose(load_sample(st, row, cfg).vertices, 3.0 * mug.vertices)  # regenerated by the plugin's model
        svc = FamilyService(st)
        assert svc.describe()["source"]["kind"] == "toy_mug"
        shape = svc.shape_from_params({})
        assert np.ptp(shape.vertices, axis=0).max() == pytest.approx(3.0 * np.ptp(get_model("mug").generate().vertices, axis=0).max())
        for bad, message in (
            ({"kind": "toy_mug", "settings": {"scale": -1}}, "positive number"),
            ({"kind": "toy_nothing", "settings": {}}, "unknown source kind"),
            ({"kind": "toy_mug", "settings": {"scale": 1}, "model": "mug"}, "exactly one"),
        ):
            with pytest.raises(ValueError, match=message):
                BuildConfig.from_dict({"source": bad})
    finally:
        unregister_source_kind("toy_mug")
        plugins._LOADED.pop(str(path), None)
