"""Texture transfer: any shape of the family textured from the template's group textures.

The run-time path (DESIGN §1, step 3), per shape:

1. **Segment** into parts (connected components by shared vertex index: milliseconds).
2. **Assign** every part to a template *slot* (a template part, hence a group and the member map
   of that part onto its group's representative) by a Hungarian assignment on placement descriptors
   (centre and extents relative to the shape's bounding box). Parts left over (a group the template
   does not have, or more copies than the template has) join a group they are another copy of:
   the same connectivity up to an affine map, else the same primitive once both bounding boxes are
   scaled to a cube (:func:`match_box`: a wider tier, a longer leg), else a rigid ICP fit; parts
   matching none form a new group.
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

import time
from dataclasses import dataclass, field
from functools import lru_cache
from typing import Any, Protocol, Sequence

import numpy as np
from scipy.optimize import linear_sum_assignment

from .geometry import SurfaceIndex, normalised_frame, sample_surface
from .inpaint import chart_labels
from .parts import Grouping, Segmentation, part_mesh, segment
from .shape import Shape
from .uv import pad_seams, sample_texture, texel_map, unwrap


# --------------------------------------------------------------------------------- template side
@dataclass
class GroupAssets:
    """What transfer needs of one template group (its representative part, in its normalised frame).

    ``vertices (k, 3)`` normalised, ``faces (f, 3)`` local, ``corner_uv (f, 3, 2)``, ``center (3,)``,
    ``radius``, ``index`` a :class:`SurfaceIndex` over the normalised mesh.
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


@dataclass
class Slot:
    """A template part as a place a shape part can take: its group and member map (linear part)."""

    part: int
    group: int
    R: np.ndarray  # (3, 3): x_rep = R x_member + t
    center: np.ndarray  # (3,) part centre relative to the shape box, in [0, 1]^3
    extents: np.ndarray  # (3,) part box extents relative to the shape box size


@dataclass
class TemplateAssets:
    """The template prepared for transfer: groups, slots, textures (arrays and encoded PNGs)."""

    shape: Shape
    grouping: Grouping
    groups: list[GroupAssets]
    slots: list[Slot]
    textures: list[np.ndarray]  # (H, W, 3) uint8 per group
    png: list[bytes]
    names: list[str]
    # Per group (H, W) bool: texels holding colour, and the "already painted" ones (painted by the
    # painter itself, not filled); None: every texel counts as both.
    painted: list[np.ndarray] | None = None
    observed: list[np.ndarray] | None = None
    charts: list[np.ndarray] | None = None  # chart ids of ``painted`` (see :func:`template_charts`)
    lookups: list[ChartLookup] | None = None  # per group, chart and room maps for the run-time coverage check (:func:`chart_lookups`)


def _box(vertices: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    lo, hi = vertices.min(axis=0), vertices.max(axis=0)
    return lo, np.maximum(hi - lo, 1e-12)


def _placement(vertices: np.ndarray, lo: np.ndarray, size: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    plo, phi = vertices.min(axis=0), vertices.max(axis=0)
    return ((plo + phi) / 2 - lo) / size, (phi - plo) / size


def prepare_template(shape: Shape, grouping: Grouping, corner_uv: np.ndarray, textures: Sequence[np.ndarray], names: Sequence[str] | None = None) -> TemplateAssets:
    """Build :class:`TemplateAssets` from a textured template.

    Args:
        shape, grouping: the template; corner_uv: (m, 3, 2) its UVs; textures: per group (H, W, 3)
        uint8 (or float in [0, 1]) images; names: per group material names.
    """
    from .export import _png

    if len(textures) != len(grouping.groups):
        raise ValueError(f"need one texture per group ({len(grouping.groups)}), got {len(textures)}")
    texs = [np.ascontiguousarray(t if np.asarray(t).dtype == np.uint8 else (np.clip(t, 0, 1) * 255).round().astype(np.uint8))[..., :3] for t in textures]
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
            slots.append(Slot(member, g.index, np.asarray(mmap.R, float), centre, extents))
    names = list(names) if names is not None else [g.label or f"group_{g.index}" for g in grouping.groups]
    return TemplateAssets(shape, grouping, groups, slots, texs, [_png(t) for t in texs], names)


# ----------------------------------------------------------------------------------- assignment
@dataclass
class PartAssignment:
    """Where one shape part goes: ``group`` (-1: none), the ``slot`` part of the template it took
    (-1: an extra part matched by ICP), ``R`` (3, 3) and ``t`` (3,) the map of its normalised frame
    into the representative's (``x -> R x + t``), ``cost`` of the assignment and ``how`` ("slot",
    "extra", "new" — a group the template does not have — or "degenerate")."""

    part: int
    group: int
    slot: int
    R: np.ndarray
    cost: float
    how: str
    t: np.ndarray = field(default_factory=lambda: np.zeros(3))


def representative_frame(vertices: np.ndarray, assignment: PartAssignment) -> np.ndarray:
    """A part's vertices ``(k, 3)`` (shape frame) in its group representative's normalised frame:
    the part's own normalised frame (bounding-box centre, L∞ radius), then the assignment's map
    ``x -> R x + t`` onto the representative's side. The one place this frame is computed: the
    build's cage pairs, the run-time transfer and the evaluation all use it."""
    v = np.asarray(vertices, dtype=np.float64)
    c, r = normalised_frame(v)
    return (v - c) / (r if r > 0 else 1.0) @ np.asarray(assignment.R, dtype=np.float64).T + np.asarray(assignment.t, dtype=np.float64)


def choose_part(assignment: Sequence[PartAssignment], group: int) -> PartAssignment | None:
    """The part of a shape that stands for group ``group``'s representative (it teaches the group's
    network and carries the cage tracker): the one in the representative's own slot (a slot of the
    group with an identity member map), else any part assigned to the group; ``None`` if none."""
    cands = [a for a in assignment if a.group == group]
    rep_side = [a for a in cands if a.how == "slot" and np.allclose(a.R, np.eye(3))]
    return (rep_side or cands or [None])[0]


def assign_parts(
    shape: Shape, seg: Segmentation, assets: TemplateAssets, w_extent: float = 1.0, extra_cost: float = 0.6, extra_tol: float = 0.02,
    box_cost: float = 1.2,
) -> list[PartAssignment]:
    """Assign each part of a shape to a template slot (see the module docstring).

    Cost between a part and a slot: distance between their centres plus ``w_extent`` times the mean
    absolute log-ratio of their extents, both relative to each shape's bounding box. Pairs costing
    more than ``extra_cost`` are not taken. Such a part ("extra") joins, in this order: the group of
    a part of the same shape it is a rigid copy of (:func:`copy_of_sibling`), the group whose
    representative has its connectivity (:func:`copy_of_group`), the group whose representative is
    the same primitive in other proportions (:func:`match_box`), the group it fits by ICP
    (:func:`match_extra`, alignment error at most ``extra_tol``); otherwise it forms a group of its
    own ("new"), which :func:`transfer` paints with the family's painter.
    """
    lo, size = _box(shape.vertices)
    parts = [p for p in seg.parts if not p.degenerate]
    out = [PartAssignment(p.index, -1, -1, np.eye(3), 0.0, "degenerate") for p in seg.parts if p.degenerate]
    if not parts or not assets.slots:
        return out + [PartAssignment(p.index, -1, -1, np.eye(3), np.inf, "unmatched") for p in parts]
    desc = [_placement(shape.vertices[p.vertices], lo, size) for p in parts]
    pc = np.array([d[0] for d in desc])
    pe = np.array([d[1] for d in desc])
    sc = np.array([s.center for s in assets.slots])
    se = np.array([s.extents for s in assets.slots])
    loge = np.abs(np.log(np.maximum(pe[:, None], 1e-6) / np.maximum(se[None], 1e-6))).mean(axis=2)
    cost = np.linalg.norm(pc[:, None] - sc[None], axis=2) + w_extent * loge
    # One "no slot" column per part at the threshold cost: a part takes a slot only where that beats
    # leaving it out, so an extra part (an armrest the template lacks) can never win a slot from
    # the part that belongs there and then be dropped for costing too much.
    stay_out = np.full((len(parts), len(parts)), extra_cost + 1e-9)
    rows, cols = linear_sum_assignment(np.hstack([cost, stay_out]))
    taken = {}
    for r, c in zip(rows, cols):
        if c < cost.shape[1] and cost[r, c] <= extra_cost:
            taken[r] = c
    slotted: list[tuple[PartAssignment, np.ndarray, np.ndarray]] = []  # (assignment, vertices, local faces)
    for i, p in enumerate(parts):
        if i in taken:
            s = assets.slots[taken[i]]
            out.append(PartAssignment(p.index, s.group, s.part, s.R, float(cost[i, taken[i]]), "slot"))
            slotted.append((out[-1], *part_mesh(shape, p)))
    for i, p in enumerate(parts):
        if i not in taken:
            # A part the template has no place for: the group it matches best by ICP, if any. Groups
            # whose representative has this part's exact connectivity are the only candidates when
            # there are any (an extra slat is a copy of the slat primitive): one ICP, not one per group.
            v, f = part_mesh(shape, p)
            twin = copy_of_sibling(p.index, v, f, slotted, extra_tol)
            if twin is not None:  # a rigid copy of a part that took a slot (a third small mushroom): its map, composed
                out.append(twin)
                continue
            c, r = normalised_frame(v)
            same = [ga.group for ga in assets.groups if not ga.degenerate and same_topology(f, len(v), ga)]
            copy = copy_of_group(v, same, assets, cost[i], extra_tol)
            if copy is not None and copy[1] <= box_cost:  # another copy of a template primitive (a third cushion): its group, template UVs
                out.append(PartAssignment(p.index, copy[0], -1, np.eye(3), copy[1], "extra"))
                continue
            u = (v - c) / (r if r > 0 else 1.0)
            box = match_box(u, f, assets, cost[i], extra_cost=box_cost)
            if box is not None:  # the same primitive in other proportions (a wider tier, a longer leg)
                out.append(PartAssignment(p.index, box.group, -1, box.A, box.score, "extra"))
                continue
            g, R, t, err = match_extra(u, f, assets, groups=same or None)
            if err <= extra_tol:
                out.append(PartAssignment(p.index, g, -1, R, err, "extra", t))
            else:
                out.append(PartAssignment(p.index, -1, -1, np.eye(3), err, "new"))
    return sorted(out, key=lambda a: a.part)


def copy_of_sibling(part: int, vertices: np.ndarray, faces: np.ndarray, slotted: Sequence[tuple[PartAssignment, np.ndarray, np.ndarray]],
                    tol: float = 0.02) -> PartAssignment | None:
    """A part that is a rigid copy of a part of the same shape that took a slot: a procedural model
    instances one mesh several times (a third small mushroom turned about the main stem, a sixth
    candle), so within one shape the copies share their connectivity and vertex order, and the
    rigid motion between them is known exactly (Kabsch with scale on the vertices, in both parts'
    normalised frames). The copy then takes the sibling's group and its map, composed with that
    motion: its true turn, not a guess among the box's axis permutations.

    ``part``: the part's index; ``vertices (k, 3)`` (shape frame) and local ``faces``; ``slotted``:
    ``(assignment, vertices, faces)`` of the parts that took slots. A sibling qualifies when its
    faces are identical and the fit's RMS residual is at most ``tol`` (normalised units); the best
    fit wins. Returns an "extra" :class:`PartAssignment`, or ``None``.
    """
    from .align import umeyama

    v = np.asarray(vertices, dtype=np.float64)
    c, r = normalised_frame(v)
    u = (v - c) / (r if r > 0 else 1.0)
    best: tuple[float, PartAssignment] | None = None
    for a, sv, sf in slotted:
        if len(sv) != len(v) or sf.shape != faces.shape or not np.array_equal(sf, faces):
            continue
        sc, sr = normalised_frame(sv)
        w = (sv - sc) / (sr if sr > 0 else 1.0)
        R, t, s = umeyama(u, w, scale=True, reflection=False)
        resid = float(np.sqrt(((s * u @ R.T + t - w) ** 2).sum(axis=1).mean()))
        if resid <= tol and (best is None or resid < best[0]):
            M = np.asarray(a.R, dtype=np.float64)
            best = (resid, PartAssignment(part, a.group, -1, s * M @ R, resid, "extra", M @ t + np.asarray(a.t, dtype=np.float64)))
    return None if best is None else best[1]


def copy_of_group(vertices: np.ndarray, candidates: Sequence[int], assets: TemplateAssets, slot_cost: np.ndarray,
                  tol: float = 0.02) -> tuple[int, float] | None:
    """The group a part is another copy of, when it has the exact connectivity of group
    representatives (``candidates``): vertex ``i`` is then the representative's vertex ``i`` of the
    same primitive, stretched. Candidates whose representative maps onto the part by an affine map
    (relative residual at most ``tol``) qualify; of those, the group with the cheapest slot
    (``slot_cost (n_slots,)``, placement in the shape's box) wins, so a third seat cushion joins the
    seat cushions even when back cushions share its connectivity. Returns ``(group, its cheapest
    slot cost)``, or ``None`` when none qualifies.

    ``vertices (k, 3)``: the part's vertices in the shape's frame.
    """
    v = np.asarray(vertices, dtype=np.float64)
    best, best_cost = None, np.inf
    size = max(float(np.linalg.norm(np.ptp(v, axis=0))), 1e-12)
    for g in candidates:
        ga = assets.groups[g]
        X = np.hstack([ga.vertices, np.ones((len(ga.vertices), 1))])
        A, *_ = np.linalg.lstsq(X, v, rcond=None)
        resid = float(np.sqrt(((X @ A - v) ** 2).sum(axis=1).mean())) / size
        if resid > tol:
            continue
        slots = [k for k, s in enumerate(assets.slots) if s.group == g]
        c = float(np.min(slot_cost[slots])) if slots else np.inf
        if c < best_cost:
            best, best_cost = g, c
    return None if best is None else (best, best_cost)


@dataclass
class BoxMatch:
    """A part matched to a group as the same primitive in other proportions (:func:`match_box`).

    ``A (3, 3)``: the linear map of the part's normalised frame onto the representative's (a signed
    axis permutation between per-axis scalings, both boxes centred on the origin); ``chamfer``:
    symmetric Chamfer distance of the two surfaces once each box is scaled to the cube [-1, 1]^3;
    ``proportion``: mean absolute log-ratio of the two boxes' half extents after the permutation;
    ``placement``: the cheapest placement cost of a slot of the group; ``score`` the sum."""

    group: int
    A: np.ndarray
    chamfer: float
    proportion: float
    placement: float
    score: float


def _half_extents(points: np.ndarray, min_extent: float) -> np.ndarray:
    return np.maximum(np.ptp(points, axis=0) / 2, min_extent)


def match_box(vertices: np.ndarray, faces: np.ndarray, assets: TemplateAssets, slot_cost: np.ndarray | None = None, n: int = 300,
              seed: int = 0, min_extent: float = 1e-3, chamfer_tol: float = 0.25, proportion_tol: float = 0.7,
              extra_cost: float = 1.2, turn_cost: float = 0.25) -> BoxMatch | None:
    """The group a left-over part is another instance of, up to per-axis scale: a cake tier wider
    than the template's, a leg of another length, a stem of another height. Rigid ICP cannot align
    those; scaling each part's bounding box to the cube [-1, 1]^3 can.

    For every non-degenerate group and every signed axis permutation (48), the part's box-scaled
    surface samples are compared with the representative's by symmetric Chamfer distance (90th
    percentiles, so a missing piece counts). Boxes are
    alike in every box frame, so the proportions of the boxes (after the permutation) and the
    placement of the group's slots in the shape (``slot_cost (n_slots,)``, as
    :func:`assign_parts` computes it; ``None``: not used) decide between groups of one primitive
    (a slat and a post are both boxes). A match needs Chamfer at most ``chamfer_tol``, proportion
    error at most ``proportion_tol`` and placement cost at most ``extra_cost``; the lowest sum wins,
    plus ``turn_cost`` per axis the permutation moves away from the part's own orientation. A
    symmetric part fits turned as well as not, and a procedural parameter stretches a part along
    its own axes rather than turning it: a desk pedestal with four drawers instead of one is the
    same box, taller, not the template's box on its side (whose proportions would be a little
    closer). So a turn must buy more than ``turn_cost`` (per axis moved) of Chamfer and proportion.

    ``vertices (k, 3)``: the part in its normalised frame; ``faces (f, 3)`` local. Axes thinner than
    ``min_extent`` (normalised units: a flat part) count as that thick; thin axes are scaled like
    the others, so a thin slab matches a thin slab of another thickness. Returns ``None`` when no
    group qualifies.
    """
    from itertools import permutations, product

    v = np.asarray(vertices, dtype=np.float64)
    hp = _half_extents(v, min_extent)
    pts = sample_surface(v / hp, faces, n, seed=seed)[0]
    part_index = SurfaceIndex(v / hp, np.asarray(faces))
    best: BoxMatch | None = None
    for ga in assets.groups:
        if ga.degenerate:
            continue
        slots = [k for k, s in enumerate(assets.slots) if s.group == ga.group]
        place = 0.0 if slot_cost is None else (float(np.min(np.asarray(slot_cost)[slots])) if slots else np.inf)
        if place > extra_cost:
            continue
        hr = _half_extents(ga.vertices, min_extent)
        rep = sample_surface(ga.vertices / hr, ga.faces, n, seed=seed)[0]
        rep_index = SurfaceIndex(ga.vertices / hr, ga.faces)
        for perm in permutations(range(3)):
            prop = float(np.abs(np.log(hp[list(perm)] / hr)).mean())
            if prop > proportion_tol:
                continue
            for signs in product((1.0, -1.0), repeat=3):
                P = np.zeros((3, 3))
                P[range(3), perm] = signs  # (P b)_i = s_i b_perm(i)
                # Point-to-surface both ways (P is orthogonal: the template's samples go back by P^T),
                # 90th percentiles: a part missing a piece of the other (a ring against a disc) shows.
                ch = 0.5 * float(np.percentile(rep_index.query(pts @ P.T, exact=False).distance, 90)
                                 + np.percentile(part_index.query(rep @ P, exact=False).distance, 90))
                if ch > chamfer_tol:
                    continue
                # Symmetric parts (a box, a cylinder) fit several ways equally well: the one
                # nearest the part's own orientation wins (no turn cost for the identity).
                score = ch + prop + place + turn_cost * (3.0 - float(np.trace(P))) / 2
                if best is None or score < best.score:
                    A = np.diag(hr) @ P @ np.diag(1.0 / hp)
                    best = BoxMatch(ga.group, A, ch, prop, place, score)
    return best


def match_extra(
    vertices: np.ndarray, faces: np.ndarray, assets: TemplateAssets, n: int = 300, seed: int = 0, groups: Sequence[int] | None = None
) -> tuple[int, np.ndarray, np.ndarray, float]:
    """Best template group for a part (normalised frame) by point-to-surface ICP.

    Tries the eight axis sign flips as starts against every non-degenerate group representative
    (or those of ``groups``).
    Returns ``(group, R (3, 3), t (3,), error)``, error = mean distance after alignment (normalised units).
    """
    from itertools import product

    from .align import icp_to_surface

    pts, _, _ = sample_surface(vertices, faces, n, seed=seed)
    best = (-1, np.eye(3), np.zeros(3), np.inf)
    for ga in assets.groups:
        if ga.degenerate or (groups is not None and ga.group not in groups):
            continue
        for signs in product((1.0, -1.0), repeat=3):
            res = icp_to_surface(pts, ga.index, R0=np.diag(signs), max_iter=30, exact=False)
            if res.error < best[3]:
                best = (ga.group, res.R, res.t, float(res.error))
    return best


# -------------------------------------------------------------------------------------- mappers
class Mapper(Protocol):
    """Maps points of a shape part (normalised frame) onto the template representative's normalised frame."""

    def map(self, group: int, vertices: np.ndarray, faces: np.ndarray, query: np.ndarray, seed: int = 0) -> np.ndarray: ...


class IdentityMapper:
    """Baseline: the normalised frames are taken to coincide (the nearest-point projection does the rest)."""

    def map(self, group: int, vertices: np.ndarray, faces: np.ndarray, query: np.ndarray, seed: int = 0) -> np.ndarray:
        return np.asarray(query, dtype=np.float64)


# ------------------------------------------------------------------------------------- transfer
@dataclass
class TransferResult:
    """UVs of a shape into the template textures.

    Attributes:
        corner_uv: (m, 3, 2) float64; face_group: (m,) int64 (-1: no texture, e.g. degenerate parts).
        assignment: one :class:`PartAssignment` per part.
        points: {part: (j, 3) mapped template points of its vertices (template representative world)}.
        seconds: total; timings: per stage.
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


def _affine_uv(target: np.ndarray, tri: np.ndarray, tri_uv: np.ndarray) -> np.ndarray:
    """UVs (k, 2) of points (k, 3) through the affine map of triangles (k, 3, 3) with UVs (k, 3, 2)
    (barycentrics of the point's projection on the triangle's plane, not clamped)."""
    a = tri[:, 0]
    e1, e2 = tri[:, 1] - a, tri[:, 2] - a
    d11, d12, d22 = (e1 * e1).sum(1), (e1 * e2).sum(1), (e2 * e2).sum(1)
    den = d11 * d22 - d12 * d12
    den = np.where(np.abs(den) > 1e-30, den, np.inf)
    d = target - a
    p1, p2 = (d * e1).sum(1), (d * e2).sum(1)
    l1 = (d22 * p1 - d12 * p2) / den
    l2 = (d11 * p2 - d12 * p1) / den
    lam = np.stack([1 - l1 - l2, l1, l2], axis=1)
    return np.einsum("ij,ijk->ik", lam, tri_uv)


def same_topology(faces: np.ndarray, n_vertices: int, assets: GroupAssets) -> bool:
    """Whether a part mesh (local ``faces (k, 3)`` over ``n_vertices``) has exactly the connectivity
    of the group's representative (same vertex count and the same face array)."""
    return n_vertices == len(assets.vertices) and faces.shape == assets.faces.shape and bool(np.array_equal(faces, assets.faces))


def template_charts(assets: TemplateAssets) -> list[np.ndarray] | None:
    """Per group :func:`chart_labels` of the template's painted masks (computed once, kept on the
    assets); None when the assets carry no painted masks."""
    if assets.painted is None:
        return None
    if assets.charts is None or len(assets.charts) != len(assets.painted):
        assets.charts = [chart_labels(m) for m in assets.painted]
    return assets.charts


#: Template faces checked first per shape face at run time (the nearest proxies of its mapped
#: centroid; the nearest one facing the face's own way wins, the search widening when none does).
UV_CANDIDATES = 4
#: ... and at most this many when none faces it (a thin wall's other side is among the nearest; a
#: face mapped far from any facing face keeps its plain nearest one instead of a wide search).
UV_MAX_CANDIDATES = 16


@dataclass(frozen=True)
class ChartLookup:
    """What the run-time coverage check (:func:`_inside_chart`) reads of one group texture.

    ``labels (H, W)``: :func:`chart_labels`. ``block_label (H*W,)``: per texel, the chart all four
    texels of its bilinear 2x2 block share, -1 where they differ (so one read answers for a whole
    bilinear lookup, :func:`proctex.uv.bilinear_blocks`). ``block_room (H*W,)``: per texel ``T``,
    the largest ``r`` such that the texels at offsets ``-r .. r + 1`` (rows and columns) from ``T``
    all lie in its chart: every point within ``r`` texels (in each coordinate) of a lookup whose
    first texel is ``T`` reads only that chart (0 when ``T``'s own block leaves it).
    """

    labels: np.ndarray
    block_label: np.ndarray
    block_room: np.ndarray


def chart_lookup(labels: np.ndarray) -> ChartLookup:
    """:class:`ChartLookup` of chart ``labels (H, W)`` (:func:`chart_labels`)."""
    from scipy import ndimage

    from .uv import bilinear_blocks

    labels = np.asarray(labels, dtype=np.int32)
    # Chessboard distance of each texel to the nearest texel outside its chart (unpainted, so also
    # to any other chart); a block [-r, r + 1]^2 around T lies in the chart when the least of it
    # over T's 2x2 block is at least r + 1.
    cheb = ndimage.distance_transform_cdt(labels > 0, metric="chessboard").astype(np.int32)
    room = np.maximum(bilinear_blocks(cheb, "min") - 1, 0)
    return ChartLookup(labels, bilinear_blocks(labels, "same").ravel(), room.ravel())


def chart_lookups(assets: TemplateAssets) -> list[ChartLookup] | None:
    """Per group :func:`chart_lookup` of the template's charts, computed once and kept on the
    assets; None without painted masks."""
    charts = template_charts(assets)
    if charts is None:
        return None
    if assets.lookups is None or len(assets.lookups) != len(charts):
        assets.lookups = [chart_lookup(c) for c in charts]
    return assets.lookups


def part_uvs(assets: GroupAssets, mapped: np.ndarray, faces: np.ndarray, charts: np.ndarray | ChartLookup | None = None,
             normals: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Corner UVs (k, 3, 2) of a part's faces from its mapped vertices (j, 3) (template normalised frame).

    Each face takes the template face nearest to its mapped centroid among those facing its way
    (:meth:`SurfaceIndex.query_facing`: a thin wall's inside never reads its outside; ``normals
    (k, 3)``: the faces' normals in the representative's frame, default those of the mapped
    triangles) and that face's affine UV map.
    With ``charts`` (the group texture's :func:`chart_labels`, or their :func:`chart_lookup`, which
    the run time keeps per template), a face whose affine UVs would leave the chart of its template
    triangle anywhere (a large face extrapolated beyond it reading unpainted texels or another
    chart; :func:`_inside_chart` proves every face inside) instead takes, per corner, the
    closest point of that template triangle: its UVs then stay in the chart (squeezed, but
    coloured). A face still reading outside the chart takes the colour at the template triangle's
    centre (all three corners there), so real-time coverage has no unpainted pixel.

    Returns (corner_uv, template face per face (k,)).
    """
    tri_mapped = mapped[faces]
    centroid = tri_mapped.mean(axis=1)
    # The template face on the face's own side: a thin wall's inside never reads its outside. The
    # side comes from the part's own faces in the representative's frame (``normals``), which a
    # mapper's small errors cannot fold over; else from the mapped triangles.
    normal = np.asarray(normals, dtype=np.float64) if normals is not None else np.cross(
        tri_mapped[:, 1] - tri_mapped[:, 0], tri_mapped[:, 2] - tri_mapped[:, 0])
    near = assets.index.query_facing(centroid, normal, k=UV_CANDIDATES, max_k=UV_MAX_CANDIDATES).faces
    tri = assets.vertices[assets.faces[near]]
    tri_uv = assets.corner_uv[near]
    out = np.empty((len(faces), 3, 2))
    for k in range(3):
        out[:, k] = _affine_uv(mapped[faces[:, k]], tri, tri_uv)
    out = np.clip(out, 0.0, 1.0)
    if charts is not None and len(faces):
        from .uv import bilinear_texels

        look = charts if isinstance(charts, ChartLookup) else chart_lookup(charts)
        h, w = look.labels.shape
        target = look.labels.ravel()[bilinear_texels(tri_uv.mean(axis=1), h, w)].max(axis=1)  # the template triangle's chart
        bad = ~_inside_chart(out, look, target)
        if bad.any():
            from .geometry import closest_point_on_triangles

            fi = np.flatnonzero(bad)
            t = tri[fi]
            for k in range(3):
                _, bary = closest_point_on_triangles(mapped[faces[fi, k]], t[:, 0], t[:, 1], t[:, 2])
                out[fi, k] = np.einsum("ij,ijk->ik", bary, tri_uv[fi])
            # Still reading outside the chart somewhere (a probe on unpainted texels: a sliver
            # template triangle on the chart's rim): the face takes the colour at its template
            # triangle's centre, so no visible pixel is unpainted.
            still = ~_inside_chart(out[fi], look, target[fi])
            out[fi[still]] = tri_uv[fi[still]].mean(axis=1)[:, None]
    return out, near


def _side_normals(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """(k, 3) area-weighted normals of a part's faces (``vertices (j, 3)`` in the representative's
    frame): which side of a thin wall each face is on (:func:`part_uvs`)."""
    tri = np.asarray(vertices, dtype=np.float64)[faces]
    return np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])


@lru_cache(maxsize=64)
def _bary_grid(n: int) -> np.ndarray:
    """((n + 1)(n + 2) / 2, 3) barycentric points of a triangle split ``n`` times per edge
    (corners and edge points included)."""
    i, j = np.meshgrid(np.arange(n + 1), np.arange(n + 1), indexing="ij")
    keep = i + j <= n
    i, j = i[keep], j[keep]
    grid = np.stack([n - i - j, i, j], axis=1) / n
    grid.flags.writeable = False  # cached: shared by every call
    return grid


def _subdivide(tri: np.ndarray) -> np.ndarray:
    """(4n, 3, 2) midpoint subdivision of triangles ``tri (n, 3, 2)``: child ``4i + c`` of triangle ``i``."""
    a, b, c = tri[:, 0], tri[:, 1], tri[:, 2]
    ab, bc, ca = (a + b) / 2, (b + c) / 2, (c + a) / 2
    out = np.empty((len(tri), 4, 3, tri.shape[2]))
    for child, corners in enumerate(((a, ab, ca), (ab, b, bc), (ca, bc, c), (ab, bc, ca))):
        for k, corner in enumerate(corners):
            out[:, child, k] = corner
    return out.reshape(-1, 3, tri.shape[2])


def _inside_chart(corner_uv: np.ndarray, charts: np.ndarray | ChartLookup, chart: np.ndarray, leaf: float = 2.0, max_level: int = 12) -> np.ndarray:
    """(k,) bool: faces with UVs ``corner_uv (k, 3, 2)`` that read (bilinearly) only texels of
    chart ``chart (k,)`` of ``charts`` (:func:`chart_labels` (H, W), or their :func:`chart_lookup`)
    anywhere on the face. Sound: a face reported inside is inside; one within a texel or two of its
    chart's rim may be reported outside though every read is inside.

    Every point of a triangle lies within half its longest edge ``e`` of one of its corners, edge
    midpoints and centre. So a (sub-)triangle passes when each of those 7 probes reads its chart
    with room ``ceil(e / 2)`` around it (:attr:`ChartLookup.block_room`), fails when a probe reads
    another chart or an unpainted texel, and is otherwise split in four, down to triangles no
    longer than ``leaf`` (<= 2) texels, which fail (within a texel of the rim: not proven). The
    work grows with the length of rim a face runs along, not with its area; a face not settled
    after ``max_level`` splits is reported outside."""
    from .uv import bilinear_corner

    if not 0 < leaf <= 2.0:
        raise ValueError(f"leaf must be in (0, 2] texels, got {leaf}")
    look = charts if isinstance(charts, ChartLookup) else chart_lookup(charts)
    h, w = look.labels.shape
    k = len(corner_uv)
    ok = np.ones(k, dtype=bool)
    grid = np.vstack([_bary_grid(2), np.full((1, 3), 1.0 / 3.0)])  # corners, midpoints, centre
    tri, owner = np.asarray(corner_uv, dtype=np.float64), np.arange(k)
    d = (tri - tri[:, [1, 2, 0]]) * np.array([w, h])
    edge = np.sqrt(np.einsum("kij,kij->ki", d, d).max(axis=1))  # texels; halved by every split
    for _ in range(int(max_level) + 1):
        if not len(tri):
            break
        idx = bilinear_corner(np.matmul(grid[None], tri).reshape(-1, 2), h, w).reshape(len(tri), -1)  # (n, 7)
        inside = (look.block_label[idx] == np.asarray(chart)[owner][:, None]).all(axis=1)
        ok[owner[~inside]] = False
        settled = look.block_room[idx].min(axis=1) >= np.ceil(edge / 2)
        open_ = inside & ~settled & ok[owner]
        ok[owner[open_ & (edge <= leaf)]] = False  # at the rim: not proven
        split = open_ & (edge > leaf)
        tri, owner, edge = _subdivide(tri[split]), np.repeat(owner[split], 4), np.repeat(edge[split] / 2, 4)
    ok[owner] = False  # not settled within max_level splits
    return ok


def transfer(shape: Shape, assets: TemplateAssets, mapper: Mapper, seed: int = 0, painter: Any = None, new_size: int = 256,
             shortcut: bool = True) -> TransferResult:
    """UVs of ``shape`` into the template textures (module docstring, steps 1-4).

    ``shortcut``: parts with their representative's exact connectivity take its UVs directly (exact
    for procedural models); off, every part goes through ``mapper`` (to compare mappers).

    Parts of a group the template does not have ("new") get a texture of their own, painted by
    ``painter`` (the family's surface painter; the template's textures are untouched), at
    ``new_size``; without a painter they stay untextured (group -1) and a note says so.
    """
    t0 = time.perf_counter()
    timings: dict[str, float] = {}
    seg = segment(shape)
    t1 = time.perf_counter()
    timings["segment"] = t1 - t0
    assignment = assign_parts(shape, seg, assets)
    t2 = time.perf_counter()
    timings["assign"] = t2 - t1
    corner = np.zeros((shape.n_faces, 3, 2))
    face_group = np.full(shape.n_faces, -1, dtype=np.int64)
    points: dict[int, np.ndarray] = {}
    direct: set[int] = set()
    notes: list[str] = []
    t_map = t_uv = 0.0
    for a in assignment:
        if a.group < 0:
            continue
        part = seg.parts[a.part]
        ga = assets.groups[a.group]
        v, f = part_mesh(shape, part)
        ta = time.perf_counter()
        if shortcut and same_topology(f, len(v), ga):
            # Same mesh connectivity as the representative: vertex i is the template's vertex i
            # (procedural models), so the part takes the template UVs directly, no mapping.
            direct.add(a.part)
            mapped, uv = ga.vertices.copy(), ga.corner_uv.copy()
            tb = time.perf_counter()
        else:
            vn = representative_frame(v, a)
            mapped = np.asarray(mapper.map(a.group, vn, f, vn, seed=seed), dtype=np.float64)
            if mapped.shape != vn.shape or not np.isfinite(mapped).all():
                raise ValueError(f"mapper returned {mapped.shape} (finite required) for part {a.part}, expected {vn.shape}")
            tb = time.perf_counter()
            lookups = chart_lookups(assets)
            uv, _ = part_uvs(ga, mapped, f, None if lookups is None else lookups[a.group], normals=_side_normals(vn, f))
        corner[part.faces] = uv
        face_group[part.faces] = a.group
        points[a.part] = mapped * ga.radius + ga.center
        t_map += tb - ta
        t_uv += time.perf_counter() - tb
    timings["map"] = t_map
    timings["uv"] = t_uv
    if assets.observed is not None:  # faces reading template texels the painter never painted
        for g in np.unique(face_group[face_group >= 0]):
            sel = np.flatnonzero(face_group == g)
            dis = disoccluded_texels(corner[sel].mean(axis=1), assets.observed[g])
            if dis.any():
                notes.append(f"group {g}: {int(dis.sum())} faces show surface the template never showed (dis-occlusion; bake to fill it)")
    result = TransferResult(corner, face_group, assignment, points, time.perf_counter() - t0, timings, notes=notes, direct=direct)
    new = [a.part for a in assignment if a.how == "new"]
    if new:
        tn = time.perf_counter()
        if painter is None:
            result.notes.append(f"parts {new} match no template group and no painter was given: left untextured")
        else:
            faces = np.concatenate([seg.parts[p].faces for p in new])
            uv, image = paint_new_parts(shape, faces, painter, new_size)
            result.corner_uv[faces] = uv
            result.face_group[faces] = len(assets.groups)
            result.new_textures.append(image)
            result.notes.append(f"parts {new} match no template group: painted as a new group {len(assets.groups)}")
        timings["new"] = time.perf_counter() - tn
        result.seconds = time.perf_counter() - t0
    return result


def paint_new_parts(shape: Shape, faces: np.ndarray, painter: Any, size: int = 256) -> tuple[np.ndarray, np.ndarray]:
    """Atlas and texture for faces of parts no template group fits, painted by a surface painter.

    Points go to the painter in the shape's normalised frame, as when the template was painted.
    Returns (corner_uv (k, 3, 2), texture (size, size, 3) uint8).
    """
    from .paint import UNPAINTED, shape_frame

    used = np.unique(shape.faces[faces])
    local = np.searchsorted(used, shape.faces[faces])
    atlas = unwrap(shape.vertices[used], local, resolution=size, padding=2)
    tm = texel_map(shape.vertices[used], local, atlas.corner_uv, size)
    center, scale = shape_frame(shape)
    image = np.full((size, size, 3), UNPAINTED, dtype=np.float32)
    image[tm.ij[:, 0], tm.ij[:, 1]] = painter.paint((tm.points - center) / scale, tm.normals)
    image, _ = pad_seams(image, tm.mask, 4)
    return atlas.corner_uv, (np.clip(image, 0, 1) * 255).round().astype(np.uint8)


def glb(shape: Shape, result: TransferResult, assets: TemplateAssets, up: str = "y") -> bytes:
    """Textured GLB bytes of a transferred shape (reuses the template's encoded PNGs); ``up``: the
    shape's up axis (the GLB stands it upright, see :func:`proctex.export.glb_bytes`)."""
    from .export import glb_bytes

    extra = [f"new_{k}" for k in range(len(result.new_textures))]
    return glb_bytes(shape.vertices, shape.faces, result.corner_uv, result.face_group, assets.png + list(result.new_textures), names=assets.names + extra, up=up)


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


def disoccluded_texels(uv: np.ndarray, observed: np.ndarray) -> np.ndarray:
    """(k,) bool: which template lookups at ``uv (k, 2)`` touch a texel outside ``observed (H, W)``
    (any of the four texels of the bilinear footprint)."""
    from .uv import bilinear_texels

    idx = bilinear_texels(np.asarray(uv, dtype=np.float64), observed.shape[0], observed.shape[1])
    return ~observed.ravel()[idx].all(axis=1)


def bake(
    shape: Shape, result: TransferResult, assets: TemplateAssets, size: int = 512, gutter: int = -1, project: bool = False,
    fill: str = "patchmatch", seed: int = 0,
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
    """
    from .inpaint import patchmatch_fill

    if fill not in ("patchmatch", "none"):
        raise ValueError(f"fill must be patchmatch or none, got {fill!r}")
    t0 = time.perf_counter()
    seg = segment(shape)
    corner = np.zeros((shape.n_faces, 3, 2))
    face_group = np.full(shape.n_faces, -1, dtype=np.int64)
    out = Baked(corner, face_group, [], [], 0.0)
    for g, ga in enumerate(assets.groups):
        parts = [a.part for a in result.assignment if a.group == g and a.part in result.points]
        observed = assets.observed[g] if assets.observed is not None else None
        if not parts:
            out.textures.append(np.full((1, 1, 3), 128, np.uint8))
            out.painted.append(np.ones((1, 1), bool))
            out.covered.append(np.ones((1, 1), bool))
            out.disoccluded.append(np.zeros((1, 1), bool))
            out.direct.append(False)
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
            continue
        used = np.unique(shape.faces[faces])
        local = np.searchsorted(used, shape.faces[faces])
        atlas = unwrap(shape.vertices[used], local, resolution=size, padding=2 if gutter < 0 else max(2, gutter // 2))
        corner[faces] = atlas.corner_uv
        tm = texel_map(shape.vertices[used], local, atlas.corner_uv, size)
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
        if observed is not None:
            dis = disoccluded_texels(uv, observed)
            hole[tm.ij[dis, 0], tm.ij[dis, 1]] = True
            if dis.any() and fill == "patchmatch":
                known = tm.mask & ~hole
                try:
                    image = patchmatch_fill(image, known, hole, seed=seed + g).image
                    out.notes.append(f"group {g}: {int(dis.sum())} dis-occluded texels filled by PatchMatch")
                except ValueError as exc:  # no usable source patch: keep the template's colours there
                    out.notes.append(f"group {g}: {int(dis.sum())} dis-occluded texels kept the template's fill ({exc})")
        image, mask = pad_seams(image, tm.mask, gutter)
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
    out.seconds = time.perf_counter() - t0
    return out


def info(result: TransferResult) -> dict[str, Any]:
    """JSON-ready summary of a transfer (assignment, timings)."""
    return {
        "notes": list(result.notes),
        "seconds": round(result.seconds, 4),
        "timings": {k: round(v, 4) for k, v in result.timings.items()},
        "parts": [
            {"part": a.part, "group": a.group, "slot": a.slot, "how": a.how, "cost": (round(a.cost, 4) if np.isfinite(a.cost) else None)}
            for a in result.assignment
        ],
    }


class SolverMapper:
    """Offline mapper: solves the correspondence of each part on the fly (``cage``, ``nearest`` or
    ``cpd``).

    Slow (seconds per part); used to build training pairs and as the pseudo-ground truth.
    ``last`` keeps the last :class:`proctex.correspond.PartCorrespondence`.
    """

    def __init__(self, assets: TemplateAssets, method: str = "cage", n_points: int = 2000, cage: Any = None) -> None:
        if method not in ("cage", "nearest", "cpd"):
            raise ValueError(f"SolverMapper method must be cage, nearest or cpd, got {method!r}")
        self.assets, self.method, self.n_points, self.cage = assets, method, n_points, cage
        self.last = None

    def map(self, group: int, vertices: np.ndarray, faces: np.ndarray, query: np.ndarray, seed: int = 0) -> np.ndarray:
        from .correspond import correspond_parts, deform

        ga = self.assets.groups[group]
        res = correspond_parts(vertices, faces, ga.vertices, ga.faces, method=self.method, n_points=self.n_points, seed=seed, cage=self.cage)
        self.last = res
        # The representative is stored in its normalised frame already: centre 0, radius 1.
        return deform(res, query, np.zeros(3), 1.0)


class NetworkMapper:
    """The run-time mapper: one ProcCorrNet per template group (:mod:`proctex.corrnet`).

    The network's global feature comes from ``context`` uniform surface samples of the part (seeded,
    so a shape always maps the same way); the per-point head then runs on the query points only.
    Groups without a network fall back to ``fallback`` (default: :class:`IdentityMapper`).
    ``threads``: torch threads during prediction (restored afterwards; None leaves them alone).
    ``autocast``: :func:`proctex.corrnet.predict`'s; "auto" (default) runs the matrix products in
    bfloat16 on CPUs with native bfloat16 (measured 1.4x faster on a sofa's parts; the mapped points
    move by 2e-4 of the normalised frame on average, 1e-3 at most), float32 elsewhere.
    """

    def __init__(self, models: dict[int, Any], context: int | None = None, fallback: Mapper | None = None, threads: int | None = 1,
                 autocast: str = "auto") -> None:
        from .corrnet import AUTOCASTS

        if autocast not in AUTOCASTS + ("auto",):
            raise ValueError(f"autocast must be one of {AUTOCASTS + ('auto',)}, got {autocast!r}")
        self.autocast = autocast
        self.models, self.context = dict(models), context  # None: the context size each network was trained with
        self.fallback = fallback or IdentityMapper()
        # One part is a few thousand points: one thread does it in milliseconds, while two threads
        # on a busy 2-core machine stall at every OpenMP barrier (measured: 30 ms vs 1.1 s per shape).
        self.threads = threads

    def map(self, group: int, vertices: np.ndarray, faces: np.ndarray, query: np.ndarray, seed: int = 0) -> np.ndarray:
        from .corrnet import predict

        model = self.models.get(group)
        if model is None:
            return self.fallback.map(group, vertices, faces, query, seed)
        ctx, _, _ = sample_surface(vertices, faces, int(self.context or model.context_points), seed=seed)
        if self.threads is None:
            return np.asarray(predict(model, ctx, query, autocast=self.autocast), dtype=np.float64)
        import torch

        before = torch.get_num_threads()
        torch.set_num_threads(self.threads)
        try:
            return np.asarray(predict(model, ctx, query, autocast=self.autocast), dtype=np.float64)
        finally:
            torch.set_num_threads(before)


#: Mapper names :func:`make_mapper` knows, and the aliases it accepts for them.
MAPPERS = ("auto", "corrnet", "identity", "cage", "nearest", "cpd")
MAPPER_ALIASES = {"net": "corrnet", "corrnet_all": "corrnet"}


def make_mapper(name: str, assets: TemplateAssets, models: dict[int, Any] | None = None, corr_points: int = 2000, cage: Any = None,
                autocast: str = "auto") -> Mapper:
    """The one place a mapper is chosen by name (the CLI, the service and the evaluation use it).

    ``"auto"``: the family's networks (``models``, group -> ProcCorrNet) when there are any, else
    the identity; ``"corrnet"`` (aliases ``"net"``, ``"corrnet_all"``): the networks, a
    ``ValueError`` without them; ``"identity"``; ``"cage"``, ``"nearest"``, ``"cpd"``: solved per
    part at transfer time on ``corr_points`` samples with the family's ``cage`` settings, as the
    build solves its pairs. ``autocast``: the networks' (:class:`NetworkMapper`).
    """
    key = MAPPER_ALIASES.get(name, name)
    if key not in MAPPERS:
        raise ValueError(f"unknown mapper {name!r}; known: {', '.join(MAPPERS + tuple(MAPPER_ALIASES))}")
    if key == "auto":
        return NetworkMapper(models, autocast=autocast) if models else IdentityMapper()
    if key == "corrnet":
        if not models:
            raise ValueError("no trained models (run the train stage)")
        return NetworkMapper(models, autocast=autocast)
    if key == "identity":
        return IdentityMapper()
    return SolverMapper(assets, key, n_points=int(corr_points), cage=cage)
