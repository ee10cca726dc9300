"""Which template slot and group each part of a shape takes, and the map of the part's normalised
frame onto its group representative's (:func:`assign_parts`; step 2 of :mod:`proctex.transfer.apply`)."""

from __future__ import annotations

import hashlib
import threading
from dataclasses import dataclass, field
from typing import Any, Sequence

import numpy as np
from scipy.optimize import linear_sum_assignment

from proctex.geometry.align import affine_fit, umeyama_batch
from proctex.geometry.parts import DEFORMED_SHARED, Segmentation, part_mesh, shared_faces
from proctex.geometry.rowmath import bounds
from proctex.geometry.shape import Shape
from proctex.geometry.surface import SurfaceIndex, normalised_points, sample_surface, snap_to_frame_grid
from proctex.transfer.assets import TemplateAssets, _box, _place, same_topology
from proctex.transfer.budget import Budget


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
    build's cage pairs, the run-time transfer and the evaluation all use it. The part's own frame is
    :func:`~proctex.geometry.surface.normalised_points` (snapped): a shape in other units gives the
    same numbers, bit for bit, as every fit that made ``R`` and ``t`` saw them."""
    return normalised_points(vertices) @ np.asarray(assignment.R, dtype=np.float64).T + np.asarray(assignment.t, dtype=np.float64)


def representative_part(vertices: np.ndarray, faces: np.ndarray, assignment: PartAssignment) -> tuple[np.ndarray, np.ndarray]:
    """A part mesh in its representative's normalised frame (:func:`representative_frame`) with
    its faces wound so that their normals keep pointing out of the part: ``(vertices (k, 3)
    float64, faces (m, 3) int64)``. A map that mirrors (``det R < 0``: a left part matched to the
    right representative) turns every face's winding inside out; its faces come back in the
    reverse corner order, the same faces in the same rows. Everything that reads a normal in this
    frame (the cage teacher's normal terms, the side of a thin wall a texel is read from) takes
    its faces from here; points alone (the networks, the projections) may use either."""
    vn = representative_frame(vertices, assignment)
    f = np.asarray(faces, dtype=np.int64)
    return vn, (f[:, ::-1].copy() if np.linalg.det(np.asarray(assignment.R, dtype=np.float64)) < 0 else f)


def choose_part(assignment: Sequence[PartAssignment], group: int) -> PartAssignment | None:
    """The part of a shape that stands for group ``group``'s representative (it teaches the group's
    network and carries the cage tracker): the one in the representative's own slot (a slot of the
    group with an identity member map), else any part assigned to the group; ``None`` if none."""
    cands = [a for a in assignment if a.group == group]
    rep_side = [a for a in cands if a.how == "slot" and np.allclose(a.R, np.eye(3))]
    return (rep_side or cands or [None])[0]


def assign_parts(
    shape: Shape,
    seg: Segmentation,
    assets: TemplateAssets,
    w_extent: float = 1.0,
    extra_cost: float = 0.6,
    extra_tol: float = 0.02,
    box_cost: float = 1.2,
    budget: Budget | None = None,
) -> list[PartAssignment]:
    """Assign each part of a shape to a template slot (see the module docstring).

    Cost between a part and a slot: distance between their centres plus ``w_extent`` times the mean
    absolute log-ratio of their extents, both relative to each shape's bounding box, or both
    relative to the template's box where that costs less (parts that kept their place in model
    units while an optional part changed the shape's box). Pairs costing
    more than ``extra_cost`` are not taken. Such a part ("extra") joins, in this order: the group of
    a part of the same shape it is a rigid copy of (:func:`copy_of_sibling`), the group whose
    representative has its connectivity (:func:`copy_of_group`), the group of the template's copies
    the model moved vertex by vertex whose vertices it shares (:func:`copy_deformed`), the group whose
    representative is the same primitive in other proportions (:func:`match_box`), the group it fits by ICP
    (:func:`match_extra`, alignment error at most ``extra_tol``); otherwise it forms a group of its
    own ("new"), which :func:`proctex.transfer.apply.transfer` paints with the family's painter.

    The box match's distances and the ICP fit depend on the part's shape alone, so identical
    left-over parts (the same faces and the same normalised vertices: copies that differ by a
    translation and a scale) are measured once, in this request or an earlier one
    (:class:`PartMatches`, kept with ``assets``).
    ``budget`` (:class:`proctex.transfer.budget.Budget`) is checked before each left-over part's
    matching; past it the assignment stops with :class:`~proctex.transfer.budget.OverBudget`.
    """
    lo, size = _box(shape.vertices)
    parts = [p for p in seg.parts if not p.degenerate]
    out = [PartAssignment(p.index, -1, -1, np.eye(3), 0.0, "degenerate") for p in seg.parts if p.degenerate]
    if not parts or not assets.slots:
        return out + [PartAssignment(p.index, -1, -1, np.eye(3), np.inf, "unmatched") for p in parts]
    sc = np.array([s.center for s in assets.slots])
    se = np.array([s.extents for s in assets.slots])

    part_bounds = [bounds(shape.vertices[p.vertices]) for p in parts]  # once: placed in two boxes below
    plo, phi = np.array([b[0] for b in part_bounds]), np.array([b[1] for b in part_bounds])

    def placement_cost(lo: np.ndarray, size: np.ndarray) -> np.ndarray:
        pc, pe = _place(plo, phi, lo, size)
        loge = np.abs(np.log(np.maximum(pe[:, None], 1e-6) / np.maximum(se[None], 1e-6))).mean(axis=2)
        return np.linalg.norm(pc[:, None] - sc[None], axis=2) + w_extent * loge

    # Placement in the shape's own box (any units, any pose of the box), or in the template's box
    # where that is cheaper: a procedural model's parts stay where they are in model units while an
    # optional part (a chair's back) changes the box, and a seat that did not move must keep the
    # seat's slot. Left-over parts are placed among groups by the shape's box alone (``own``): a
    # chair's rear legs are the lower ends of its back posts wherever the back is.
    own = placement_cost(lo, size)
    cost = np.minimum(own, placement_cost(*_box(assets.shape.vertices)))
    # One "no slot" column per part at the threshold cost: a part takes a slot only where that beats
    # leaving it out, so an extra part (an armrest the template lacks) can never win a slot from
    # the part that belongs there and then be dropped for costing too much.
    stay_out = np.full((len(parts), len(parts)), extra_cost + 1e-9)
    rows, cols = linear_sum_assignment(np.hstack([cost, stay_out]))
    taken = {}
    for r, c in zip(rows, cols):
        if c < cost.shape[1] and cost[r, c] <= extra_cost:
            taken[r] = c
    slot_of: dict[int, PartAssignment] = {}
    for i, p in enumerate(parts):
        if i in taken:
            s = assets.slots[taken[i]]
            out.append(PartAssignment(p.index, s.group, s.part, s.R, float(cost[i, taken[i]]), "slot"))
            slot_of[i] = out[-1]
    # Slotted parts' meshes, for copies among the left-over parts: only when there are any (the
    # common case, every part in a slot, pays nothing).
    slotted = [(a, *part_mesh(shape, parts[i])) for i, a in slot_of.items()] if len(taken) < len(parts) else []
    by_faces: dict[bytes, list[tuple[PartAssignment, np.ndarray, np.ndarray]]] = {}  # slotted parts by their exact connectivity
    for entry in slotted:
        by_faces.setdefault(len(entry[1]).to_bytes(8, "little") + entry[2].tobytes(), []).append(entry)
    stacks: dict[bytes, np.ndarray] = {}  # ... their vertices in their normalised frames, stacked once
    known = _part_matches(assets)  # what earlier left-over parts of this geometry measured (any request)
    n_left = len(parts) - len(taken)
    for i, p in enumerate(parts):
        if i not in taken:
            if budget is not None:
                budget.check(f"matching {n_left} parts the template has no slot for")
            # A part the template has no place for: the group it matches best by ICP, if any. Groups
            # whose representative has this part's exact connectivity are the only candidates when
            # there are any (an extra slat is a copy of the slat primitive): one ICP, not one per group.
            v, f = part_mesh(shape, p)
            topo = len(v).to_bytes(8, "little") + f.tobytes()
            twin = None
            if topo in by_faces:
                if topo not in stacks:
                    stacks[topo] = _normalised_stack(np.stack([sv for _, sv, _ in by_faces[topo]]))
                twin = _best_sibling(p.index, v, [a for a, _, _ in by_faces[topo]], stacks[topo], extra_tol)
            if twin is not None:  # a rigid copy of a part that took a slot (a third small mushroom): its map, composed
                out.append(twin)
                continue
            same = [ga.group for ga in assets.groups if not ga.degenerate and same_topology(f, len(v), ga)]
            copy = copy_of_group(v, same, assets, own[i], extra_tol)
            if copy is not None and copy[1] <= box_cost:  # another copy of a template primitive (a third cushion): its group, template UVs
                out.append(PartAssignment(p.index, copy[0], -1, np.eye(3), copy[1], "extra"))
                continue
            u = normalised_points(v)
            bent = copy_deformed(u, f, assets)
            if bent is not None:  # another of the template's copies moved vertex by vertex (a scattered set's trunks)
                out.append(PartAssignment(p.index, bent[0], -1, bent[1], bent[3], "extra", bent[2]))
                continue
            seen = known.entry(hashlib.sha1(f.tobytes() + (np.round(u, 6) + 0.0).tobytes()).digest())  # copies of one part share it
            box = match_box(u, f, assets, own[i], extra_cost=box_cost, memo=seen["box"])
            if box is not None:  # the same primitive in other proportions (a wider tier, a longer leg)
                out.append(PartAssignment(p.index, box.group, -1, box.A, box.score, "extra"))
                continue
            fit_key = (tuple(same), extra_tol)
            if fit_key not in seen["fit"]:
                seen["fit"][fit_key] = match_extra(u, f, assets, groups=same or None, tol=extra_tol)
            g, R, t, err = seen["fit"][fit_key]
            if err <= extra_tol:
                out.append(PartAssignment(p.index, g, -1, R, err, "extra", t))
            else:
                out.append(PartAssignment(p.index, -1, -1, np.eye(3), err, "new"))
    return sorted(out, key=lambda a: a.part)


class PartMatches:
    """What :func:`assign_parts` measured for left-over parts, per part geometry (the key of a part's
    faces and its normalised vertices to 1e-6): :func:`match_box`'s Chamfer distances and
    :func:`match_extra`'s fits, which depend on the geometry and the template alone (placement is
    each part's own and is not kept). Kept with the template's assets (:func:`_part_matches`), so
    a request meeting a part geometry an earlier one met (a chair's slats, whatever their number)
    measures nothing again; at most ``size`` geometries, the least recently met dropped first."""

    def __init__(self, size: int = 512) -> None:
        from collections import OrderedDict

        self.size, self._entries, self._lock = int(size), OrderedDict(), threading.Lock()

    def entry(self, key: bytes) -> dict[str, dict]:
        """``{"box": Chamfer memo, "fit": {(groups, tol): match_extra's answer}}`` of one geometry."""
        with self._lock:
            if key in self._entries:
                self._entries.move_to_end(key)
                return self._entries[key]
            made = self._entries[key] = {"box": {}, "fit": {}}
            while len(self._entries) > self.size:
                self._entries.popitem(last=False)
            return made

    def __len__(self) -> int:
        return len(self._entries)


def _part_matches(assets: TemplateAssets) -> PartMatches:
    """The assets' :class:`PartMatches` (made on first use; a new snapshot of the family starts empty)."""
    found = assets.derived.get("part_matches")
    if found is None:
        found = assets.derived.setdefault("part_matches", PartMatches())
    return found


def copy_of_sibling(part: int, vertices: np.ndarray, faces: np.ndarray, slotted: Sequence[tuple[PartAssignment, np.ndarray, np.ndarray]], tol: float = 0.02) -> PartAssignment | None:
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
    v = np.asarray(vertices, dtype=np.float64)
    cands = [(a, sv) for a, sv, sf in slotted if len(sv) == len(v) and sf.shape == faces.shape and np.array_equal(sf, faces)]
    if not cands:
        return None
    return _best_sibling(part, v, [a for a, _ in cands], _normalised_stack(np.stack([sv for _, sv in cands])), tol)


def _normalised_stack(S: np.ndarray) -> np.ndarray:
    """``S (m, k, 3)``, each part in its own normalised frame, snapped (:func:`normalised_points`, all at once)."""
    centre = (S.min(axis=1) + S.max(axis=1)) / 2
    radius = np.abs(S - centre[:, None]).max(axis=(1, 2))
    return snap_to_frame_grid((S - centre[:, None]) / np.where(radius > 0, radius, 1.0)[:, None, None])


def _best_sibling(part: int, v: np.ndarray, siblings: Sequence[PartAssignment], W: np.ndarray, tol: float) -> PartAssignment | None:
    """:func:`copy_of_sibling` among siblings known to share the part's connectivity, ``W (m, k, 3)``
    their vertices in their normalised frames."""
    u = normalised_points(v)
    R, t, s = umeyama_batch(u, W, scale=True, reflection=False)  # every sibling at once (a scene's thousand leaves)
    resid = np.sqrt(((s[:, None, None] * (u @ np.swapaxes(R, 1, 2)) + t[:, None] - W) ** 2).sum(axis=2).mean(axis=1))
    i = int(np.argmin(resid))  # the first of the best
    if not resid[i] <= tol:
        return None
    a = siblings[i]
    M = np.asarray(a.R, dtype=np.float64)
    return PartAssignment(part, a.group, -1, s[i] * M @ R[i], float(resid[i]), "extra", M @ t[i] + np.asarray(a.t, dtype=np.float64))


def copy_deformed(vertices: np.ndarray, faces: np.ndarray, assets: TemplateAssets) -> tuple[int, np.ndarray, np.ndarray, float] | None:
    """The group a left-over part is another copy of when the template's own grouping took copies
    the model moved vertex by vertex into it ("deformed" members, see
    :func:`proctex.geometry.parts.group_parts`): a group whose representative has the part's vertex
    count and at least :data:`~proctex.geometry.parts.DEFORMED_SHARED` of its faces on the same
    vertices. Only such groups: a family whose template has no deformed members answers None.

    ``vertices (k, 3)``: the part in its normalised frame; ``faces (m, 3)`` local. Returns ``(group,
    A (3, 3), t (3,), residual)``, the least-squares affine map onto the representative's
    normalised vertices (vertex i onto vertex i; ``residual`` its mean distance), or ``None``.
    """
    u = np.asarray(vertices, dtype=np.float64)
    for ga in assets.groups:
        if ga.degenerate or len(ga.vertices) != len(u) or not any(m.method == "deformed" for m in assets.grouping.groups[ga.group].maps):
            continue
        if shared_faces(faces, ga.faces) < DEFORMED_SHARED:
            continue
        A, t, fitted = affine_fit(u, ga.vertices)
        if np.all(np.isfinite(A)):
            return ga.group, A, t, float(np.linalg.norm(fitted - ga.vertices, axis=1).mean())
    return None


def copy_of_group(vertices: np.ndarray, candidates: Sequence[int], assets: TemplateAssets, slot_cost: np.ndarray, tol: float = 0.02) -> tuple[int, float] | None:
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
        fitted = affine_fit(ga.vertices, v)[2]
        resid = float(np.sqrt(((fitted - v) ** 2).sum(axis=1).mean())) / size
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


def match_box(
    vertices: np.ndarray,
    faces: np.ndarray,
    assets: TemplateAssets,
    slot_cost: np.ndarray | None = None,
    n: int = 300,
    seed: int = 0,
    min_extent: float = 1e-3,
    chamfer_tol: float = 0.25,
    proportion_tol: float = 0.7,
    extra_cost: float = 1.2,
    turn_cost: float = 0.25,
    memo: dict | None = None,
) -> BoxMatch | None:
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
    Each slot's member map that is no axis permutation is a candidate too (its own placement, no
    turn cost): copies the model turned about an axis (small caps leaning out from a stem at their
    own azimuths) fit the turn of the slot they sit nearest, where the permutations fit only a
    reflection (a mirrored texture).

    ``vertices (k, 3)``: the part in its normalised frame; ``faces (f, 3)`` local. Axes thinner than
    ``min_extent`` (normalised units: a flat part) count as that thick; thin axes are scaled like
    the others, so a thin slab matches a thin slab of another thickness. Returns ``None`` when no
    group qualifies.

    ``memo``: a dict kept across calls for parts of the same geometry (within one shape: several
    copies of a slat differ only in their placement), holding the Chamfer distances already measured
    (the expensive part; placement is each part's own).
    """
    from itertools import permutations, product

    v = np.asarray(vertices, dtype=np.float64)
    hp = _half_extents(v, min_extent)
    memo = {} if memo is None else memo
    part: list = []  # the part's box-scaled samples and surface, made on the first Chamfer measured

    reps: dict[int, tuple] = {}  # per group its representative's box-scaled samples and surface, when first needed

    def measured(ga: Any, hr: np.ndarray, key: tuple, M: np.ndarray) -> float:
        key = (ga.group, n, seed, min_extent, *key)
        if key not in memo:
            if not part:
                part.extend([sample_surface(v / hp, faces, n, seed=seed)[0], SurfaceIndex(v / hp, np.asarray(faces))])
            if ga.group not in reps:
                reps[ga.group] = (sample_surface(ga.vertices / hr, ga.faces, n, seed=seed)[0], SurfaceIndex(ga.vertices / hr, ga.faces))
            memo[key] = _box_chamfer(part[0], part[1], *reps[ga.group], M)
        return memo[key]

    best: BoxMatch | None = None
    for ga in assets.groups:
        if ga.degenerate:
            continue
        slots = [k for k, s in enumerate(assets.slots) if s.group == ga.group]
        place = 0.0 if slot_cost is None else (float(np.min(np.asarray(slot_cost)[slots])) if slots else np.inf)
        if place > extra_cost:
            continue
        hr = _half_extents(ga.vertices, min_extent)

        def chamfer(M: np.ndarray, key: tuple, ga: Any = ga, hr: np.ndarray = hr) -> float:
            return measured(ga, hr, key, M)

        for perm in permutations(range(3)):
            prop = float(np.abs(np.log(hp[list(perm)] / hr)).mean())
            if prop > proportion_tol:
                continue
            for signs in product((1.0, -1.0), repeat=3):
                P = np.zeros((3, 3))
                P[range(3), perm] = signs  # (P b)_i = s_i b_perm(i)
                ch = chamfer(P, ("axes", perm, signs))
                if ch > chamfer_tol:
                    continue
                # Symmetric parts (a box, a cylinder) fit several ways equally well: the one
                # nearest the part's own orientation wins (no turn cost for the identity).
                score = ch + prop + place + turn_cost * (3.0 - float(np.trace(P))) / 2
                if best is None or score < best.score:
                    A = np.diag(hr) @ P @ np.diag(1.0 / hp)
                    best = BoxMatch(ga.group, A, ch, prop, place, score)
        # The turns off the axes the template's own copies take: each such slot's member map
        # (x_rep = R x_member), as the part would get it had it taken that slot. Copies placed
        # around an axis (leaning caps around a stem) differ from the representative by such a
        # turn, which no axis permutation makes; a reflection across the plane between the two would
        # fit as well and mirror the texture. Placement is the slot's own, and no turn cost (the
        # template made the turn).
        for k in slots:
            slot = assets.slots[k]
            slot_place = 0.0 if slot_cost is None else float(np.asarray(slot_cost)[k])
            if slot_place > extra_cost:
                continue
            if np.allclose(np.abs(slot.R), np.round(np.abs(slot.R)), atol=1e-3):
                continue  # an axis permutation (the representative's own slot, mirrored legs): tried above, box to box
            # the slot's map as it is (both normalised frames have L-infinity radius 1; a turn by an
            # angle off the axes has no per-axis scaling to fit): proportions are the turned part's
            # own half extents against the representative's
            A = np.asarray(slot.R, dtype=np.float64)
            Q = np.diag(1.0 / hr) @ A @ np.diag(hp)  # box-scaled part -> box-scaled representative
            if not np.all(np.isfinite(Q)) or abs(np.linalg.det(Q)) < 1e-12:
                continue
            prop = float(np.abs(np.log(_half_extents(v @ A.T, min_extent) / hr)).mean())
            if prop > proportion_tol:
                continue
            ch = chamfer(Q, ("slot", k))
            score = ch + prop + slot_place
            if ch <= chamfer_tol and (best is None or score < best.score):
                best = BoxMatch(ga.group, A, ch, prop, slot_place, score)
    return best


def _box_chamfer(pts: np.ndarray, part_index: SurfaceIndex, rep: np.ndarray, rep_index: SurfaceIndex, M: np.ndarray) -> float:
    """:func:`match_box`'s Chamfer distance: point-to-surface both ways under ``M`` (box-scaled part
    ``pts (n, 3)`` / ``part_index`` -> box-scaled representative ``rep (n, 3)`` / ``rep_index``; the
    representative's samples go back by ``M``'s inverse), 90th percentiles: a part missing a piece
    of the other (a ring against a disc) shows."""
    back = M if np.allclose(M @ M.T, np.eye(3)) else np.linalg.inv(M).T  # orthogonal: M^-T = M
    return 0.5 * float(np.percentile(rep_index.query(pts @ M.T, exact=False).distance, 90) + np.percentile(part_index.query(rep @ back, exact=False).distance, 90))


def match_extra(
    vertices: np.ndarray,
    faces: np.ndarray,
    assets: TemplateAssets,
    n: int = 300,
    seed: int = 0,
    groups: Sequence[int] | None = None,
    tol: float = 0.02,
) -> tuple[int, np.ndarray, np.ndarray, float]:
    """Best template group for a part (normalised frame) by point-to-surface ICP.

    Candidates: the non-degenerate group representatives (or those of ``groups``) whose exact
    surface moments (:func:`proctex.geometry.parts.surface_moments`, both in their normalised frames)
    are within :data:`~proctex.geometry.parts.MOMENT_TOLS` x ``tol`` of the part's (a fit whose mean
    distance is within ``tol`` moves them less), at most
    :data:`~proctex.geometry.parts.MAX_MATCH_TRIES` of them, nearest first. Per candidate the eight
    axis sign flips are ranked by the mean distance of the part's samples to the representative's
    samples, and ICP to the exact surface refines the good ones (within 1.5 x the best plus ``tol``),
    at most :data:`~proctex.geometry.parts.ICP_STARTS`, in their order (the identity first).
    Returns ``(group, R (3, 3), t (3,), error)``, error = mean distance after alignment (normalised
    units); ``(-1, I, 0, inf)`` when no candidate passes the prefilter.
    """
    from itertools import product

    from proctex.geometry.align import icp_to_surface
    from proctex.geometry.parts import (
        ICP_STARTS,
        MAX_MATCH_TRIES,
        MOMENT_TOLS,
        surface_moments,
    )

    pts, _, _ = sample_surface(vertices, faces, n, seed=seed)
    mom = surface_moments(vertices, faces)
    near = []
    for ga in assets.groups:
        if ga.degenerate or (groups is not None and ga.group not in groups):
            continue
        gm, _, tree = ga.probe(n, seed)
        gap = np.abs(mom - gm)
        if np.all(gap <= MOMENT_TOLS * tol * max(mom[0], gm[0], 1e-300)):
            near.append((float(gap.sum()), ga, tree))
    near.sort(key=lambda c: c[0])
    best = (-1, np.eye(3), np.zeros(3), np.inf)
    for _, ga, tree in near[:MAX_MATCH_TRIES]:
        starts = [(float(tree.query(pts * np.asarray(signs))[0].mean()), np.diag(signs)) for signs in product((1.0, -1.0), repeat=3)]
        lowest = min(d for d, _ in starts)
        for R0 in [R0 for d, R0 in starts if d <= 1.5 * lowest + tol][:ICP_STARTS]:
            res = icp_to_surface(pts, ga.index, R0=R0, max_iter=30, exact=False)
            if res.error < best[3]:
                best = (ga.group, res.R, res.t, float(res.error))
    return best
