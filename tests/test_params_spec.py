"""Parameter spec files and conditional inputs (issue 31): the ranges of a real model's inputs come
from the spec beside its file, and inputs that only matter under others are sampled only there."""

import json

import numpy as np
import pytest

from proctex.params import (
    MAX_SPEC_DEPTH,
    ParamSpace,
    ParamSpec,
    choice,
    continuous,
    integer,
    read_params_spec,
    select_template,
    with_conditions,
)

from .conftest import SOFA

BLEND = SOFA.parent / "blend"


def chair_like_space() -> ParamSpace:
    space = ParamSpace(
        (
            integer("Legs Type", 0, 2, 0),
            choice("Has Middle Support", (False, True), False),
            continuous("Middle Offset", 0.0, 0.5, 0.0),
            choice("Has Arms", (False, True), False),
            continuous("Arm Height", 0.1, 0.3, 0.1),
            choice("Has Drawers", (False, True), False),
            integer("Boards", 2, 6, 2),
        )
    )
    return with_conditions(
        space,
        {
            "Has Middle Support": {"when": [["Legs Type", 0]]},
            "Middle Offset": {"when": [["Legs Type", 0], ["Has Middle Support", True]]},
            "Arm Height": {"when": [["Has Arms", True]]},
            "Boards": {"unless": [["Has Drawers", True]]},
        },
    )


def test_the_real_chair_spec_reads_with_its_ranges_and_conditions():
    path = BLEND / "sp_chair.json"
    if not path.is_file():
        pytest.skip("the shared .blend specs are absent")
    spec = read_params_spec(path)
    assert len(spec.kinds) == 20 and spec.kinds["Has Back"] == "bool" and spec.kinds["Legs Type"] == "int"
    assert spec.bounds["Legs Size"] == [0.02, 0.08] and spec.bounds["Legs Type"] == [0, 2] and "Has Back" not in spec.bounds
    assert spec.conditions["Middle Offset"] == {"when": [["Legs Type", 0], ["Has Middle Support", True]]}
    assert spec.conditions["Back Height"] == {"when": [["Has Back", True]]}
    cab = read_params_spec(BLEND / "sp_cabinet.json")
    assert cab.conditions["Has Back"] == {"unless": [["Has Drawers", True]]}


def test_conditional_inputs_are_sampled_only_where_they_matter():
    space = chair_like_space()
    rows = space.sample(400, seed=3, method="lhs")
    for p in rows:
        if not (p["Legs Type"] == 0 and p["Has Middle Support"]):
            assert p["Middle Offset"] == 0.0
        if p["Legs Type"] != 0:
            assert p["Has Middle Support"] is False and p["Middle Offset"] == 0.0
        if not p["Has Arms"]:
            assert p["Arm Height"] == 0.1
        if p["Has Drawers"]:
            assert p["Boards"] == 2
    active = [p for p in rows if p["Legs Type"] == 0 and p["Has Middle Support"]]
    assert len(active) > 30 and np.std([p["Middle Offset"] for p in active]) > 0.1  # it does vary where it matters
    assert len({p["Boards"] for p in rows if not p["Has Drawers"]}) == 5
    # The check fails for a space without the conditions: inactive inputs vary there.
    plain = ParamSpace(tuple(ParamSpec.from_dict({k: v for k, v in s.to_dict().items() if k not in ("when", "unless")}) for s in space.specs)).sample(400, seed=3, method="lhs")
    assert any(p["Legs Type"] != 0 and p["Middle Offset"] != 0.0 for p in plain)


def test_settings_that_differ_only_where_nothing_matters_are_one_setting():
    space = chair_like_space()
    a = {"Legs Type": 1, "Middle Offset": 0.4, "Has Middle Support": True, "Has Arms": False, "Arm Height": 0.25}
    b = {"Legs Type": 1, "Middle Offset": 0.1, "Has Middle Support": False, "Has Arms": False, "Arm Height": 0.12}
    np.testing.assert_array_equal(space.feature(a), space.feature(b))
    assert space.settle(a) == space.settle(b)
    assert "Middle Offset" not in space.active(a) and "Legs Type" in space.active(a)
    c = {**a, "Legs Type": 0}
    assert "Middle Offset" in space.active(c) and not np.array_equal(space.feature(c), space.feature({**c, "Middle Offset": 0.1}))
    # Round trip through the stored form.
    again = ParamSpace.from_list(json.loads(json.dumps(space.to_list())))
    assert again.settle(a) == space.settle(a) and again["Middle Offset"].when == (("Legs Type", 0), ("Has Middle Support", True))


def test_flat_specs_and_hostile_specs(tmp_path):
    assert read_params_spec({"Height": [0.5, 2], "Rings": [3, 9]}).bounds == {"Height": [0.5, 2.0], "Rings": [3.0, 9.0]}
    deep: dict = {"type": "float", "range": [0, 1]}
    for _ in range(MAX_SPEC_DEPTH + 1):
        deep = {"type": "nested", "params": {"g": deep}}
    bad = [
        ({"params": {"a": {"type": "float", "range": [1, 0]}}}, "low > high"),
        ({"params": {"a": {"type": "float", "range": [0, float("inf")]}}}, "finite"),
        ({"params": {"a": {"type": "float"}}}, "needs a range"),
        ({"params": {"a": {"type": "vector", "range": [0, 1]}}}, "type must be"),
        ({"params": {"a": {"type": "int", "range": [0.5, 2]}}}, "whole numbers"),
        ({"params": {"a": {"type": "bool", "or_dependencies": ["nope"]}}}, "does not have"),
        ({"params": {"a": {"type": "bool", "or_dependencies": [[1, 2, 3]]}}}, "dependency"),
        ({"params": {"g": deep}}, "deeper"),
        ({"params": {f"p{i}": {"type": "bool"} for i in range(1001)}}, "more than"),
        ({"params": {}}, "names no input"),
        ({}, "non-empty"),
        ({"a": "x"}, "range must be"),
    ]
    for spec, message in bad:
        with pytest.raises(ValueError, match=message):
            read_params_spec(spec)
    (tmp_path / "broken.json").write_text("{ not json")
    with pytest.raises(ValueError, match="cannot parse"):
        read_params_spec(tmp_path / "broken.json")
    with pytest.raises(ValueError, match="not found"):
        read_params_spec(tmp_path / "none.json")
    with pytest.raises(ValueError, match="is not a parameter"):
        ParamSpace((ParamSpec("a", "continuous", 0.0, 0.0, 1.0, when=(("b", 1),)),))


def test_a_config_reads_its_spec_once_and_stores_what_it_read(tmp_path):
    from proctex.store.config import BuildConfig

    spec = {"params": {"radius": {"type": "float", "range": [0.04, 0.05]}, "taper": {"type": "float", "range": [-0.01, 0.0]}}}
    (tmp_path / "sp.json").write_text(json.dumps(spec))
    (tmp_path / "build.toml").write_text('[source]\nmodel = "mug"\nparams_spec = "sp.json"\n[source.params]\ntaper = [-0.005, 0.0]\n')
    cfg = BuildConfig.from_file(tmp_path / "build.toml")
    assert cfg.source.params == {"radius": [0.04, 0.05], "taper": [-0.005, 0.0]}  # the config's own bounds win
    space = cfg.procedural_model().space
    assert (space["radius"].low, space["radius"].high) == (0.04, 0.05)
    (tmp_path / "sp.json").unlink()  # the stored config needs the file no more
    again = BuildConfig.from_dict(cfg.to_dict())
    assert again.source.params == cfg.source.params and "params_spec" not in cfg.to_dict()["source"]
    with pytest.raises(ValueError, match="not found"):
        BuildConfig.from_file(tmp_path / "build.toml")


def test_the_template_covers_the_optional_parts():
    from proctex.geometry.parts import kind_groups, part_kinds

    from .meshes import unlabelled_chair

    full, bare = unlabelled_chair(), unlabelled_chair(arms=False, back=False)
    assert part_kinds(full) == 4 and part_kinds(bare) == 2
    assert sorted(len(g.members) for g in kind_groups(full).groups) == [1, 1, 2, 4]
    space = ParamSpace((continuous("x", 0, 1, 0.5),))
    samples = [{"x": 0.5}, {"x": 0.1}, {"x": 0.95}, {"x": 0.7}]
    assert select_template(space, samples) == 0
    assert select_template(space, samples, coverage=[2, 4, 3, 4]) == 3  # of the two with most kinds, nearest the mean
    with pytest.raises(ValueError, match="one value per sample"):
        select_template(space, samples, coverage=[1])


def test_keys_not_understood_are_named_and_a_near_misspelling_is_read_as_its_key():
    """Every key outside the spec's vocabulary is reported by name with the closest known key; one
    within two edits of exactly one known key the entry lacks is read as that key, saying so."""
    from proctex.params import closest_key, edit_distance, read_params_spec

    assert edit_distance("or_dependcies", "or_dependencies") == 2 and edit_distance("rnage", "range") == 2
    assert edit_distance("", "abc") == 3 and edit_distance("abc", "abc") == 0 and edit_distance("a" * 300, "b", limit=4) == 5
    assert closest_key("tpye", ["type", "range"]) == ("type", 2)
    spec = read_params_spec(
        {
            "class_name": "bed",
            "clas_name": "x",
            "params": {
                "Width": {"type": "float", "range": [0.5, 2.0], "or_dependcies": [["Has Back", True]], "colour": "red"},
                "Has Back": {"type": "bool"},
                "Depth": {"tpye": "float", "range": [1.0, 2.0]},
            },
        }
    )
    notes = "\n".join(spec.notes)
    assert spec.conditions["Width"] == {"when": [["Has Back", True]]} and spec.bounds["Depth"] == [1.0, 2.0]
    assert "read key 'or_dependcies' as 'or_dependencies'" in notes and "read key 'tpye' as 'type'" in notes
    assert "key 'colour' was not understood and is ignored (the closest known key is" in notes
    # "clas_name" is one edit from "class_name", which the spec holds already: reported, not read
    assert "key 'clas_name' was not understood" in notes
    # a flat spec's keys are input names: nothing to report
    assert read_params_spec({"Width": [0.5, 2.0]}).notes == ()
