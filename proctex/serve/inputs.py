"""What a request brings, checked before any work: the service's errors (each a ``ValueError`` a
server maps to an HTTP code), its :class:`Limits`, a transfer's edits (:class:`GroupEdit`,
:func:`parse_edit`) and the :class:`Inputs` of a loaded family: a shape from parameters or from an
uploaded mesh (its header checked against the limits before it is parsed), a group by index or
label, a request's edits."""

from __future__ import annotations

import json
import math
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from proctex.geometry.meshcounts import declared_counts
from proctex.geometry.meshio import load_mesh_bytes
from proctex.geometry.parts import parts_of
from proctex.serve.timing import StageClock
from proctex.texture.painting import MAX_PROMPT
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
    turn holding no thread): :class:`proctex.looks.LookLimits`. One client (its TCP peer;
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
        for name in (
            "max_bytes",
            "max_vertices",
            "max_faces",
            "max_prompt",
            "max_parts",
            "body_min_rate",
            "max_uploads",
            "max_small_bodies",
            "small_body",
            "look_texels",
            "look_bytes",
            "max_looks",
            "look_paints",
            "client_small_bodies",
            "client_uploads",
        ):
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
        raise BadInput(f"the mesh is {extent:.3g} wide but {reach:.3g} from the origin: float32 positions would collapse it; move it near the origin")


class Inputs:
    """A loaded family's checks of what a request brings (a mixin of
    :class:`proctex.serve.service.FamilyService`: ``self.limits``, ``self.model``, ``self.assets``)."""

    def shape_from_params(self, params: Any, clock: StageClock | None = None):
        """The shape of new parameters, made by the family's model and checked (:meth:`check_shape`);
        ``clock`` (:class:`~proctex.serve.timing.StageClock`) times ``generate`` and ``segment``."""
        clock = clock or StageClock()
        if not self.source_kind.regenerates:
            raise BadInput(f"family {self.name!r} comes from a folder of meshes: send a mesh, not parameters")
        if not isinstance(params, dict):
            raise BadInput("params must be a JSON object of parameter values")
        try:
            with clock.stage("generate"):
                shape = self.model.generate(params)
        except (ValueError, OverflowError, RecursionError) as exc:
            raise BadInput(str(exc)[:500] or type(exc).__name__) from exc
        return self.check_shape(shape, clock)

    def check_shape(self, shape, clock: StageClock | None = None):
        """``shape`` if within the limits on vertices, faces (:class:`TooLarge`) and parts
        (:class:`BadInput`: every part beyond the template's is matched on its own). Its
        segmentation, kept on the shape for the transfer, is timed as ``segment`` on ``clock``."""
        clock = clock or StageClock()
        if shape.n_vertices > self.limits.max_vertices or shape.n_faces > self.limits.max_faces:
            raise TooLarge(f"mesh has {shape.n_vertices} vertices and {shape.n_faces} faces; limits are {self.limits.max_vertices} and {self.limits.max_faces}")
        check_extent(shape)
        with clock.stage("segment"):
            n_parts = parts_of(shape).n_parts if shape.n_faces else 0  # kept on the shape for the transfer
        if n_parts > self.limits.max_parts:
            raise BadInput(f"mesh has {n_parts} parts (connected components); the limit is {self.limits.max_parts}")
        return shape

    def check_declared(self, data: bytes, suffix: str) -> None:
        """What the upload's header declares against the limits, before any parse
        (:func:`proctex.geometry.meshcounts.declared_counts`): :class:`TooLarge` for more vertices or
        triangles than allowed, :class:`BadInput` for a header that cannot be read or a node tree
        too deep."""
        try:
            c = declared_counts(data, suffix.lstrip("."), "the upload")
        except ValueError as exc:
            raise BadInput(str(exc)) from exc
        if c.vertices is not None and c.vertices > self.limits.max_vertices:
            raise TooLarge(f"the upload declares {c.vertices} vertices; the limit is {self.limits.max_vertices}")
        if c.triangles is not None and c.triangles > self.limits.max_faces:
            raise TooLarge(f"the upload declares {c.triangles} faces (triangles); the limit is {self.limits.max_faces}")

    def shape_from_mesh(self, data: bytes, filename: str = "mesh.obj", budget: Any = None, clock: StageClock | None = None):
        """The shape of an uploaded mesh file, its header checked against the limits first
        (:meth:`check_declared`). With a ``budget`` (a request's) the file is read in the mesh
        reader process (:mod:`proctex.serve.parse_worker`), killed when the budget runs out or is
        cancelled (:class:`~proctex.transfer.budget.OverBudget`); without, here. ``clock``
        (:class:`~proctex.serve.timing.StageClock`) times ``parse`` and ``segment``."""
        clock = clock or StageClock()
        t_parse = time.perf_counter()
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
        clock.add("parse", time.perf_counter() - t_parse)
        return self.check_shape(shape, clock)

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
