"""The offline surface painter: prompt -> procedural solid texture evaluated at 3D surface points.

:class:`SurfacePainter` parses the global prompt and per-group prompts once (:func:`.prompt.parse_prompt`)
and colours points with :func:`.materials.shade`. Colour is a pure function of (point, normal, prompt,
seed), evaluated in cache-sized chunks: the same point gets the same colour whatever batch it comes in,
which is what lets the multi-view paint loop reproduce a texture painted texel by texel.

Points are expected in the *shape's* normalised frame (bounding-box centre subtracted, divided by the L∞
radius, so roughly [-1, 1]^3, +z up); pattern scales are set for that frame (about 20 stripes across,
a few wood rings per part, a weave period of 0.03).
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np

from .materials import shade
from .partwords import PartPlan, plan_parts
from .pbr import height, surface_props
from .prompt import MaterialSpec, parse_prompt
from .regions import RegionFrame, region_weight, split_regions
from .shading import Ctx

__all__ = ["SurfacePainter", "CHUNK", "MAX_COORD", "RELIEF_STEP"]

#: largest accepted |coordinate|: points live in the normalised frame (about [-1, 1]); far larger values
#: would overflow the noise lattice (int32 cells) and mean the caller forgot to normalise.
MAX_COORD = 1000.0
#: points per evaluation chunk: keeps each temporary array (~128 KiB) in the L2 cache.
CHUNK = 32768
#: finite-difference step (normalised frame) of the relief's surface gradient: well under the finest
#: feature (wavelength ~0.02), well over float32 resolution at |p| ~ 1.
RELIEF_STEP = 0.0015


@dataclass(frozen=True)
class _Layer:
    """One material of a group: its spec, and where it lies (None: everywhere, the base layer)."""

    spec: MaterialSpec
    region: str | None = None
    frame: RegionFrame | None = None
    named: tuple[str, ...] = ()


class SurfacePainter:
    """Colours surface points from a text prompt, with optional per-group prompts.

    A prompt may place materials in regions ("a dinner fork with a silver tip and a dark wood
    handle", :mod:`.regions`): once the painter knows the shape (:meth:`bind`), clauses naming a part
    group become that group's prompt and region clauses are blended over the rest along the scope's
    own frame. Before :meth:`bind` (or for points of an unknown group) the rest's material is used.

    Args:
        prompt: the global prompt (any string; unknown words are reported in :meth:`notes`).
        group_prompts: optional overrides keyed by part label or group id (``str(group)`` or int).
        seed: texture seed (same seed: bit-identical colours; another seed: a different texture). The seed
            does not depend on the group, so neighbouring parts with the same prompt join seamlessly.
    Raises:
        ValueError: a prompt that is not a string, a key that is neither str nor int, a non-int seed.
    """

    def __init__(self, prompt: str, group_prompts: Mapping[str, str] | None = None, seed: int = 0):
        if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)):
            raise ValueError(f"seed must be an int, got {type(seed).__name__}")
        self.prompt = prompt
        self.seed = int(seed)
        self._plan = split_regions(prompt)
        self._spec = parse_prompt(self._plan.base if self._plan.has_regions else prompt)
        self._group_texts: dict[str, str] = {}
        self._group_specs: dict[str, MaterialSpec] = {}
        for key, text in (group_prompts or {}).items():
            if isinstance(key, bool) or not isinstance(key, (str, int, np.integer)):
                raise ValueError(f"group_prompts keys must be labels (str) or group ids (int), got {key!r}")
            try:
                plan = split_regions(text)
                self._group_specs[str(key)] = parse_prompt(plan.base if plan.has_regions else text)
            except ValueError as exc:
                raise ValueError(f"group prompt for {key!r}: {exc}") from None
            self._group_texts[str(key)] = text
        self._bound: dict | None = None
        self._parts: PartPlan | None = None
        self._layers: dict[tuple[int | None, str], tuple[_Layer, ...]] = {}

    def bind(self, shape, grouping, up: str = "z", parts: PartPlan | None = None) -> "SurfacePainter":
        """Let the painter place the prompt's regions and parts on ``shape`` (a
        :class:`proctex.geometry.shape.Shape`) with its ``grouping``: clauses naming a part (by label
        or by what the part is, :mod:`.partwords`) paint that group in its representative's frame, the
        rest's regions lie in the whole shape's frame; ``up`` ("x", "y" or "z") is the shape's up
        axis. ``parts``: the prompt's :class:`PartPlan` on this shape when the caller has it.
        Returns the painter."""
        from proctex.geometry.surface import normalised_frame

        if up not in ("x", "y", "z"):
            raise ValueError(f"up must be x, y or z, got {up!r}")
        center, radius = normalised_frame(shape.vertices)
        vn = (np.asarray(shape.vertices, dtype=np.float64) - center) / (radius if radius > 0 else 1.0)
        reps = {g.index: np.asarray(shape.faces)[grouping.parts[g.representative].faces] for g in grouping.groups}
        self._bound = {"vertices": vn, "faces": np.asarray(shape.faces), "reps": reps, "up": "xyz".index(up), "frames": {}}
        self._parts = parts if parts is not None else plan_parts(self.prompt, shape.vertices, shape.faces, grouping, up)
        self._plan = self._parts.regions
        self._layers = {}
        return self

    def _frame(self, scope: int | None) -> RegionFrame:
        frames = self._bound["frames"]
        if scope not in frames:
            faces = self._bound["faces"] if scope is None else self._bound["reps"][scope]
            frames[scope] = RegionFrame.from_mesh(self._bound["vertices"], faces, self._bound["up"])
        return frames[scope]

    def _layers_for(self, group: int | None, label: str) -> tuple[_Layer, ...]:
        key = (group, label)
        if key in self._layers:
            return self._layers[key]
        text = None
        if label and label in self._group_texts:
            text = self._group_texts[label]
        elif group is not None and str(group) in self._group_texts:
            text = self._group_texts[str(group)]
        scope: int | None = group
        if text is None or text == self.prompt:  # the global prompt (make_painter repeats it per group)
            routed = self._parts.texts.get(group) if self._parts is not None and group is not None else None
            if routed is not None:  # a clause naming the group, or what it borrows (PartPlan)
                plan = split_regions(routed)
            else:
                plan, scope = self._plan, None
        else:
            plan = split_regions(text)
        if not plan.has_regions:
            layers: tuple[_Layer, ...] = (_Layer(parse_prompt(plan.prompt)),)
        elif self._bound is None or (scope is not None and scope not in self._bound["reps"]):
            layers = (_Layer(parse_prompt(plan.base)),)
        else:
            frame = self._frame(scope)
            named = tuple(r for r, _ in plan.regions)
            layers = (_Layer(parse_prompt(plan.base)),) + tuple(_Layer(parse_prompt(t), r, frame, named) for r, t in plan.regions)
        self._layers[key] = layers
        return layers

    @property
    def spec(self) -> MaterialSpec:
        """The global prompt's spec (its rest's, when it names regions)."""
        return self._spec

    def spec_for(self, group: int | None = None, label: str = "") -> MaterialSpec:
        """The spec used for a group (the rest's, where regions add others): ``group_prompts[label]``,
        else ``group_prompts[str(group)]``, else a clause of the global prompt naming the group, else
        the global prompt's."""
        return self._layers_for(group, label)[0].spec

    def region_notes(self) -> list[str]:
        """What the global prompt's region and part clauses became (none without them)."""
        lines = []
        if self._plan.has_regions:
            lines.append(f"prompt {self.prompt!r} regions: " + "; ".join(self._plan.notes))
            if self._bound is None:
                lines.append("regions are placed once the painter knows the shape; painted with the rest's material")
        if self._parts is not None:
            lines.extend(f"prompt {self.prompt!r} parts: {n}" for n in self._parts.notes)
        return lines

    def notes(self) -> list[str]:
        """One human-readable line per prompt: what was understood and what was ignored."""
        head = f"prompt {self.prompt!r}: {self._spec.notes}"
        if self._parts is not None and self._parts.texts and not self._spec.understood:
            head = f"prompt {self.prompt!r}: the rest names no material; its groups are painted from the clauses naming parts"
        lines = [head, *self.region_notes()]
        for key, spec in self._group_specs.items():
            if self._group_texts[key] != self.prompt:
                lines.append(f"group {key} prompt {spec.prompt!r}: {spec.notes}")
        return lines

    def _text_layers(self, text: str) -> tuple[_Layer, ...]:
        """The layers of a text painted without a place on the template (a new part at run time):
        its rest's material (its regions have no frame there)."""
        key = (None, "text:" + text)
        if key not in self._layers:
            plan = split_regions(text)
            self._layers[key] = (_Layer(parse_prompt(plan.base if plan.has_regions and plan.base else text)),)
        return self._layers[key]

    def paint(self, points: np.ndarray, normals: np.ndarray, group: int | None = None, label: str = "", text: str | None = None) -> np.ndarray:
        """Colours of surface points.

        Args:
            points: ``(n, 3)`` float, in the shape's normalised frame (roughly [-1, 1]^3).
            normals: ``(n, 3)`` float unit normals (renormalised here; zero rows are tolerated).
            group, label: which group prompt applies (see :meth:`spec_for`).
            text: paint this text instead (a new part's clause, :func:`.partwords.new_part_texts`).
        Returns:
            ``(n, 3) float32`` RGB in [0, 1]; ``n == 0`` gives an empty array.
        Raises:
            ValueError: shapes other than (n, 3) / mismatched n, non-numeric, NaN or infinite values,
                coordinates beyond :data:`MAX_COORD`.
        """
        pts = _check_array("points", points)
        nrm = _check_array("normals", normals)
        if len(pts) != len(nrm):
            raise ValueError(f"points and normals must have the same length, got {len(pts)} and {len(nrm)}")
        if text is not None and not isinstance(text, str):
            raise ValueError(f"text must be a string, got {type(text).__name__}")
        layers = self._text_layers(text) if text is not None else self._layers_for(group, label)
        out = np.empty((len(pts), 3), dtype=np.float32)
        for s in range(0, len(pts), CHUNK):
            p = pts[s : s + CHUNK].astype(np.float32)
            n = _unit(nrm[s : s + CHUNK].astype(np.float32))
            out[s : s + CHUNK] = _blend(layers, p, n, lambda L, q, m: shade(Ctx(q, m, self.seed, L.spec.scale), L.spec)).T
        return out

    def material(
        self, points: np.ndarray, normals: np.ndarray, tangents: np.ndarray, bitangents: np.ndarray, group: int | None = None, label: str = "", relief: bool = True
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """PBR properties of surface points: the twin of :meth:`paint` for the other maps.

        Args:
            points, normals: as in :meth:`paint`.
            tangents, bitangents: ``(n, 3)`` unit surface directions of increasing u and v (the frame
                the normal map is expressed in; :func:`proctex.texture.pbr.texel_frames`).
            group, label: which group prompt applies.
            relief: differentiate the relief (False: the normal is flat (0, 0, 1), for a caller that
                makes its own, at a fifth of the cost).
        Returns:
            ``(roughness (n,), metallic (n,), normal (n, 3))`` float32: roughness and metalness in
            [0, 1] and the unit tangent-space normal of the relief, ``normalize(-dh/dT, -dh/dB, 1)``
            with ``h`` the material's height (:func:`.pbr.height`, blended over regions like the
            colour), differentiated by central differences of :data:`RELIEF_STEP` along the two
            directions.
        Raises:
            ValueError: as :meth:`paint`, for any of the four arrays.
        """
        pts = _check_array("points", points)
        nrm = _check_array("normals", normals)
        tan = _check_array("tangents", tangents)
        bit = _check_array("bitangents", bitangents)
        if not len(pts) == len(nrm) == len(tan) == len(bit):
            raise ValueError(f"points, normals, tangents and bitangents must have the same length, got {len(pts)}, {len(nrm)}, {len(tan)}, {len(bit)}")
        layers = self._layers_for(group, label)
        n_pts = len(pts)
        rough = np.empty(n_pts, np.float32)
        metal = np.empty(n_pts, np.float32)
        out_n = np.empty((n_pts, 3), np.float32)
        step = np.float32(RELIEF_STEP * layers[0].spec.scale)

        def props(L, q, m):
            r, mt, _ = surface_props(Ctx(q, m, self.seed, L.spec.scale), L.spec)
            return np.stack([r, mt])

        def relief(L, q, m):
            return height(Ctx(q, m, self.seed, L.spec.scale), L.spec)[None]

        for s in range(0, n_pts, CHUNK):
            p = pts[s : s + CHUNK].astype(np.float32)
            n = _unit(nrm[s : s + CHUNK].astype(np.float32))
            t = _unit(tan[s : s + CHUNK].astype(np.float32))
            b = _unit(bit[s : s + CHUNK].astype(np.float32))
            rm = _blend(layers, p, n, props)
            rough[s : s + CHUNK], metal[s : s + CHUNK] = rm[0], rm[1]
            if not relief:
                out_n[s : s + CHUNK] = (0.0, 0.0, 1.0)
                continue
            dh = []
            for d in (t, b):
                hp = _blend(layers, p + step * d, n, relief)[0]
                hm = _blend(layers, p - step * d, n, relief)[0]
                dh.append((hp - hm) / (np.float32(2.0) * step))
            nt = np.stack([-dh[0], -dh[1], np.ones_like(dh[0])], axis=1)
            out_n[s : s + CHUNK] = nt / np.linalg.norm(nt, axis=1, keepdims=True)
        return rough, metal, out_n


def _blend(layers: tuple[_Layer, ...], p: np.ndarray, n: np.ndarray, fn) -> np.ndarray:
    """``fn(layer, points, normals) -> (k, n')`` of the base layer, with each region layer laid over it
    by its weight (evaluated only where the weight is not 0). Returns ``(k, n) float32``."""
    out = np.asarray(fn(layers[0], p, n), dtype=np.float32)
    for L in layers[1:]:
        w = region_weight(L.region, L.frame, p, n, L.named).astype(np.float32)
        sel = np.flatnonzero(w > 0)
        if len(sel) == 0:
            continue
        val = np.asarray(fn(L, np.ascontiguousarray(p[sel]), np.ascontiguousarray(n[sel])), dtype=np.float32)
        out[:, sel] += (val - out[:, sel]) * w[sel]
    return out


def _unit(a: np.ndarray) -> np.ndarray:
    length = np.sqrt((a * a).sum(axis=1, keepdims=True))
    return np.divide(a, length, out=np.zeros_like(a), where=length > 1e-12)


def _check_array(name: str, a) -> np.ndarray:
    try:
        arr = np.asarray(a)
    except Exception as exc:  # ragged lists and the like
        raise ValueError(f"{name} must be an (n, 3) numeric array: {exc}") from None
    if arr.ndim != 2 or arr.shape[1] != 3:
        raise ValueError(f"{name} must have shape (n, 3), got {arr.shape}")
    if not (np.issubdtype(arr.dtype, np.floating) or np.issubdtype(arr.dtype, np.integer)) or arr.dtype == bool:
        raise ValueError(f"{name} must be numeric, got dtype {arr.dtype}")
    if arr.size and not np.isfinite(arr).all():
        raise ValueError(f"{name} contains NaN or infinite values")
    if arr.size and np.abs(arr).max() > MAX_COORD:
        raise ValueError(f"{name} must be in the shape's normalised frame (|coordinate| <= {MAX_COORD:g}), got up to {np.abs(arr).max():.3g}")
    return arr
