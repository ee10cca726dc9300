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

import numpy as np

from .materials import shade
from .pbr import height, surface_props
from .prompt import MaterialSpec, parse_prompt
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


class SurfacePainter:
    """Colours surface points from a text prompt, with optional per-group prompts.

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
        self._spec = parse_prompt(prompt)
        self._group_specs: dict[str, MaterialSpec] = {}
        for key, text in (group_prompts or {}).items():
            if isinstance(key, bool) or not isinstance(key, (str, int, np.integer)):
                raise ValueError(f"group_prompts keys must be labels (str) or group ids (int), got {key!r}")
            try:
                self._group_specs[str(key)] = parse_prompt(text)
            except ValueError as exc:
                raise ValueError(f"group prompt for {key!r}: {exc}") from None

    @property
    def spec(self) -> MaterialSpec:
        """The global prompt's spec."""
        return self._spec

    def spec_for(self, group: int | None = None, label: str = "") -> MaterialSpec:
        """The spec used for a group: ``group_prompts[label]``, else ``group_prompts[str(group)]``, else
        the global prompt's."""
        if label and label in self._group_specs:
            return self._group_specs[label]
        if group is not None and str(group) in self._group_specs:
            return self._group_specs[str(group)]
        return self._spec

    def notes(self) -> list[str]:
        """One human-readable line per prompt: what was understood and what was ignored."""
        lines = [f"prompt {self.prompt!r}: {self._spec.notes}"]
        for key, spec in self._group_specs.items():
            lines.append(f"group {key} prompt {spec.prompt!r}: {spec.notes}")
        return lines

    def paint(self, points: np.ndarray, normals: np.ndarray, group: int | None = None, label: str = "") -> np.ndarray:
        """Colours of surface points.

        Args:
            points: ``(n, 3)`` float, in the shape's normalised frame (roughly [-1, 1]^3).
            normals: ``(n, 3)`` float unit normals (renormalised here; zero rows are tolerated).
            group, label: which group prompt applies (see :meth:`spec_for`).
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
        spec = self.spec_for(group, label)
        out = np.empty((len(pts), 3), dtype=np.float32)
        for s in range(0, len(pts), CHUNK):
            p = pts[s : s + CHUNK].astype(np.float32)
            n = _unit(nrm[s : s + CHUNK].astype(np.float32))
            out[s : s + CHUNK] = shade(Ctx(p, n, self.seed, spec.scale), spec).T
        return out


    def material(self, points: np.ndarray, normals: np.ndarray, tangents: np.ndarray, bitangents: np.ndarray,
                 group: int | None = None, label: str = "") -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """PBR properties of surface points: the twin of :meth:`paint` for the other maps.

        Args:
            points, normals: as in :meth:`paint`.
            tangents, bitangents: ``(n, 3)`` unit surface directions of increasing u and v (the frame
                the normal map is expressed in; :func:`proctex.texture.pbr.texel_frames`).
            group, label: which group prompt applies.
        Returns:
            ``(roughness (n,), metallic (n,), normal (n, 3))`` float32: roughness and metalness in
            [0, 1] and the unit tangent-space normal of the relief, ``normalize(-dh/dT, -dh/dB, 1)``
            with ``h`` the material's height (:func:`.pbr.height`), differentiated by central
            differences of :data:`RELIEF_STEP` along the two directions.
        Raises:
            ValueError: as :meth:`paint`, for any of the four arrays.
        """
        pts = _check_array("points", points)
        nrm = _check_array("normals", normals)
        tan = _check_array("tangents", tangents)
        bit = _check_array("bitangents", bitangents)
        if not len(pts) == len(nrm) == len(tan) == len(bit):
            raise ValueError(f"points, normals, tangents and bitangents must have the same length, got {len(pts)}, {len(nrm)}, {len(tan)}, {len(bit)}")
        spec = self.spec_for(group, label)
        n_pts = len(pts)
        rough = np.empty(n_pts, np.float32)
        metal = np.empty(n_pts, np.float32)
        out_n = np.empty((n_pts, 3), np.float32)
        step = np.float32(RELIEF_STEP * spec.scale)
        for s in range(0, n_pts, CHUNK):
            p = pts[s : s + CHUNK].astype(np.float32)
            n = _unit(nrm[s : s + CHUNK].astype(np.float32))
            t = _unit(tan[s : s + CHUNK].astype(np.float32))
            b = _unit(bit[s : s + CHUNK].astype(np.float32))
            r, m, _ = surface_props(Ctx(p, n, self.seed, spec.scale), spec)
            dh = []
            for d in (t, b):
                hp = height(Ctx(p + step * d, n, self.seed, spec.scale), spec)
                hm = height(Ctx(p - step * d, n, self.seed, spec.scale), spec)
                dh.append((hp - hm) / (np.float32(2.0) * step))
            nt = np.stack([-dh[0], -dh[1], np.ones_like(dh[0])], axis=1)
            rough[s : s + CHUNK], metal[s : s + CHUNK] = r, m
            out_n[s : s + CHUNK] = nt / np.linalg.norm(nt, axis=1, keepdims=True)
        return rough, metal, out_n


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
