"""The build config (:class:`BuildConfig`): what a family is made of and how it is built; read from
JSON or TOML files, checked, and stored resolved in ``family.json``."""

from __future__ import annotations

import json
import os
import sys
import tomllib
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

from proctex.params import check_integer, read_params_spec
from proctex.sources.registry import SourceConfig, open_source, source_kind
from proctex.texture.painting import PaintConfig

#: Flat settings (the config format before sections, still read) -> (section, field).
FLAT_KEYS: dict[str, tuple[str, str]] = {
    **{k: ("source", k) for k in ("model", "folder", "generator", "blender", "n_train", "n_test", "sampling", "params", "tessellation", "up")},
    **{k: ("paint", k) for k in ("prompt", "group_prompts", "part_words", "painter", "texture_size", "views", "view_size", "paint_hidden", "fill", "model_dir", "device", "steps", "occlusion")},
    "cage_level": ("cage", "level"),
    "cage_iterations": ("cage", "iterations"),
}
SECTIONS = ("source", "paint", "cage", "train")
TOP_LEVEL = ("seed", "corr_points", "truth")
MAX_SETTINGS = 256  # keys in one section (a config is small; a huge one is a mistake or an attack)


#: What ``--truth`` accepts: ``auto`` picks canonical for built-in and ``.blend`` models, the family config's
#: ``truth`` otherwise; ``none`` means no ground truth (the cage tracker, pseudo-ground truth only).
TRUTHS = ("auto", "canonical", "vertex-index", "none")


@dataclass
class BuildConfig:
    """Everything a build needs, in sections: ``source`` (:class:`SourceConfig`), ``paint``
    (:class:`PaintConfig`), ``cage`` (the cage solver per pair, :class:`proctex.correspond.cage.CageConfig`)
    and ``train`` (ProcCorrNet, :class:`proctex.correspond.corrnet.CorrNetConfig`; its seed is the
    family seed unless set), plus:

    Attributes:
        seed: the family seed; sample ``i`` and pair ``(i, g)`` derive theirs from it.
        corr_points: surface points per shape in each cage pair.
        truth: what the evaluation takes as ground truth (:data:`proctex.store.config.TRUTHS`): "auto"
            (canonical coordinates for built-in models, ``.blend`` models whose node tree could be
            read and folders whose every mesh file has a truth file beside it, ``<stem>.truth.npz``:
            :mod:`proctex.sources.truthfiles`; none otherwise), "vertex-index" (the
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
        if self.truth not in TRUTHS:
            raise ValueError(f"truth must be one of {', '.join(TRUTHS)}, got {self.truth!r}")
        if self.truth == "canonical" and not source_kind(self.source).canonical:
            from proctex.sources.truthfiles import folder_truth

            if not (self.source.folder and folder_truth(self.source.folder)):
                raise ValueError("truth 'canonical' needs a built-in model, a .blend model (canonical coordinates) or a folder whose every mesh file has a truth file beside it (<stem>.truth.npz)")
        check_integer("seed", self.seed, 0, 2**32 - 1)
        check_integer("corr_points", self.corr_points, 100, 1_000_000)
        return self

    def shapes(self):
        """The family's open shape source (:func:`proctex.sources.registry.open_source`, one per
        process): its parameter space, procedural model (None for a folder), samples and shapes."""
        return open_source(self.source)

    def procedural_model(self):
        """The family's procedural model (a built-in one, the user's generator, a ``.blend`` file's
        modifier), its parameter space restricted to the source's ``params`` bounds; ``ValueError``
        for a folder of meshes, which has none."""
        model = self.shapes().model
        if model is None:
            raise ValueError(f"a {self.source.kind_name} source has no procedural model: send meshes")
        return model

    def up_axis(self) -> str:
        """The shapes' up axis: the source's ``up``, or for "auto" its kind's (y for files: OBJ /
        glTF, z for models)."""
        if self.source.up != "auto":
            return self.source.up
        return source_kind(self.source).default_up

    def to_dict(self) -> dict[str, Any]:
        """The resolved config as JSON-able sections (what ``family.json`` stores)."""
        return json.loads(
            json.dumps(
                {
                    "seed": self.seed,
                    "corr_points": self.corr_points,
                    "truth": self.truth,
                    "source": asdict(self.source),
                    "paint": asdict(self.paint),
                    "cage": asdict(self.cage),
                    "train": self.train.to_dict(),
                }
            )
        )

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
            return BuildConfig(source=SourceConfig(**nested.get("source", {})), paint=PaintConfig(**nested.get("paint", {})), cage=cage, train=CorrNetConfig.from_dict(train), **top).validate()
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


def resolve_params_spec(source: dict[str, Any]) -> dict[str, Any]:
    """A source section with its ``params_spec`` file (if any) read into ``params`` (bounds of the
    spec's float and int inputs, under the section's own), ``conditions`` (the section's own win),
    ``listed`` (the inputs the spec names) and ``spec_notes`` (keys it did not understand, printed
    to stderr too), the key itself removed: a stored family needs no spec file to be read again.
    A ``.blend`` source with ``params`` and neither a spec nor ``listed`` lists the inputs
    ``params`` bounds."""
    if "params_spec" not in source:
        if isinstance(source.get("blender"), dict) and "listed" not in source and isinstance(source.get("params"), dict) and source["params"]:
            # [source.params] without a spec: the inputs it bounds vary, the others keep the file's values
            return {**source, "listed": sorted(source["params"])}
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
    out["listed"] = sorted(set(spec.kinds) | set(out.get("listed") or []))
    out["spec_notes"] = [*(out.get("spec_notes") or []), *spec.notes]
    for note in spec.notes:
        print(f"params spec: {note}", file=sys.stderr)
    return out


#: Settings whose default changed after stores without them were written: their value then.
LEGACY_SETTINGS = {
    "tessellation": "fixed",
    # the cage solver before the box pre-alignment, face normals, rest term and best iterate
    "cage": {"prealign": "icp", "normal_target": "vertex", "keep_best": False, "w_rest": 0.0},
}


def with_legacy(settings: dict[str, Any]) -> dict[str, Any]:
    """A stored config's settings with the values older stores were built with filled in. Stores
    written with sections store every setting resolved and are returned as they are, but for a
    ``.blend`` source stored before ``listed`` existed: every input with a range varied then (no
    list)."""
    source = settings.get("source")
    if isinstance(source, dict) and isinstance(source.get("blender"), dict) and "listed" not in source:
        settings = {**settings, "source": {**source, "listed": None}}
    if any(k in settings for k in ("source", "paint")):
        return settings
    return {**LEGACY_SETTINGS, **settings}


#: Settings of how the networks are trained, not of what they learn (float rounding apart), read as
#: "auto" by :func:`without_devices`.
HOW_TRAINED = ("autocast", "together")


def without_devices(data: dict[str, Any]) -> dict[str, Any]:
    """A config dict (sections) with every device read as "cpu", how the networks are trained
    (:data:`HOW_TRAINED`: bfloat16 or not, groups in one loop or not) as "auto" and how the cage
    pairs are batched (``cage.batch``) as 0: where and how a
    family is built (a GPU, a CPU with bfloat16) is no part of what it is, and a family built on a
    GPU must load where there is none."""
    out = dict(data)
    for section in ("paint", "cage", "train"):
        if isinstance(out.get(section), dict) and "device" in out[section]:
            out[section] = {**out[section], "device": "cpu"}
    if isinstance(out.get("train"), dict):
        out["train"] = {**out["train"], **{k: "auto" for k in HOW_TRAINED if k in out["train"]}}
    if isinstance(out.get("cage"), dict) and "batch" in out["cage"]:
        out["cage"] = {**out["cage"], "batch": 0}  # pairs solved alone or batched: how, not what
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
    "demo": {
        "source": {"model": "sofa", "n_train": 10, "n_test": 3},
        "paint": {"prompt": "a patchwork bohemian sofa", "texture_size": 512},
        "corr_points": 1000,
        "cage": {"iterations": 200},
        "train": {"iterations": 600},
    },
}
