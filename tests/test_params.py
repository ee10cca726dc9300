import numpy as np
import pytest

from proctex.params import ParamSpace, ParamSpec, choice, continuous, infer_space, integer, select_template

SPACE = ParamSpace((continuous("width", 1.0, 3.0, 2.0, "m"), integer("legs", 3, 6, 4), choice("style", ["round", "square"], "round")))


def test_validate_fills_defaults_and_coerces():
    p = SPACE.validate({"width": 2, "legs": 5.0})
    assert p == {"width": 2.0, "legs": 5, "style": "round"}
    assert isinstance(p["legs"], int) and isinstance(p["width"], float)


@pytest.mark.parametrize(
    "params,match",
    [
        ({"width": 3.5}, r"in \[1.0, 3.0\] m"),
        ({"width": float("nan")}, "finite"),
        ({"width": "wide"}, "expected a number"),
        ({"width": True}, "expected a number"),
        ({"legs": 4.5}, "integer"),
        ({"legs": 7}, r"\[3, 6\]"),
        ({"style": "oval"}, "one of"),
        ({"colour": 1}, "unknown parameters"),
    ],
)
def test_validation_errors_are_clear(params, match):
    with pytest.raises(ValueError, match=match):
        SPACE.validate(params)


def test_bool_choice_does_not_accept_ints():
    spec = choice("arms", [True, False], True)
    assert spec.validate(False) is False
    with pytest.raises(ValueError):
        spec.validate(1)


@pytest.mark.parametrize(
    "kwargs,match",
    [
        (dict(name="a", kind="continuous", default=1, low=2, high=1), "low"),
        (dict(name="a", kind="continuous", default=5, low=0, high=1), r"\[0, 1\]"),
        (dict(name="a", kind="integer", default=1, low=0.5, high=3), "whole"),
        (dict(name="a", kind="choice", default="x", options=()), "at least one"),
        (dict(name="a", kind="fuzzy", default=1), "kind"),
        (dict(name="", kind="integer", default=1, low=0, high=2), "name"),
    ],
)
def test_bad_specs(kwargs, match):
    with pytest.raises(ValueError, match=match):
        ParamSpec(**kwargs)


def test_duplicate_names():
    with pytest.raises(ValueError, match="duplicate"):
        ParamSpace((integer("a", 0, 1, 0), integer("a", 0, 2, 0)))


def test_spec_dict_round_trip():
    assert ParamSpace.from_list(SPACE.to_list()) == SPACE


@pytest.mark.parametrize("method", ["random", "lhs"])
def test_sampling_is_seeded_and_in_bounds(method):
    a = SPACE.sample(200, seed=3, method=method)
    b = SPACE.sample(200, seed=3, method=method)
    assert a == b
    assert a != SPACE.sample(200, seed=4, method=method)
    for p in a:
        assert SPACE.validate(p) == p
    legs = [p["legs"] for p in a]
    assert set(legs) == {3, 4, 5, 6}
    assert {p["style"] for p in a} == {"round", "square"}


def test_lhs_stratifies_every_parameter():
    n = 50
    samples = SPACE.sample(n, seed=0, method="lhs")
    w = np.array([p["width"] for p in samples])
    strata = np.floor((w - 1.0) / 2.0 * n).astype(int)
    assert sorted(strata) == list(range(n))  # exactly one sample per stratum
    counts = np.bincount([p["legs"] - 3 for p in samples])
    assert counts.max() - counts.min() <= 1  # integers are balanced too


def test_template_is_nearest_mean():
    space = ParamSpace((continuous("a", 0, 10, 5), continuous("b", 0, 1, 0.5)))
    samples = [{"a": 0, "b": 0}, {"a": 10, "b": 1}, {"a": 6, "b": 0.4}, {"a": 4, "b": 0.9}]
    # Mean of scaled features = (0.5, 0.575); sample 2 is at (0.6, 0.4), sample 3 at (0.4, 0.9).
    assert select_template(space, samples) == 2
    # Scaling matters: unscaled, 'a' would dominate.
    samples2 = [{"a": 0, "b": 0}, {"a": 10, "b": 1}, {"a": 5.5, "b": 0.0}, {"a": 4.0, "b": 0.5}]
    assert select_template(space, samples2) == 3
    with pytest.raises(ValueError):
        select_template(space, [])


def test_infer_space_from_observed_values():
    samples = [{"w": 1.5, "n": 3, "s": "a"}, {"w": 2.5, "n": 5, "s": "b"}, {"w": 2.0, "n": 4, "s": "a"}]
    space = infer_space(samples)
    assert space["w"].kind == "continuous" and (space["w"].low, space["w"].high) == (1.5, 2.5)
    assert space["n"].kind == "integer" and space["n"].default == 4
    assert space["s"].kind == "choice" and space["s"].default == "a"
    with pytest.raises(ValueError, match="missing"):
        infer_space([{"w": 1.0}, {"x": 2.0}])
