"""Serving families: load a built family once, answer transfer requests, notice rebuilds.

:class:`FamilyService` holds one family ready for transfer (template assets, networks, mapper, the
painter for new parts); :class:`proctex.serve.catalog.Catalog` holds the families under a root.
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
import hashlib
import io
import json
import math
import threading
import time
from collections import OrderedDict
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np

from proctex.store.layout import MAP_KINDS, FamilyStore, StoreDamaged
from proctex.store.looks import look_paint, looks, resolve_look
from proctex.sources.registry import source_kind
from proctex.store.family import Family
from proctex.store.state import Changed
from proctex.texture.painting import MAX_PROMPT
from proctex.transfer.assets import texture_hw
from proctex.transfer.budget import OverBudget


class NotFound(ValueError):
    """An unknown family."""


class BadInput(ValueError):
    """A request that cannot be served as given (bad parameters, unreadable mesh)."""


class TooLarge(ValueError):
    """A request over the size limits."""


class Unavailable(ValueError):
    """A family whose store is damaged: it is not served (the others are)."""


@dataclass
class Limits:
    """Request limits: body bytes, mesh vertices, faces and parts (connected components), characters
    of an edit prompt, and seconds of work per transfer (the request's
    :class:`~proctex.transfer.budget.Budget`); and the time bounds on reading a body: at most
    ``body_seconds`` in all, no gap between bytes longer than ``body_idle_seconds``, at least
    ``body_min_rate`` bytes per second on average once the first ``body_idle_seconds`` have passed,
    and at most ``max_uploads`` bodies read at once per ingress replica (a stalled client holds one
    slot, never the health route or other families' requests); bodies that declare at most
    ``small_body`` bytes (JSON requests: a transfer by parameters, an edit) have their own
    ``max_small_bodies`` slots, so stalled uploads never refuse them (at most
    ``max_small_bodies * small_body`` bytes held). A new look (``POST .../looks``) paints for at most
    ``look_seconds`` (cancelled, nothing written, when its client leaves), of at most ``look_texels``
    (texture side squared times groups) and ``look_bytes`` of files, into a family of at most
    ``max_looks`` looks, ``look_paints`` of one family at a time per replica (the others wait their
    turn holding no thread): :class:`proctex.build.looks.LookLimits`. One client (its TCP peer;
    behind ``trusted_proxies``, the address they forward; IPv6 grouped by /64) holds at most
    ``client_small_bodies`` and ``client_uploads`` of those slots: one more waits a moment, then is
    refused (429), and every other client is served."""

    max_bytes: int = 32 * 2**20
    max_vertices: int = 500_000
    max_faces: int = 1_000_000
    max_prompt: int = MAX_PROMPT
    max_parts: int = 512
    max_seconds: float = 30.0
    body_seconds: float = 120.0
    body_idle_seconds: float = 10.0
    body_min_rate: int = 16_384
    max_uploads: int = 4
    max_small_bodies: int = 256
    small_body: int = 65_536
    look_seconds: float = 600.0
    look_texels: int = 8 * 2048 * 2048
    look_bytes: int = 256 * 2**20
    max_looks: int = 64
    look_paints: int = 1
    client_small_bodies: int = 64
    client_uploads: int = 2
    trusted_proxies: str = ""

    def __post_init__(self) -> None:
        for name in ("max_bytes", "max_vertices", "max_faces", "max_prompt", "max_parts", "body_min_rate", "max_uploads",
                     "max_small_bodies", "small_body", "look_texels", "look_bytes", "max_looks", "look_paints",
                     "client_small_bodies", "client_uploads"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, int) or value < 1:
                raise ValueError(f"limit {name} must be a positive integer, got {value!r}")
        for name in ("max_seconds", "body_seconds", "body_idle_seconds", "look_seconds"):
            value = getattr(self, name)
            if isinstance(value, bool) or not (isinstance(value, (int, float)) and math.isfinite(value) and value > 0):
                raise ValueError(f"limit {name} must be a positive number, got {value!r}")
        self.proxies()  # checked here

    def proxies(self) -> tuple:
        """``trusted_proxies`` (comma-separated addresses or networks) as :mod:`ipaddress` networks."""
        import ipaddress

        if not isinstance(self.trusted_proxies, str) or len(self.trusted_proxies) > 4096:
            raise ValueError("limit trusted_proxies must be text: addresses or networks separated by commas")
        try:
            return tuple(ipaddress.ip_network(x.strip(), strict=False) for x in self.trusted_proxies.split(",") if x.strip())
        except ValueError as exc:
            raise ValueError(f"limit trusted_proxies: {exc}") from None


MESH_SUFFIXES = (".obj", ".ply", ".stl", ".glb", ".gltf")


def _check_self_contained_gltf(data: bytes) -> None:
    """An uploaded .gltf may carry its buffers and images only as ``data:`` URIs: a reference to a
    file or a URL would make the server read it (:class:`BadInput`)."""
    try:
        doc = json.loads(data)
    except (ValueError, RecursionError) as exc:
        raise BadInput(f"cannot read the .gltf upload as JSON ({type(exc).__name__})") from exc
    if not isinstance(doc, dict):
        raise BadInput("a .gltf upload must be a JSON object")
    for key in ("buffers", "images"):
        items = doc.get(key) or []
        if not isinstance(items, list):
            raise BadInput(f".gltf {key} must be a list")
        for item in items:
            uri = item.get("uri") if isinstance(item, dict) else None
            if isinstance(uri, str) and not uri.startswith("data:"):
                raise BadInput(f"a .gltf upload must be self-contained: {key} refer to {uri[:80]!r} (embed them as data: URIs, or send a .glb)")


# ------------------------------------------------------------------------------------------- edits
EDIT_FIELDS = ("hue", "saturation", "value", "prompt", "roughness", "metallic")
HUE_RANGE = (-360.0, 360.0)
SCALE_RANGE = (0.0, 4.0)  # saturation and value scales
THUMB_SIZES = (8, 1024)


@dataclass(frozen=True)
class GroupEdit:
    """A non-destructive edit of one group texture: re-paint with ``prompt`` (None: keep the
    texture), then rotate the hue by ``hue`` degrees and scale saturation and value."""

    hue: float = 0.0
    saturation: float = 1.0
    value: float = 1.0
    prompt: str | None = None
    roughness: float | None = None  # the group's roughness map moved to this mean (None: as painted)
    metallic: float | None = None  # the same for metalness

    @property
    def identity(self) -> bool:
        return self.prompt is None and self.hue == 0.0 and self.saturation == 1.0 and self.value == 1.0 and not self.changes_maps

    @property
    def changes_colour(self) -> bool:
        """Whether the edit changes the group's base colour (a re-paint or an HSV shift)."""
        return self.prompt is not None or self.hue != 0.0 or self.saturation != 1.0 or self.value != 1.0

    @property
    def changes_maps(self) -> bool:
        """Whether the edit changes the group's PBR maps (a re-paint, roughness or metalness): an HSV
        shift leaves them as they are."""
        return self.prompt is not None or self.roughness is not None or self.metallic is not None


def _number(name: str, raw: Any, default: float | None, lo: float, hi: float) -> float | None:
    if raw is None or raw == "":
        return default
    if isinstance(raw, bool) or not isinstance(raw, (int, float, str)):
        raise BadInput(f"{name} must be a number, got {raw!r}")
    try:
        v = float(raw)
    except ValueError:
        raise BadInput(f"{name} must be a number, got {raw!r}") from None
    if not math.isfinite(v):
        raise BadInput(f"{name} must be a finite number, got {raw!r}")
    if not lo <= v <= hi:
        raise BadInput(f"{name} must be in [{lo:g}, {hi:g}], got {v:g}")
    return v


def parse_edit(raw: Any, max_prompt: int = MAX_PROMPT, extra: tuple[str, ...] = ()) -> GroupEdit:
    """A :class:`GroupEdit` from a JSON object or query parameters (strings accepted); raises
    :class:`BadInput` with a clear message. Keys in ``extra`` are allowed and ignored."""
    if not isinstance(raw, dict):
        raise BadInput(f"an edit must be a JSON object with some of {', '.join(EDIT_FIELDS)}, got {type(raw).__name__}")
    unknown = sorted(set(raw) - set(EDIT_FIELDS) - set(extra))
    if unknown:
        raise BadInput(f"unknown edit field(s) {', '.join(map(repr, unknown))}; known: {', '.join(EDIT_FIELDS)}")
    prompt = raw.get("prompt")
    if prompt is not None:
        if not isinstance(prompt, str):
            raise BadInput(f"prompt must be a string, got {type(prompt).__name__}")
        prompt = " ".join(prompt.split())  # one line, single spaces
        if len(prompt) > max_prompt:
            raise BadInput(f"prompt of {len(prompt)} characters is over the limit of {max_prompt}")
        prompt = prompt or None
    return GroupEdit(
        hue=_number("hue", raw.get("hue"), 0.0, *HUE_RANGE),
        saturation=_number("saturation", raw.get("saturation"), 1.0, *SCALE_RANGE),
        value=_number("value", raw.get("value"), 1.0, *SCALE_RANGE),
        prompt=prompt,
        roughness=_number("roughness", raw.get("roughness"), None, 0.0, 1.0),
        metallic=_number("metallic", raw.get("metallic"), None, 0.0, 1.0),
    )


_EDIT_LOCK = threading.Lock()  # persisted edits rewrite store files: one at a time per process




#: A mesh is served when its coordinates are below this and its extent is at least this share of
#: its distance from the origin: GLB positions are float32 (24-bit mantissa), so a shape 1e9 from
#: the origin and a metre wide would collapse to a point, and 1e300 overflows every norm.
MAX_COORDINATE = 1e12
MIN_EXTENT_SHARE = 1e-5


def check_extent(shape) -> None:
    """:class:`BadInput` naming the problem for a mesh whose positions cannot be served without
    losing its shape: non-finite, beyond :data:`MAX_COORDINATE`, of no extent, or so far from the
    origin for its size that float32 positions would merge its vertices."""
    v = shape.vertices
    if not v.size:
        return
    if not np.isfinite(v).all():
        raise BadInput("the mesh has non-finite vertex positions (NaN or infinity)")
    reach = float(np.abs(v).max())
    if reach > MAX_COORDINATE:
        raise BadInput(f"the mesh reaches {reach:.3g} from the origin (at most {MAX_COORDINATE:.0e}): scale or move it near the origin")
    extent = float((v.max(axis=0) - v.min(axis=0)).max())
    if extent <= 0.0 or not np.isfinite(extent):
        raise BadInput("the mesh has no extent (every vertex at one point)")
    if extent < MIN_EXTENT_SHARE * reach:
        raise BadInput(f"the mesh is {extent:.3g} wide but {reach:.3g} from the origin: float32 positions would collapse it; "
                       "move it near the origin")


class FamilyService:
    """One built family, loaded for transfer."""

    def __init__(self, store: FamilyStore, name: str | None = None, limits: Limits | None = None, mapper: str = "auto",
                 device: str = "cpu", family: Family | None = None, look: str | None = None) -> None:
        """Load the family in ``store``; ``mapper``: a :mod:`proctex.transfer.methods` name
        ("auto": the group networks where trained, the default); ``device``: where the networks and a
        cage fallback run ("cpu", "cuda", "cuda:<i>"; ``ValueError`` when CUDA is asked for and absent);
        ``family``: the family's records when the caller has opened them (a catalog, :class:`Family`),
        else opened here, once, under the edit lock;
        ``look``: the family's look to texture with (:mod:`proctex.store.looks`; default: the build's)."""
        from proctex.correspond.corrnet import resolve_device
        from proctex.serve.edits import edit_lock, read_again
        from proctex.texture.painters import SurfacePainter
        from proctex.transfer.assets import template_assets
        from proctex.transfer.methods import get_method, make_mapper

        t0 = time.perf_counter()
        method = get_method(mapper)  # an unknown name fails before anything is read
        self.device = str(resolve_device(device))
        self.store = store
        self.name = name or Path(store.base).name
        self.limits = limits or Limits()
        self._description: dict[str, Any] | None = None  # describe()'s, made once

        def read() -> None:
            with edit_lock(store, shared=True):  # the template's files as one version, never half an edit
                opened = Family.open(store, family.state if family is not None else None)  # its version hashed under the lock
                self.family, self.state, self.stamp = opened, opened.state, opened.version  # one version value
                self.config = opened.config
                self.source_kind = source_kind(self.config.source)  # the source is opened on first use (model)
                self.up = self.config.up_axis()  # GLBs stand the shape upright in glTF's +Y-up world
                self.look = resolve_look(store, look)
                self.paint = look_paint(store, self.look, self.config.paint)  # the look's prompts paint new parts
                self.assets = template_assets(opened.template(self.look))
                # every method that uses the networks loads them ("auto": where there are any)
                self.models = opened.networks(self.device) if method.networks != "none" else {}
                # what describe() says, read with the rest: the description is of the version loaded
                self.paint_record = store.read_json(self.look.PAINT) if store.exists(self.look.PAINT) else {}
                self.metrics_record = opened.metrics
                self.look_names = [lk.name for lk in opened.looks]
                self.space = opened.space  # recorded: a .blend family's Blender is not started to read it

        read_again(read)  # on an object store, again if an edit ran while it read
        self._digest_textures()
        if method.networks == "required" and not self.models:
            raise ValueError(f"{store.uri} has no trained models (run the train stage)")
        cage = replace(self.config.cage, device=self.device) if self.config.cage is not None else None
        self.mapper: Any = make_mapper(mapper, self.assets, self.models, corr_points=self.config.corr_points, cage=cage)
        self.painter = SurfacePainter(self.paint.prompt, seed=self.config.seed)
        self.load_seconds = time.perf_counter() - t0
        self.lock = threading.Lock()  # transfers share the torch models and the painter
        # Edited group textures: (group, GroupEdit) -> (uint8 texture, PNG); re-paints: (group, prompt) -> float texture.
        self.edit_cache_size = 32
        self._clear_edit_caches()
        self._views: dict[str, FamilyService] = {self.look.name: self}  # the family's looks, each made when first asked for
        self._views_lock = threading.Lock()

    @property
    def model(self) -> Any:
        """The family's procedural model (None for a folder of meshes, which takes meshes only),
        opened on first use, once per process: loading a ``.blend`` family starts no Blender; its
        first transfer by parameters does."""
        return self.config.procedural_model() if self.source_kind.regenerates else None

    def _clear_edit_caches(self) -> None:
        """Empty caches of this look's edited textures and re-paints (each look keeps its own)."""
        self._edited: OrderedDict[tuple[int, GroupEdit], tuple[Any, bytes]] = OrderedDict()
        self._repaints: OrderedDict[tuple[int, str], Any] = OrderedDict()
        self._edit_lock = threading.Lock()
        self.edit_stats = {"hits": 0, "misses": 0, "repaints": 0}

    def _digest_textures(self) -> None:
        """The sha256 of every stored texture and PBR map (ETags, linked URIs) of this look."""
        self.texture_digests = [hashlib.sha256(png).hexdigest() for png in self.assets.png]
        self.map_digests = [None if m is None else (hashlib.sha256(m.orm).hexdigest(), hashlib.sha256(m.normal).hexdigest())
                            for m in (self.assets.pbr_png or [None] * len(self.assets.png))]

    # ------------------------------------------------------------------------------------ looks
    def look_view(self, name: str | None) -> "FamilyService":
        """This family textured as its look ``name`` (None, or this service's own look: itself):
        the same shapes, networks and mapper, that look's textures, PBR maps, masks and prompt
        (:func:`proctex.transfer.assets.with_look`), made on first use and kept. :class:`NotFound`
        for a look the family does not have."""
        from proctex.serve.edits import edit_lock, read_again
        from proctex.store.looks import UnknownLook
        from proctex.store.template import LookImages
        from proctex.texture.painters import SurfacePainter
        from proctex.transfer.assets import with_look

        if name is None or name == self.look.name:
            return self
        with self._views_lock:
            view = self._views.get(name)
            if view is not None:
                return view
            def read() -> tuple[Any, Any, Any]:
                with edit_lock(self.store, shared=True):  # the look's files as one version
                    found = resolve_look(self.store, name)
                    return found, LookImages.read(self.store, found), self.store.read_json(found.PAINT) if self.store.exists(found.PAINT) else {}

            try:
                look, images, paint_record = read_again(read)
            except UnknownLook as exc:
                raise NotFound(str(exc)) from None
            view = copy.copy(self)
            view.look, view.paint = look, look_paint(self.store, look, self.config.paint)
            view.paint_record, view._description = paint_record, None
            view.assets = with_look(self.assets, images)
            view._digest_textures()
            view.painter = SurfacePainter(view.paint.prompt, seed=self.config.seed)
            view._clear_edit_caches()
            view._views, view._views_lock = self._views, self._views_lock  # one table for every look of the family
            self._views[name] = view
            return view

    def looks(self) -> list[dict[str, Any]]:
        """The family's looks (:func:`proctex.store.looks.look_summary`), the build's first."""
        from proctex.store.looks import look_summary

        return [look_summary(self.store, lk, self.config.paint) for lk in looks(self.store)]

    def _look_query(self, sep: str = "&") -> str:
        """The query part naming this service's look in a linked texture's URI ("" for the build's)."""
        return "" if self.look.built else f"{sep}look={self.look.name}"

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
            "source": {**{k.name: bool(self.config.source.value(k.name)) for k in source_kinds()}, "model": self.config.source.model,
                       "kind": self.source_kind.name},
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
            "groups": [{"group": g.group, "label": g.label, "names": self.assets.grouping.names(self.assets.grouping.groups[g.group]),
                        "degenerate": g.degenerate, "network": g.group in self.models,
                        "material": self.assets.names[g.group] if g.group < len(self.assets.names) else None,
                        "prompt": next((p.get("prompt") for p in paint.get("groups", []) if p.get("group") == g.group), None),
                        "texture_size": list(texture_hw(self.assets, g.group)), **self._material_means(g.group)}
                       for g in self.assets.groups],
            "edits": len(paint.get("edits", [])),
            "stages": {k: v.get("state") for k, v in self.state.stages.items()},
            "stamp": self.stamp,
            "metrics": None if metrics is None else {k: {kk: vv for kk, vv in v.items() if kk != "per_shape"} for k, v in metrics.get("methods", {}).items()},
            "limits": {"max_bytes": self.limits.max_bytes, "max_vertices": self.limits.max_vertices, "max_faces": self.limits.max_faces,
                       "max_prompt": self.limits.max_prompt},
        }

    # --------------------------------------------------------------------------------- transfer
    def shape_from_params(self, params: Any):
        if not self.source_kind.regenerates:
            raise BadInput(f"family {self.name!r} comes from a folder of meshes: send a mesh, not parameters")
        if not isinstance(params, dict):
            raise BadInput("params must be a JSON object of parameter values")
        try:
            shape = self.model.generate(params)
        except (ValueError, OverflowError, RecursionError) as exc:
            raise BadInput(str(exc)[:500] or type(exc).__name__) from exc
        return self.check_shape(shape)

    def check_shape(self, shape):
        """``shape`` if within the limits on vertices, faces (:class:`TooLarge`) and parts
        (:class:`BadInput`: every part beyond the template's is matched on its own)."""
        from proctex.geometry.parts import parts_of

        if shape.n_vertices > self.limits.max_vertices or shape.n_faces > self.limits.max_faces:
            raise TooLarge(f"mesh has {shape.n_vertices} vertices and {shape.n_faces} faces; limits are "
                           f"{self.limits.max_vertices} and {self.limits.max_faces}")
        check_extent(shape)
        n_parts = parts_of(shape).n_parts if shape.n_faces else 0  # kept on the shape for the transfer
        if n_parts > self.limits.max_parts:
            raise BadInput(f"mesh has {n_parts} parts (connected components); the limit is {self.limits.max_parts}")
        return shape

    def check_declared(self, data: bytes, suffix: str) -> None:
        """What the upload's header declares against the limits, before any parse
        (:func:`proctex.geometry.meshcounts.declared_counts`): :class:`TooLarge` for more vertices or
        triangles than allowed, :class:`BadInput` for a header that cannot be read or a node tree
        too deep."""
        from proctex.geometry.meshcounts import declared_counts

        try:
            c = declared_counts(data, suffix.lstrip("."), "the upload")
        except ValueError as exc:
            raise BadInput(str(exc)) from exc
        if c.vertices is not None and c.vertices > self.limits.max_vertices:
            raise TooLarge(f"the upload declares {c.vertices} vertices; the limit is {self.limits.max_vertices}")
        if c.triangles is not None and c.triangles > self.limits.max_faces:
            raise TooLarge(f"the upload declares {c.triangles} faces (triangles); the limit is {self.limits.max_faces}")

    def shape_from_mesh(self, data: bytes, filename: str = "mesh.obj", budget: Any = None):
        """The shape of an uploaded mesh file, its header checked against the limits first
        (:meth:`check_declared`). With a ``budget`` (a request's) the file is read in the mesh
        reader process (:mod:`proctex.serve.parse_worker`), killed when the budget runs out or is
        cancelled (:class:`~proctex.transfer.budget.OverBudget`); without, here."""
        from proctex.geometry.meshio import load_mesh_bytes

        if len(data) > self.limits.max_bytes:
            raise TooLarge(f"mesh of {len(data)} bytes is over the limit of {self.limits.max_bytes}")
        suffix = Path(filename or "mesh.obj").suffix.lower() or ".obj"
        if suffix not in MESH_SUFFIXES:
            raise BadInput(f"unsupported mesh type {suffix!r}; send one of {', '.join(MESH_SUFFIXES)}")
        if not data:
            raise BadInput("empty mesh upload")
        if suffix == ".gltf":
            _check_self_contained_gltf(data)
        self.check_declared(data, suffix)
        name = f"upload{suffix}"
        try:
            if budget is not None:  # a request's: read where it can be stopped
                from proctex.serve.parse_worker import READER, ReadTimeout

                budget.check("reading the mesh")
                left = max(0.1, budget.seconds - budget.elapsed()) if budget.seconds is not None else self.limits.max_seconds
                try:
                    shape = READER.read(data, name, groups=True, seconds=left, cancelled=lambda: budget.cancelled)
                except ReadTimeout as exc:
                    raise OverBudget(f"{exc} (reading the mesh)", cancelled=budget.cancelled) from None
            else:
                shape, _ = load_mesh_bytes(data, name, groups=True)  # OBJ groups are parts (the add-on's part attribute)
        except OverBudget:
            raise
        except Exception as exc:  # ValueError, or a parser crashing on garbage: the client's bad mesh
            text = str(exc).replace(name, Path(filename or "mesh").name)[:300]
            raise BadInput(f"cannot read the mesh: {text if isinstance(exc, ValueError) else exc.__class__.__name__ + ': ' + text}") from exc
        return self.check_shape(shape)

    def transfer(self, shape, seed: int = 0, edits: dict[int, GroupEdit] | None = None, budget: Any = None,
                 linked: bool = False) -> tuple[bytes, dict[str, Any]]:
        """Textured GLB bytes of ``shape`` and a summary (timings, notes); see :meth:`textured`."""
        answer, summary = self.textured(shape, seed, edits, budget=budget, linked=linked)
        return answer.data, summary

    def texture_uris(self, edited: Any = (), base: str | None = None) -> list[str | None]:
        """Per template group the URI of its texture, relative to the transfer route's URL
        (``textures/<g>.png?v=<digest>``, see :meth:`texture_png`), or None for the groups in
        ``edited`` (a per-request edit: that texture is this answer's own, so it is embedded).
        ``base``: another folder the textures lie in (files named as :meth:`shared_textures` names
        them, no version query: e.g. ``../textures/`` for files written next to a folder of GLBs)."""
        if base is not None:
            return [None if g in edited else f"{base}{g}.png" for g in range(len(self.texture_digests))]
        look = self._look_query()
        return [None if g in edited else f"textures/{g}.png?v={d[:16]}{look}" for g, d in enumerate(self.texture_digests)]

    def shared_textures(self) -> dict[str, bytes]:
        """``{file name: PNG bytes}`` of every texture and PBR map of the family, as linked answers
        name them without a version (``<g>.png``, ``<g>.orm.png``, ``<g>.normal.png``)."""
        out = {f"{g}.png": png for g, png in enumerate(self.assets.png)}
        for g, maps in enumerate(self.assets.pbr_png or []):
            if maps is not None:
                out[f"{g}.orm.png"], out[f"{g}.normal.png"] = maps.orm, maps.normal
        return out

    def _material_means(self, group: int) -> dict[str, Any]:
        """``{"pbr": bool, "roughness": mean, "metallic": mean}`` of a group's maps over its painted
        texels (what the studio's sliders start at); ``{"pbr": False}`` without maps."""
        import numpy as np

        maps = self.assets.pbr[group] if self.assets.pbr is not None else None
        if maps is None:
            return {"pbr": False}
        orm = maps.orm_uint8()
        mask = self.assets.painted[group] if self.assets.painted is not None and self.assets.painted[group].shape == orm.shape[:2] else np.ones(orm.shape[:2], bool)
        return {"pbr": True, "roughness": round(float(orm[..., 1][mask].mean()) / 255, 3), "metallic": round(float(orm[..., 2][mask].mean()) / 255, 3)}

    def map_uris(self, edits: dict[int, GroupEdit] | None = None, base: str | None = None) -> list[tuple[str, str] | None] | None:
        """Per template group the URIs of its PBR maps (``textures/<g>.orm.png?v=...``,
        ``textures/<g>.normal.png?v=...``; None for a map this answer carries itself: the ORM after a
        re-paint or a roughness / metallic edit, the normal map after a re-paint), or None for a group
        without maps; None when the family has no maps."""
        if self.assets.pbr_png is None:
            return None
        out: list[tuple[str | None, str | None] | None] = []
        for g, d in enumerate(self.map_digests):
            edit = (edits or {}).get(g)
            if d is None:
                out.append(None)
                continue
            orm_uri = f"{base}{g}.orm.png" if base is not None else f"textures/{g}.orm.png?v={d[0][:16]}{self._look_query()}"
            normal_uri = f"{base}{g}.normal.png" if base is not None else f"textures/{g}.normal.png?v={d[1][:16]}{self._look_query()}"
            orm = None if edit is not None and edit.changes_maps else orm_uri
            normal = None if edit is not None and edit.prompt is not None else normal_uri
            out.append((orm, normal))
        return out

    def texture_png(self, group: Any) -> tuple[bytes, str]:
        """``(PNG bytes, sha256 digest)`` of a template group's texture as stored (edits included);
        ``group`` may end in one ``.orm`` or ``.normal`` for one of its PBR maps (``0.normal.orm`` is
        no group)."""
        kind = ""
        text = str(group)
        for k in MAP_KINDS:
            if text.endswith("." + k):
                text, kind = text[: -len(k) - 1], k
                break
        g = self.group_index(text, missing=NotFound)
        if not kind:
            return self.assets.png[g], self.texture_digests[g]
        if self.assets.pbr_png is None or self.assets.pbr_png[g] is None:
            raise NotFound(f"group {g} has no {kind} map (a family painted before PBR maps were made)")
        return getattr(self.assets.pbr_png[g], kind), self.map_digests[g][MAP_KINDS.index(kind)]

    def edited_maps(self, group: int, edit: GroupEdit) -> Any:
        """The group's PBR maps after ``edit`` as PNGs (:class:`proctex.texture.pbr.PbrMaps`), the
        maps :func:`proctex.serve.edits.edit_group` would store: a re-paint makes them again, a
        roughness / metallic edit moves those channels; None when the family has no maps."""
        from proctex.fileio import encode_png
        from proctex.serve.edits import adjust_orm, repaint_maps
        from proctex.texture.pbr import PbrMaps

        if self.assets.pbr_png is None or self.assets.pbr_png[group] is None:
            return None
        if not edit.changes_maps:
            return self.assets.pbr_png[group]
        key = ("maps", group, edit.prompt, edit.roughness, edit.metallic)
        with self._edit_lock:
            hit = self._edited.get(key)
            if hit is not None:
                self._edited.move_to_end(key)
                return hit
        if edit.prompt is not None:
            ga = self.assets.groups[group]
            fresh = repaint_maps(edit.prompt, group, ga.label, self.assets.shape, self.assets.grouping.parts[ga.rep].faces, ga.corner_uv,
                                 texture_hw(self.assets, group), seed=self.config.seed)
            orm, normal = fresh.orm_uint8(), encode_png(fresh.normal_uint8())
        else:
            orm, normal = self.assets.pbr[group].orm, self.assets.pbr_png[group].normal
        if edit.roughness is not None or edit.metallic is not None:  # means over the painted texels, as the studio shows them
            orm = adjust_orm(orm, edit.roughness, edit.metallic, self.assets.painted[group] if self.assets.painted is not None else None)
        out = PbrMaps(encode_png(orm), normal, self.assets.pbr[group].occlusion)
        with self._edit_lock:
            self._edited[key] = out
            while len(self._edited) > self.edit_cache_size:
                self._edited.popitem(last=False)
        return out

    def textured(self, shape, seed: int = 0, edits: dict[int, GroupEdit] | None = None,
                 bake_size: int | None = None, budget: Any = None, linked: bool = False, link_base: str | None = None) -> tuple[Any, dict[str, Any]]:
        """``shape`` textured by the family (:func:`proctex.transfer.apply.shape_to_glb`, a
        :class:`~proctex.transfer.apply.TexturedGLB`) and a summary (timings, notes).

        ``edits`` ({group index: :class:`GroupEdit`}, see :meth:`parse_edits`) use edited copies of
        those group textures in this GLB only; the family is unchanged. ``bake_size``: give the shape
        its own atlas of that size instead of the template's textures. ``budget``
        (:class:`proctex.transfer.budget.Budget`): past it, or cancelled, the transfer stops with
        :class:`~proctex.transfer.budget.OverBudget`. ``linked``: the GLB refers to the template's
        textures by URI (:meth:`texture_uris`) instead of carrying them, so a client that caches
        them is sent the geometry and UVs only; ``link_base``: the folder those URIs point into
        instead of the texture route (:meth:`texture_uris`)."""
        from proctex.transfer.apply import check_transfer_args, info, shape_to_glb

        try:
            check_transfer_args(seed, bake_size)
        except ValueError as exc:
            raise BadInput(str(exc)) from exc
        t0 = time.perf_counter()
        assets = self.assets
        if edits:  # an edited copy of those groups' images, arrays and bytes together (a bake samples the edited colours)
            edited = {g: self.edited_texture(g, edit) for g, edit in edits.items()}
            textures = assets.textures.with_items({g: png for g, (_, png) in edited.items()}, {g: tex for g, (tex, _) in edited.items()})
            maps = assets.pbr
            if maps is not None:
                changed = {g: self.edited_maps(g, edit) for g, edit in edits.items() if edit.changes_maps and assets.pbr_png[g] is not None}
                maps = maps.with_items(changed) if changed else maps
            assets = replace(assets, textures=textures, pbr=maps)
        t_edit = time.perf_counter() - t0
        with self.lock:
            try:
                recoloured = {g for g, e in (edits or {}).items() if e.changes_colour}
                uris = self.texture_uris(recoloured, link_base) if linked and not bake_size else None
                m_uris = self.map_uris(edits, link_base) if linked and not bake_size else None
                answer = shape_to_glb(shape, assets, self.mapper, seed=seed, painter=self.painter, up=self.up, bake_size=bake_size,
                                      budget=budget, texture_uris=uris, map_uris=m_uris)
            except OverBudget:
                raise
            except ValueError as exc:
                raise BadInput(f"cannot texture this shape: {exc}") from exc
        summary = {**info(answer.result), "seconds": round(time.perf_counter() - t0, 4), "faces": shape.n_faces, "vertices": shape.n_vertices,
                   "bytes": len(answer.data)}
        if edits:
            summary["edits"] = {"groups": sorted(edits), "seconds": round(t_edit, 4)}
        return answer, summary

    # ------------------------------------------------------------------------------------ edits
    def group_index(self, key: Any, missing: type[ValueError] = BadInput) -> int:
        """The index of a template group given by index (int or digits) or label; ``missing`` is
        raised for an unknown one."""
        for g in self.assets.groups:
            if (isinstance(key, int) and not isinstance(key, bool) and key == g.group) or (isinstance(key, str) and key in (str(g.group), g.label or "\0")):
                return g.group
        names = ", ".join(f"{g.group}" + (f" ({g.label})" if g.label else "") for g in self.assets.groups)
        raise missing(f"unknown group {key!r} of family {self.name!r}; groups: {names}")

    def parse_edits(self, raw: Any) -> dict[int, GroupEdit]:
        """``{"<group index or label>": {"hue": deg, "saturation": s, "value": v, "prompt": text}}`` ->
        {group index: GroupEdit}, no-op edits left out; raises :class:`BadInput`."""
        if raw is None:
            return {}
        if not isinstance(raw, dict):
            raise BadInput('edits must be a JSON object {"<group index or label>": {"hue": ..., "saturation": ..., "value": ..., "prompt": ...}}')
        if len(raw) > len(self.assets.groups):
            raise BadInput(f"{len(raw)} edits for {len(self.assets.groups)} groups")
        out: dict[int, GroupEdit] = {}
        for key, value in raw.items():
            g = self.group_index(key)
            if g in out:
                raise BadInput(f"group {g} is edited twice (by index and by label)")
            try:
                out[g] = parse_edit(value, self.limits.max_prompt)
            except BadInput as exc:
                raise BadInput(f"edit of group {key!r}: {exc}") from None
        return {g: e for g, e in out.items() if not e.identity}

    def _repainted(self, group: int, prompt: str):
        """The group's texture re-painted with ``prompt`` (float, before any HSV shift; cached)."""
        from proctex.serve.edits import edit_texture

        key = (group, prompt)
        with self._edit_lock:
            if key in self._repaints:
                self._repaints.move_to_end(key)
                return self._repaints[key]
        ga = self.assets.groups[group]
        tex, _, _ = edit_texture(self.assets.textures[group], group, ga.label, prompt=prompt, template=self.assets.shape,
                                 rep_faces=self.assets.grouping.parts[ga.rep].faces, rep_corner_uv=ga.corner_uv, seed=self.config.seed)
        with self._edit_lock:
            self.edit_stats["repaints"] += 1
            self._repaints[key] = tex
            while len(self._repaints) > max(1, self.edit_cache_size // 4):
                self._repaints.popitem(last=False)
        return tex

    def edited_texture(self, group: int, edit: GroupEdit) -> tuple[Any, bytes]:
        """``(uint8 (H, W, 3) texture, PNG bytes)`` of template group ``group`` after ``edit``, the same
        texture :func:`proctex.serve.edits.edit_group` would store (an identity edit: the template's own)."""
        import numpy as np

        from proctex.fileio import encode_png
        from proctex.serve.edits import edit_texture

        if not edit.changes_colour:  # identity, or roughness / metalness only
            return self.assets.textures[group], self.assets.png[group]
        key = (group, edit)
        with self._edit_lock:
            hit = self._edited.get(key)
            if hit is not None:
                self._edited.move_to_end(key)
                self.edit_stats["hits"] += 1
                return hit
        base = self.assets.textures[group] if edit.prompt is None else self._repainted(group, edit.prompt)
        tex, _, _ = edit_texture(base, group, self.assets.groups[group].label, edit.hue, edit.saturation, edit.value)
        tex8 = (np.clip(tex, 0, 1) * 255).round().astype(np.uint8)
        out = (tex8, encode_png(tex8))
        with self._edit_lock:
            self.edit_stats["misses"] += 1
            self._edited[key] = out
            while len(self._edited) > self.edit_cache_size:
                self._edited.popitem(last=False)
        return out

    def thumbnail(self, group: int, edit: GroupEdit, size: Any = 128) -> bytes:
        """PNG of the (edited) group texture scaled to at most ``size`` pixels a side."""
        from PIL import Image

        try:
            n = int(size) if not isinstance(size, bool) else None
        except (TypeError, ValueError):
            n = None
        if n is None or not THUMB_SIZES[0] <= n <= THUMB_SIZES[1]:
            raise BadInput(f"size must be an integer in [{THUMB_SIZES[0]}, {THUMB_SIZES[1]}], got {size!r}")
        tex, png = self.edited_texture(group, edit)
        h, w = tex.shape[:2]
        if max(h, w) <= n:  # never enlarged
            return png
        scale = n / max(h, w)
        img = Image.fromarray(tex).resize((max(1, round(w * scale)), max(1, round(h * scale))), Image.LANCZOS)
        buf = io.BytesIO()
        img.save(buf, format="PNG")
        return buf.getvalue()

    def persist_edit(self, raw: Any, expect_stamp: str | None = None) -> Changed:
        """Store an edit into the family (:func:`proctex.serve.edits.changed_edit`: versioned, under
        the family's edit lock, undoable): ``{"group": index or label, "hue", "saturation", "value",
        "prompt"}``. ``expect_stamp``: the build stamp the edit was made against
        (:class:`~proctex.serve.edits.EditConflict` when the family changed since). Returns the edit
        record and the family's stamp after it, read under the same lock; this service is stale
        afterwards (the catalog reloads the family on its new stamp)."""
        from proctex.serve.edits import EditConflict, changed_edit

        if not isinstance(raw, dict) or "group" not in raw:
            raise BadInput('send {"group": <index or label>, "hue": deg, "saturation": s, "value": v, "prompt": text}')
        g = self.group_index(raw["group"])
        edit = parse_edit(raw, self.limits.max_prompt, extra=("group",))
        if edit.identity:
            raise BadInput("no edit given: send a prompt, a hue, saturation or value change, or a roughness or metallic")
        with _EDIT_LOCK:
            try:
                return changed_edit(self.store, g, expect_stamp=expect_stamp, hue=edit.hue, saturation=edit.saturation, value=edit.value,
                                    prompt=edit.prompt, roughness=edit.roughness, metallic=edit.metallic, look=self.look.name)
            except (EditConflict, StoreDamaged):
                raise
            except ValueError as exc:
                raise BadInput(str(exc)) from exc

    def undo_edit(self, expect_stamp: str | None = None, all_edits: bool = False) -> Changed:
        """Undo the family's last stored edit (``all_edits``: every one, back to the painted
        template); returns the undone records and the family's stamp after them, read under the same
        lock. :class:`~proctex.serve.edits.EditConflict` when there is nothing to undo or
        ``expect_stamp`` is stale."""
        from proctex.serve.edits import undo_edits

        with _EDIT_LOCK:
            return undo_edits(self.store, expect_stamp=expect_stamp, look=self.look.name, all_edits=all_edits)


