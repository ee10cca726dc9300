"""The paint loop: :func:`paint_template` paints a template with the offline surface painter
(:func:`proctex.texture.paint.paint_surface`) or with a *view painter* in the InTex-style multi-view
loop (:func:`paint_views`): render a view, trimap it against what is painted, ask the painter,
back-project with a per-component depth test, and finally fill what no view saw."""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from typing import Any, Callable, Mapping, Sequence

import numpy as np
from scipy.spatial import cKDTree

from proctex.geometry.parts import Grouping, MemberMap, PartGroup, part_mesh
from proctex.geometry.shape import Shape
from proctex.texture.painters.base import (
    BACKGROUND,
    GENERATE,
    KEEP,
    REFINE,
    ViewPainter,
    ViewRequest,
)
from proctex.texture.painters.partwords import plan_parts

from .paint import (
    UNPAINTED,
    GroupTexture,
    TemplateTexture,
    group_texels,
    paint_material_maps,
    paint_surface,
    resolve_group_prompts,
    resolve_photos,
    shape_frame,
)
from .painting import PaintConfig, get_painter, make_painter
from .render import (
    Buffers,
    Camera,
    Tracer,
    bounding_sphere,
    canonical_cameras,
    orbit_path,
    render_buffers,
    textured_albedo,
)
from .uv import ShapeUV, TexelMap, pad_seams, sample_texture, shape_uv


# -------------------------------------------------------------------------------- view painting
@dataclass
class _Member:
    """A group member's map ``x_rep = R x + t``; ``back (3, 3)``: ``R^-1`` (``R^T`` for a rigid map),
    or ``points (t, 3)``: where the group's texels lie on this member when ``R, t`` only approximate
    it (a "deformed" member: the same barycentrics on its own copy of each face; ``back`` None)."""

    part: int
    R: np.ndarray
    t: np.ndarray
    back: np.ndarray | None
    points: np.ndarray | None = None

    def texel_points(self, texels: TexelMap) -> np.ndarray:
        """``(t, 3)`` member-space points of the group's texels."""
        return self.points if self.points is not None else (texels.points - self.t) @ self.back.T


#: texels past each chart's edge that a photo look paints on the surface extended (paint_surface's ``ring``)
PHOTO_RING = 2


def _member(shape: Shape, grouping: Grouping, g: PartGroup, m: MemberMap, texels: TexelMap) -> _Member:
    R, t = np.asarray(m.R, float), np.asarray(m.t, float)
    if m.method == "deformed":  # vertex i of the member is vertex i of the representative
        _, rep_faces = part_mesh(shape, grouping.parts[g.representative])
        v_mem, _ = part_mesh(shape, grouping.parts[m.part])
        return _Member(m.part, R, t, None, np.einsum("tk,tkd->td", texels.bary, v_mem[rep_faces[texels.face]]))
    return _Member(m.part, R, t, np.linalg.inv(R) if m.method == "similar" else R.T)


@dataclass
class _GroupState:
    """Running blend of one group texture over the covered texels (t of them)."""

    group: PartGroup
    texels: TexelMap
    members: list[_Member]
    accum: np.ndarray  # (t, 3) sum of w * colour
    weight: np.ndarray  # (t,) sum of w
    best: np.ndarray  # (t,) best view cosine so far (0: never painted)
    cache: dict = field(default_factory=dict)  # images of the current state (cleared on update)

    def image(self, size: int) -> np.ndarray:
        if "image" not in self.cache:
            self.cache["image"] = self._image(size)
        return self.cache["image"]

    def best_image(self, size: int) -> np.ndarray:
        if "best" not in self.cache:
            self.cache["best"] = self._best_image(size)
        return self.cache["best"]

    def _image(self, size: int, gutter: int = 2) -> np.ndarray:
        """(size, size, 3) float32 current texture (unpainted texels grey, seams padded)."""
        img = np.full((size, size, 3), UNPAINTED, dtype=np.float32)
        seen = self.weight > 0
        ij = self.texels.ij[seen]
        img[ij[:, 0], ij[:, 1]] = self.accum[seen] / self.weight[seen, None]
        m = np.zeros((size, size), dtype=bool)
        m[ij[:, 0], ij[:, 1]] = True
        return pad_seams(img, m, gutter)[0]

    def _best_image(self, size: int) -> np.ndarray:
        """(size, size, 1) float32 best cosine per texel, padded so lookups near chart edges see it."""
        img = np.zeros((size, size, 1), dtype=np.float32)
        img[self.texels.ij[:, 0], self.texels.ij[:, 1], 0] = self.best
        return pad_seams(img, self.texels.mask, 2)[0]


def _states(shape: Shape, grouping: Grouping, uv: ShapeUV, size: int) -> list[_GroupState]:
    states = []
    for g, texels in zip(grouping.groups, group_texels(shape, grouping, uv, size)):
        members = [_member(shape, grouping, g, m, texels) for m in g.maps]
        n = len(texels.face)
        states.append(_GroupState(g, texels, members, np.zeros((n, 3)), np.zeros(n), np.zeros(n)))
    return states


def trimap(buffers: Buffers, uv: ShapeUV, best_images: Sequence[np.ndarray], margin: float) -> np.ndarray:
    """(H, W) uint8 BACKGROUND / KEEP / REFINE / GENERATE per pixel of a view.

    A pixel is GENERATE where its texel was never painted, REFINE where this view sees it more
    frontally than any earlier view by more than ``margin`` in cosine, else KEEP.
    """
    from .render import pixel_uv

    out = np.full(buffers.face.shape, BACKGROUND, dtype=np.uint8)
    m = buffers.mask
    puv = pixel_uv(buffers, uv.corner_uv)[m]
    grp = buffers.group[m]
    best = np.zeros(len(puv))
    for g, img in enumerate(best_images):
        sel = grp == g
        if sel.any():
            best[sel] = sample_texture(img, puv[sel], bilinear=False)[:, 0]
    cos = buffers.cos[m]
    state = np.where(best <= 0, GENERATE, np.where(cos > best + margin, REFINE, KEEP)).astype(np.uint8)
    out[m] = state
    return out


def backproject(points: np.ndarray, part: int, buffers: Buffers, trimap_: np.ndarray, view: np.ndarray, plane_tol: float = 1.0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Pull painted colours onto surface points of one part (the per-component depth test).

    Each point is projected into the view; of the four pixels around it, those that see ``part``,
    were painted (trimap REFINE or GENERATE) and whose tangent plane passes within
    ``plane_tol`` pixel footprints of the point count; the colour and view cosine are their bilinear
    average (weights renormalised over the valid pixels).

    Args:
        points: (t, 3) float64 world points of the part; part: its part id.
        buffers: the view's buffers; trimap_: (H, W) uint8; view: (H, W, 3) painted image.

    Returns:
        idx (k,) int64 indices of the points that got a colour, colours (k, 3), cos (k,).
    """
    cam = buffers.camera
    H, W = buffers.face.shape
    eye = np.asarray(cam.eye)
    footprint = 2 * cam.tan_half / H
    part_img = buffers.part.ravel()
    xy, _ = cam.project(points)
    ok = (xy[:, 0] >= 0.5) & (xy[:, 0] < W - 0.5) & (xy[:, 1] >= 0.5) & (xy[:, 1] < H - 0.5)  # NaN -> False
    idx = np.flatnonzero(ok)
    px, py = xy[idx, 0] - 0.5, xy[idx, 1] - 0.5
    i0 = py.astype(np.int64)  # >= 0, so truncation is floor
    j0 = px.astype(np.int64)
    base = i0 * W + j0
    # np.take: several times faster than fancy indexing for these gathers.
    near = (np.take(part_img, base) == part) | (np.take(part_img, base + 1) == part)
    near |= (np.take(part_img, base + W) == part) | (np.take(part_img, base + W + 1) == part)
    idx, px, py, i0, j0, base = idx[near], px[near], py[near], i0[near], j0[near], base[near]
    if len(idx) == 0:
        return idx, np.zeros((0, 3)), np.zeros(0)
    tri_f = trimap_.ravel()
    nrm_f = buffers.normal.reshape(-1, 3)
    plane_f = np.einsum("ij,ij->i", buffers.points.reshape(-1, 3), nrm_f)  # tangent plane n . x = plane
    view_f = np.asarray(view, dtype=np.float64).reshape(-1, 3)
    cos_f = buffers.cos.ravel()
    x = np.take(points, idx, axis=0)
    tol = plane_tol * footprint * np.sqrt(np.einsum("ij,ij->i", x - eye, x - eye))
    fy, fx = py - i0, px - j0
    col = np.zeros((len(idx), 3))
    wsum = np.zeros(len(idx))
    cos = np.zeros(len(idx))
    for off, wb in ((0, (1 - fy) * (1 - fx)), (1, (1 - fy) * fx), (W, fy * (1 - fx)), (W + 1, fy * fx)):
        lin = base + off
        valid = (np.take(part_img, lin) == part) & (np.take(tri_f, lin) >= REFINE)
        valid &= np.abs(np.einsum("ij,ij->i", x, np.take(nrm_f, lin, axis=0)) - np.take(plane_f, lin)) <= tol
        w = np.where(valid, wb + 1e-6, 0.0)
        col += w[:, None] * np.take(view_f, lin, axis=0)
        cos += w * np.take(cos_f, lin)
        wsum += w
    hit = wsum > 0
    return idx[hit], col[hit] / wsum[hit, None], cos[hit] / wsum[hit]


def _pull(
    state: _GroupState,
    buffers: Buffers,
    tri: np.ndarray,
    view: np.ndarray,
    margin: float,
    power: float,
    plane_tol: float,
    members: Sequence[_Member] | None = None,
) -> int:
    """Back-project one painted view into one group texture (every member); returns texels updated."""
    updated = 0
    for mem in members if members is not None else state.members:
        x = mem.texel_points(state.texels)  # member-space points (x_rep = R x + t)
        t_idx, c, cs = backproject(x, mem.part, buffers, tri, view, plane_tol)
        if len(t_idx) == 0:
            continue
        # Generate where never painted, refine where this view is more frontal by ``margin``.
        upd = (state.best[t_idx] <= 0) | (cs > state.best[t_idx] + margin)
        t_idx, c, cs = t_idx[upd], c[upd], cs[upd]
        # A texel shared by several members seen in the same view accumulates each of them.
        w = np.maximum(cs, 1e-3) ** power
        np.add.at(state.accum, t_idx, w[:, None] * c)
        np.add.at(state.weight, t_idx, w)
        np.maximum.at(state.best, t_idx, cs)
        updated += len(t_idx)
        state.cache.clear()
    return updated


def _request(
    buffers: Buffers,
    tri: np.ndarray,
    rgb: np.ndarray,
    prompt: str,
    prompts: dict[int, str],
    center: np.ndarray,
    scale: float,
    k: int,
    n: int,
    seed: int,
    labels: Mapping[int, str],
) -> ViewRequest:
    return ViewRequest(
        prompt=prompt,
        group_prompts=dict(prompts),
        rgb=rgb.astype(np.float32),
        trimap=tri,
        depth=buffers.depth.astype(np.float32),
        normal=buffers.normal.astype(np.float32),
        points=buffers.points.astype(np.float32),
        group=buffers.group,
        center=center,
        scale=scale,
        view_index=k,
        n_views=n,
        seed=int(seed) * 1000003 + k,
        camera=buffers.camera,
        part=buffers.part,
        extra={"group_labels": dict(labels)},
    )


def _check_view(image: Any, H: int, W: int) -> np.ndarray:
    img = np.asarray(image, dtype=np.float64)
    if img.shape != (H, W, 3):
        raise ValueError(f"view painter returned {img.shape}, expected ({H}, {W}, 3)")
    if not np.isfinite(img).all():
        raise ValueError("view painter returned NaN or inf")
    return np.clip(img, 0, 1)


def fill_unseen(points: np.ndarray, colors: np.ndarray, seen: np.ndarray, k: int = 8) -> np.ndarray:
    """Colours for unseen texels from the ``k`` nearest seen texels on the surface (inverse distance).

    Args:
        points: (t, 3) texel surface points; colors: (t, 3) (only seen rows are read);
        seen: (t,) bool. Returns (t, 3) with unseen rows filled (unchanged when nothing is seen).
    """
    out = np.array(colors, dtype=np.float64, copy=True)
    if seen.all() or not seen.any():
        return out
    src = np.flatnonzero(seen)
    kk = min(k, len(src))
    d, j = cKDTree(points[src]).query(points[~seen], k=kk)
    d, j = d.reshape(len(d), kk), j.reshape(len(j), kk)
    w = 1.0 / np.maximum(d, 1e-12) ** 2
    out[~seen] = np.einsum("ij,ijk->ik", w, out[src][j]) / w.sum(axis=1, keepdims=True)
    return out


def fill_texture(
    texels: TexelMap,
    colors: np.ndarray,
    seen: np.ndarray,
    size: int,
    method: str = "patchmatch",
    seed: int = 0,
    notes: list[str] | None = None,
    group: int = 0,
) -> np.ndarray:
    """A group texture (size, size, 3) float32 from per-texel colours where only ``seen`` ones are painted.

    Unseen covered texels are filled by exemplar PatchMatch restricted to this group's painted texels
    (``method="patchmatch"``; painted texels are never changed) or on the surface by inverse distance
    (``"surface"``). Nothing painted: the unpainted grey stays.
    """
    image = np.full((size, size, 3), UNPAINTED, dtype=np.float32)
    ij = texels.ij
    if not seen.any() or seen.all() or method == "surface":
        image[ij[:, 0], ij[:, 1]] = fill_unseen(texels.points, colors, seen) if seen.any() else colors
        return image
    from .inpaint import patchmatch_fill

    image[ij[seen, 0], ij[seen, 1]] = colors[seen]
    known = np.zeros((size, size), dtype=bool)
    known[ij[seen, 0], ij[seen, 1]] = True
    hole = np.zeros((size, size), dtype=bool)
    hole[ij[~seen, 0], ij[~seen, 1]] = True
    try:
        res = patchmatch_fill(image, known, hole, seed=seed)
        if notes is not None:
            notes.extend(f"group {group}: {n}" for n in res.notes)
        return res.image.astype(np.float32)
    except ValueError as exc:  # no usable source patch (tiny charts): fall back to the surface fill
        if notes is not None:
            notes.append(f"group {group}: PatchMatch impossible ({exc}); filled on the surface")
        image[ij[:, 0], ij[:, 1]] = fill_unseen(texels.points, colors, seen)
        return image


def paint_views(
    shape: Shape,
    grouping: Grouping,
    painter: ViewPainter,
    prompt: str = "",
    group_prompts: Mapping[str, str] | None = None,
    cameras: Sequence[Camera] | None = None,
    n_views: int = 11,
    view_size: int = 512,
    size: int = 1024,
    up: str = "z",
    uv: ShapeUV | None = None,
    seed: int = 0,
    margin: float = 0.1,
    power: float = 4.0,
    plane_tol: float = 1.0,
    gutter: int = 8,
    complete_hidden: bool = True,
    fill: str = "patchmatch",
    backend: str = "auto",
    on_view: Callable[[int, int, dict[str, Any]], None] | None = None,
) -> TemplateTexture:
    """The multi-view paint loop (module docstring). Returns a :class:`TemplateTexture` (method "views").

    Args:
        painter: a :class:`ViewPainter`.
        prompt, group_prompts: the global prompt and overrides keyed by group label or index.
        cameras: the camera path (default: :func:`proctex.texture.render.orbit_path` with ``n_views`` views of
            ``view_size`` pixels around the shape, ``up`` being its up axis).
        size: texture size; uv: a precomputed layout.
        margin: cosine gain needed to refine an already painted texel; power: blend weight ``cos^power``.
        plane_tol: how far (in pixel footprints) a texel may lie off the seen surface and still be painted.
        complete_hidden: paint groups with texels no path view saw from six views of the group's
            representative alone (inner parts hidden by others).
        fill: how texels no view saw are filled: "patchmatch" (exemplar PatchMatch from the group's
            painted texels, :mod:`proctex.texture.inpaint`) or "surface" (:func:`fill_unseen`, inverse distance
            on the surface).
        on_view: progress callback ``(k, n, stats)``.
    """
    if not isinstance(painter, ViewPainter):
        raise ValueError("painter must implement paint_view(request) -> (H, W, 3) image")
    if fill not in ("patchmatch", "surface"):
        raise ValueError(f"fill must be patchmatch or surface, got {fill!r}")
    if size < 8:
        raise ValueError(f"texture size must be >= 8, got {size}")
    t0 = time.perf_counter()
    prompts = resolve_group_prompts(grouping, prompt, group_prompts)
    labels = {g.index: g.label for g in grouping.groups}
    uv = uv if uv is not None else shape_uv(shape, grouping, resolution=size)
    center, scale = shape_frame(shape)
    c, r = bounding_sphere(shape.vertices)
    cams = list(cameras) if cameras is not None else orbit_path(c, r, up, n_views, view_size)
    if not cams:
        raise ValueError("no cameras")
    states = _states(shape, grouping, uv, size)
    tracer = Tracer(shape.vertices, shape.faces, backend)
    face_part = grouping.segmentation.face_part
    view_stats = []
    for k, cam in enumerate(cams):
        tv = time.perf_counter()
        buffers = render_buffers(tracer, cam, face_part, uv.face_group)
        rgb = textured_albedo(buffers, uv.corner_uv, uv.face_group, [s.image(size) for s in states], default=(UNPAINTED,) * 3)
        tri = trimap(buffers, uv, [s.best_image(size) for s in states], margin)
        request = _request(buffers, tri, rgb, prompt, prompts, center, scale, k, len(cams), seed, labels)
        tp = time.perf_counter()
        view = _check_view(painter.paint_view(request), cam.height, cam.width)
        tb = time.perf_counter()
        updated = sum(_pull(s, buffers, tri, view, margin, power, plane_tol) for s in states)
        stats = {
            "view": k,
            "camera": cam.name,
            "generate": int((tri == GENERATE).sum()),
            "refine": int((tri == REFINE).sum()),
            "keep": int((tri == KEEP).sum()),
            "texels_updated": int(updated),
            "render_s": round(tp - tv, 3),
            "painter_s": round(tb - tp, 3),
            "backproject_s": round(time.perf_counter() - tb, 3),
        }
        view_stats.append(stats)
        if on_view is not None:
            on_view(k, len(cams), stats)
    seen_path = {s.group.index: float((s.weight > 0).mean()) if len(s.weight) else 1.0 for s in states}
    hidden_views = 0
    if complete_hidden:
        hidden_views = _complete_hidden(shape, grouping, uv, states, painter, prompt, prompts, labels, center, scale, up, view_size, size, seed, margin, power, plane_tol, backend)
    notes: list[str] = []
    groups = []
    for s in states:
        seen = s.weight > 0
        colors = np.full((len(seen), 3), UNPAINTED)
        colors[seen] = s.accum[seen] / s.weight[seen, None]
        if not seen.any() and len(seen):
            notes.append(f"group {s.group.index}: no view saw it (zero area?): filled grey")
        image = fill_texture(s.texels, colors, seen, size, fill, seed=seed + s.group.index, notes=notes, group=s.group.index)
        image, painted = pad_seams(image, s.texels.mask, gutter)
        share = float(seen.mean()) if len(seen) else 1.0
        groups.append(GroupTexture(s.group.index, s.group.label, prompts[s.group.index], image, painted, s.texels, share, seen))
    for gi, a in enumerate(uv.atlases):
        notes.extend(f"group {gi}: {n}" for n in a.notes)
    stats = {"views": view_stats, "seen_by_path": seen_path, "hidden_views": hidden_views}
    return TemplateTexture(shape, grouping, uv, groups, "views", time.perf_counter() - t0, notes, stats)


def _complete_hidden(
    shape,
    grouping,
    uv,
    states,
    painter,
    prompt,
    prompts,
    labels,
    center,
    scale,
    up,
    view_size,
    size,
    seed,
    margin,
    power,
    plane_tol,
    backend,
    min_unseen: float = 0.05,
) -> int:
    """Paint groups the path left partly unseen from six views of their representative alone."""
    n = 0
    for s in states:
        if not len(s.weight) or s.group.degenerate or (s.weight <= 0).mean() < min_unseen:
            continue
        rep = grouping.parts[s.group.representative]
        faces = shape.faces[rep.faces]
        tracer = Tracer(shape.vertices, faces, backend)
        face_part = np.full(len(faces), rep.index, dtype=np.int64)
        face_group = np.full(len(faces), s.group.index, dtype=np.int64)
        c, r = bounding_sphere(shape.vertices[rep.vertices])
        sub_uv = ShapeUV(uv.corner_uv[rep.faces], face_group, uv.atlases, uv.resolution)
        rep_member = [m for m in s.members if m.part == rep.index]
        for cam in canonical_cameras(c, r, up, view_size):
            buffers = render_buffers(tracer, cam, face_part, face_group)
            images = [st.image(size) if st is s else np.zeros((1, 1, 3), np.float32) for st in states]
            best = [st.best_image(size) if st is s else np.zeros((1, 1, 1), np.float32) for st in states]
            rgb = textured_albedo(buffers, sub_uv.corner_uv, face_group, images, default=(UNPAINTED,) * 3)
            tri = trimap(buffers, sub_uv, best, margin)
            request = _request(buffers, tri, rgb, prompt, prompts, center, scale, 1000 + n, 6, seed, labels)
            view = _check_view(painter.paint_view(request), cam.height, cam.width)
            _pull(s, buffers, tri, view, margin, power, plane_tol, rep_member)
            n += 1
    return n


def paint_template(
    shape: Shape,
    grouping: Grouping,
    prompt: str,
    group_prompts: Mapping[str, str] | None = None,
    painter: str = "surface",
    size: int = 1024,
    seed: int = 0,
    up: str = "z",
    views: int = 11,
    view_size: int = 512,
    complete_hidden: bool = True,
    fill: str = "patchmatch",
    model_dir: str | None = None,
    device: str = "cpu",
    steps: int = 20,
    on_view: Callable[[int, int, dict[str, Any]], None] | None = None,
    uv: ShapeUV | None = None,
    maps: bool = True,
    occlusion: bool = False,
    part_words: Mapping[str, str] | None = None,
    photos: Mapping[str, Any] | None = None,
    under_prompt: bool = True,
    check: Callable[[str], None] | None = None,
    settings: PaintConfig | None = None,
) -> TemplateTexture:
    """Texture a template with one of the registered painters (:mod:`proctex.texture.painting`):
    ``"surface"`` (:func:`paint_surface`), ``"views"`` (the multi-view loop with
    :class:`SolidViewPainter`) or ``"diffusion"`` (the loop with a local diffusers model in
    ``model_dir``), made by :func:`proctex.texture.painting.make_painter`; the remaining arguments
    go to :func:`paint_views`. ``uv`` (e.g. :func:`proctex.texture.uv.source_uv`) replaces the
    per-group unwrap. ``maps``: also make each group's PBR maps (:func:`paint_material_maps`: from
    the prompts' materials, whichever painter made the colour); ``occlusion``: bake ambient occlusion
    into them too. ``part_words``: the user's word per group (``{"3": "legs"}``), which the prompt's
    clauses follow (:func:`proctex.texture.painters.partwords.plan_parts`). ``photos``: a look from
    photos (:class:`proctex.texture.exemplar.PhotoLayer` by part key, ``"*"`` for the rest; the
    surface painter only): their groups are synthesised from the photos (:func:`resolve_photos`;
    ``under_prompt``: the prompt's named parts keep their clauses instead of the ``"*"`` photo).
    ``check(what)``: called before each group and each view, and may raise to stop the work (a
    look's budget, :class:`proctex.looks.LookLimits`). ``settings``: the paint settings these
    arguments came from (:func:`paint_with` hands them whole), which the painter is made with; without
    them they are made of these arguments, so a plugin painter sees every one of them."""
    part_words = dict(part_words or {})
    if settings is None:
        settings = PaintConfig(
            prompt=prompt,
            group_prompts={str(k): v for k, v in (group_prompts or {}).items()},
            part_words=part_words,
            painter=painter,
            texture_size=size,
            views=views,
            view_size=view_size,
            paint_hidden=complete_hidden,
            fill=fill,
            model_dir=model_dir,
            device=device,
            steps=steps,
            occlusion=occlusion,
        )
    if check is not None:
        check("planning the parts")
        seen = on_view

        def on_view(k: int, n: int, stats: dict[str, Any]) -> None:  # noqa: F811 (the budget's check beside the caller's)
            check(f"painting view {k + 1} of {n}")
            if seen is not None:
                seen(k, n, stats)

    prompts = resolve_group_prompts(grouping, prompt, group_prompts, shape, up, part_words)  # validates the keys (labels, indices, part words)
    named = {g for g, text in prompts.items() if text != prompt}  # groups a group prompt names
    # Clauses naming parts (by label or by what the parts are) become those groups' prompts, for
    # every painter and in the record; explicit group prompts win.
    parts = plan_parts(prompt, shape.vertices, shape.faces, grouping, up, assigned=part_words)
    prompts = {g: (parts.text_for(g) if text == prompt else text) for g, text in prompts.items()}
    kind = get_painter(painter)
    chosen = make_painter(painter, grouping, prompt, prompts, seed=seed, settings=settings)
    if photos:
        if kind.views:
            raise ValueError(f"a look from photos paints with the surface painter, not {painter!r}")
        from proctex.texture.exemplar import PhotoPainter

        named |= {g for g in parts.texts if parts.routes.get(g) != "alike"}  # a clause borrowed for want of one names nothing
        by_group = resolve_photos(grouping, prompt, photos, shape, up, part_words, named if under_prompt else set())
        chosen = PhotoPainter(chosen, by_group, seed=seed, texture_size=size)
        prompts = {g: (f"photo {by_group[g].photo.name}" if g in by_group else text) for g, text in prompts.items()}
    surface = chosen if not kind.views else getattr(chosen, "surface", None)
    if surface is not None:
        surface.bind(shape, grouping, up, parts=parts)  # places the prompt's regions on this shape
    if not kind.views:
        tex = paint_surface(shape, grouping, chosen, size=size, prompts=prompts, uv=uv, ring=PHOTO_RING if photos else 0, check=check)
    else:
        tex = paint_views(
            shape,
            grouping,
            chosen,
            prompt,
            {str(g): t for g, t in prompts.items()},
            n_views=views,
            view_size=view_size,
            size=size,
            up=up,
            seed=seed,
            complete_hidden=complete_hidden,
            fill=fill,
            on_view=on_view,
            uv=uv,
        )
    tex.notes.extend(line for line in (f"prompt {prompt!r} parts: {n}" for n in parts.notes) if line not in tex.notes)
    if maps:
        materials = surface if surface is not None else make_painter("surface", grouping, prompt, prompts, seed=seed).bind(shape, grouping, up, parts=parts)
        paint_material_maps(tex, materials, occlusion=occlusion, seed=seed, check=check)
        tex.notes.extend(n for n in materials.region_notes() if n not in tex.notes)  # the surface painter's notes hold them already
    return tex


def paint_with(
    shape: Shape,
    grouping: Grouping,
    settings: PaintConfig,
    seed: int = 0,
    up: str = "z",
    uv: ShapeUV | None = None,
    on_view: Callable[[int, int, dict[str, Any]], None] | None = None,
    photos: Mapping[str, Any] | None = None,
    check: Callable[[str], None] | None = None,
) -> TemplateTexture:
    """:func:`paint_template` with the paint settings as they travel (a build config's ``[paint]``
    section, :class:`proctex.texture.painting.PaintConfig`), whole. ``photos``: the
    :class:`proctex.texture.exemplar.Photo` of each ``settings.images`` key already read (the others are
    read from their files). ``check``: see :func:`paint_template`."""
    s = settings
    layers = None
    if s.images:
        from proctex.texture.exemplar import layers as photo_layers

        layers = photo_layers(s.images, photos)
    return paint_template(
        shape,
        grouping,
        s.prompt,
        s.group_prompts,
        painter=s.painter,
        size=s.texture_size,
        seed=seed,
        up=up,
        views=s.views,
        view_size=s.view_size,
        complete_hidden=s.paint_hidden,
        fill=s.fill,
        model_dir=s.model_dir,
        device=s.device,
        steps=s.steps,
        on_view=on_view,
        uv=uv,
        occlusion=s.occlusion,
        part_words=s.part_words,
        photos=layers,
        under_prompt=bool((s.images.get("*") or {}).get("under_prompt", True)),
        check=check,
        settings=s,
    )
