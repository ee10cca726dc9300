"""The family state record (:class:`FamilyState`, ``family.json``): the build config, the stage
records and the library versions. It is the only reader and writer of ``family.json``: a reader
loads it once (:meth:`FamilyState.load`) and passes it on."""

from __future__ import annotations

import copy
import hashlib
import json
import platform
import time
from contextlib import contextmanager
from dataclasses import dataclass, field
from typing import Any, Iterator

import pyarrow as pa

from proctex.store.config import (
    BuildConfig,
    resolved_settings,
    with_legacy,
    without_devices,
)
from proctex.store.layout import FamilyStore, StoreLayout
from proctex.store.looks import other_looks

STAGES = ("sample", "template", "paint", "pairs", "train", "evaluate")
FIELDS = ("config", "stages", "versions")


def library_versions() -> dict[str, str]:
    """The versions of ProcTex and the libraries a build ran with (recorded in ``family.json``)."""
    import numpy
    import scipy
    import torch
    import trimesh

    from proctex import __version__

    return {
        "proctex": __version__,
        "python": platform.python_version(),
        "numpy": numpy.__version__,
        "scipy": scipy.__version__,
        "torch": torch.__version__,
        "trimesh": trimesh.__version__,
        "pyarrow": pa.__version__,
    }


@dataclass
class FamilyState:
    """``family.json``: ``config`` (the resolved settings as :meth:`BuildConfig.to_dict` wrote them,
    None before the first build), ``stages`` (per stage its record: ``{"state": "done",
    "finished", ...}``) and ``versions`` (:func:`library_versions`); keys this version does not know
    are kept in ``other`` and written back."""

    config: dict[str, Any] | None = None
    stages: dict[str, dict[str, Any]] = field(default_factory=dict)
    versions: dict[str, str] = field(default_factory=dict)
    other: dict[str, Any] = field(default_factory=dict)

    @classmethod
    def load(cls, store: FamilyStore) -> "FamilyState":
        """The store's state, read once (an empty state where there is no ``family.json``); a file
        that is not an object, or whose sections are not, is a ``ValueError`` naming it. Inside
        :func:`held_state` for this store (a build, under its exclusive lock), a copy of the state
        held in memory: the file is read once a build."""
        held = _HELD.get(store.uri)
        if held is not None:
            return copy.deepcopy(held)
        if not store.exists(StoreLayout.STATE):
            return cls()
        raw = store.read_json(StoreLayout.STATE)
        where = store.path(StoreLayout.STATE)
        if not isinstance(raw, dict):
            raise ValueError(f"{where}: damaged family state (not an object)")
        for key, kind in (("config", dict), ("stages", dict), ("versions", dict)):
            if raw.get(key) is not None and not isinstance(raw[key], kind):
                raise ValueError(f"{where}: damaged family state ({key} is a {type(raw[key]).__name__})")
        stages = raw.get("stages") or {}
        if not all(isinstance(v, dict) for v in stages.values()):
            raise ValueError(f"{where}: damaged family state (a stage record is not an object)")
        return cls(raw.get("config"), dict(stages), dict(raw.get("versions") or {}), {k: v for k, v in raw.items() if k not in FIELDS})

    def to_dict(self) -> dict[str, Any]:
        out: dict[str, Any] = {} if self.config is None else {"config": self.config}
        if self.versions:
            out["versions"] = self.versions
        return {**out, "stages": self.stages, **self.other}

    def save(self, store: FamilyStore) -> None:
        """Write ``family.json`` (atomically); inside :func:`held_state`, the held state too."""
        store.write_json(StoreLayout.STATE, self.to_dict())
        if store.uri in _HELD:
            _HELD[store.uri] = copy.deepcopy(self)

    def stage(self, name: str) -> dict[str, Any]:
        """The record of stage ``name`` ({} before it ran)."""
        return self.stages.get(name) or {}

    def done(self, name: str) -> bool:
        return self.stage(name).get("state") == "done"

    def mark(self, name: str, **info: Any) -> "FamilyState":
        """Record stage ``name`` as done now, with ``info``; returns self (not saved)."""
        self.stages[name] = {"state": "done", "finished": time.strftime("%Y-%m-%dT%H:%M:%S"), **info}
        return self

    def build_config(self, where: str = "family") -> BuildConfig:
        """The config the family was built with. Its devices read as "cpu": where a family was built
        (a GPU, say) is not where it is used; readers choose their own device."""
        if self.config is None:
            raise ValueError(f"{where}: not a ProcTex family (no family.json with a config)")
        return BuildConfig.from_dict(without_devices(with_legacy(self.config)))

    def with_config(self, config: BuildConfig, where: str = "family") -> "FamilyState":
        """Set the build config (and the library versions); ``ValueError`` when the family was built
        with other settings. Returns self (not saved)."""
        new = config.to_dict()
        if self.config is not None and resolved_settings(self.config) != without_devices(new):
            old = resolved_settings(self.config)
            if {k: v for k, v in old.items() if k != "paint"} == {k: v for k, v in without_devices(new).items() if k != "paint"}:
                # only the paint settings differ: the geometry is built; another prompt is a look
                raise ValueError(
                    f"{where} was built with other paint settings (prompt {old['paint'].get('prompt')!r}); its geometry, "
                    f"pairs and networks do not depend on them: paint it with the new ones in seconds with "
                    f"`proctex look add {where} NAME --prompt ...` (a new look), or use a new folder to build again"
                )
            raise ValueError(f"{where} was built with another config; use a new folder (or delete it) to change settings")
        self.config = new
        self.versions = library_versions()
        return self


#: The states held in memory by :func:`held_state`, per store URI (this process only).
_HELD: dict[str, "FamilyState"] = {}


@contextmanager
def held_state(store: FamilyStore) -> Iterator[None]:
    """Inside the block this process reads ``store``'s ``family.json`` once: :meth:`FamilyState.load`
    gives copies of the state held in memory and :meth:`FamilyState.save` writes through it. For a
    build, which holds the store's exclusive build lock (no edit or other build writes the file
    meanwhile); the processes it starts read the file themselves. Nested blocks share the outer one."""
    if store.uri in _HELD:
        yield
        return
    _HELD[store.uri] = FamilyState.load(store)
    try:
        yield
    finally:
        _HELD.pop(store.uri, None)


def mark_stage(store: FamilyStore, stage: str, **info: Any) -> None:
    """Record ``stage`` as done in the store's state (read, marked, written)."""
    FamilyState.load(store).mark(stage, **info).save(store)


def stage_done(store: FamilyStore, stage: str) -> bool:
    return FamilyState.load(store).done(stage)


def stored_config(store: FamilyStore, state: FamilyState | None = None) -> BuildConfig:
    """The config the family was built with (:meth:`FamilyState.build_config`)."""
    return (state if state is not None else FamilyState.load(store)).build_config(store.uri)


def write_config(store: FamilyStore, config: BuildConfig) -> None:
    """Record ``config`` as the family's (:meth:`FamilyState.with_config`)."""
    FamilyState.load(store).with_config(config, store.uri).save(store)


@dataclass(frozen=True)
class Changed:
    """What a stored change of a family gives back: its ``record`` (an edit's record, the undone
    records, a new look's record) and ``version``, the family's :func:`build_stamp` right after it,
    read under the same edit lock as the change (no other change can come between: the one version
    value a client conditions its next change on)."""

    record: Any
    version: str


def build_stamp(store: FamilyStore, state: FamilyState | None = None) -> str:
    """The family's version: its stage records and every look's paint record (edits append to
    them). Changes whenever the family is rebuilt or edited, or a look is added or removed; the
    service, the catalog and the Ray workers' cached template all key on it."""
    state = state if state is not None else FamilyState.load(store)
    paint = store.read_bytes(StoreLayout.PAINT) if store.exists(StoreLayout.PAINT) else b""
    h = hashlib.sha256(json.dumps(state.stages, sort_keys=True).encode())
    h.update(paint)
    for look in other_looks(store):  # a store without looks lists none
        h.update(look.name.encode() + b"\0" + (store.read_bytes(look.PAINT) if store.exists(look.PAINT) else b""))
    return h.hexdigest()[:16]
