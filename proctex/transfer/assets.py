"""The template prepared for transfer (:class:`TemplateAssets`): per group its representative in
its normalised frame with UVs, a surface index and its texture, and the slots (template parts) a
shape's parts are assigned to (:mod:`proctex.transfer.assign`)."""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from typing import Any, Sequence

import numpy as np

from proctex.geometry.rowmath import bounds
from proctex.geometry.parts import Grouping, part_mesh, surface_moments
from proctex.geometry.shape import Shape
from proctex.geometry.surface import SurfaceIndex, normalised_frame, sample_surface
from proctex.store.layout import FamilyStore, LookLayout
from proctex.store.state import FamilyState
from proctex.store.template import LookImages, StoredImages, StoredMaps, Template, load_template
from proctex.texture.export import png_bytes
from proctex.texture.pbr import PbrMaps
from proctex.texture.uv import pad_seams, texel_map


@dataclass
class GroupAssets:
    """What transfer needs of one template group (its representative part, in its normalised frame).

    ``vertices (k, 3)`` normalised, ``faces (f, 3)`` local, ``corner_uv (f, 3, 2)``, ``center (3,)``,
    ``radius``, ``index`` a :class:`SurfaceIndex` over the normalised mesh. :meth:`probe` gives
    what matching a left-over part against it needs, computed once.
    """

    group: int
    label: str
    rep: int
    vertices: np.ndarray
    faces: np.ndarray
    corner_uv: np.ndarray
    center: np.ndarray
    radius: float
    index: SurfaceIndex
    degenerate: bool
    _probes: dict = field(default_factory=dict, repr=False, compare=False)

    def probe(self, n: int = 300, seed: int = 0) -> tuple[np.ndarray, np.ndarray, Any]:
        """``(moments (3,), samples (n, 3), tree)`` of the normalised representative: its exact
        surface moments (:func:`proctex.geometry.parts.surface_moments`), ``n`` surface samples
        (``seed``) and a cKDTree over them; computed on first use and kept."""
        if (n, seed) not in self._probes:
            from scipy.spatial import cKDTree

            pts = sample_surface(self.vertices, self.faces, n, seed=seed)[0]
            self._probes[(n, seed)] = (surface_moments(self.vertices, self.faces), pts, cKDTree(pts))
        return self._probes[(n, seed)]


@dataclass
class Slot:
    """A template part as a place a shape part can take: its group and member map (linear part)."""

    part: int
    group: int
    R: np.ndarray  # (3, 3): x_rep = R x_member + t
    center: np.ndarray  # (3,) part centre relative to the shape box, in [0, 1]^3
    extents: np.ndarray  # (3,) part box extents relative to the shape box size


@dataclass(frozen=True)
class TemplateAssets:
    """The template prepared for transfer: groups, slots and its images, one snapshot that is not
    changed after it is made (a new look, masks or an edited preview is a new one,
    :func:`dataclasses.replace`). The textures and PBR maps are one object each that holds both the
    arrays (decoded when first used) and their PNG bytes (:attr:`png`, :attr:`pbr_png`): an edit
    replaces both together (:meth:`proctex.store.template.StoredImages.with_items`), so what is
    sampled and what is embedded cannot disagree.

    Attributes:
        textures: per group its (H, W, 3) uint8 image and PNG (:class:`~proctex.store.template.StoredImages`).
        names: per group its material name.
        painted, observed: per group (H, W) bool: texels holding colour, and the "already painted"
            ones (painted by the painter itself, not filled); None: every texel counts as both.
        pbr: per group its PBR maps and their PNGs (:class:`~proctex.store.template.StoredMaps`),
            or None (no maps).
    """

    shape: Shape
    grouping: Grouping
    groups: list[GroupAssets]
    slots: list[Slot]
    textures: StoredImages
    names: list[str]
    painted: list[np.ndarray] | None = None
    observed: list[np.ndarray] | None = None
    pbr: StoredMaps | None = None
    # made from the fields above when first needed (charts and run-time lookups of the painted
    # masks, :mod:`proctex.transfer.uvlookup`; left-over part matches, :mod:`proctex.transfer.assign`);
    # a new snapshot starts without. Nothing here depends on the images: a copy with other images
    # of the same layout shares them (:func:`with_images`)
    derived: dict[str, Any] = field(default_factory=dict, init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        if not isinstance(self.textures, StoredImages) or (self.pbr is not None and not isinstance(self.pbr, StoredMaps)):
            raise ValueError("TemplateAssets holds its images as StoredImages / StoredMaps (their arrays and PNGs together)")

    @property
    def png(self) -> list[bytes]:
        """Per group the texture's PNG bytes (a store's as stored)."""
        return self.textures.png

    @property
    def pbr_png(self) -> list[Any] | None:
        """Per group its PBR maps as PNG bytes (:class:`proctex.texture.pbr.PbrMaps`) or None; None without maps."""
        return None if self.pbr is None else self.pbr.png


def with_images(assets: TemplateAssets, textures: StoredImages, pbr: StoredMaps | None) -> TemplateAssets:
    """``assets`` with other images of the same layout (a request's edited copies of some groups'
    textures and maps): the geometry, the masks and what was derived from them (the UV lookup's
    tables, left-over part matches: :attr:`TemplateAssets.derived`) shared, not made again."""
    out = dataclasses.replace(assets, textures=textures, pbr=pbr)
    object.__setattr__(out, "derived", assets.derived)  # frozen: set once, here
    return out


def with_textures(assets: TemplateAssets, textures: Sequence[np.ndarray]) -> TemplateAssets:
    """``assets`` with other (H, W, 3) uint8 group textures (encoded here, arrays and bytes together;
    e.g. a measurement's smooth colour field), everything else shared."""
    if len(textures) != len(assets.groups):
        raise ValueError(f"need one texture per group ({len(assets.groups)}), got {len(textures)}")
    return with_images(assets, StoredImages.of_decoded([np.ascontiguousarray(t, dtype=np.uint8) for t in textures], png_bytes), assets.pbr)


def texture_hw(assets: TemplateAssets, group: int) -> tuple[int, int]:
    """(height, width) of a group's texture, decoding nothing where it was read from a store."""
    t = assets.textures
    return t.hw(group) if isinstance(t, StoredImages) else tuple(t[group].shape[:2])


def _box(vertices: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    lo, hi = bounds(vertices)
    return lo, np.maximum(hi - lo, 1e-12)


def _placement(vertices: np.ndarray, lo: np.ndarray, size: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    return _place(*bounds(vertices), lo, size)


def _place(plo: np.ndarray, phi: np.ndarray, lo: np.ndarray, size: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(centre, extents) of boxes ``plo, phi (..., 3)`` relative to the box ``lo, size (3,)``."""
    return ((plo + phi) / 2 - lo) / size, (phi - plo) / size


def prepare_template(shape: Shape, grouping: Grouping, corner_uv: np.ndarray, textures: Sequence[np.ndarray], names: Sequence[str] | None = None, pbr: Sequence[Any] | None = None) -> TemplateAssets:
    """Build :class:`TemplateAssets` from a textured template.

    Args:
        shape, grouping: the template; corner_uv: (m, 3, 2) its UVs; textures: per group (H, W, 3)
        uint8 (or float in [0, 1]) images, or a store's :class:`proctex.store.template.StoredImages`
        (kept as they are: decoded where used, their PNG bytes never encoded again); names: per group
        material names; pbr: per group its :class:`proctex.texture.pbr.PbrMaps` or None (encoded
        once here, like the textures), or a store's :class:`proctex.store.template.StoredMaps`.
    """
    if len(textures) != len(grouping.groups):
        raise ValueError(f"need one texture per group ({len(grouping.groups)}), got {len(textures)}")
    if isinstance(textures, StoredImages):  # a store's: its PNG bytes as stored, decoded where used
        texs = textures
    else:
        arrays = [np.ascontiguousarray(t if np.asarray(t).dtype == np.uint8 else (np.clip(t, 0, 1) * 255).round().astype(np.uint8))[..., :3] for t in textures]
        texs = StoredImages.of_decoded(arrays, png_bytes)
    groups = []
    for g in grouping.groups:
        rep = grouping.parts[g.representative]
        v, f = part_mesh(shape, rep)
        c, r = normalised_frame(v)
        r = r if r > 0 else 1.0
        vn = (v - c) / r
        groups.append(GroupAssets(g.index, g.label, rep.index, vn, f, np.asarray(corner_uv)[rep.faces], c, r, SurfaceIndex(vn, f), g.degenerate))
    lo, size = _box(shape.vertices)
    slots = []
    for g in grouping.groups:
        if g.degenerate:
            continue
        for member, mmap in zip(g.members, g.maps):
            part = grouping.parts[member]
            centre, extents = _placement(shape.vertices[part.vertices], lo, size)
            # between normalised frames (each part's own centre and radius) a scaled or deformed member's map is its rotation
            slots.append(Slot(member, g.index, mmap.rotation if mmap.method in ("similar", "deformed") else np.asarray(mmap.R, float), centre, extents))
    names = list(names) if names is not None else [g.label or f"group_{g.index}" for g in grouping.groups]
    maps = None
    if isinstance(pbr, StoredMaps):
        if len(pbr) != len(texs):
            raise ValueError(f"need PBR maps (or None) per group ({len(texs)}), got {len(pbr)}")
        maps = pbr
    elif pbr is not None and any(m is not None for m in pbr):
        if len(pbr) != len(texs):
            raise ValueError(f"need PBR maps (or None) per group ({len(texs)}), got {len(pbr)}")
        decoded = [None if m is None else PbrMaps(m.orm_uint8(), m.normal_uint8(), m.occlusion) for m in pbr]
        maps = StoredMaps.of_decoded(decoded, lambda m: PbrMaps(png_bytes(m.orm), png_bytes(m.normal), m.occlusion), where="maps")
    return TemplateAssets(shape, grouping, groups, slots, texs, names, pbr=maps)


def same_topology(faces: np.ndarray, n_vertices: int, assets: GroupAssets) -> bool:
    """Whether a part mesh (local ``faces (k, 3)`` over ``n_vertices``) has exactly the connectivity
    of the group's representative (same vertex count and the same face array)."""
    return n_vertices == len(assets.vertices) and faces.shape == assets.faces.shape and bool(np.array_equal(faces, assets.faces))


def template_assets(template: Template) -> TemplateAssets:
    """The stored template record (:class:`proctex.store.template.Template`) ready for transfer. Without
    stored masks, the texels each group's UV charts cover plus an 8-texel gutter count as painted and
    observed."""
    assets = prepare_template(template.shape, template.grouping, template.corner_uv, template.textures, template.names, pbr=template.pbr)
    return _with_masks(assets, template.painted, template.observed)


def _with_masks(assets: TemplateAssets, painted: list[np.ndarray] | None, observed: list[np.ndarray] | None) -> TemplateAssets:
    """``assets`` with the painted and observed masks; without stored ones, the texels each group's
    UV charts cover plus an 8-texel gutter count as both."""
    if painted is None:
        masks = []
        for ga in assets.groups:
            h, w = texture_hw(assets, ga.group)
            tm = texel_map(ga.vertices, ga.faces, ga.corner_uv, h, w)
            _, mask = pad_seams(np.zeros((h, w, 1)), tm.mask, 8)
            masks.append(mask)
        painted = observed = masks
    return dataclasses.replace(assets, painted=painted, observed=observed if observed is not None else painted)  # charts made anew when first used


def with_look(assets: TemplateAssets, images: LookImages) -> TemplateAssets:
    """``assets`` textured as another look of the family (:class:`proctex.store.template.LookImages`):
    the same geometry (groups, slots, surface indexes: shared, not copied), that look's textures, PBR
    maps and masks. ``ValueError`` when the look does not have the family's groups."""
    if len(images.textures) != len(assets.groups) or [ga.label or "" for ga in assets.groups] != list(images.labels):
        raise ValueError(f"the look has {len(images.textures)} groups {images.labels}, the family {[ga.label for ga in assets.groups]}")
    return _with_masks(dataclasses.replace(assets, textures=images.textures, pbr=images.pbr), images.painted, images.observed)


def load_assets(store: FamilyStore, state: FamilyState | None = None, look: LookLayout | None = None) -> TemplateAssets:
    """The template ready for transfer (:class:`TemplateAssets`), from the store, textured as
    ``look`` (default: the build's look); ``state``: the family state, when the caller has it (else
    read here)."""
    return template_assets(load_template(store, state=state, look=look))
