"""The build config (:class:`BuildConfig`): what a family is made of and how it is built; read from
JSON or TOML files, checked, and stored resolved in ``family.json``."""

from __future__ import annotations

import json
import os
import tomllib
from dataclasses import dataclass, field, fields
from pathlib import Path
from typing import Any

@dataclass
class BuildConfig:
    """Everything a build needs. Exactly one of ``model`` (built-in name), ``folder`` (samples on
    disk) or ``generator`` (a generator config file) names the family.

    Attributes:
        prompt, group_prompts: what to paint (group prompts keyed by group label or index).
        seed: the family seed; sample ``i`` and pair ``(i, g)`` derive theirs from it.
        n_train, n_test, sampling: how many shapes to sample from a model ("lhs" or "random").
        params: bounds overrides ``{"name": [low, high]}`` for continuous / integer parameters.
        texture_size, painter: template texturing: "surface" (the solid surface painter), "views"
            (the multi-view loop with the offline view painter) or "diffusion" (the multi-view loop
            with a local diffusers model in ``model_dir``).
        views, view_size, paint_hidden, fill: the multi-view loop (cameras on the orbit, their size,
            whether parts hidden from the orbit get views of their own, and how unseen texels are
            filled: "patchmatch" or "surface"). Texels no view saw stay out of the template's
            "already painted" mask, so transfer can detect dis-occlusion.
        model_dir, device, steps: the diffusion painter.
        up: the shapes' up axis ("auto": y for OBJ/glTF files, z otherwise).
        corr_points, cage_level, cage_iterations: the cage solver per pair; cage: other
            :class:`proctex.cage.CageConfig` settings (e.g. ``{"w_rest": 0.3}``).
        train: ProcCorrNet settings (``proctex.corrnet.CorrNetConfig`` fields).
        tessellation: built-in models only: "adaptive" (segments follow each part's size, so most
            parameter changes change a part's connectivity, as real procedural exports do: the
            networks are exercised) or "fixed" (every part keeps its connectivity: the
            same-connectivity shortcut textures it). Stores built before the setting existed are
            "fixed".
        truth: what the evaluation takes as ground truth (:data:`proctex.fidelity.TRUTHS`): "auto"
            (canonical coordinates for built-in models, none otherwise), "vertex-index" (the
            samples share one vertex order: vertex *i* is the same point in every sample; checked
            when evaluating), "canonical" or "none" (the cage solver tracks points; no GT error).
    """

    model: str | None = None
    folder: str | None = None
    generator: str | None = None
    prompt: str = "oak"
    group_prompts: dict[str, str] = field(default_factory=dict)
    seed: int = 0
    n_train: int = 24
    n_test: int = 8
    sampling: str = "lhs"
    params: dict[str, list[float]] = field(default_factory=dict)
    texture_size: int = 512
    painter: str = "surface"
    views: int = 11
    view_size: int = 512
    paint_hidden: bool = True
    fill: str = "patchmatch"
    model_dir: str | None = None
    device: str = "cpu"
    steps: int = 20
    up: str = "auto"
    corr_points: int = 2000
    cage_level: int = 1
    cage_iterations: int = 300
    train: dict[str, Any] = field(default_factory=dict)
    cage: dict[str, Any] = field(default_factory=dict)
    tessellation: str = "adaptive"
    truth: str = "auto"

    def validate(self) -> "BuildConfig":
        named = [x for x in (self.model, self.folder, self.generator) if x]
        if len(named) != 1:
            raise ValueError("name exactly one of model, folder or generator")
        if self.model:
            from proctex.models import get_model

            get_model(self.model)  # unknown names raise ValueError listing the models
        if self.folder and not os.path.isdir(self.folder):
            raise ValueError(f"folder {self.folder!r} not found")
        if self.generator and not os.path.isfile(self.generator):
            raise ValueError(f"generator config {self.generator!r} not found")
        if not isinstance(self.prompt, str):
            raise ValueError("prompt must be a string")
        if self.n_train < 2 or self.n_test < 0:
            raise ValueError(f"need n_train >= 2 and n_test >= 0, got {self.n_train}, {self.n_test}")
        if self.sampling not in ("lhs", "random"):
            raise ValueError(f"sampling must be lhs or random, got {self.sampling!r}")
        if self.texture_size < 16:
            raise ValueError(f"texture_size must be >= 16, got {self.texture_size}")
        if self.painter not in ("surface", "views", "diffusion"):
            raise ValueError(f"painter must be surface, views or diffusion, got {self.painter!r}")
        if self.views < 3 or self.view_size < 16 or self.steps < 1:
            raise ValueError("views must be >= 3, view_size >= 16 and steps >= 1")
        if self.fill not in ("patchmatch", "surface"):
            raise ValueError(f"fill must be patchmatch or surface, got {self.fill!r}")
        if self.painter == "diffusion" and not (self.model_dir and os.path.isdir(self.model_dir)):
            raise ValueError(f"painter 'diffusion' needs model_dir, a local diffusers model folder (got {self.model_dir!r})")
        if self.up not in ("auto", "x", "y", "z"):
            raise ValueError(f"up must be auto, x, y or z, got {self.up!r}")
        if self.tessellation not in ("adaptive", "fixed"):
            raise ValueError(f"tessellation must be adaptive or fixed, got {self.tessellation!r}")
        from .fidelity import TRUTHS

        if self.truth not in TRUTHS:
            raise ValueError(f"truth must be one of {', '.join(TRUTHS)}, got {self.truth!r}")
        if self.truth == "canonical" and not self.model:
            raise ValueError("truth 'canonical' needs a built-in model (canonical coordinates)")
        if self.corr_points < 100 or self.cage_iterations < 1 or not 0 <= self.cage_level <= 4:
            raise ValueError("corr_points >= 100, cage_iterations >= 1 and cage_level in [0, 4] required")
        self.cage_config()
        return self

    def cage_config(self):
        """The cage solver's settings of this build (:class:`proctex.cage.CageConfig`):
        ``cage_level``, ``cage_iterations`` and the ``cage`` overrides; ``ValueError`` on bad ones."""
        from dataclasses import fields as dc_fields

        from proctex.correspond.cage import CageConfig

        if not isinstance(self.cage, dict):
            raise ValueError(f"cage must be an object of cage solver settings, got {type(self.cage).__name__}")
        clash = sorted(set(self.cage) & {"level", "iterations"})
        if clash:
            raise ValueError(f"set the cage's {', '.join(clash)} with cage_level / cage_iterations, not in cage")
        known = {f.name for f in dc_fields(CageConfig)}
        unknown = sorted(set(self.cage) - known)
        if unknown:
            raise ValueError(f"unknown cage settings {unknown}; known: {sorted(known - {'level', 'iterations'})}")
        try:
            return CageConfig(level=self.cage_level, iterations=self.cage_iterations, **self.cage).validate()
        except TypeError as exc:
            raise ValueError(f"bad cage settings: {exc}") from exc

    def procedural_model(self):
        """The family's procedural model (a built-in one, or the user's generator), its parameter
        space restricted to ``params``' bounds."""
        from proctex.models import get_model
        from .sources import load_generator

        model = load_generator(self.generator) if self.generator else get_model(self.model, tessellation=self.tessellation)
        if self.params:
            model.space = _restricted(model.space, self.params)
        return model

    def up_axis(self) -> str:
        """The shapes' up axis: ``up``, or for "auto" y for files (OBJ / glTF) and z for models."""
        if self.up != "auto":
            return self.up
        return "y" if self.folder else "z"

    def corrnet_config(self):
        """The ProcCorrNet settings of the build (``train`` over the defaults, the family seed)."""
        from proctex.correspond.corrnet import CorrNetConfig

        return CorrNetConfig.from_dict({**self.train, "seed": self.train.get("seed", self.seed)})

    @staticmethod
    def from_dict(data: dict[str, Any]) -> "BuildConfig":
        known = {f.name for f in fields(BuildConfig)}
        unknown = sorted(set(data) - known)
        if unknown:
            raise ValueError(f"unknown config keys: {', '.join(unknown)} (known: {', '.join(sorted(known))})")
        return BuildConfig(**data).validate()

    @staticmethod
    def read_settings(path: str | os.PathLike) -> dict[str, Any]:
        """The settings of a JSON or TOML config file, unvalidated (relative paths made relative to
        the file); a missing or unparsable file is a ``ValueError``."""
        p = Path(path)
        if not p.is_file():
            raise ValueError(f"{path}: config file not found")
        try:
            data = tomllib.loads(p.read_text()) if p.suffix == ".toml" else json.loads(p.read_text())
        except (json.JSONDecodeError, tomllib.TOMLDecodeError) as exc:
            raise ValueError(f"{path}: cannot parse config ({exc})") from exc
        if not isinstance(data, dict):
            raise ValueError(f"{path}: a config must be an object of settings")
        for key in ("folder", "generator", "model_dir"):
            if data.get(key) and not os.path.isabs(data[key]):
                data[key] = str((p.parent / data[key]).resolve())
        return data

    @staticmethod
    def from_file(path: str | os.PathLike) -> "BuildConfig":
        """Read a JSON or TOML config (keys as the attributes; relative paths are relative to the file)."""
        return BuildConfig.from_dict(BuildConfig.read_settings(path))


def _restricted(space, bounds: dict[str, list[float]]):
    from proctex.params import ParamSpace, ParamSpec

    specs = []
    for s in space.specs:
        if s.name in bounds:
            lo, hi = bounds[s.name]
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


#: Settings whose default changed after stores without them were written: their value then.
LEGACY_SETTINGS = {"tessellation": "fixed",
                   # the cage solver before the box pre-alignment, face normals, rest term and best iterate
                   "cage": {"prealign": "icp", "normal_target": "vertex", "keep_best": False, "w_rest": 0.0}}


def with_legacy(settings: dict[str, Any]) -> dict[str, Any]:
    """A stored config's settings with the values older stores were built with filled in."""
    return {**LEGACY_SETTINGS, **settings}


