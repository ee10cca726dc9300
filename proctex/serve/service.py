"""Serving families: load a built family once, answer transfer requests, notice rebuilds.

:class:`FamilyService` holds one family ready for transfer: an immutable :class:`Snapshot` of one
version (:mod:`proctex.serve.snapshot`: template assets, networks, the look, what ``describe()``
says), the mapper and the painter for new parts, and one module per job: what a request brings
(:mod:`proctex.serve.inputs`), texturing (:mod:`proctex.serve.texturing`), edits
(:mod:`proctex.serve.editing`) and looks (:mod:`proctex.serve.lookviews`).
:class:`proctex.serve.catalog.Catalog` holds the families under a root.
Both are plain Python: the Ray Serve deployment (``workers/serve.py``) and any other server wrap
them.

Requests are validated here with ``ValueError`` subclasses that a server maps to HTTP codes:
:class:`NotFound` (404), :class:`BadInput` (422), :class:`TooLarge` (413) and :class:`Unavailable`
(503: a damaged family, which the catalog isolates). Transfers run within :class:`Limits`, with a
:class:`~proctex.transfer.budget.Budget`; a :class:`proctex.serve.catalog.Watchdog` tells a stuck
transfer from a busy one.
Stored edits are versioned, serialised across processes and undoable (:mod:`proctex.serve.edits`).

Non-destructive edits (:class:`GroupEdit`): a transfer can take, per template group, a re-paint
prompt and an HSV shift applied to a copy of the group's texture (:func:`proctex.serve.edits.edit_texture`,
the code :func:`proctex.serve.edits.edit_group` persists with); edited textures are kept in a small LRU
cache per service so that a client dragging a hue slider costs one HSV shift per new value.
"""

from __future__ import annotations

import copy
import threading
import time
from dataclasses import replace
from pathlib import Path
from typing import Any

from proctex.store.family import Family
from proctex.store.layout import FamilyStore
from proctex.transfer.assets import texture_hw

from .editing import Editing
from .inputs import (  # noqa: F401  (the service's errors, limits and edits, imported from here by servers)
    EDIT_FIELDS,
    MESH_SUFFIXES,
    THUMB_SIZES,
    BadInput,
    GroupEdit,
    Limits,
    NotFound,
    TooLarge,
    Unavailable,
    check_extent,
    parse_edit,
)
from .inputs import Inputs
from .lookviews import LookViews
from .snapshot import Snapshot, read_snapshot
from .texturing import Texturing


def _of_snapshot(name: str, doc: str) -> property:
    """A read-only attribute of the service that is its snapshot's ``name``."""
    return property(lambda self: getattr(self.snapshot, name), doc=doc)


class FamilyService(Inputs, Texturing, Editing, LookViews):
    """One built family, loaded for transfer: :attr:`snapshot` (what was read, immutable) and the
    mapper and painter made from it; a view of another look replaces the snapshot, never mutates it."""

    def __init__(
        self, store: FamilyStore, name: str | None = None, limits: Limits | None = None, mapper: str = "auto", device: str = "cpu", family: Family | None = None, look: str | None = None
    ) -> None:
        """Load the family in ``store``; ``mapper``: a :mod:`proctex.transfer.methods` name
        ("auto": the group networks where trained, the default); ``device``: where the networks and a
        cage fallback run ("cpu", "cuda", "cuda:<i>"; ``ValueError`` when CUDA is asked for and absent);
        ``family``: the family's records when the caller has opened them (a catalog, :class:`Family`),
        else opened here; either way its version is hashed again under the edit lock;
        ``look``: the family's look to texture with (:mod:`proctex.store.looks`; default: the build's)."""
        from proctex.correspond.corrnet import resolve_device
        from proctex.serve.edits import edit_lock, read_again
        from proctex.texture.painters import SurfacePainter
        from proctex.transfer.methods import get_method, make_mapper
        from proctex.transfer.uvlookup import group_rooms

        t0 = time.perf_counter()
        method = get_method(mapper)  # an unknown name fails before anything is read
        self.device = str(resolve_device(device))
        self.store = store
        self.name = name or Path(store.base).name
        self.limits = limits or Limits()
        self._description: dict[str, Any] | None = None  # describe()'s, made once

        def read() -> Snapshot:
            with edit_lock(store, shared=True):  # the template's files as one version, never half an edit
                opened = Family.open(store, family.state if family is not None else None)  # its version hashed under the lock
                # every method that uses the networks loads them ("auto": where there are any)
                return read_snapshot(opened, look, networks=method.networks != "none", device=self.device)

        self.snapshot: Snapshot = read_again(read)  # on an object store, again if an edit ran while it read
        if method.networks == "required" and not self.models:
            raise ValueError(f"{store.uri} has no trained models (run the train stage)")
        cage = replace(self.config.cage, device=self.device) if self.config.cage is not None else None
        self.mapper: Any = make_mapper(mapper, self.assets, self.models, corr_points=self.config.corr_points, cage=cage)
        self.painter = SurfacePainter(self.paint.prompt, seed=self.config.seed)
        group_rooms(self.assets)  # the UV lookup's tables of this version (~0.2 s on a sofa), made here, not in the first request
        self.load_seconds = time.perf_counter() - t0
        self.lock = threading.Lock()  # transfers share the torch models and the painter
        # Edited group textures: (group, GroupEdit) -> (uint8 texture, PNG); re-paints: (group, prompt) -> float texture.
        self.edit_cache_size = 32
        self._clear_edit_caches()
        self._views: dict[str, FamilyService] = {self.look.name: self}  # the family's looks, each made when first asked for
        self._views_lock = threading.Lock()

    family = _of_snapshot("family", "The family's records (:class:`proctex.store.family.Family`).")
    config = _of_snapshot("config", "The config the family was built with.")
    stamp = _of_snapshot("stamp", "The family's version, as loaded.")
    source_kind = _of_snapshot("source_kind", "The kind of the family's shape source.")
    up = _of_snapshot("up", "The up axis: GLBs stand the shape upright in glTF's +Y-up world.")
    look = _of_snapshot("look", "The look served (:class:`proctex.store.layout.LookLayout`).")
    paint = _of_snapshot("paint", "The look's paint settings: its prompts paint new parts.")
    assets = _of_snapshot("assets", "The template ready for transfer (:class:`proctex.transfer.assets.TemplateAssets`).")
    models = _of_snapshot("models", "{group: ProcCorrNet} of the trained groups the method uses.")
    space = _of_snapshot("space", "The parameter space (recorded: a .blend family's Blender is not started to read it).")
    paint_record = _of_snapshot("paint_record", "The look's paint record.")
    metrics_record = _of_snapshot("metrics_record", "The evaluate stage's metrics (None before it ran).")
    look_names = _of_snapshot("look_names", "The family's looks, by name.")
    texture_digests = _of_snapshot("texture_digests", "sha256 of each group's texture PNG.")
    map_digests = _of_snapshot("map_digests", "sha256 of each group's PBR maps (None without).")

    @property
    def state(self) -> Any:
        return self.snapshot.family.state

    @property
    def model(self) -> Any:
        """The family's procedural model (None for a folder of meshes, which takes meshes only),
        opened on first use, once per process: loading a ``.blend`` family starts no Blender; its
        first transfer by parameters does."""
        return self.config.procedural_model() if self.source_kind.regenerates else None

    # --------------------------------------------------------------------------------- describe
    def describe(self) -> dict[str, Any]:
        """Parameter specs, groups, prompts and state of the family (JSON-ready): of the version this
        service loaded, from what it read then (no store file is read here; a new dict each call)."""
        if self._description is None:
            self._description = self._describe()
        return copy.deepcopy(self._description)

    def _describe(self) -> dict[str, Any]:
        from proctex.sources.registry import source_kinds

        space, paint, metrics = self.space, self.paint_record, self.metrics_record
        return {
            "name": self.name,
            "source": {**{k.name: bool(self.config.source.value(k.name)) for k in source_kinds()}, "model": self.config.source.model, "kind": self.source_kind.name},
            "inputs": ["params", "mesh"] if self.source_kind.regenerates else ["mesh"],
            # the attribute whose values are the parts: a mesh sent with it as OBJ groups keeps them apart
            "parts_attribute": self.config.source.parts_attribute,
            "up": self.up,
            "parameters": [s.to_dict() for s in space.specs],
            "look": self.look.name,
            "looks": list(self.look_names),
            "prompt": self.paint.prompt,
            "group_prompts": dict(self.paint.group_prompts),
            # names: every name its parts carry (a node tree's "Left Arm", "Right Arm"), untrusted text
            "groups": [
                {
                    "group": g.group,
                    "label": g.label,
                    "names": self.assets.grouping.names(self.assets.grouping.groups[g.group]),
                    "degenerate": g.degenerate,
                    "network": g.group in self.models,
                    "material": self.assets.names[g.group] if g.group < len(self.assets.names) else None,
                    "prompt": next((p.get("prompt") for p in paint.get("groups", []) if p.get("group") == g.group), None),
                    "texture_size": list(texture_hw(self.assets, g.group)),
                    **self._material_means(g.group),
                }
                for g in self.assets.groups
            ],
            "edits": len(paint.get("edits", [])),
            "stages": {k: v.get("state") for k, v in self.state.stages.items()},
            "stamp": self.stamp,
            "metrics": None if metrics is None else {k: {kk: vv for kk, vv in v.items() if kk != "per_shape"} for k, v in metrics.get("methods", {}).items()},
            "limits": {"max_bytes": self.limits.max_bytes, "max_vertices": self.limits.max_vertices, "max_faces": self.limits.max_faces, "max_prompt": self.limits.max_prompt},
        }
