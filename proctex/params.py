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
    """

    name: str
    kind: str
    default: Any
    low: float | None = None
    high: float | None = None
    options: tuple = ()
    unit: str = ""
    description: str = ""

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
            raise ValueError(
                f"parameter {self.name!r}: expected a value in [{self.low}, {self.high}]"
                f"{' ' + self.unit if self.unit else ''}, got {value!r}"
            )
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
        return d

    @staticmethod
    def from_dict(d: Mapping[str, Any]) -> "ParamSpec":
        if not isinstance(d, Mapping):
            raise ValueError(f"a parameter spec must be a mapping, got {type(d).__name__}")
        unknown = set(d) - {"name", "kind", "default", "low", "high", "options", "unit", "description"}
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
        )


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
        p = self.validate(params)
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
        return [{s.name: s.from_unit(u[i, j]) for j, s in enumerate(self.specs)} for i in range(n)]

    def to_list(self) -> list[dict]:
        return [s.to_dict() for s in self.specs]

    @staticmethod
    def from_list(items: Iterable[Mapping[str, Any]]) -> "ParamSpace":
        return ParamSpace(tuple(ParamSpec.from_dict(d) for d in items))


def select_template(space: ParamSpace, samples: Sequence[Mapping[str, Any]]) -> int:
    """Index of the sample nearest the mean parameter vector (each parameter scaled by its range).

    Ties go to the lowest index, so the choice is deterministic.
    """
    if len(samples) == 0:
        raise ValueError("cannot select a template from zero samples")
    feats = np.stack([space.feature(p) for p in samples]) if len(space) else np.zeros((len(samples), 0))
    mean = feats.mean(axis=0)
    dist = np.linalg.norm(feats - mean, axis=1)
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
