"""Texturing the template: one UV texture per part group (docs/texturing.md).

Two ways to fill the group textures:

- :func:`paint_surface` evaluates a *surface painter* (colour from 3D point and normal) at every
  covered texel's surface point, then pads the seams. Seamless by construction.
- :func:`proctex.texture.paint_loop.paint_views` is the InTex-style multi-view loop for a *view
  painter* (:class:`proctex.texture.painters.base.ViewPainter`): for each camera it renders the current texture, a
  generate / refine / keep trimap from the view cosines seen so far, depth, normals and group ids; it
  asks the painter for the view; it back-projects into each group texture by pulling, for every texel
  of every group member, the painted pixel its surface point projects to — only where that pixel sees
  the same part (the component that wins the depth test) at the same place. Views blend by
  ``cos^power`` weights. Texels no view saw are filled from the nearest seen texels *on the surface*
  (same group, inverse-distance weights in 3D, so the fill is continuous across UV seams), then seams
  are padded.

Points handed to painters are in the shape's normalised frame (bounding-box centre, L∞ radius), so a
prompt looks the same on a 3-unit sofa and a 0.15-unit one.

This module holds the results (:class:`TemplateTexture`), the prompts per group, the surface painter's
pass and the previews; :mod:`proctex.texture.paint_loop` holds the view loop and
:func:`~proctex.texture.paint_loop.paint_template`, which picks one of the two.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from typing import Any, Mapping

import numpy as np

from proctex.geometry.parts import Grouping, PartGroup
from proctex.geometry.shape import Shape
from proctex.geometry.surface import normalised_frame
from proctex.texture.painters.base import ViewRequest
from proctex.texture.painters.partwords import groups_of_word

from .lighting import pbr_surface, shade_pbr, vertex_occlusion
from .pbr import PbrMaps, bake_maps, vertex_normals
from .render import Tracer, bounding_sphere, canonical_cameras, render_buffers, shade, textured_albedo
from .uv import ShapeUV, TexelMap, pad_seams, ring_texels, shape_uv, texel_map


UNPAINTED = 0.5  # grey shown where nothing is painted yet


# ------------------------------------------------------------------------------------- results
@dataclass
class GroupTexture:
    """The texture of one part group.

    Attributes:
        group: group id; label: its semantic label ("" when unknown); prompt: the prompt it was painted with.
        image: (H, W, 3) float32 in [0, 1].
        painted: (H, W) bool texels holding colour (covered texels plus the padded gutter).
        texels: the texel map of the group's representative.
        seen: share of covered texels painted directly (views: seen by a view; surface painter: 1).
        direct: (t,) bool per covered texel: painted directly (None: all of them).
        pbr: the group's PBR maps over the same layout (:func:`paint_material_maps`), or None.
        blend: (t, 3) the smooth normal field the colour's projections followed at the covered
            texels (:func:`blend_normals`; a photographed group), or None: the maps follow it too.
    """

    group: int
    label: str
    prompt: str
    image: np.ndarray
    painted: np.ndarray
    texels: TexelMap
    seen: float = 1.0
    direct: np.ndarray | None = None
    pbr: PbrMaps | None = None
    blend: np.ndarray | None = None

    def uint8(self) -> np.ndarray:
        """(H, W, 3) uint8 image."""
        return (np.clip(self.image, 0, 1) * 255).round().astype(np.uint8)

    @property
    def observed(self) -> np.ndarray:
        """(H, W) bool "already painted" mask: texels the painter coloured directly (views: seen by a
        view; the surface painter: every covered texel), plus the gutter texels padded from them.
        Texels of ``painted`` outside it hold fill (PatchMatch or surface fill of unseen texels)."""
        if self.direct is None:
            return self.painted.copy()

        flag = np.zeros(self.painted.shape + (1,), dtype=np.float32)
        ij = self.texels.ij[self.direct]
        flag[ij[:, 0], ij[:, 1]] = 1.0
        padded, _ = pad_seams(flag, self.texels.mask, -1)  # every texel takes its nearest covered texel's flag
        return (padded[..., 0] > 0.5) & self.painted


@dataclass
class TemplateTexture:
    """A textured template: its UV layout and one texture per group, with how it was made."""

    shape: Shape
    grouping: Grouping
    uv: ShapeUV
    groups: list[GroupTexture]
    method: str
    seconds: float
    notes: list[str] = field(default_factory=list)
    stats: dict[str, Any] = field(default_factory=dict)

    @property
    def images(self) -> list[np.ndarray]:
        return [g.image for g in self.groups]

    @property
    def pbr(self) -> list[PbrMaps | None]:
        """Per group its PBR maps (None where none were made)."""
        return [g.pbr for g in self.groups]

    @property
    def painted_masks(self) -> list[np.ndarray]:
        return [g.painted for g in self.groups]

    @property
    def observed_masks(self) -> list[np.ndarray]:
        return [g.observed for g in self.groups]

    def summary(self) -> dict[str, Any]:
        """JSON-ready description (no arrays)."""
        return {
            "method": self.method,
            "seconds": round(self.seconds, 3),
            "texture_size": [int(self.groups[0].image.shape[0]), int(self.groups[0].image.shape[1])] if self.groups else [],
            "groups": [
                {
                    "group": g.group,
                    "label": g.label,
                    "prompt": g.prompt,
                    "parts": [int(p) for p in self.grouping.groups[g.group].members],
                    "atlas": self.uv.atlases[g.group].method,
                    "charts": self.uv.atlases[g.group].charts,
                    "covered_texels": int(len(g.texels.face)),
                    "seen": round(float(g.seen), 4),
                }
                for g in self.groups
            ],
            "notes": list(self.notes),
            **self.stats,
        }


# ------------------------------------------------------------------------------------- prompts
def resolve_group_prompts(
    grouping: Grouping, prompt: str, group_prompts: Mapping[str, str] | None = None, shape: Shape | None = None, up: str = "z", part_words: Mapping[str, str] | None = None
) -> dict[int, str]:
    """Prompt per group id: ``group_prompts`` keyed by group label, group index (as a string) or,
    given the ``shape``, a part word (``"legs"``, ``"table top"``: the groups the word takes on that
    shape, :func:`proctex.texture.painters.partwords.groups_of_word`) overrides the global
    ``prompt``; an index wins over a label, a label over a word; ``part_words`` (the user's word per
    group) decide which groups a word takes. Unknown keys raise ``ValueError`` listing the valid ones."""
    if not isinstance(prompt, str):
        raise ValueError(f"prompt must be a string, got {type(prompt).__name__}")
    out = {g.index: prompt for g in grouping.groups}
    if not group_prompts:
        return out
    if not isinstance(group_prompts, Mapping):
        raise ValueError("group prompts must be a mapping {group label, index or part word: prompt}")
    valid = {str(g.index): [g.index] for g in grouping.groups}
    for g in grouping.groups:
        if g.label:
            valid.setdefault(g.label, []).append(g.index)
    by_word: dict[str, list[int]] = {}
    for key, text in group_prompts.items():
        if str(key) not in valid and shape is not None:
            gids = groups_of_word(str(key), prompt, shape.vertices, shape.faces, grouping, up, assigned=dict(part_words or {}))
            if gids:
                by_word[str(key)] = gids
        if str(key) not in valid and str(key) not in by_word:
            names = sorted(valid, key=lambda k: (k.isdigit(), int(k) if k.isdigit() else 0, k))
            also = " (or a part word one of them passes)" if shape is not None else ""
            raise ValueError(f"unknown group {key!r} in group prompts; this shape's groups are: {', '.join(names)}{also}")
        if not isinstance(text, str):
            raise ValueError(f"group prompt for {key!r} must be a string")
    # Part words first, then labels, then explicit indices (more specific) win.
    for key, text in group_prompts.items():
        for gi in by_word.get(str(key), []):
            out[gi] = text
    for key, text in group_prompts.items():
        if not str(key).isdigit() and str(key) in valid:
            for gi in valid[str(key)]:
                out[gi] = text
    for key, text in group_prompts.items():
        if str(key).isdigit():
            out[int(key)] = text
    return out


def resolve_photos(
    grouping: Grouping, prompt: str, photos: Mapping[str, Any], shape: Shape | None = None, up: str = "z", part_words: Mapping[str, str] | None = None, named: set[int] | frozenset[int] = frozenset()
) -> dict[int, Any]:
    """The photo of each group: ``photos`` keyed as group prompts are (a group number, label or part
    word, :func:`resolve_group_prompts`'s rules: a number beats a label, a label a word), and ``"*"``
    for every group no key reaches and ``named`` does not hold (the groups the prompt's clauses or
    group prompts name). Returns group index -> photo; ``ValueError`` for an unknown key."""
    keyed = {str(k): v for k, v in photos.items() if k != "*"}
    tags = {k: f"\x00photo{i}" for i, k in enumerate(keyed)}
    out: dict[int, Any] = {}
    if keyed:
        by_tag = {t: k for k, t in tags.items()}
        for g, text in resolve_group_prompts(grouping, prompt, tags, shape, up, part_words).items():
            if text in by_tag:
                out[g] = keyed[by_tag[text]]
    if "*" in photos:
        for g in grouping.groups:
            if g.index not in out and g.index not in named:
                out[g.index] = photos["*"]
    return out


def shape_frame(shape: Shape) -> tuple[np.ndarray, float]:
    """The shape's normalised frame ``(centre (3,), L∞ radius)`` (radius 1 for a single point)."""
    center, radius = normalised_frame(shape.vertices)
    return center, (radius if radius > 0 else 1.0)


def group_texels(shape: Shape, grouping: Grouping, uv: ShapeUV, size: int) -> list[TexelMap]:
    """Texel map of each group's representative part, in group order."""
    maps = []
    for g in grouping.groups:
        rep = grouping.parts[g.representative]
        maps.append(texel_map(shape.vertices, shape.faces[rep.faces], uv.corner_uv[rep.faces], size))
    return maps


# ----------------------------------------------------------------------------- surface painter
def paint_surface(
    shape: Shape,
    grouping: Grouping,
    painter: Any,
    size: int = 1024,
    uv: ShapeUV | None = None,
    gutter: int = 8,
    prompts: Mapping[int, str] | None = None,
    ring: int = 0,
    check: Any = None,
) -> TemplateTexture:
    """Paint every group texture with a surface painter.

    Args:
        shape, grouping: the template and its parts/groups.
        painter: has ``paint(points (n, 3), normals (n, 3), group=int, label=str) -> (n, 3)`` (e.g.
            :class:`proctex.texture.painters.SurfacePainter`); points are in the shape's normalised frame.
        size: texture size (square); uv: a precomputed layout (else unwrapped here at ``size``).
        gutter: seam padding in texels.
        prompts: prompt per group for the record (defaults to what the painter reports, if anything).
        ring: for the painter's ``blend_groups`` (a :class:`proctex.texture.exemplar.PhotoPainter`'s
            photographed groups, which also get :func:`blend_normals` instead of face normals), also
            paint the texels within this many texels of a chart at their place on the surface
            extended past its edge (:func:`proctex.texture.uv.ring_texels`) before the gutter is
            filled: chart borders read true colours (0, and every other group: the gutter copies
            the nearest texel only, as ever).
        check: ``check(what)`` before each group (:func:`per_group`): raises to stop (a budget).

    Returns:
        :class:`TemplateTexture` (method "surface").
    """
    if size < 8:
        raise ValueError(f"texture size must be >= 8, got {size}")
    t0 = time.perf_counter()
    uv = uv if uv is not None else shape_uv(shape, grouping, resolution=size)
    center, scale = shape_frame(shape)
    t1 = time.perf_counter()
    maps = group_texels(shape, grouping, uv, size)
    timings: dict[str, float] = {"uv": t1 - t0, "texels": time.perf_counter() - t1}
    blended = set(getattr(painter, "blend_groups", ()))  # groups painted by projections that follow a smooth normal field

    def one(g: PartGroup, texels: TexelMap) -> GroupTexture:
        rep = grouping.parts[g.representative]
        smooth = g.index in blended
        normals = blend_normals(shape, rep.faces, texels) if smooth else texels.normals
        colors = np.asarray(painter.paint((texels.points - center) / scale, normals, group=g.index, label=g.label), dtype=np.float32)
        if colors.shape != (len(texels.face), 3) or not np.isfinite(colors).all():
            raise ValueError(f"painter returned {colors.shape} (finite required), expected ({len(texels.face)}, 3)")
        image = np.full((size, size, 3), UNPAINTED, dtype=np.float32)
        image[texels.ij[:, 0], texels.ij[:, 1]] = np.clip(colors, 0, 1)
        held = texels.mask
        if ring > 0 and smooth:
            extra = ring_texels(texels, shape.vertices, shape.faces[rep.faces], uv.corner_uv[rep.faces], ring)
            if len(extra.face):
                en = blend_normals(shape, rep.faces, extra)
                more = np.asarray(painter.paint((extra.points - center) / scale, en, group=g.index, label=g.label), dtype=np.float32)
                if more.shape != (len(extra.face), 3) or not np.isfinite(more).all():
                    raise ValueError(f"painter returned {more.shape} (finite required), expected ({len(extra.face)}, 3)")
                image[extra.ij[:, 0], extra.ij[:, 1]] = np.clip(more, 0, 1)
                held = held.copy()
                held[extra.ij[:, 0], extra.ij[:, 1]] = True
        image, painted = pad_seams(image, held, gutter)
        prompt = (prompts or {}).get(g.index, _painter_prompt(painter, g))
        return GroupTexture(g.index, g.label, prompt, image, painted, texels, blend=normals if smooth else None)

    t1 = time.perf_counter()
    out = per_group(one, list(zip(grouping.groups, maps)), check=check)
    t_paint = time.perf_counter() - t1
    timings["paint"] = t_paint
    notes = list(painter.notes()) if hasattr(painter, "notes") else []
    for gi, a in enumerate(uv.atlases):
        notes.extend(f"group {gi}: {n}" for n in a.notes)
    return TemplateTexture(shape, grouping, uv, out, "surface", time.perf_counter() - t0, notes, {"timings": timings})


#: groups painted at a time (:func:`per_group`): numpy and the painters' noise let go of the GIL
#: for most of their work, so two threads paint a family's groups in about 0.6x the time on 2 cores.
PAINT_THREADS = 2


def per_group(fn: Any, items: list[tuple[Any, Any]], threads: int | None = None, check: Any = None) -> list[Any]:
    """``[fn(a, b) for a, b in items]``, up to ``threads`` at a time (default :data:`PAINT_THREADS`,
    at most the CPUs), results in order; the first error is raised. ``fn`` must be safe to run
    beside itself (the painters keep per-call state, and their caches hold values that do not depend
    on the order they were made in, so the textures are the same bit for bit). ``check(what)``, where
    given, runs before each item and may raise to stop the work (a look's budget: the items under
    way finish, no other starts)."""
    import os

    n = min(PAINT_THREADS, os.cpu_count() or 1) if threads is None else int(threads)
    n = max(1, min(n, len(items)))

    def run(k: int) -> Any:
        if check is not None:
            check(f"painting part group {k + 1} of {len(items)}")
        return fn(*items[k])

    if n == 1:
        return [run(k) for k in range(len(items))]
    from concurrent.futures import ThreadPoolExecutor

    with ThreadPoolExecutor(n, thread_name_prefix="paint") as pool:
        return list(pool.map(run, range(len(items))))


#: rounds of neighbour averaging of the blend normals (:func:`blend_normals`): each widens the band
#: over which a projection hands over to the next by about one edge.
SMOOTH_ROUNDS = 8


def blend_normals(shape: Shape, faces: np.ndarray, texels: TexelMap, rounds: int = SMOOTH_ROUNDS) -> np.ndarray:
    """(t, 3) a smooth normal field at ``texels`` of ``shape``'s ``faces`` (a part's face indices), for
    painters that blend projections by the normal (:attr:`proctex.texture.exemplar.PhotoPainter.blend_groups`):
    the area-weighted vertex normals with vertices at one place welded (an export splits them at UV
    seams and hard edges), averaged with their neighbours ``rounds`` times (so a crease hands over
    across a few faces, not at the edge), interpolated by the texels' barycentrics."""
    from scipy.sparse import coo_matrix

    f = shape.faces[faces]
    used, local = np.unique(f, return_inverse=True)
    v = shape.vertices[used]
    size = max(float(np.ptp(v, axis=0).max()), 1e-12)
    _, weld = np.unique(np.round((v - v.min(axis=0)) / (size * 1e-6)).astype(np.int64), axis=0, return_inverse=True)
    welded = weld.ravel()[local.reshape(f.shape)]
    k = int(weld.max()) + 1
    first = np.zeros(k, dtype=np.int64)
    first[weld.ravel()] = np.arange(len(used))
    vn = vertex_normals(v[first], welded)
    if rounds > 0:
        e = np.concatenate([welded[:, [0, 1]], welded[:, [1, 2]], welded[:, [2, 0]]])
        adj = coo_matrix((np.ones(2 * len(e)), (np.concatenate([e[:, 0], e[:, 1]]), np.concatenate([e[:, 1], e[:, 0]]))), shape=(k, k)).tocsr()
        adj.data[:] = 1.0
        for _ in range(int(rounds)):
            vn = vn + adj @ vn
            vn /= np.maximum(np.linalg.norm(vn, axis=1, keepdims=True), 1e-12)
    n = np.einsum("kc,kcd->kd", texels.bary, vn[welded][texels.face])
    length = np.linalg.norm(n, axis=1, keepdims=True)
    return np.where(length > 1e-12, n / np.maximum(length, 1e-12), texels.normals)


def paint_material_maps(tex: TemplateTexture, painter: Any, gutter: int = 8, occlusion: bool = False, seed: int = 0, check: Any = None) -> TemplateTexture:
    """Give every group texture of ``tex`` its PBR maps (:class:`proctex.texture.pbr.PbrMaps`), in place.

    ``painter`` has ``material(points, normals, tangents, bitangents, group=, label=)`` (a
    :class:`proctex.texture.painters.SurfacePainter` of the same prompts): whatever painted the
    colour (surface, views, diffusion), roughness, metalness and relief come from the prompt's
    materials, evaluated at each covered texel's surface point in the representative's tangent frame
    (the frame the GLB's TANGENT attribute carries). ``occlusion``: also bake ambient occlusion into
    the maps' R channel (:func:`proctex.texture.lighting.vertex_occlusion` on the whole shape, so parts
    shade each other, interpolated to the texels; ``seed`` fixes its rays). ``check(what)`` before each
    group (:func:`per_group`). Returns ``tex``; its stats get ``timings.maps``.
    """
    t0 = time.perf_counter()
    center, scale = shape_frame(tex.shape)
    ao = None
    if occlusion:
        ao = vertex_occlusion(tex.shape.vertices, tex.shape.faces, seed=seed)
    blended = set(getattr(painter, "blend_groups", ()))

    def one(g: PartGroup, gt: GroupTexture) -> None:
        rep = tex.grouping.parts[g.representative]
        blend = None
        if g.index in blended:
            blend = gt.blend if gt.blend is not None and len(gt.blend) == len(gt.texels.face) else blend_normals(tex.shape, rep.faces, gt.texels)

        def props(p, n, t, b):
            if blend is not None:  # the field the colour's projections followed, for the relief's
                return painter.material(p, n, t, b, group=g.index, label=g.label, blend=blend)
            return painter.material(p, n, t, b, group=g.index, label=g.label)

        faces = tex.shape.faces[rep.faces]
        texel_ao = None if ao is None else (gt.texels.bary * ao[faces[gt.texels.face]]).sum(1)
        gt.pbr = bake_maps(gt.texels, tex.shape.vertices, faces, tex.uv.corner_uv[rep.faces], props, center, scale, gutter, occlusion=texel_ao)

    per_group(one, list(zip(tex.grouping.groups, tex.groups)), check=check)
    tex.stats.setdefault("timings", {})["maps"] = time.perf_counter() - t0
    return tex


def _painter_prompt(painter: Any, g: PartGroup) -> str:
    if hasattr(painter, "spec_for"):  # SurfacePainter: the prompt that applies to this group
        return str(painter.spec_for(g.index, g.label).prompt)
    return str(getattr(painter, "prompt", ""))


# ------------------------------------------------------------------------- a solid view painter
class SolidViewPainter:
    """A view painter that paints each pixel with a surface painter at the pixel's 3D point.

    It is what a perfectly view-consistent image generator would produce; the multi-view loop must
    reproduce :func:`paint_surface`'s texture with it on seen texels (the loop's correctness test).
    Given the grouping, pixels of a group member are painted at the corresponding point of the
    group's representative (``x_rep = R x + t``), as the shared texture requires.
    """

    def __init__(self, surface_painter: Any, grouping: Grouping | None = None) -> None:
        self.surface = surface_painter
        self.maps = {}
        if grouping is not None:
            # normals go by R's inverse transpose: R itself for a rigid map, renormalised otherwise
            self.maps = {
                m.part: (np.asarray(m.R, float), np.asarray(m.t, float), None if m.method in ("self", "topology", "icp") else np.linalg.pinv(np.asarray(m.R, float)).T)
                for g in grouping.groups
                for m in g.maps
            }

    def paint_view(self, request: ViewRequest) -> np.ndarray:
        out = np.array(request.rgb, dtype=np.float32, copy=True)
        m = request.foreground
        pts = request.points[m].astype(np.float64)
        nrm = request.normal[m].astype(np.float64)
        if self.maps and request.part is not None:
            part = request.part[m]
            for p in np.unique(part):
                if int(p) in self.maps:
                    R, t, N = self.maps[int(p)]
                    sel = part == p
                    pts[sel] = pts[sel] @ R.T + t
                    if N is None:
                        nrm[sel] = nrm[sel] @ R.T
                    else:  # a scaled or deformed member: unit normals again
                        n = nrm[sel] @ N.T
                        nrm[sel] = n / np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-12)
        pts = (pts - request.center) / request.scale
        grp = request.group[m]
        labels = request.extra.get("group_labels", {})
        colors = np.zeros((len(pts), 3), dtype=np.float32)
        for g in np.unique(grp):
            sel = grp == g
            colors[sel] = self.surface.paint(pts[sel], nrm[sel], group=int(g), label=labels.get(int(g), ""))
        out[m] = colors
        return out


# ------------------------------------------------------------------------------------- outputs
def preview_views(tex: TemplateTexture, up: str = "z", size: int = 256, backend: str = "auto") -> list[np.ndarray]:
    """The six canonical views of the textured template, shaded (lit physically when it has PBR
    maps): list of (size, size, 3) uint8."""
    shape = tex.shape
    tracer = Tracer(shape.vertices, shape.faces, backend)
    c, r = bounding_sphere(shape.vertices)
    images = []
    maps = tex.pbr if any(m is not None for m in tex.pbr) else None
    for cam in canonical_cameras(c, r, up, size):
        b = render_buffers(tracer, cam, face_group=tex.uv.face_group)
        if maps is not None:
            images.append(shade_pbr(b, pbr_surface(b, shape.vertices, shape.faces, tex.uv.corner_uv, tex.uv.face_group, tex.images, maps)))
        else:
            images.append(shade(b, textured_albedo(b, tex.uv.corner_uv, tex.uv.face_group, tex.images)))
    return images
