"""The build config (:class:`BuildConfig`): what a family is made of and how it is built; read from
JSON or TOML files, checked, and stored resolved in ``family.json``."""

from __future__ import annotations

import json
import math
import os
import tomllib
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

from proctex.params import read_params_spec, with_conditions

#: Flat settings (the config format before sections, still read) -> (section, field).
FLAT_KEYS: dict[str, tuple[str, str]] = {
    **{k: ("source", k) for k in ("model", "folder", "generator", "blender", "n_train", "n_test", "sampling", "params", "tessellation", "up")},
    **{k: ("paint", k) for k in ("prompt", "group_prompts", "painter", "texture_size", "views", "view_size", "paint_hidden", "fill",
                                 "model_dir", "device", "steps", "occlusion")},
    "cage_level": ("cage", "level"), "cage_iterations": ("cage", "iterations"),
}
SECTIONS = ("source", "paint", "cage", "train")
TOP_LEVEL = ("seed", "corr_points", "truth")
MAX_SETTINGS = 256  # keys in one section (a config is small; a huge one is a mistake or an attack)


def _integer(name: str, value: Any, lo: int, hi: int) -> None:
    """``ValueError`` unless ``value`` is an int (not a bool, not a float) in [lo, hi]."""
    if isinstance(value, bool) or not isinstance(value, int) or not lo <= value <= hi:
        raise ValueError(f"{name} must be an integer in [{lo}, {hi}], got {str(value)[:40]}")


@dataclass
class SourceConfig:
    """Where the family's shapes come from. Exactly one of ``model`` (built-in name), ``folder``
    (samples on disk), ``generator`` (a generator config file) or ``blender`` (a ``.blend`` file's
    Geometry Nodes modifier: ``{"file", "object", "modifier": "GeometryNodes", "pins": {input: value}}``;
    ``params`` narrows its inputs' ranges, see :mod:`proctex.family.blender`).

    Attributes:
        n_train, n_test, sampling: how many shapes to sample from a model ("lhs" or "random").
        params: bounds overrides ``{"name": [low, high]}`` for continuous / integer parameters.
        conditions: ``{"name": {"when": [[other, value], ...], "unless": [...]}}``: inputs that
            matter only under others are sampled only where they do (:class:`proctex.params.ParamSpec`).
            A ``params_spec`` file (``[source] params_spec = "sp_chair.json"``, ``--params-spec``)
            fills ``params`` and ``conditions`` when the config is read
            (:func:`proctex.params.read_params_spec`); bounds given in ``params`` win.
        tessellation: built-in models only: "adaptive" (segments follow each part's size, so most
            parameter changes change a part's connectivity, as real procedural exports do: the
            networks are exercised) or "fixed" (every part keeps its connectivity: the
            same-connectivity shortcut textures it). Stores built before the setting existed are
            "fixed".
        up: the shapes' up axis ("auto": y for OBJ/glTF files, z otherwise).
    """

    model: str | None = None
    folder: str | None = None
    generator: str | None = None
    blender: dict[str, Any] | None = None
    n_train: int = 24
    n_test: int = 8
    sampling: str = "lhs"
    params: dict[str, list[float]] = field(default_factory=dict)
    tessellation: str = "adaptive"
    up: str = "auto"
    conditions: dict[str, dict[str, list]] = field(default_factory=dict)

    def validate(self) -> "SourceConfig":
        named = [x for x in (self.model, self.folder, self.generator, self.blender) if x]
        if len(named) != 1:
            raise ValueError("name exactly one of model, folder, generator or blender")
        if self.blender is not None:
            b = self.blender
            if not isinstance(b, dict) or not isinstance(b.get("file"), str) or not isinstance(b.get("object"), str):
                raise ValueError('blender must be {"file": "x.blend", "object": "Name", "modifier": "GeometryNodes", "pins": {...}, '
                                 '"parts": "part_id", "uv": "UVMap"}')
            unknown = sorted(set(b) - set(BLENDER_KEYS))
            if unknown:
                raise ValueError(f"unknown blender settings {unknown}; known: {', '.join(BLENDER_KEYS)}")
            for key in ("parts", "uv"):
                if b.get(key) is not None and (not isinstance(b[key], str) or not b[key] or len(b[key]) > 256):
                    raise ValueError(f"blender {key} must name an attribute of the evaluated mesh, got {b[key]!r}")
            if not os.path.isfile(b["file"]):
                raise ValueError(f"blender file {b['file']!r} not found")
            if not isinstance(b.get("pins", {}), dict) or not isinstance(b.get("modifier", "GeometryNodes"), str):
                raise ValueError("blender pins must be an object {input: value} and modifier a name")
        if self.model:
            from proctex.models import get_model

            get_model(self.model)  # unknown names raise ValueError listing the models
        if self.folder and not os.path.isdir(self.folder):
            raise ValueError(f"folder {self.folder!r} not found")
        if self.generator and not os.path.isfile(self.generator):
            raise ValueError(f"generator config {self.generator!r} not found")
        _integer("n_train", self.n_train, 2, 100_000)
        _integer("n_test", self.n_test, 0, 100_000)
        if self.sampling not in ("lhs", "random"):
            raise ValueError(f"sampling must be lhs or random, got {self.sampling!r}")
        if not isinstance(self.params, dict):
            raise ValueError("params must be an object of bounds {name: [low, high]}")
        if not isinstance(self.conditions, dict) or not all(
                isinstance(c, dict) and set(c) <= {"when", "unless"} for c in self.conditions.values()):
            raise ValueError('conditions must be an object {"name": {"when": [[other, value], ...], "unless": [...]}}')
        if self.up not in ("auto", "x", "y", "z"):
            raise ValueError(f"up must be auto, x, y or z, got {self.up!r}")
        if self.tessellation not in ("adaptive", "fixed"):
            raise ValueError(f"tessellation must be adaptive or fixed, got {self.tessellation!r}")
        return self


@dataclass
class PaintConfig:
    """How the template is painted.

    Attributes:
        prompt, group_prompts: what to paint (group prompts keyed by group label or index).
        texture_size, painter: template texturing: "surface" (the solid surface painter), "views"
            (the multi-view loop with the offline view painter) or "diffusion" (the multi-view loop
            with a local diffusers model in ``model_dir``).
        views, view_size, paint_hidden, fill: the multi-view loop (cameras on the orbit, their size,
            whether parts hidden from the orbit get views of their own, and how unseen texels are
            filled: "patchmatch" or "surface"). Texels no view saw stay out of the template's
            "already painted" mask, so transfer can detect dis-occlusion.
        model_dir, device, steps: the diffusion painter.
        occlusion: bake ambient occlusion into the PBR maps (the ORM's R channel).
    """

    prompt: str = "oak"
    group_prompts: dict[str, str] = field(default_factory=dict)
    painter: str = "surface"
    texture_size: int = 512
    views: int = 11
    view_size: int = 512
    paint_hidden: bool = True
    fill: str = "patchmatch"
    model_dir: str | None = None
    device: str = "cpu"
    steps: int = 20
    occlusion: bool = False

    def validate(self) -> "PaintConfig":
        if not isinstance(self.prompt, str):
            raise ValueError("prompt must be a string")
        if not isinstance(self.group_prompts, dict) or not all(isinstance(v, str) for v in self.group_prompts.values()):
            raise ValueError("group_prompts must be an object of prompts {group label or index: prompt}")
        _integer("texture_size", self.texture_size, 16, 8192)
        _integer("views", self.views, 3, 256)
        _integer("view_size", self.view_size, 16, 4096)
        _integer("steps", self.steps, 1, 1000)
        from proctex.texture.paint_loop import PAINTERS

        if self.painter not in PAINTERS:
            raise ValueError(f"painter must be one of {', '.join(PAINTERS)}, got {self.painter!r}")
        if self.views < 3 or self.view_size < 16 or self.steps < 1:
            raise ValueError("views must be >= 3, view_size >= 16 and steps >= 1")
        if self.fill not in ("patchmatch", "surface"):
            raise ValueError(f"fill must be patchmatch or surface, got {self.fill!r}")
        if not isinstance(self.occlusion, bool):
            raise ValueError(f"occlusion must be true or false, got {self.occlusion!r}")
        if self.painter == "diffusion" and not (self.model_dir and os.path.isdir(self.model_dir)):
            raise ValueError(f"painter 'diffusion' needs model_dir, a local diffusers model folder (got {self.model_dir!r})")
        return self


@dataclass
class BuildConfig:
    """Everything a build needs, in sections: ``source`` (:class:`SourceConfig`), ``paint``
    (:class:`PaintConfig`), ``cage`` (the cage solver per pair, :class:`proctex.correspond.cage.CageConfig`)
    and ``train`` (ProcCorrNet, :class:`proctex.correspond.corrnet.CorrNetConfig`; its seed is the
    family seed unless set), plus:

    Attributes:
        seed: the family seed; sample ``i`` and pair ``(i, g)`` derive theirs from it.
        corr_points: surface points per shape in each cage pair.
        truth: what the evaluation takes as ground truth (:data:`proctex.family.fidelity.TRUTHS`): "auto"
            (canonical coordinates for built-in models, none otherwise), "vertex-index" (the
            samples share one vertex order: vertex *i* is the same point in every sample; checked
            when evaluating), "canonical" or "none" (the cage solver tracks points; no GT error).

    Build one with :meth:`from_dict` (sections or the older flat keys, optionally over a preset of
    :data:`PRESETS`); :meth:`to_dict` is what ``family.json`` stores.
    """

    source: SourceConfig = field(default_factory=SourceConfig)
    paint: PaintConfig = field(default_factory=PaintConfig)
    cage: Any = None  # CageConfig, filled in by validate()
    train: Any = None  # CorrNetConfig, filled in by validate()
    seed: int = 0
    corr_points: int = 2000
    truth: str = "auto"

    def validate(self) -> "BuildConfig":
        from proctex.correspond.cage import CageConfig
        from proctex.correspond.corrnet import CorrNetConfig

        self.source.validate()
        self.paint.validate()
        if self.cage is None:
            self.cage = CageConfig()
        if self.train is None:
            self.train = CorrNetConfig(seed=self.seed)
        self.cage.validate()
        self.train.validate()
        from .fidelity import TRUTHS

        if self.truth not in TRUTHS:
            raise ValueError(f"truth must be one of {', '.join(TRUTHS)}, got {self.truth!r}")
        if self.truth == "canonical" and not self.source.model:
            raise ValueError("truth 'canonical' needs a built-in model (canonical coordinates)")
        _integer("seed", self.seed, 0, 2**32 - 1)
        _integer("corr_points", self.corr_points, 100, 1_000_000)
        return self

    def procedural_model(self):
        """The family's procedural model (a built-in one, or the user's generator), its parameter
        space restricted to the source's ``params`` bounds."""
        from proctex.models import get_model

        from .sources import load_generator

        src = self.source
        if src.blender:
            return blender_model(src.blender, src.params, src.conditions)
        model = load_generator(src.generator) if src.generator else get_model(src.model, tessellation=src.tessellation)
        if src.params:
            model.space = restricted_space(model.space, src.params)
        model.space = with_conditions(model.space, src.conditions)
        return model

    def up_axis(self) -> str:
        """The shapes' up axis: the source's ``up``, or for "auto" y for files (OBJ / glTF) and z for models."""
        if self.source.up != "auto":
            return self.source.up
        return "y" if self.source.folder else "z"

    def to_dict(self) -> dict[str, Any]:
        """The resolved config as JSON-able sections (what ``family.json`` stores)."""
        return json.loads(json.dumps({"seed": self.seed, "corr_points": self.corr_points, "truth": self.truth,
                                      "source": asdict(self.source), "paint": asdict(self.paint),
                                      "cage": asdict(self.cage), "train": self.train.to_dict()}))

    @staticmethod
    def from_dict(data: dict[str, Any], preset: str | None = None) -> "BuildConfig":
        """A checked config from sections (``{"source": {...}, "paint": {...}, "cage": {...},
        "train": {...}, "seed": ...}``) or the flat keys of older configs (:data:`FLAT_KEYS`, ``cage``
        and ``train`` as objects), over the preset ``preset`` of :data:`PRESETS` when given. Unknown
        keys, sections that are not objects and bad values are ``ValueError``."""
        from proctex.correspond.cage import CageConfig
        from proctex.correspond.corrnet import CorrNetConfig

        nested = sections(data)
        if preset is not None:
            if preset not in PRESETS:
                raise ValueError(f"unknown preset {preset!r}; presets: {', '.join(sorted(PRESETS))}")
            nested = merge(sections(PRESETS[preset]), nested)
        if "source" in nested:
            nested = {**nested, "source": resolve_params_spec(nested["source"])}
        top = {k: nested[k] for k in TOP_LEVEL if k in nested}
        train = dict(nested.get("train", {}))
        train.setdefault("seed", top.get("seed", 0))
        try:
            cage = CageConfig(**nested.get("cage", {}))
        except TypeError as exc:
            raise ValueError(f"bad cage settings: {exc}") from exc
        try:
            return BuildConfig(source=SourceConfig(**nested.get("source", {})), paint=PaintConfig(**nested.get("paint", {})), cage=cage,
                               train=CorrNetConfig.from_dict(train), **top).validate()
        except TypeError as exc:
            raise ValueError(f"bad config: {exc}") from exc

    @staticmethod
    def read_settings(path: str | os.PathLike) -> dict[str, Any]:
        """The settings of a JSON or TOML config file as sections (:func:`sections`), unvalidated,
        with relative paths made relative to the file; a missing or unparsable file is a ``ValueError``."""
        p = Path(path)
        if not p.is_file():
            raise ValueError(f"{path}: config file not found")
        try:
            data = tomllib.loads(p.read_text()) if p.suffix == ".toml" else json.loads(p.read_text())
        except (json.JSONDecodeError, tomllib.TOMLDecodeError, RecursionError, UnicodeDecodeError) as exc:
            raise ValueError(f"{path}: cannot parse config ({type(exc).__name__}: {str(exc)[:200]})") from exc
        data = sections(data, where=str(path))
        for section, key in (("source", "folder"), ("source", "generator"), ("source", "params_spec"), ("paint", "model_dir")):
            value = data.get(section, {}).get(key)
            if value and isinstance(value, str) and not os.path.isabs(value):
                data[section][key] = str((p.parent / value).resolve())
        blend = data.get("source", {}).get("blender")
        if isinstance(blend, dict) and isinstance(blend.get("file"), str) and not os.path.isabs(blend["file"]):
            data["source"]["blender"] = {**blend, "file": str((p.parent / blend["file"]).resolve())}
        return data

    @staticmethod
    def from_file(path: str | os.PathLike, preset: str | None = None) -> "BuildConfig":
        """Read a JSON or TOML config (sections or flat keys; relative paths are relative to the file)."""
        return BuildConfig.from_dict(BuildConfig.read_settings(path), preset=preset)


def sections(data: Any, where: str = "config") -> dict[str, Any]:
    """``data`` (sections, flat keys of older configs, or a mix) as sections: ``{"source": {...},
    "paint": {...}, "cage": {...}, "train": {...}}`` plus the top-level keys. Nothing is checked but
    the shape: unknown keys and sections that are not objects are ``ValueError``."""
    if not isinstance(data, dict):
        raise ValueError(f"{where}: a config must be an object of settings")
    out: dict[str, Any] = {}
    unknown = []
    for key, value in data.items():
        if key in SECTIONS:
            if not isinstance(value, dict):
                raise ValueError(f"{where}: {key} must be an object of settings, got {type(value).__name__}")
            if len(value) > MAX_SETTINGS:
                raise ValueError(f"{where}: {key} has {len(value)} settings (at most {MAX_SETTINGS})")
            if key == "cage" and set(value) & {"level", "iterations"} and ("cage_level" in data or "cage_iterations" in data):
                raise ValueError(f"{where}: set the cage's level and iterations once (cage_level / cage_iterations or cage)")
            out[key] = {**out.get(key, {}), **value}
        elif key in FLAT_KEYS:
            section, name = FLAT_KEYS[key]
            out.setdefault(section, {})[name] = value
        elif key in TOP_LEVEL:
            out[key] = value
        else:
            unknown.append(str(key)[:80])
    if unknown:
        known = sorted(set(SECTIONS) | set(TOP_LEVEL) | set(FLAT_KEYS))
        raise ValueError(f"{where}: unknown config keys: {', '.join(sorted(unknown)[:20])} (known: {', '.join(known)})")
    return out


def merge(base: dict[str, Any], over: dict[str, Any]) -> dict[str, Any]:
    """Sections ``over`` laid over ``base``: per section key by key, top-level keys replaced."""
    out = {k: (dict(v) if isinstance(v, dict) else v) for k, v in base.items()}
    for k, v in over.items():
        out[k] = {**out.get(k, {}), **v} if k in SECTIONS else v
    return out


#: One Blender process per .blend source per process (a Ray worker opens the file once).
_BLENDER_MODELS: dict[str, Any] = {}
#: The settings of a ``blender`` source: ``parts`` names an attribute whose values are the parts
#: (instead of the mesh's connectivity); ``uv`` names a UV map the graph makes, kept as the
#: template's UVs (each group's representative keeps its own layout).
BLENDER_KEYS = ("file", "object", "modifier", "pins", "parts", "uv")


def blender_model(settings: dict[str, Any], bounds: dict[str, list[float]] | None = None,
                  conditions: dict[str, dict[str, list]] | None = None):
    """The :class:`proctex.family.blender.BlenderModel` of a ``blender`` source, kept per process;
    ``conditions`` as :attr:`SourceConfig.conditions`."""
    from .blender import BlenderModel

    key = json.dumps({"settings": settings, "bounds": bounds or {}, "conditions": conditions or {}}, sort_keys=True)
    if key not in _BLENDER_MODELS:
        model = BlenderModel(settings["file"], settings["object"], settings.get("modifier", "GeometryNodes"),
                             bounds=bounds, pins=settings.get("pins"), uv=settings.get("uv"), parts=settings.get("parts"))
        model.space = with_conditions(model.space, conditions or {})
        _BLENDER_MODELS[key] = model
    return _BLENDER_MODELS[key]


def resolve_params_spec(source: dict[str, Any]) -> dict[str, Any]:
    """A source section with its ``params_spec`` file (if any) read into ``params`` (bounds of the
    spec's float and int inputs, under the section's own) and ``conditions`` (the section's own win),
    the key itself removed: a stored family needs no spec file to be read again."""
    if "params_spec" not in source:
        return source
    out = dict(source)
    path = out.pop("params_spec")
    if path is None:
        return out
    if not isinstance(path, (str, os.PathLike)):
        raise ValueError(f"params_spec must be a path to a JSON spec, got {type(path).__name__}")
    spec = read_params_spec(path)
    params = out.get("params") or {}
    conditions = out.get("conditions") or {}
    if not isinstance(params, dict) or not isinstance(conditions, dict):
        raise ValueError("params and conditions must be objects")
    out["params"] = {**spec.bounds, **params}
    out["conditions"] = {**spec.conditions, **conditions}
    return out


def restricted_space(space, bounds: dict[str, list[float]]):
    """``space`` with the ranges of the named float / int parameters narrowed to ``bounds``
    ``{name: [low, high]}`` (within the old ones); ``ValueError`` for unknown names, choices or
    ranges outside."""
    from proctex.params import ParamSpace, ParamSpec

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


#: Settings whose default changed after stores without them were written: their value then.
LEGACY_SETTINGS = {"tessellation": "fixed",
                   # the cage solver before the box pre-alignment, face normals, rest term and best iterate
                   "cage": {"prealign": "icp", "normal_target": "vertex", "keep_best": False, "w_rest": 0.0}}


def with_legacy(settings: dict[str, Any]) -> dict[str, Any]:
    """A stored config's settings with the values older stores were built with filled in. Stores
    written with sections store every setting resolved and are returned as they are."""
    if any(k in settings for k in ("source", "paint")):
        return settings
    return {**LEGACY_SETTINGS, **settings}


def without_devices(data: dict[str, Any]) -> dict[str, Any]:
    """A config dict (sections) with every device read as "cpu": where a family is built or used (a
    GPU, say) is no part of what it is, and a family built on a GPU must load where there is none."""
    out = dict(data)
    for section in ("paint", "cage", "train"):
        if isinstance(out.get(section), dict) and "device" in out[section]:
            out[section] = {**out[section], "device": "cpu"}
    return out


def resolved_settings(stored: dict[str, Any]) -> dict[str, Any]:
    """A stored config (sections, or the flat keys of older stores) resolved as :meth:`BuildConfig.to_dict`
    writes it today: settings added since that build count at their value then, or their default;
    devices read as "cpu" (:func:`without_devices`)."""
    return BuildConfig.from_dict(without_devices(with_legacy(stored))).to_dict()


#: Named starting points for a build (``BuildConfig.from_dict(data, preset=...)``, ``proctex build
#: --preset``): the settings given lay over them.
PRESETS: dict[str, dict[str, Any]] = {
    # The main job (``make demo``): the sofa with one design that has to follow every cushion, arm and
    # leg; fewer shapes, points and iterations than a production build, every stage run; a few
    # minutes on 2 cores.
    "demo": {"source": {"model": "sofa", "n_train": 10, "n_test": 3}, "paint": {"prompt": "a patchwork bohemian sofa", "texture_size": 512},
             "corr_points": 1000, "cage": {"iterations": 200}, "train": {"iterations": 600}},
}


