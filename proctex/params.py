"""Parameter specifications, validation, sampling and template selection.

A procedural model is described by an ordered list of :class:`ParamSpec`. Parameters are one of
three kinds:

- ``continuous``: a float in ``[low, high]``;
- ``integer``: an int in ``[low, high]`` (both inclusive);
- ``choice``: one of a finite tuple of options (strings, numbers or booleans).

Every random choice takes a seed or a :class:`numpy.random.Generator`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any, Iterable, Mapping, Sequence

import numpy as np

KINDS = ("continuous", "integer", "choice")
#: Conditions per parameter (``when`` / ``unless``), and the bounds on a parameter spec file.
MAX_CONDITIONS = 32
MAX_SPEC_PARAMS = 1000
MAX_SPEC_DEPTH = 16
MAX_SPEC_BYTES = 1 << 20


@dataclass(frozen=True)
class ParamSpec:
    """One parameter of a procedural model.

    Attributes:
        name: unique name within the model.
        kind: ``"continuous"``, ``"integer"`` or ``"choice"``.
        low, high: inclusive bounds (continuous and integer kinds).
        default: default value; must be valid for the spec.
        options: allowed values (choice kind).
        unit: free-text unit ("m", "count", "deg", ...), informational.
        description: one line for help texts and the studio.
        when: ``((name, value), ...)``: the parameter matters only while every named parameter has
            that value (a model's input that only acts under another: "Middle Offset" with "Legs
            Type" 0 and "Has Middle Support"); :meth:`ParamSpace.settle` holds it at its default
            otherwise.
        unless: ``((name, value), ...)``: it matters only while none of them holds.
    """

    name: str
    kind: str
    default: Any
    low: float | None = None
    high: float | None = None
    options: tuple = ()
    unit: str = ""
    description: str = ""
    when: tuple = ()
    unless: tuple = ()

    def __post_init__(self) -> None:
        if not isinstance(self.name, str) or not self.name:
            raise ValueError(f"parameter name must be a non-empty string, got {self.name!r}")
        if self.kind not in KINDS:
            raise ValueError(f"parameter {self.name!r}: kind must be one of {KINDS}, got {self.kind!r}")
        if self.kind in ("continuous", "integer"):
            if self.low is None or self.high is None:
                raise ValueError(f"parameter {self.name!r}: {self.kind} needs low and high bounds")
            if not (math.isfinite(self.low) and math.isfinite(self.high)):
                raise ValueError(f"parameter {self.name!r}: bounds must be finite, got [{self.low}, {self.high}]")
            if self.low > self.high:
                raise ValueError(f"parameter {self.name!r}: low {self.low} > high {self.high}")
            if self.kind == "integer" and (int(self.low) != self.low or int(self.high) != self.high):
                raise ValueError(f"parameter {self.name!r}: integer bounds must be whole numbers")
            if self.options:
                raise ValueError(f"parameter {self.name!r}: options are only for choice parameters")
        else:
            if len(self.options) == 0:
                raise ValueError(f"parameter {self.name!r}: choice needs at least one option")
            object.__setattr__(self, "options", tuple(self.options))
            if len(set(map(repr, self.options))) != len(self.options):
                raise ValueError(f"parameter {self.name!r}: options must be distinct, got {self.options}")
        for key in ("when", "unless"):
            conds = getattr(self, key)
            if not isinstance(conds, (tuple, list)) or not all(isinstance(c, (tuple, list)) and len(c) == 2 and isinstance(c[0], str) and c[0] for c in conds):
                raise ValueError(f"parameter {self.name!r}: {key} must be a list of [name, value] pairs, got {conds!r}")
            if len(conds) > MAX_CONDITIONS:
                raise ValueError(f"parameter {self.name!r}: at most {MAX_CONDITIONS} conditions in {key}")
            object.__setattr__(self, key, tuple((str(n), v) for n, v in conds))
        # Validate the default with the same rules as user values.
        object.__setattr__(self, "default", self.validate(self.default))

    # ------------------------------------------------------------------ validation
    def validate(self, value: Any) -> Any:
        """Return ``value`` coerced to the spec's type, or raise ``ValueError``."""
        if self.kind == "choice":
            for opt in self.options:
                # True == 1 in Python; a bool only matches a bool option.
                if value == opt and isinstance(value, bool) == isinstance(opt, bool):
                    return opt
            raise ValueError(f"parameter {self.name!r}: expected one of {list(self.options)}, got {value!r}")
        if isinstance(value, bool) or not isinstance(value, (int, float, np.integer, np.floating)):
            raise ValueError(f"parameter {self.name!r}: expected a number, got {value!r}")
        v = float(value)
        if not math.isfinite(v):
            raise ValueError(f"parameter {self.name!r}: expected a finite number, got {value!r}")
        if self.kind == "integer":
            if v != round(v):
                raise ValueError(f"parameter {self.name!r}: expected an integer, got {value!r}")
            v = int(round(v))
        # A small relative tolerance so values that round-tripped through JSON/text still pass.
        tol = 1e-9 * max(1.0, abs(self.low), abs(self.high))
        if v < self.low - tol or v > self.high + tol:
            raise ValueError(f"parameter {self.name!r}: expected a value in [{self.low}, {self.high}]{' ' + self.unit if self.unit else ''}, got {value!r}")
        if self.kind == "integer":
            return int(v)
        return float(min(max(v, self.low), self.high))

    # ------------------------------------------------------------------ unit cube maps
    def from_unit(self, u: float) -> Any:
        """Map ``u`` in [0, 1) to a value; uniform ``u`` gives a uniform value over the spec."""
        u = float(min(max(u, 0.0), np.nextafter(1.0, 0.0)))
        if self.kind == "continuous":
            return float(self.low + u * (self.high - self.low))
        if self.kind == "integer":
            n = int(self.high - self.low) + 1
            return int(self.low) + min(int(u * n), n - 1)
        return self.options[min(int(u * len(self.options)), len(self.options) - 1)]

    def normalise(self, value: Any) -> np.ndarray:
        """Feature vector of a value with each parameter scaled by its range.

        Continuous and integer parameters give one number in [0, 1]; a choice gives a one-hot
        vector (distance 1 between different options, like the ends of a range).
        """
        v = self.validate(value)
        if self.kind == "choice":
            out = np.zeros(len(self.options))
            out[self.options.index(v)] = 1.0 / math.sqrt(2.0)
            return out
        span = self.high - self.low
        return np.array([0.0 if span == 0 else (v - self.low) / span])

    def to_dict(self) -> dict:
        d: dict[str, Any] = {"name": self.name, "kind": self.kind, "default": self.default}
        if self.kind == "choice":
            d["options"] = list(self.options)
        else:
            d["low"], d["high"] = self.low, self.high
        if self.unit:
            d["unit"] = self.unit
        if self.description:
            d["description"] = self.description
        for key in ("when", "unless"):
            if getattr(self, key):
                d[key] = [[n, v] for n, v in getattr(self, key)]
        return d

    @staticmethod
    def from_dict(d: Mapping[str, Any]) -> "ParamSpec":
        if not isinstance(d, Mapping):
            raise ValueError(f"a parameter spec must be a mapping, got {type(d).__name__}")
        unknown = set(d) - {"name", "kind", "default", "low", "high", "options", "unit", "description", "when", "unless"}
        if unknown:
            raise ValueError(f"parameter spec {d.get('name')!r}: unknown keys {sorted(unknown)}")
        for key in ("name", "kind", "default"):
            if key not in d:
                raise ValueError(f"parameter spec {d.get('name')!r}: missing {key!r}")
        return ParamSpec(
            name=d["name"],
            kind=d["kind"],
            default=d["default"],
            low=d.get("low"),
            high=d.get("high"),
            options=tuple(d.get("options", ())),
            unit=d.get("unit", ""),
            description=d.get("description", ""),
            when=tuple(tuple(c) if isinstance(c, list) else c for c in d.get("when", ())),
            unless=tuple(tuple(c) if isinstance(c, list) else c for c in d.get("unless", ())),
        )


def check_integer(name: str, value: Any, lo: int, hi: int) -> None:
    """``ValueError`` unless ``value`` is an int (not a bool, not a float) in [lo, hi]."""
    if isinstance(value, bool) or not isinstance(value, int) or not lo <= value <= hi:
        raise ValueError(f"{name} must be an integer in [{lo}, {hi}], got {str(value)[:40]}")


def continuous(name: str, low: float, high: float, default: float, unit: str = "", description: str = "") -> ParamSpec:
    return ParamSpec(name, "continuous", default, low=low, high=high, unit=unit, description=description)


def integer(name: str, low: int, high: int, default: int, unit: str = "count", description: str = "") -> ParamSpec:
    return ParamSpec(name, "integer", default, low=low, high=high, unit=unit, description=description)


def choice(name: str, options: Sequence, default: Any, description: str = "") -> ParamSpec:
    return ParamSpec(name, "choice", default, options=tuple(options), description=description)


@dataclass(frozen=True)
class ParamSpace:
    """An ordered set of parameter specs with validation, sampling and normalisation."""

    specs: tuple[ParamSpec, ...] = field(default_factory=tuple)

    def __post_init__(self) -> None:
        object.__setattr__(self, "specs", tuple(self.specs))
        names = [s.name for s in self.specs]
        dup = {n for n in names if names.count(n) > 1}
        if dup:
            raise ValueError(f"duplicate parameter names: {sorted(dup)}")
        for spec in self.specs:
            for other, value in spec.when + spec.unless:
                if other == spec.name or other not in names:
                    raise ValueError(f"parameter {spec.name!r}: its condition names {other!r}, {'itself' if other == spec.name else 'which is not a parameter'}")
                try:
                    self[other].validate(value)
                except ValueError as exc:
                    raise ValueError(f"parameter {spec.name!r}: condition on {other!r}: {exc}") from None

    def active(self, params: Mapping[str, Any]) -> list[str]:
        """The parameters that matter at ``params`` (validated, defaults filled): those whose
        conditions hold, where a parameter that does not matter counts at its default (so
        conditions chain: "Middle Offset" needs "Has Middle Support", which needs "Legs Type" 0)."""
        return [n for n, on in self._activity(self.validate(params)).items() if on]

    def _activity(self, p: dict[str, Any]) -> dict[str, bool]:
        on = {s.name: True for s in self.specs}
        for _ in range(len(self.specs) + 1):
            cur = {n: (p[n] if on[n] else self[n].default) for n in p}
            new = {s.name: all(cur[n] == v for n, v in s.when) and not any(cur[n] == v for n, v in s.unless) for s in self.specs}
            if new == on:
                break
            on = new
        return on

    def settle(self, params: Mapping[str, Any]) -> dict[str, Any]:
        """``params`` (validated, defaults filled) with every parameter that does not matter
        (:meth:`active`) at its default: two settings that differ only there are the same setting."""
        p = self.validate(params)
        if not any(s.when or s.unless for s in self.specs):
            return p
        on = self._activity(p)
        return {n: (v if on[n] else self[n].default) for n, v in p.items()}

    @property
    def names(self) -> list[str]:
        return [s.name for s in self.specs]

    def __len__(self) -> int:
        return len(self.specs)

    def __getitem__(self, name: str) -> ParamSpec:
        for s in self.specs:
            if s.name == name:
                return s
        raise KeyError(name)

    def defaults(self) -> dict[str, Any]:
        return {s.name: s.default for s in self.specs}

    def validate(self, params: Mapping[str, Any] | None, fill_defaults: bool = True) -> dict[str, Any]:
        """Validate a parameter mapping; unknown names are an error, missing ones take defaults.

        Returns a new dict in spec order.
        """
        if params is None:
            params = {}
        if not isinstance(params, Mapping):
            raise ValueError(f"parameters must be a mapping of name to value, got {type(params).__name__}")
        unknown = set(params) - set(self.names)
        if unknown:
            raise ValueError(f"unknown parameters {sorted(unknown)}; expected a subset of {self.names}")
        out: dict[str, Any] = {}
        for s in self.specs:
            if s.name in params:
                out[s.name] = s.validate(params[s.name])
            elif fill_defaults:
                out[s.name] = s.default
            else:
                raise ValueError(f"missing parameter {s.name!r}")
        return out

    def feature(self, params: Mapping[str, Any]) -> np.ndarray:
        """(d,) float64 feature vector: each parameter scaled by its range (choices one-hot)."""
        p = self.settle(params)
        if not self.specs:
            return np.zeros(0)
        return np.concatenate([s.normalise(p[s.name]) for s in self.specs])

    def sample(self, n: int, seed: int | np.random.Generator | None = 0, method: str = "random") -> list[dict[str, Any]]:
        """Draw ``n`` parameter settings within bounds.

        Args:
            n: number of samples (>= 1).
            seed: int seed or Generator (required for reproducibility; ``None`` is fresh entropy).
            method: ``"random"`` (independent uniform) or ``"lhs"`` (Latin hypercube: every
                parameter's range is cut into ``n`` strata and each stratum is used once).
        """
        if not isinstance(n, (int, np.integer)) or isinstance(n, bool) or n < 1:
            raise ValueError(f"n must be a positive integer, got {n!r}")
        rng = seed if isinstance(seed, np.random.Generator) else np.random.default_rng(seed)
        d = len(self.specs)
        if method == "random":
            u = rng.random((n, d))
        elif method == "lhs":
            # Latin hypercube: per dimension, a random permutation of the strata plus jitter.
            u = np.empty((n, d))
            for j in range(d):
                u[:, j] = (rng.permutation(n) + rng.random(n)) / n
        else:
            raise ValueError(f"sampling method must be 'random' or 'lhs', got {method!r}")
        drawn = [{s.name: s.from_unit(u[i, j]) for j, s in enumerate(self.specs)} for i in range(n)]
        return [self.settle(p) for p in drawn] if any(s.when or s.unless for s in self.specs) else drawn

    def to_list(self) -> list[dict]:
        return [s.to_dict() for s in self.specs]

    @staticmethod
    def from_list(items: Iterable[Mapping[str, Any]]) -> "ParamSpace":
        return ParamSpace(tuple(ParamSpec.from_dict(d) for d in items))


def select_template(space: ParamSpace, samples: Sequence[Mapping[str, Any]], coverage: Sequence[float] | None = None) -> int:
    """Index of the sample nearest the mean parameter vector (each parameter scaled by its range),
    among the samples of the highest ``coverage`` when given (e.g. how many kinds of part each
    has: a family with optional parts gets a template that carries them).

    Ties go to the lowest index, so the choice is deterministic.
    """
    if len(samples) == 0:
        raise ValueError("cannot select a template from zero samples")
    if coverage is not None and len(coverage) != len(samples):
        raise ValueError(f"coverage needs one value per sample, got {len(coverage)} for {len(samples)}")
    feats = np.stack([space.feature(p) for p in samples]) if len(space) else np.zeros((len(samples), 0))
    mean = feats.mean(axis=0)
    dist = np.linalg.norm(feats - mean, axis=1)
    if coverage is not None:
        cov = np.asarray(coverage, dtype=np.float64)
        dist = np.where(cov >= cov.max(), dist, np.inf)
    return int(np.argmin(dist))


def infer_space(samples: Sequence[Mapping[str, Any]]) -> ParamSpace:
    """Infer continuous/integer/choice specs from observed parameter values (e.g. a folder of samples).

    Bounds are the observed min and max; the default is the median (numbers) or the most common
    option (anything else).
    """
    if len(samples) == 0:
        raise ValueError("cannot infer parameter specs from zero samples")
    names: list[str] = []
    for p in samples:
        for k in p:
            if k not in names:
                names.append(k)
    specs = []
    for name in names:
        values = [p[name] for p in samples if name in p]
        if len(values) != len(samples):
            raise ValueError(f"parameter {name!r} is missing from {len(samples) - len(values)} samples")
        numeric = all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in values)
        if numeric and all(math.isfinite(float(v)) for v in values):
            arr = np.array(values, dtype=float)
            if all(isinstance(v, int) for v in values):
                specs.append(integer(name, int(arr.min()), int(arr.max()), int(np.median(arr).round())))
            else:
                med = float(np.median(arr))
                specs.append(continuous(name, float(arr.min()), float(arr.max()), med))
        else:
            opts: list = []
            for v in values:
                if v not in opts:
                    opts.append(v)
            most = max(opts, key=lambda o: sum(1 for v in values if v == o))
            specs.append(choice(name, opts, most))
    return ParamSpace(tuple(specs))


# ----------------------------------------------------------------------------- parameter spec files
@dataclass(frozen=True)
class ParamsSpec:
    """The usable ranges and conditions of a model's inputs, as a spec file beside a ``.blend`` gives
    them (:func:`read_params_spec`).

    Attributes:
        bounds: ``{name: [low, high]}`` for float and int inputs.
        kinds: ``{name: "float" | "int" | "bool" | "range"}`` (``"range"``: a flat file's entry).
        conditions: ``{name: {"when": [[other, value], ...], "unless": [...]}}`` for inputs that
            matter only under others (:class:`ParamSpec` ``when`` / ``unless``).
    """

    bounds: dict[str, list[float]]
    kinds: dict[str, str]
    conditions: dict[str, dict[str, list]]
    notes: tuple[str, ...] = ()


#: The keys a nested spec file's top level and entries may hold.
SPEC_TOP_KEYS = ("params", "class_name", "blend_path")
SPEC_ENTRY_KEYS = ("type", "range", "params", "or_dependencies", "not_dependencies")
NEAR_KEY = 2  # an unknown key within this edit distance of exactly one known key is read as that key


def edit_distance(a: str, b: str, limit: int = 64) -> int:
    """Levenshtein distance between ``a`` and ``b`` (insertions, deletions, substitutions), capped at
    ``limit + 1`` (strings longer than 256 characters compare by their first 256)."""
    a, b = str(a)[:256], str(b)[:256]
    if abs(len(a) - len(b)) > limit:
        return limit + 1
    prev = list(range(len(b) + 1))
    for i, ca in enumerate(a, 1):
        cur = [i]
        for j, cb in enumerate(b, 1):
            cur.append(min(prev[j] + 1, cur[j - 1] + 1, prev[j - 1] + (ca != cb)))
        if min(cur) > limit:
            return limit + 1
        prev = cur
    return min(prev[-1], limit + 1)


def closest_key(key: str, known: Sequence[str]) -> tuple[str, int]:
    """The known key nearest ``key`` by :func:`edit_distance` (ties: the first) and its distance."""
    best = min(known, key=lambda k: edit_distance(key, k))
    return best, edit_distance(key, best)


def _read_keys(entry: Mapping[str, Any], known: Sequence[str], where: str, notes: list[str]) -> dict[str, Any]:
    """``entry`` with every key it holds that is not in ``known`` reported in ``notes`` (by name,
    with the closest known key) and, when that key is within :data:`NEAR_KEY` edits of exactly one
    known key the entry does not hold already, read as that key."""
    out = {k: v for k, v in entry.items() if k in known}
    for key in entry:
        if key in known:
            continue
        name = str(key)[:80]
        near, d = closest_key(name, known)
        rivals = [k for k in known if k != near and edit_distance(name, k) == d]
        if d <= NEAR_KEY and not rivals and near not in entry and near not in out:
            out[near] = entry[key]
            notes.append(f"{where}: read key {name!r} as {near!r} (not a known key; {d} edit{'s' if d > 1 else ''} from it)")
        else:
            notes.append(f"{where}: key {name!r} was not understood and is ignored (the closest known key is {near!r})")
    return out


def _condition(item: Any, where: str) -> list:
    """``"Name"`` (a bool input that must be on) or ``["Name", value]`` as ``[name, value]``."""
    if isinstance(item, str) and item:
        return [item, True]
    if (
        isinstance(item, (list, tuple))
        and len(item) == 2
        and isinstance(item[0], str)
        and item[0]
        and isinstance(item[1], (bool, int, float, str))
        and not (isinstance(item[1], float) and not math.isfinite(item[1]))
    ):
        return [item[0], item[1]]
    raise ValueError(f"{where}: a dependency must be a name or [name, value], got {str(item)[:80]}")


def read_params_spec(spec: Any) -> ParamsSpec:
    """The ranges and conditions of a parameter spec: a path to a JSON file or its parsed content.

    Two forms are read:

    - nested (the PyTorchGeoNodes ``sp_<name>.json`` form): ``{"params": {name: entry}}`` where an
      entry is ``{"type": "nested", "params": {...}}`` (a group, any depth up to
      :data:`MAX_SPEC_DEPTH`) or ``{"type": "float" | "int" | "bool", "range": [low, high],
      "or_dependencies": [...], "not_dependencies": [...]}``. A dependency is an input name (a bool
      that must be on) or ``[name, value]``. The input matters only while every one of its
      ``or_dependencies`` holds (the data's own reading: "Middle Offset" only with "Legs Type" 0
      *and* "Has Middle Support") and none of its ``not_dependencies``;
    - flat: ``{name: [low, high]}``.

    ``class_name`` and ``blend_path`` are read and ignored; any other key is reported in
    :attr:`ParamsSpec.notes` by name with the closest known key, and read as that key when it is
    within :data:`NEAR_KEY` edits of exactly one (a misspelt ``or_dependcies``). ``ValueError`` for
    anything else: files over :data:`MAX_SPEC_BYTES`, more than :data:`MAX_SPEC_PARAMS` inputs,
    deeper nesting, unknown types, ranges that are not two finite numbers with low <= high, a
    dependency on an input the spec does not have.
    """
    import json
    from pathlib import Path

    where = "params spec"
    if isinstance(spec, (str, Path)):
        path = Path(spec)
        where = str(path)
        if not path.is_file():
            raise ValueError(f"{where}: params spec file not found")
        if path.stat().st_size > MAX_SPEC_BYTES:
            raise ValueError(f"{where}: params spec is larger than {MAX_SPEC_BYTES} bytes")
        try:
            spec = json.loads(path.read_text())
        except (json.JSONDecodeError, UnicodeDecodeError, RecursionError) as exc:
            raise ValueError(f"{where}: cannot parse ({type(exc).__name__}: {str(exc)[:200]})") from None
    if not isinstance(spec, Mapping) or not spec:
        raise ValueError(f"{where}: a params spec must be a non-empty object")
    bounds: dict[str, list[float]] = {}
    kinds: dict[str, str] = {}
    conditions: dict[str, dict[str, list]] = {}
    notes: list[str] = []

    def number_pair(value: Any, name: str, kind: str) -> list[float]:
        if not (isinstance(value, (list, tuple)) and len(value) == 2 and all(isinstance(x, (int, float)) and not isinstance(x, bool) and math.isfinite(x) for x in value)):
            raise ValueError(f"{where}: {name!r}: range must be two finite numbers, got {str(value)[:80]}")
        lo, hi = float(value[0]), float(value[1])
        if lo > hi:
            raise ValueError(f"{where}: {name!r}: range [{lo:g}, {hi:g}] has low > high")
        if kind == "int" and (lo != int(lo) or hi != int(hi)):
            raise ValueError(f"{where}: {name!r}: an int range must be whole numbers, got [{lo:g}, {hi:g}]")
        return [int(lo), int(hi)] if kind == "int" else [lo, hi]

    def add(name: Any) -> str:
        if not isinstance(name, str) or not name or len(name) > 256:
            raise ValueError(f"{where}: input names must be non-empty strings of at most 256 characters, got {str(name)[:80]!r}")
        if name in kinds:
            raise ValueError(f"{where}: input {name!r} appears twice")
        if len(kinds) >= MAX_SPEC_PARAMS:
            raise ValueError(f"{where}: more than {MAX_SPEC_PARAMS} inputs")
        return name

    def walk(params: Any, depth: int) -> None:
        if depth > MAX_SPEC_DEPTH:
            raise ValueError(f"{where}: nested deeper than {MAX_SPEC_DEPTH}")
        if not isinstance(params, Mapping):
            raise ValueError(f"{where}: 'params' must be an object of inputs")
        for name, entry in params.items():
            if not isinstance(entry, Mapping):
                raise ValueError(f"{where}: {str(name)[:80]!r}: an entry must be an object with a 'type'")
            if len(notes) < MAX_SPEC_PARAMS:
                entry = _read_keys(entry, SPEC_ENTRY_KEYS, f"{str(name)[:80]!r}", notes)
            kind = entry.get("type")
            if kind == "nested":
                walk(entry.get("params", {}), depth + 1)
                continue
            if kind not in ("float", "int", "bool"):
                raise ValueError(f"{where}: {str(name)[:80]!r}: type must be nested, float, int or bool, got {str(kind)[:40]!r}")
            name = add(name)
            kinds[name] = kind
            if kind != "bool":
                if "range" not in entry:
                    raise ValueError(f"{where}: {name!r}: a {kind} input needs a range")
                bounds[name] = number_pair(entry["range"], name, kind)
            cond = {}
            for key, out in (("or_dependencies", "when"), ("not_dependencies", "unless")):
                items = entry.get(key, [])
                if not isinstance(items, list) or len(items) > MAX_CONDITIONS:
                    raise ValueError(f"{where}: {name!r}: {key} must be a list of at most {MAX_CONDITIONS} dependencies")
                if items:
                    cond[out] = [_condition(i, f"{where}: {name!r}") for i in items]
            if cond:
                conditions[name] = cond

    nested = "params" in spec or any(isinstance(v, Mapping) for v in spec.values())
    if nested:
        spec = _read_keys(spec, SPEC_TOP_KEYS, "the spec", notes)
        if "params" not in spec:
            raise ValueError(f"{where}: a nested params spec needs 'params'")
        walk(spec["params"], 1)
    else:  # flat {name: [low, high]}
        for name, value in spec.items():
            name = add(name)
            kinds[name] = "range"
            bounds[name] = number_pair(value, name, "float")
    if not kinds:
        raise ValueError(f"{where}: the spec names no input")
    for name, cond in conditions.items():
        for other, _ in cond.get("when", []) + cond.get("unless", []):
            if other not in kinds:
                raise ValueError(f"{where}: {name!r} depends on {other!r}, which the spec does not have")
    return ParamsSpec(bounds, kinds, conditions, tuple(notes))


def with_conditions(space: ParamSpace, conditions: Mapping[str, Mapping[str, Any]]) -> ParamSpace:
    """``space`` with ``{name: {"when": [[other, value], ...], "unless": [...]}}`` attached to its
    parameters (:class:`ParamSpec`); conditions on parameters the space lacks (pinned, say) are
    dropped, a condition naming a missing parameter drops that one condition (the input it names is
    fixed, so it cannot switch)."""
    if not conditions:
        return space
    names = set(space.names)
    specs = []
    for s in space.specs:
        c = conditions.get(s.name)
        if not c:
            specs.append(s)
            continue
        d = s.to_dict()
        for key in ("when", "unless"):
            kept = [list(x) for x in c.get(key, []) if x[0] in names]
            if kept:
                d[key] = kept
        specs.append(ParamSpec.from_dict(d))
    return ParamSpace(tuple(specs))


def restricted_space(space, bounds: dict[str, list[float]]):
    """``space`` with the ranges of the named float / int parameters narrowed to ``bounds``
    ``{name: [low, high]}`` (within the old ones); ``ValueError`` for unknown names, choices or
    ranges outside."""
    if not isinstance(bounds, dict) or not all(isinstance(b, (list, tuple)) and len(b) == 2 for b in bounds.values()):
        raise ValueError('bounds must be an object {"name": [low, high]}')

    specs = []
    for s in space.specs:
        if s.name in bounds:
            lo, hi = bounds[s.name]
            if not all(isinstance(x, (int, float)) and not isinstance(x, bool) and math.isfinite(x) for x in (lo, hi)):
                raise ValueError(f"bounds for {s.name!r} must be two finite numbers, got {bounds[s.name]!r}")
            if s.kind not in ("continuous", "integer"):
                raise ValueError(f"bounds given for {s.name!r}, which is a {s.kind} parameter")
            if not (s.low <= lo <= hi <= s.high):
                raise ValueError(f"bounds for {s.name!r} must lie within [{s.low}, {s.high}], got [{lo}, {hi}]")
            d = s.to_dict()
            d.update(low=lo, high=hi, default=min(max(d["default"], lo), hi))
            specs.append(ParamSpec.from_dict(d))
        else:
            specs.append(s)
    unknown = set(bounds) - {s.name for s in space.specs}
    if unknown:
        raise ValueError(f"bounds for unknown parameters: {', '.join(sorted(unknown))}")
    return ParamSpace(tuple(specs))
