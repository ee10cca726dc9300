"""Matching one shape's part groups to the template's (:func:`match_groups`): a descriptor per group
(size, shape, placement in the shape's box), a per-axis box map fitted between the shapes, and a
minimum-cost assignment with a threshold for groups the template does not have."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
from scipy.optimize import linear_sum_assignment
from scipy.spatial import cKDTree

from .align import apply, icp_points, rotation_angle, umeyama
from .parts import Grouping, PartGroup, part_mesh
from .shape import Shape
from .surface import sample_surface


# ------------------------------------------------------------------------------- group matching
@dataclass
class GroupMatch:
    """Groups of a shape matched to the template's.

    Attributes:
        pairs: list of ``(shape_group, template_group)``.
        added: shape groups with no template counterpart.
        missing: template groups absent from the shape.
        cost: (Gs, Gt) float64 matrix the assignment was solved on.
        methods: per pair, "topology" or "icp".
        threshold: cost above which a pair is not a match.
    """

    pairs: list[tuple[int, int]]
    added: list[int]
    missing: list[int]
    cost: np.ndarray
    methods: list[str]
    threshold: float

    def mapping(self) -> dict[int, int]:
        return dict(self.pairs)

    def to_dict(self) -> dict[str, Any]:
        return {
            "matched": [{"shape_group": int(a), "template_group": int(b), "cost": float(self.cost[a, b]), "method": m} for (a, b), m in zip(self.pairs, self.methods)],
            "added": [int(i) for i in self.added],
            "missing": [int(i) for i in self.missing],
            "threshold": self.threshold,
        }


def _shape_box(shape: Shape) -> tuple[np.ndarray, np.ndarray]:
    pts = shape.vertices[np.unique(shape.faces)]
    return pts.min(0), pts.max(0)


def _group_descriptor(shape: Shape, grouping: Grouping, g: PartGroup, n_samples: int, seed: int) -> dict[str, Any]:
    """World placement (member centres, extents) and normalised surface samples of a group's representative."""
    part = grouping.parts[g.representative]
    v, f = part_mesh(shape, part)
    ext = (v.max(0) - v.min(0)) / 2
    scale = np.maximum(ext, 1e-3 * max(part.radius, 1e-300))  # per-axis normalisation, no division by 0
    vn = (v - part.center) / scale
    samples, _, _ = sample_surface(vn, f, n_samples, seed=seed)
    return {
        "topo_key": len(v).to_bytes(8, "little") + np.sort(f, axis=1).tobytes(),
        "vertices_n": vn,
        "samples": samples,
        "tree": cKDTree(samples),
        "extent": ext,
        "centers": np.array([grouping.parts[i].center for i in g.members]),
        "degenerate": g.degenerate,
    }


def _shape_term(a: dict[str, Any], b: dict[str, Any], w_rot: float) -> tuple[float, str]:
    """Distance of two representatives in per-axis normalised frames plus a rotation penalty.

    Equal topology: mean vertex distance after a rigid fit. Otherwise point-to-point ICP between
    surface samples and the symmetric mean nearest-sample distance (its floor is the sample
    spacing, small against the differences between distinct parts).
    """
    if a["topo_key"] == b["topo_key"]:
        R, t, _ = umeyama(a["vertices_n"], b["vertices_n"])
        surf = float(np.linalg.norm(apply(a["vertices_n"], R, t) - b["vertices_n"], axis=1).mean())
        method = "topology"
    else:
        res = icp_points(a["samples"], b["samples"], b["tree"], max_iter=20)
        R = res.R
        back = a["tree"].query((b["samples"] - res.t) @ res.R)[0].mean()
        surf = float(0.5 * (res.error + back))
        method = "icp"
    penalty = 1.0 if a["degenerate"] != b["degenerate"] else 0.0
    return surf + w_rot * rotation_angle(R) + penalty, method


def _placed(d: dict[str, Any], scale: np.ndarray, shift: np.ndarray, center: np.ndarray, radius: float) -> tuple[np.ndarray, np.ndarray]:
    """Member centres (k, 3) and size (3,) of a group after ``x -> scale x + shift``, in a (center, radius) frame."""
    return (d["centers"] * scale + shift - center) / radius, d["extent"] * np.abs(scale) / radius


def _set_offsets(a: np.ndarray, b: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Each member of the smaller of two centre sets (k, 3) paired with its nearest in the other.

    Returns index arrays ``(ia, ib)`` into ``a`` and ``b``. Repeated parts vary in number across a
    family (4 or 6 legs), so a group is placed like another when each member of the smaller group
    has a counterpart nearby.
    """
    if len(a) <= len(b):
        return np.arange(len(a)), cKDTree(b).query(a)[1]
    ib, ia = np.arange(len(b)), cKDTree(a).query(b)[1]
    return ia, ib


def _fit_axis_map(src: np.ndarray, dst: np.ndarray, w: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per-axis weighted least squares ``dst ≈ scale * src + shift``; src, dst (k, 3), w (k,)."""
    scale, shift = np.ones(3), np.zeros(3)
    for k in range(3):
        A = np.stack([src[:, k], np.ones(len(src))], axis=1) * np.sqrt(w)[:, None]
        sol, *_ = np.linalg.lstsq(A, dst[:, k] * np.sqrt(w), rcond=None)
        scale[k], shift[k] = sol
    return scale, shift


def _solve_assignment(cost: np.ndarray, threshold: float) -> list[tuple[int, int]]:
    """Min-cost matching where any row or column may stay unmatched at cost ``threshold``."""
    na, nb = cost.shape
    big = threshold * 10 + 1.0
    padded = np.full((na + nb, nb + na), big)
    padded[:na, :nb] = np.where(np.isfinite(cost), np.minimum(cost, big), big)
    padded[:na, nb:] = np.where(np.eye(na) > 0, threshold, big)
    padded[na:, :nb] = np.where(np.eye(nb) > 0, threshold, big)
    padded[na:, nb:] = 0.0
    rows, cols = linear_sum_assignment(padded)
    return sorted((int(r), int(c)) for r, c in zip(rows, cols) if r < na and c < nb and cost[r, c] < threshold)


def match_groups(
    shape: Shape,
    grouping: Grouping,
    template: Shape,
    template_grouping: Grouping,
    threshold: float = 1.5,
    w_rot: float = 0.5,
    w_pos: float = 2.0,
    w_size: float = 0.5,
    n_samples: int = 300,
    rounds: int = 3,
    seed: int = 0,
) -> GroupMatch:
    """Match a shape's part groups to the template's as one assignment problem.

    The cost of a pair sums: the mean surface distance after ICP (or a vertex fit when the
    topologies are equal) of the representatives in per-axis normalised part frames, ``w_rot`` ×
    the ICP rotation angle (families keep their orientation), ``w_pos`` × the mean distance from
    each member of the smaller group to the nearest member of the other (repeated parts vary in
    number), and ``w_size`` × the summed |log| ratios of their extents. Positions and sizes are compared in the template's frame: the shape is first mapped
    by per-axis scale and shift taking its bounding box onto the template's, then, for up to
    ``rounds`` rounds, by the per-axis map fitted to the groups matched so far (so a part that
    appears or vanishes at the edge of the shape does not shift everything else). Pairs costing
    more than ``threshold`` are left unmatched (the shape group is *added*, the template group
    *missing*).
    """
    da = [_group_descriptor(shape, grouping, g, n_samples, seed) for g in grouping.groups]
    db = [_group_descriptor(template, template_grouping, g, n_samples, seed) for g in template_grouping.groups]
    shape_term = np.zeros((len(da), len(db)))
    methods = np.full((len(da), len(db)), "none", dtype=object)
    for i, a in enumerate(da):
        for j, b in enumerate(db):
            shape_term[i, j], methods[i, j] = _shape_term(a, b, w_rot)
    s_lo, s_hi = _shape_box(shape)
    t_lo, t_hi = _shape_box(template)
    t_center = (t_lo + t_hi) / 2
    t_radius = max(float((t_hi - t_lo).max()) / 2, 1e-300)
    box_src, box_dst = np.stack([s_lo, s_hi]), np.stack([t_lo, t_hi])
    scale, shift = _fit_axis_map(box_src, box_dst, np.ones(2))
    tb = [_placed(b, np.ones(3), np.zeros(3), t_center, t_radius) for b in db]
    pairs: list[tuple[int, int]] = []
    for _ in range(max(rounds, 1)):
        sa = [_placed(a, scale, shift, t_center, t_radius) for a in da]
        cost = shape_term.copy()
        for i, (ca, sz_a) in enumerate(sa):
            for j, (cb, sz_b) in enumerate(tb):
                ia, ib = _set_offsets(ca, cb)
                pos = np.linalg.norm(ca[ia] - cb[ib], axis=1).mean()
                size = np.abs(np.log((sz_a + 1e-3) / (sz_b + 1e-3))).sum()
                cost[i, j] += w_pos * pos + w_size * size
        new_pairs = _solve_assignment(cost, threshold)
        if new_pairs == pairs or not new_pairs:
            pairs = new_pairs or pairs
            break
        pairs = new_pairs
        # Refit the shape -> template map on the matched members (box corners as a weak prior).
        src, dst = [box_src], [box_dst]
        for i, j in pairs:
            ia, ib = _set_offsets(sa[i][0], tb[j][0])
            src.append(da[i]["centers"][ia])
            dst.append(db[j]["centers"][ib])
        n_pts = sum(len(x) for x in src[1:])
        scale, shift = _fit_axis_map(np.concatenate(src), np.concatenate(dst), np.r_[np.ones(2), np.full(n_pts, 2.0)])
    na, nb = cost.shape
    matched_a = {a for a, _ in pairs}
    matched_b = {b for _, b in pairs}
    return GroupMatch(
        pairs=pairs,
        added=[i for i in range(na) if i not in matched_a],
        missing=[j for j in range(nb) if j not in matched_b],
        cost=cost,
        methods=[str(methods[a, b]) for a, b in pairs],
        threshold=threshold,
    )
