"""Shape sources: the one registry of where a family's shapes come from, and the ``[source]``
settings (:class:`SourceConfig`) that travel whole.

A :class:`SourceKind` is a name (the ``[source]`` key that names it: ``model``, ``folder``,
``generator``, ``blender``; a plugin kind is named by ``[source] kind`` with its ``settings``),
what it is (``regenerates``: shapes are made from parameters, so a stored sample is made again
exactly; ``canonical``: its shapes carry canonical coordinates; ``default_up``), ``check`` (its
setting validated) and ``open`` (a :class:`ShapeSource`: the parameter space, the procedural model
if any, the samples of a build and each sample's shape). :func:`open_source` keeps one open source
per setting per process (a Ray worker opens a ``.blend`` file once). Adding a kind is one file::

    from proctex.sources.registry import ShapeSource, SourceKind, register_source_kind
    register_source_kind(SourceKind("mine", open=lambda cfg: MySource(cfg.settings), check=..., summary="..."))

and ``PROCTEX_PLUGINS=path/to/that_file.py`` (:mod:`proctex.plugins`).
"""

from __future__ import annotations

import json
import os
import threading
from dataclasses import dataclass, field
from typing import Any, Callable

from proctex.geometry.shape import ProceduralModel, Shape
from proctex.params import ParamSpace, check_integer, restricted_space, with_conditions
from proctex.plugins import Registry

#: The built-in kinds' own ``[source]`` fields.
BUILT_IN_FIELDS = ("model", "folder", "generator", "blender")


@dataclass
class SourceConfig:
    """Where the family's shapes come from. Exactly one of ``model`` (built-in name), ``folder``
    (samples on disk), ``generator`` (a generator config file) or ``blender`` (a ``.blend`` file's
    Geometry Nodes modifier: ``{"file", "object", "modifier": "GeometryNodes", "pins": {input: value}}``;
    ``params`` narrows its inputs' ranges, see :mod:`proctex.sources.blender`).

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
        kind, settings: a source kind added by a plugin (:func:`register_source_kind`) and its
            settings, in place of the built-in kinds' own fields.
        listed: the inputs a ``params_spec`` file lists, or ``params`` bounds where there is no spec
            (filled when a config is read, :func:`proctex.store.config.resolve_params_spec`); None:
            no list. A ``blender`` source varies the inputs listed here or bounded in ``params`` and
            holds the others at the file's values; with no list, every input with a usable range
            varies (:func:`proctex.sources.blender.input_specs`).
        spec_notes: what reading the spec file said: keys it did not understand, keys it read as a
            near known key.
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
    kind: str | None = None
    settings: dict[str, Any] | None = None
    listed: list[str] | None = None
    spec_notes: list[str] = field(default_factory=list)

    def validate(self) -> "SourceConfig":
        if self.kind is not None:
            if self.kind in BUILT_IN_FIELDS:
                raise ValueError(f"a {self.kind} source is named by its own field ({self.kind} = ...), not by kind")
            get_source_kind(self.kind)  # an unknown kind says which are known
        named = [k.name for k in source_kinds() if self.value(k.name)]
        if len(named) != 1:
            raise ValueError(f"name exactly one of {', '.join(k.name for k in source_kinds())}" + (f" (got {', '.join(named)})" if named else ""))
        kind = get_source_kind(named[0])
        if kind.settings_key == "settings" and not isinstance(self.settings, dict):
            raise ValueError(f"settings of a {kind.name} source must be an object")
        kind.check(self.value(kind.name))
        check_integer("n_train", self.n_train, 2, 100_000)
        check_integer("n_test", self.n_test, 0, 100_000)
        if self.sampling not in ("lhs", "random"):
            raise ValueError(f"sampling must be lhs or random, got {self.sampling!r}")
        if not isinstance(self.params, dict):
            raise ValueError("params must be an object of bounds {name: [low, high]}")
        if not isinstance(self.conditions, dict) or not all(isinstance(c, dict) and set(c) <= {"when", "unless"} for c in self.conditions.values()):
            raise ValueError('conditions must be an object {"name": {"when": [[other, value], ...], "unless": [...]}}')
        if self.listed is not None and not (isinstance(self.listed, list) and len(self.listed) <= 10_000 and all(isinstance(n, str) and 0 < len(n) <= 256 for n in self.listed)):
            raise ValueError("listed must be a list of input names")
        if not (isinstance(self.spec_notes, list) and len(self.spec_notes) <= 1000 and all(isinstance(n, str) for n in self.spec_notes)):
            raise ValueError("spec_notes must be a list of strings")
        if self.up not in ("auto", "x", "y", "z"):
            raise ValueError(f"up must be auto, x, y or z, got {self.up!r}")
        if self.tessellation not in ("adaptive", "fixed"):
            raise ValueError(f"tessellation must be adaptive or fixed, got {self.tessellation!r}")
        return self

    def value(self, kind: str) -> Any:
        """The setting naming the source of kind ``kind`` (a built-in kind's own field; a plugin
        kind's ``settings`` when ``kind`` is it), or None."""
        if kind in BUILT_IN_FIELDS:
            return getattr(self, kind)
        return self.settings if self.kind == kind else None

    @property
    def kind_name(self) -> str:
        """The kind of this source (:func:`source_kinds`)."""
        for k in source_kinds():
            if self.value(k.name):
                return k.name
        raise ValueError("the source names no kind")

    @property
    def parts_attribute(self) -> str | None:
        """The attribute whose values are the shapes' parts (a ``.blend`` model's ``parts``), or None."""
        return (self.blender or {}).get("parts")


@dataclass(frozen=True)
class SampleJob:
    """One sample of the family: its position in the sample list, id, split and parameters."""

    index: int
    id: str
    split: str
    params: dict[str, Any]


class ShapeSource:
    """An open source: :attr:`space` (the parameter space; a folder's, inferred from its samples),
    :attr:`model` (the procedural model, ``params -> Shape``; None for a folder of meshes), the
    samples of a build (:meth:`sample_jobs`) and each one's shape (:meth:`shape`). The defaults are
    those of a procedural model; a folder overrides them."""

    def __init__(self, kind: "SourceKind", model: ProceduralModel | None, space: ParamSpace, uv_map: str | None = None, parts_attribute: str | None = None) -> None:
        self.kind, self.model, self.space = kind, model, space
        self.uv_map, self.parts_attribute = uv_map, parts_attribute

    def sample_jobs(self, config: SourceConfig, seed: int) -> list[SampleJob]:
        """Every sample of a build: ``n_train + n_test`` drawn from the model with ``seed``, in order."""
        params = self.space.sample(config.n_train + config.n_test, seed=seed, method=config.sampling)
        return [SampleJob(i, f"s{i:04d}", "train" if i < config.n_train else "test", p) for i, p in enumerate(params)]

    def shape(self, job: SampleJob) -> Shape:
        """The shape of sample ``job``."""
        return self.model.generate(job.params)


class FolderShapes(ShapeSource):
    """A folder of samples (:class:`proctex.sources.files.FolderSource`): its own samples, in order."""

    def __init__(self, kind: "SourceKind", path: str) -> None:
        from proctex.sources.files import FolderSource

        self.folder = FolderSource(path)
        super().__init__(kind, None, self.folder.space)

    def sample_jobs(self, config: SourceConfig, seed: int) -> list[SampleJob]:
        return [SampleJob(i, s.store_id, s.split, self.folder.params(i)) for i, s in enumerate(self.folder.samples)]

    def shape(self, job: SampleJob) -> Shape:
        return self.folder.load(job.index)


@dataclass(frozen=True)
class SourceKind:
    """A kind of shape source.

    Attributes:
        name: the ``[source]`` key that names it (a plugin kind: the value of ``[source] kind``).
        open: ``SourceConfig -> ShapeSource``.
        check: ``check(value)`` raises ``ValueError`` for a setting it cannot open (the value of
            its key; a plugin kind's: ``[source] settings``).
        summary: one line for help texts.
        regenerates: shapes are made from parameters: a stored sample is regenerated exactly (its
            labels and canonical coordinates included) rather than read back from its mesh.
        canonical: its shapes carry canonical coordinates (the evaluation's "canonical" truth).
        default_up: the up axis of its shapes when the source says "auto".
        starts_program: making a shape starts another program (Blender): readers of a built family
            never make shapes of such a source (a family records its template whole).
    """

    name: str
    open: Callable[[SourceConfig], ShapeSource]
    check: Callable[[Any], None] = lambda value: None
    summary: str = ""
    regenerates: bool = True
    canonical: bool = False
    default_up: str = "z"
    starts_program: bool = False

    @property
    def settings_key(self) -> str:
        return self.name if self.name in BUILT_IN_FIELDS else "settings"


_KINDS: Registry[SourceKind] = Registry("source kind", lambda name, known: f"unknown source kind {name!r}; known: {', '.join(known)}")
_OPEN: dict[str, ShapeSource] = {}
_LOCK = threading.RLock()


def register_source_kind(kind: SourceKind, replace: bool = False) -> SourceKind:
    """Add ``kind`` to the registry (``replace``: over one of the same name); returns it."""
    if not isinstance(kind.name, str) or not kind.name.isidentifier() or kind.name in ("kind", "settings"):
        raise ValueError(f"a source kind's name must be an identifier, got {str(kind.name)[:60]!r}")
    return _KINDS.add(kind.name, kind, replace=replace)


def unregister_source_kind(name: str) -> None:
    _KINDS.remove(name)
    with _LOCK:
        for key in [k for k, s in _OPEN.items() if s.kind.name == name]:
            del _OPEN[key]


def source_kinds() -> list[SourceKind]:
    """The registered kinds (plugins loaded), in registration order."""
    return _KINDS.entries()


def get_source_kind(name: str) -> SourceKind:
    return _KINDS.get(name)


def source_kind(config: SourceConfig) -> SourceKind:
    """The kind of the source ``config`` names."""
    if config.kind is not None and config.kind not in BUILT_IN_FIELDS:
        return get_source_kind(config.kind)
    return get_source_kind(config.kind_name)


def open_source(config: SourceConfig) -> ShapeSource:
    """The open source of ``config``, one per setting per process (what makes the shapes: the kind,
    its setting, the parameter bounds, conditions and tessellation; not the sample counts)."""
    kind = source_kind(config)
    key = json.dumps(
        {"kind": kind.name, "value": config.value(kind.name), "params": config.params, "conditions": config.conditions, "tessellation": config.tessellation, "listed": config.listed},
        sort_keys=True,
        default=str,
    )
    with _LOCK:
        if key not in _OPEN:
            _OPEN[key] = kind.open(config)
        return _OPEN[key]


def _narrowed(model: ProceduralModel, config: SourceConfig) -> ProceduralModel:
    if config.params:
        model.space = restricted_space(model.space, config.params)
    model.space = with_conditions(model.space, config.conditions)
    return model


def _open_model(config: SourceConfig) -> ShapeSource:
    from proctex.models import get_model

    model = _narrowed(get_model(config.model, tessellation=config.tessellation), config)
    return ShapeSource(get_source_kind("model"), model, model.space)


def _open_generator(config: SourceConfig) -> ShapeSource:
    from proctex.sources.files import load_generator

    model = _narrowed(load_generator(config.generator), config)
    return ShapeSource(get_source_kind("generator"), model, model.space)


def _open_blender(config: SourceConfig) -> ShapeSource:
    from proctex.sources.blender import BlenderModel

    b = config.blender
    listed = None if config.listed is None else [*config.listed, *config.params]
    model = BlenderModel(b["file"], b["object"], b.get("modifier", "GeometryNodes"), bounds=config.params, pins=b.get("pins"), uv=b.get("uv"), parts=b.get("parts"), listed=listed)
    model.space = with_conditions(model.space, config.conditions)
    return ShapeSource(get_source_kind("blender"), model, model.space, uv_map=b.get("uv"), parts_attribute=config.parts_attribute)


def _check_model(name: Any) -> None:
    from proctex.models import get_model

    get_model(name)  # unknown names raise ValueError listing the models


def _check_folder(path: Any) -> None:
    if not isinstance(path, str) or not os.path.isdir(path):
        raise ValueError(f"folder {path!r} not found")


def _check_generator(path: Any) -> None:
    if not isinstance(path, str) or not os.path.isfile(path):
        raise ValueError(f"generator config {path!r} not found")


def _check_blender(b: Any) -> None:
    from proctex.sources.blender import BLENDER_KEYS

    if not isinstance(b, dict) or not isinstance(b.get("file"), str) or not isinstance(b.get("object"), str):
        raise ValueError('blender must be {"file": "x.blend", "object": "Name", "modifier": "GeometryNodes", "pins": {...}, "parts": "part_id", "uv": "UVMap"}')
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


register_source_kind(SourceKind("model", _open_model, _check_model, "a built-in procedural model (proctex models)", canonical=True))
register_source_kind(
    SourceKind(
        "folder",
        lambda config: FolderShapes(get_source_kind("folder"), config.folder),
        _check_folder,
        "a folder of exported meshes with their parameters (JSON beside each)",
        regenerates=False,
        default_up="y",
    )
)
register_source_kind(SourceKind("generator", _open_generator, _check_generator, "your Python generator, named in a TOML/JSON file"))
register_source_kind(SourceKind("blender", _open_blender, _check_blender, "a .blend file's Geometry Nodes modifier, evaluated by Blender", canonical=True, starts_program=True))
