"""Texture transfer: any shape of the family textured from the template's group textures.

The run-time path (docs/architecture.md, "What happens"), per shape:

The steps live in their own modules, in the order they run: :mod:`proctex.transfer.assets` (the template
side), :mod:`proctex.transfer.assign` (step 2), :mod:`proctex.transfer.mappers` (step 3), :mod:`proctex.transfer.uvlookup`
(step 4); this module strings them together, writes the GLB and bakes.

1. **Segment** into parts (connected components by shared vertex index: milliseconds).
2. **Assign** every part to a template *slot* (a template part, hence a group and the member map
   of that part onto its group's representative) by a Hungarian assignment on placement descriptors
   (centre and extents relative to the shape's bounding box). Parts left over (a group the template
   does not have, or more copies than the template has) join a group they are another copy of:
   the same connectivity up to an affine map, else the same primitive once both bounding boxes are
   scaled to a cube (:func:`proctex.transfer.assign.match_box`: a wider tier, a longer leg), else a rigid
   ICP fit; parts matching none form a new group.
3. **Map** each part, in its normalised frame (and mirrored into the representative's side by the
   slot's member map), onto the template representative's normalised frame with a *mapper* (a
   ProcCorrNet, the cage solver, or a baseline), at its vertices only.
4. **UVs**: each face takes the template face nearest to its mapped centroid (fast spatial index)
   and gives its three corners UVs through that face's affine UV map, so a face never straddles two
   charts. The shape then reads the template's own texture images: colours are consistent across the
   family by construction, and nothing is unwrapped or encoded per request.
5. Optionally **bake** (:func:`bake`): give the shape its own atlas and textures, colouring every
   covered texel from its mapped point (vertex predictions interpolated inside the face, then
   projected onto the template surface) through the template UV and texture.
"""

from __future__ import annotations

import os
import time
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from functools import lru_cache
from typing import Any

import numpy as np

from proctex.geometry.parts import part_mesh, parts_of
from proctex.geometry.shape import Shape
from proctex.texture.export import glb_bytes
from proctex.texture.inpaint import patchmatch_fill
from proctex.texture.paint import UNPAINTED, shape_frame
from proctex.texture.painters.partwords import new_part_texts
from proctex.texture.pbr import PbrMaps, corner_normals, corner_tangents, decode_normal, encode_normal, flat_maps, texel_frames
from proctex.texture.uv import bilinear_texels, pad_seams, sample_texture, texel_map, unwrap
from proctex.transfer.assets import TemplateAssets, same_topology, texture_hw
from proctex.transfer.assign import PartAssignment, assign_parts, representative_part
from proctex.transfer.budget import Budget
from proctex.transfer.mappers import Mapper
from proctex.transfer.uvlookup import chart_lookups, group_rooms, part_uvs, side_normals

# ------------------------------------------------------------------------------------- transfer
#: Bake sizes (texels per side of a shape's own atlas) and seeds a transfer takes.
BAKE_SIZES = (8, 8192)
SEED_MAX = 2**31 - 1


def check_transfer_args(seed: object = 0, bake_size: object = None) -> None:
    """``ValueError`` unless ``seed`` is an integer in [0, :data:`SEED_MAX`] and ``bake_size`` None or
    an integer in :data:`BAKE_SIZES` (a 100000² atlas is 10¹⁰ texels: refused before any work)."""
    if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or not 0 <= seed <= SEED_MAX:
        raise ValueError(f"seed must be an integer in [0, {SEED_MAX}], got {str(seed)[:40]}")
    if bake_size is not None and (isinstance(bake_size, bool) or not isinstance(bake_size, (int, np.integer)) or not BAKE_SIZES[0] <= bake_size <= BAKE_SIZES[1]):
        raise ValueError(f"a bake size must be an integer in [{BAKE_SIZES[0]}, {BAKE_SIZES[1]}] texels, got {str(bake_size)[:40]}")


@dataclass
class TransferResult:
    """UVs of a shape into the template textures.

    Attributes:
        corner_uv: (m, 3, 2) float64; face_group: (m,) int64 (-1: no texture, e.g. degenerate parts).
        assignment: one :class:`PartAssignment` per part.
        points: {part: (j, 3) mapped template points of its vertices (template representative world)}.
        seconds: total; timings: per stage in seconds (segment, assign, map, uv, new; glb or bake from
            :func:`shape_to_glb`); map and uv share the parts' wall time when the parts run side by side.
        new_textures: textures painted for parts of groups the template does not have; their faces
            use group ids ``G, G + 1, ...`` after the template's ``G`` groups.
        notes: what a user should know (new groups, unpainted parts).
        direct: parts with the representative's own connectivity, which took its UVs unchanged.
    """

    corner_uv: np.ndarray
    face_group: np.ndarray
    assignment: list[PartAssignment]
    points: dict[int, np.ndarray] = field(default_factory=dict)
    seconds: float = 0.0
    timings: dict[str, float] = field(default_factory=dict)
    new_textures: list[np.ndarray] = field(default_factory=list)  # (H, W, 3) uint8, groups G, G+1, ...
    notes: list[str] = field(default_factory=list)
    direct: set[int] = field(default_factory=set)


def transfer(
    shape: Shape,
    assets: TemplateAssets,
    mapper: Mapper,
    seed: int = 0,
    painter: Any = None,
    new_size: int | None = None,
    shortcut: bool = True,
    budget: Budget | None = None,
    workers: int | None = None,
    up: str = "z",
) -> TransferResult:
    """UVs of ``shape`` into the template textures (module docstring, steps 1-4).

    ``shortcut``: parts with their representative's exact connectivity take its UVs directly (exact
    for procedural models); off, every part goes through ``mapper`` (to compare mappers).

    Parts of a group the template does not have ("new") get a texture of their own, painted by
    ``painter`` (the family's surface painter; the template's textures are untouched), at
    ``new_size`` texels a side (default :func:`new_texture_size`: no finer than the family's own
    textures); without a painter they stay untextured (group -1) and a note says so. A painter
    with a ``prompt`` (the surface painter) paints each new part with what the prompt says of it,
    read on this shape (``up`` its up axis; :func:`proctex.texture.painters.partwords.new_part_texts`):
    arms the template lacked take the arms' clause, not a default.

    ``budget`` (:class:`proctex.transfer.budget.Budget`) is checked between parts; past its deadline,
    or cancelled, the transfer stops with :class:`~proctex.transfer.budget.OverBudget`.

    ``workers``: 1 maps the parts one after the other; otherwise they share a small thread pool
    (:func:`_parts_pool`), in the pieces :func:`part_chunks` makes. The result is the same either way.
    """
    t0 = time.perf_counter()
    timings: dict[str, float] = {}
    seg = parts_of(shape)  # once per shape: the service's check computed it already
    t1 = time.perf_counter()
    timings["segment"] = t1 - t0
    assignment = assign_parts(shape, seg, assets, budget=budget)
    t2 = time.perf_counter()
    timings["assign"] = t2 - t1
    corner = np.zeros((shape.n_faces, 3, 2))
    face_group = np.full(shape.n_faces, -1, dtype=np.int64)
    points: dict[int, np.ndarray] = {}
    direct: set[int] = set()
    notes: list[str] = []
    lookups = chart_lookups(assets)  # computed once, before any part (the parts may run in threads)
    rooms = group_rooms(assets)
    todo = [a for a in assignment if a.group >= 0]

    def one(a: PartAssignment) -> tuple[Any, np.ndarray, np.ndarray, bool, float, float]:
        """``(part, corner UVs, mapped points, direct, map seconds, uv seconds)`` of one assigned part."""
        if budget is not None:
            budget.check(f"mapping {len(assignment)} parts")
        part = seg.parts[a.part]
        ga = assets.groups[a.group]
        v, f = part_mesh(shape, part)
        ta = time.perf_counter()
        if shortcut and same_topology(f, len(v), ga):
            # Same mesh connectivity as the representative: vertex i is the template's vertex i
            # (procedural models), so the part takes the template UVs directly, no mapping.
            return part, ga.corner_uv.copy(), ga.vertices.copy(), True, time.perf_counter() - ta, 0.0
        vn, fo = representative_part(v, f, a)  # fo: f wound outward in this frame (reversed under a mirror)
        mapped = np.asarray(mapper.map(a.group, vn, fo, vn, seed=seed), dtype=np.float64)
        if mapped.shape != vn.shape or not np.isfinite(mapped).all():
            raise ValueError(f"mapper returned {mapped.shape} (finite required) for part {a.part}, expected {vn.shape}")
        tb = time.perf_counter()
        uv, _ = part_uvs(ga, mapped, f, None if lookups is None else lookups[a.group], normals=side_normals(vn, fo), rooms=None if rooms is None else rooms[a.group])
        return part, uv, mapped, False, tb - ta, time.perf_counter() - tb

    # Parts are independent: on a multi-core machine they run side by side (numpy and torch let go
    # of the GIL in their loops); the results land in disjoint rows, in the same order either way.
    pool = _parts_pool() if len(todo) > 1 and workers != 1 else None
    t_parts = time.perf_counter()
    if pool is not None:
        pieces = pool.map(lambda chunk: [(i, one(todo[i])) for i in chunk], part_chunks(todo, mapper))
        done = dict(pair for piece in pieces for pair in piece)
        outcomes = [done[i] for i in range(len(todo))]
    else:
        outcomes = [one(a) for a in todo]
    t_parts = time.perf_counter() - t_parts
    t_map = t_uv = 0.0
    for a, (part, uv, mapped, is_direct, dt_map, dt_uv) in zip(todo, outcomes):
        ga = assets.groups[a.group]
        if is_direct:
            direct.add(a.part)
        corner[part.faces] = uv
        face_group[part.faces] = a.group
        points[a.part] = mapped * ga.radius + ga.center
        t_map += dt_map
        t_uv += dt_uv
    # The parts ran side by side: the pool's wall time, shared out in proportion to each step's time
    # summed over the parts, so the stages add up to the transfer's own time.
    share = t_parts / (t_map + t_uv) if t_map + t_uv > 0 else 0.0
    timings["map"] = t_map * share
    timings["uv"] = t_uv * share
    if assets.observed is not None:  # faces reading template texels the painter never painted
        for g in sorted({a.group for a in todo}):  # the groups of the textured faces (np.unique of them, without a sort of every face)
            n_dis = disoccluded_count(corner, face_group, int(g), assets.observed[g])
            if n_dis:
                notes.append(f"group {g}: {n_dis} faces show surface the template never showed (dis-occlusion; bake to fill it)")
    result = TransferResult(corner, face_group, assignment, points, time.perf_counter() - t0, timings, notes=notes, direct=direct)
    new = [a.part for a in assignment if a.how == "new"]
    if new:
        tn = time.perf_counter()
        if painter is None:
            result.notes.append(f"parts {new} match no template group and no painter was given: left untextured")
        else:
            faces = np.concatenate([seg.parts[p].faces for p in new])
            texts = new_part_texts(painter.prompt, shape, seg, new, up) if isinstance(getattr(painter, "prompt", None), str) else {}
            face_texts = np.concatenate([np.full(len(seg.parts[p].faces), texts.get(p), dtype=object) for p in new]) if texts else None
            for text in dict.fromkeys(texts.values()):
                result.notes.append(f"new parts {[p for p in new if texts.get(p) == text]} painted with {text!r} (what the prompt says of them)")
            uv, image = paint_new_parts(shape, faces, painter, new_texture_size(assets) if new_size is None else new_size, face_texts)
            result.corner_uv[faces] = uv
            result.face_group[faces] = len(assets.groups)
            result.new_textures.append(image)
            result.notes.append(f"parts {new} match no template group: painted as a new group {len(assets.groups)}")
        timings["new"] = time.perf_counter() - tn
        result.seconds = time.perf_counter() - t0
    return result


def part_chunks(todo: list[PartAssignment], mapper: Any) -> list[list[int]]:
    """The parts ``todo`` as the pieces of work the parts' threads take (indices into ``todo``): the
    parts a network maps (``mapper.serves``) together in one piece, one after the other in one
    thread, each after the first finding the networks' kernels warm in that core's caches (a
    prediction took 1.8 ms back to back and 2.7 ms after other work, on the demo family), while the
    other thread takes the other parts, each a piece of its own, in order. Where networks map every
    part, they are two pieces (the first half and the rest), one per thread."""
    serves = getattr(mapper, "serves", None)
    networked = [i for i, a in enumerate(todo) if serves is not None and serves(a.group) == "network"]
    rest = sorted(set(range(len(todo))) - set(networked))
    if not rest and len(networked) > 1:
        half = (len(networked) + 1) // 2
        return [networked[:half], networked[half:]]
    return ([networked] if networked else []) + [[i] for i in rest]


def warm_kernels() -> None:
    """Compile, or load from numba's cache, the compiled kernels a transfer runs (an OBJ upload's
    reading and header count, the shape's segmentation, the UV lookup's tree and affine maps, the GLB's normals and tangents): a serving process calls this at start so that its
    first request does not pay it (seconds on a machine's first run, a fraction of one after).
    Nothing where numba does not import (the array forms and libigl answer then)."""
    try:
        from proctex.geometry import bvh, mesh_kernels, obj_kernels
        from proctex.texture import vertex_kernels
        from proctex.transfer import uv_kernels
    except ImportError:
        return
    bvh.warm()
    mesh_kernels.warm()
    obj_kernels.warm()
    vertex_kernels.warm()
    uv_kernels.warm()


@lru_cache(maxsize=1)
def _parts_pool() -> ThreadPoolExecutor:
    """The process's thread pool for parts of one transfer (two workers at most: a request is a few
    parts, and replicas are what use more cores)."""
    return ThreadPoolExecutor(max_workers=max(1, min(2, os.cpu_count() or 1)), thread_name_prefix="proctex-parts")


#: The largest texture side new parts are painted at (:func:`new_texture_size`).
NEW_SIZE = 256


def new_texture_size(assets: TemplateAssets) -> int:
    """The side of the texture new parts are painted at: the family's largest group texture side, at
    most :data:`NEW_SIZE` (a family of 128-texel textures does not paint a part it lacks at 256,
    which costs four times the texels to rasterise and paint in the request)."""
    sides = [max(texture_hw(assets, g)) for g in range(len(assets.groups))]
    return int(min(NEW_SIZE, max(sides, default=NEW_SIZE)))


def paint_new_parts(shape: Shape, faces: np.ndarray, painter: Any, size: int = NEW_SIZE, face_texts: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Atlas and texture for faces of parts no template group fits, painted by a surface painter.

    Points go to the painter in the shape's normalised frame, as when the template was painted.
    ``face_texts``: (k,) object, per face a text the painter paints there (``paint(..., text=)``) or
    None (its default). Returns (corner_uv (k, 3, 2), texture (size, size, 3) uint8).
    """
    used = np.unique(shape.faces[faces])
    local = np.searchsorted(used, shape.faces[faces])
    atlas = unwrap(shape.vertices[used], local, resolution=size, padding=2)
    tm = texel_map(shape.vertices[used], local, atlas.corner_uv, size)
    center, scale = shape_frame(shape)
    image = np.full((size, size, 3), UNPAINTED, dtype=np.float32)
    pts = (tm.points - center) / scale
    if face_texts is None:
        colors = np.asarray(painter.paint(pts, tm.normals), dtype=np.float32)
    else:  # each texel painted once: by its face's text, or the painter's default where it has none
        texts = list(dict.fromkeys(t for t in face_texts if t is not None))
        number = {t: k for k, t in enumerate(texts)}
        per_texel = np.array([-1 if t is None else number[t] for t in face_texts], dtype=np.int64)[tm.face]  # -1: no text
        colors = np.empty((len(pts), 3), dtype=np.float32)
        for k, text in [(-1, None)] + list(enumerate(texts)):
            sel = np.flatnonzero(per_texel == k)
            if len(sel):
                colors[sel] = painter.paint(pts[sel], tm.normals[sel], text=text) if text is not None else painter.paint(pts[sel], tm.normals[sel])
    image[tm.ij[:, 0], tm.ij[:, 1]] = colors
    image, _ = pad_seams(image, tm.mask, 4)
    return atlas.corner_uv, (np.clip(image, 0, 1) * 255).round().astype(np.uint8)


def glb(shape: Shape, result: TransferResult, assets: TemplateAssets, up: str = "y", texture_uris: list[str | None] | None = None, map_uris: list[tuple[str, str] | None] | None = None) -> bytes:
    """Textured GLB bytes of a transferred shape (reuses the template's encoded PNGs and PBR maps:
    the maps share the textures' UVs, so nothing is recomputed); ``up``: the shape's up axis (the
    GLB stands it upright, see :func:`proctex.texture.export.glb_bytes`). ``texture_uris``: per
    template group a URI its texture is read from instead of being embedded (None: embedded);
    ``map_uris``: the same for its PBR maps, ``(orm URI, normal URI)`` (an edit replaces
    ``assets.pbr_png``). Textures painted for new parts are always embedded (colour only)."""
    extra = [f"new_{k}" for k in range(len(result.new_textures))]
    uris = (list(texture_uris) + [None] * len(extra)) if texture_uris is not None else None
    maps = (list(assets.pbr_png) + [None] * len(extra)) if assets.pbr_png is not None else None
    m_uris = (list(map_uris) + [None] * len(extra)) if map_uris is not None and maps is not None else None
    return glb_bytes(
        shape.vertices, shape.faces, result.corner_uv, result.face_group, assets.png + list(result.new_textures), names=assets.names + extra, up=up, image_uris=uris, pbr=maps, pbr_uris=m_uris
    )


# ------------------------------------------------------------------------------------------ bake
@dataclass
class Baked:
    """A shape with its own atlas and textures.

    Attributes:
        corner_uv: (m, 3, 2); face_group: (m,) int64.
        textures: per group (H, W, 3) uint8 (groups absent from the shape: 1x1 grey).
        painted: per group (H, W) bool texels holding colour (``covered`` ones and their gutter).
        covered: per group (H, W) bool texels inside the group's charts.
        disoccluded: per group (H, W) bool texels whose template lookup touched template texels the
            painter never painted (surface the template did not show); they were filled by PatchMatch
            from this group's other texels (``fill="patchmatch"``).
        direct: per group whether it kept the template's UVs and texture (every part of it has the
            representative's connectivity: nothing baked).
        pbr: per group its PBR maps in the shape's own atlas (None: none), or None when the
            template has no maps.
        seconds; notes.
    """

    corner_uv: np.ndarray
    face_group: np.ndarray
    textures: list[np.ndarray]
    painted: list[np.ndarray]
    seconds: float
    covered: list[np.ndarray] = field(default_factory=list)
    disoccluded: list[np.ndarray] = field(default_factory=list)
    direct: list[bool] = field(default_factory=list)
    notes: list[str] = field(default_factory=list)
    pbr: list[Any] | None = None


def bake_pbr(maps: Any, vertices: np.ndarray, faces: np.ndarray, template_uv: np.ndarray, atlas_uv: np.ndarray, tm: Any, uv: np.ndarray, gutter: int, nnf: np.ndarray | None = None) -> Any:
    """A group's template PBR maps baked into a shape's own atlas.

    Args:
        maps: the template's :class:`~proctex.texture.pbr.PbrMaps`; vertices (n, 3), faces (k, 3):
            the group's faces on the shape; template_uv, atlas_uv: (k, 3, 2) their corners' UVs into
            the template textures and in the new atlas; tm: the atlas's texel map; uv: (t, 2) each
            covered texel's template UV; gutter: seam padding (-1: the whole atlas); nnf: (H, W, 2)
            the source texel PatchMatch copied each dis-occluded texel's colour from (-1 elsewhere):
            those texels take that texel's maps too, so relief and sheen follow the synthesised colour.
    The ORM is resampled like the colour. A tangent-space normal is relative to the UV directions,
    so each texel's normal is decoded in the frame the template UVs give this surface (what the
    un-baked GLB shows) and encoded again in the atlas's frame: the relief stays where it was.
    """
    size = tm.height
    out = flat_maps(size, tm.width)
    orm = out.orm.copy()
    orm[tm.ij[:, 0], tm.ij[:, 1]] = sample_texture(maps.orm_uint8(), uv)[:, :3]
    cn = corner_normals(vertices, faces)
    T1, B1, N = texel_frames(tm, corner_tangents(vertices, faces, template_uv, cn), cn)
    T2, B2, _ = texel_frames(tm, corner_tangents(vertices, faces, atlas_uv, cn), cn)
    nt = decode_normal(sample_texture(maps.normal_uint8(), uv)[:, :3])
    world = nt[:, :1] * T1 + nt[:, 1:2] * B1 + nt[:, 2:] * N
    normal = out.normal.copy()
    normal[tm.ij[:, 0], tm.ij[:, 1]] = encode_normal(np.stack([(world * T2).sum(1), (world * B2).sum(1), (world * N).sum(1)], 1))
    if nnf is not None:  # tangent-space values move with the UV-space patches the colour was copied in
        ti, tj = np.nonzero(nnf[..., 0] >= 0)
        si, sj = nnf[ti, tj, 0], nnf[ti, tj, 1]
        orm[ti, tj] = orm[si, sj]
        normal[ti, tj] = normal[si, sj]
    orm, _ = pad_seams(orm, tm.mask, gutter)
    normal, _ = pad_seams(normal, tm.mask, gutter)
    return PbrMaps(orm.astype(np.float32), normal.astype(np.float32), maps.occlusion)


def disoccluded_count(corner_uv: np.ndarray, face_group: np.ndarray, group: int, observed: np.ndarray) -> int:
    """How many faces of ``group`` read a texel outside ``observed`` at the centre of their UVs
    (:func:`disoccluded_texels` of their corner means): compiled
    (:func:`proctex.transfer.uv_kernels.disoccluded_faces`, one pass, nothing gathered), or in
    arrays where numba does not import."""
    try:
        from proctex.transfer.uv_kernels import disoccluded_faces
    except ImportError:
        c = corner_uv[np.flatnonzero(face_group == group)]
        return int(disoccluded_texels((c[:, 0] + c[:, 1] + c[:, 2]) / 3, observed).sum())  # the corners' mean, as .mean(axis=1) adds them
    return disoccluded_faces(corner_uv, face_group, group, observed)


def disoccluded_texels(uv: np.ndarray, observed: np.ndarray) -> np.ndarray:
    """(k,) bool: which template lookups at ``uv (k, 2)`` touch a texel outside ``observed (H, W)``
    (any of the four texels of the bilinear footprint)."""
    idx = bilinear_texels(np.asarray(uv, dtype=np.float64), observed.shape[0], observed.shape[1])
    return ~observed.ravel()[idx].all(axis=1)


def group_atlas(shape: Shape, faces: np.ndarray, size: int, padding: int, cache: dict | None = None) -> tuple[np.ndarray, np.ndarray, Any, Any]:
    """The own atlas of the faces ``faces (k,)`` of ``shape`` that :func:`bake` bakes into:
    ``(used (u,) vertex ids, local (k, 3) faces over them, the xatlas Atlas, its TexelMap at
    size x size)``. ``cache``: a dict kept across calls, keyed by the faces' and their vertices'
    bytes, the size and padding (xatlas is deterministic: a hit is what unwrapping again gives)."""
    import hashlib

    used = np.unique(shape.faces[faces])
    local = np.searchsorted(used, shape.faces[faces])
    key = None
    if cache is not None:
        h = hashlib.blake2b(digest_size=16)
        for a in (np.ascontiguousarray(local, dtype=np.int64), np.ascontiguousarray(shape.vertices[used], dtype=np.float64)):
            h.update(a.tobytes())
        key = (h.hexdigest(), int(size), int(padding))
        if key in cache:
            return (used, local, *cache[key])
    atlas = unwrap(shape.vertices[used], local, resolution=size, padding=padding)
    tm = texel_map(shape.vertices[used], local, atlas.corner_uv, size)
    if cache is not None:
        cache[key] = (atlas, tm)
    return used, local, atlas, tm


def bake(
    shape: Shape,
    result: TransferResult,
    assets: TemplateAssets,
    size: int = 512,
    gutter: int = -1,
    project: bool = False,
    fill: str = "patchmatch",
    seed: int = 0,
    pbr: bool = True,
    atlases: dict | None = None,
) -> Baked:
    """Give a transferred shape its own UV atlas per group and bake the template textures into it.

    Each covered texel reads the template texture (bilinear) at its template UV. By default that UV is
    the barycentric interpolation of its face's transferred corner UVs (``result.corner_uv``, the
    face's affine map into one template chart); with ``project=True`` every texel's mapped point (the
    interpolated mapped vertices) is projected onto the template surface and its UV looked up there,
    ten times slower (the benchmark compares both). Seams are padded ``gutter`` texels from the
    nearest covered texel; the default (-1) pads the whole atlas, because the sharp tip of a sliver
    triangle owns no texel centre for several texels (measured on the sofa: a 5 x 37-texel triangle
    read unpainted texels 5 texels beyond a 4-texel gutter).

    Groups whose parts all have the representative's connectivity (``result.direct``) keep the
    template's UVs and texture (nothing is baked) unless the template's painter left some of the
    group unpainted. Dis-occlusion: texels whose template lookup touches
    template texels outside ``assets.observed`` (surface the template never showed its painter) are
    detected and, with ``fill="patchmatch"``, re-synthesised by exemplar PatchMatch from this group's
    other texels; no other texel changes (``fill="none"`` keeps the template's colours there).
    ``pbr=False`` bakes the base colour only (``Baked.pbr`` None): what a measurement of colours needs
    (the PBR maps were two thirds of the demo's evaluation). ``atlases``: a dict kept by the caller
    across bakes of the same shape (e.g. by several methods): a group's atlas and texel map depend
    only on its faces, so each is unwrapped once (:func:`group_atlas`).
    """
    if fill not in ("patchmatch", "none"):
        raise ValueError(f"fill must be patchmatch or none, got {fill!r}")
    t0 = time.perf_counter()
    seg = parts_of(shape)  # once per shape: the service's check computed it already
    corner = np.zeros((shape.n_faces, 3, 2))
    face_group = np.full(shape.n_faces, -1, dtype=np.int64)
    out = Baked(corner, face_group, [], [], 0.0, pbr=[] if assets.pbr is not None and pbr else None)
    for g, ga in enumerate(assets.groups):
        maps = assets.pbr[g] if out.pbr is not None else None
        parts = [a.part for a in result.assignment if a.group == g and a.part in result.points]
        observed = assets.observed[g] if assets.observed is not None else None
        if not parts:
            out.textures.append(np.full((1, 1, 3), 128, np.uint8))
            out.painted.append(np.ones((1, 1), bool))
            out.covered.append(np.ones((1, 1), bool))
            out.disoccluded.append(np.zeros((1, 1), bool))
            out.direct.append(False)
            if out.pbr is not None:
                out.pbr.append(None)
            continue
        faces = np.concatenate([seg.parts[p].faces for p in parts])
        face_group[faces] = g
        hidden = observed is not None and assets.painted is not None and bool((assets.painted[g] & ~observed).any())
        if all(p in result.direct for p in parts) and not hidden:
            corner[faces] = result.corner_uv[faces]
            out.textures.append(assets.textures[g])
            out.painted.append(assets.painted[g] if assets.painted is not None else np.ones(assets.textures[g].shape[:2], bool))
            out.covered.append(out.painted[-1])
            out.disoccluded.append(np.zeros(assets.textures[g].shape[:2], bool))
            out.direct.append(True)
            if out.pbr is not None:
                out.pbr.append(maps)
            continue
        used, local, atlas, tm = group_atlas(shape, faces, size, 2 if gutter < 0 else max(2, gutter // 2), atlases)
        corner[faces] = atlas.corner_uv
        if project:
            # Mapped points per used vertex, in the representative's normalised frame.
            mapped = np.zeros((len(used), 3))
            for p in parts:
                ids = np.searchsorted(used, seg.parts[p].vertices)
                mapped[ids] = (result.points[p] - ga.center) / ga.radius
            target = np.einsum("ij,ijk->ik", tm.bary, mapped[local[tm.face]])
            hit = ga.index.query(target, exact=False)
            uv = np.einsum("ij,ijk->ik", hit.bary, ga.corner_uv[hit.faces])
        else:
            uv = np.einsum("ij,ijk->ik", tm.bary, result.corner_uv[faces[tm.face]])
        image = np.zeros((size, size, 3))
        image[tm.ij[:, 0], tm.ij[:, 1]] = sample_texture(assets.textures[g], uv)
        hole = np.zeros((size, size), dtype=bool)
        nnf = None
        if observed is not None:
            dis = disoccluded_texels(uv, observed)
            hole[tm.ij[dis, 0], tm.ij[dis, 1]] = True
            if dis.any() and fill == "patchmatch":
                known = tm.mask & ~hole
                try:
                    filled = patchmatch_fill(image, known, hole, seed=seed + g)
                    image, nnf = filled.image, filled.nnf
                    out.notes.append(f"group {g}: {int(dis.sum())} dis-occluded texels filled by PatchMatch")
                except ValueError as exc:  # no usable source patch: keep the template's colours there
                    out.notes.append(f"group {g}: {int(dis.sum())} dis-occluded texels kept the template's fill ({exc})")
        image, mask = pad_seams(image, tm.mask, gutter)
        if out.pbr is not None:
            out.pbr.append(None if maps is None else bake_pbr(maps, shape.vertices[used], local, result.corner_uv[faces], atlas.corner_uv, tm, uv, gutter, nnf))
        out.textures.append((np.clip(image, 0, 1) * 255).round().astype(np.uint8))
        out.painted.append(mask)
        out.covered.append(tm.mask)
        out.disoccluded.append(hole)
        out.direct.append(False)
    for k, image in enumerate(result.new_textures):  # new groups already have their own atlas
        sel = result.face_group == len(assets.groups) + k
        corner[sel] = result.corner_uv[sel]
        face_group[sel] = len(assets.groups) + k
        out.textures.append(image)
        out.painted.append(np.ones(image.shape[:2], dtype=bool))
        out.covered.append(out.painted[-1])
        out.disoccluded.append(np.zeros(image.shape[:2], dtype=bool))
        out.direct.append(False)
        if out.pbr is not None:
            out.pbr.append(None)
    out.seconds = time.perf_counter() - t0
    return out


def info(result: TransferResult) -> dict[str, Any]:
    """JSON-ready summary of a transfer (assignment, timings)."""
    return {
        "notes": list(result.notes),
        "seconds": round(result.seconds, 4),
        "timings": {k: round(v, 4) for k, v in result.timings.items()},
        "parts": [{"part": a.part, "group": a.group, "slot": a.slot, "how": a.how, "cost": (round(a.cost, 4) if np.isfinite(a.cost) else None)} for a in result.assignment],
    }


# ------------------------------------------------------------------------------- shape in, GLB out
@dataclass
class TexturedGLB:
    """A textured shape as answered: ``data`` (GLB bytes), the transfer ``result``, and what the GLB
    shows (``corner_uv`` (m, 3, 2), ``face_group`` (m,), ``textures``: per material an (H, W, 3)
    uint8 image or encoded PNG bytes), e.g. for a preview. ``baked``: the bake, when asked for.
    ``pbr``: per material its PBR maps (uint8 images) or None; None when the family has none."""

    data: bytes
    result: TransferResult
    corner_uv: np.ndarray
    face_group: np.ndarray
    textures: list[Any]
    baked: Baked | None = None
    pbr: list[Any] | None = None


def shape_to_glb(
    shape: Shape,
    assets: TemplateAssets,
    mapper: Mapper,
    seed: int = 0,
    painter: Any = None,
    up: str = "y",
    bake_size: int | None = None,
    shortcut: bool = True,
    budget: Budget | None = None,
    texture_uris: list[str | None] | None = None,
    map_uris: list[tuple[str, str] | None] | None = None,
) -> TexturedGLB:
    """The run-time path, shape in, GLB out: :func:`transfer` with ``mapper`` (``painter`` colours
    parts of groups the template lacks), then the GLB (:func:`glb`, the template's encoded PNGs), or
    with ``bake_size`` the shape's own atlas and textures (:func:`bake`). The command line, the
    service, the demo and the evaluation all answer with this. ``budget``: see :func:`transfer`.
    ``texture_uris``, ``map_uris``: see :func:`glb` (not with ``bake_size``: a baked atlas is the shape's own).
    The result's ``timings`` gain ``glb`` (or ``bake``: the atlas, its textures and the GLB)."""
    result = transfer(shape, assets, mapper, seed=seed, painter=painter, shortcut=shortcut, budget=budget, up=up)
    if budget is not None:
        budget.check("encoding the answer")
    t0 = time.perf_counter()
    if bake_size:
        baked = bake(shape, result, assets, size=bake_size)
        names = assets.names + [f"new_{k}" for k in range(len(result.new_textures))]
        pbr = baked.pbr if baked.pbr is not None and any(m is not None for m in baked.pbr) else None
        data = glb_bytes(shape.vertices, shape.faces, baked.corner_uv, baked.face_group, baked.textures, names=names, up=up, pbr=pbr)
        result.timings["bake"] = time.perf_counter() - t0
        return TexturedGLB(data, result, baked.corner_uv, baked.face_group, list(baked.textures), baked, pbr)
    data = glb(shape, result, assets, up=up, texture_uris=texture_uris, map_uris=map_uris)
    result.timings["glb"] = time.perf_counter() - t0
    return TexturedGLB(
        data,
        result,
        result.corner_uv,
        result.face_group,
        list(assets.textures) + list(result.new_textures),
        pbr=None if assets.pbr is None else list(assets.pbr) + [None] * len(result.new_textures),
    )
