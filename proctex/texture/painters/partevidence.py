"""The measured evidence of a part group that part words are scored on (issue 51): its members'
principal axes (bars, plates, blobs, discs, lying or upright), its height band, what it rests on and
what rests on it, repetition and mirrored pairs, its place against the main mass and its share of
the area (:func:`evidence`), and the soft conditions the scorers of :mod:`.partvocab` multiply."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import numpy as np


@dataclass(frozen=True)
class Evidence:
    """What one part group is, measured in the shape's up frame.

    Attributes:
        group: group index; members: its number of parts.
        up: the up axis; horizontal: the other two.
        lo, hi: (3,) the members' union box in the shape's box taken to [0, 1] per axis.
        centers: (members, 3) member box centres in that frame.
        extent: (3,) one member's box extents relative to the shape's largest extent.
        shape_extent: (3,) the shape's box extents relative to its largest.
        axes: (3,) one member's extents along its principal axes, longest first, relative to the
            shape's largest extent.
        long_up: |cos| between the member's longest principal axis and up (1: upright).
        thin_up: |cos| between its thinnest principal axis and up (1: lying flat).
        area_share: the group's share of the shape's area; rank: by area (0: the largest).
        rise: how much one member rises towards its end farther from the main mass's middle
            (across), over its length, times the share of its length that runs across: > 0 when
            the outer end is higher (a spout), < 0 lower, near 0 for an upright part.
        rests_on, holds: groups it stands on, and groups standing on it (touching along up).
        touches: groups whose boxes touch or overlap its own.
    """

    group: int
    members: int
    up: int
    horizontal: tuple[int, int]
    lo: np.ndarray
    hi: np.ndarray
    centers: np.ndarray
    extent: np.ndarray
    shape_extent: np.ndarray
    axes: np.ndarray
    long_up: float
    thin_up: float
    area_share: float
    rank: int
    rise: float = 0.0
    rests_on: tuple[int, ...] = ()
    holds: tuple[int, ...] = ()
    touches: tuple[int, ...] = ()

    # ------------------------------------------------------------------------------- measured
    @property
    def u_lo(self) -> float:
        return float(self.lo[self.up])

    @property
    def u_hi(self) -> float:
        return float(self.hi[self.up])

    @property
    def u_mid(self) -> float:
        return float(self.centers[:, self.up].mean())

    @property
    def slender(self) -> float:
        """Longest over middle principal extent (a bar: >= 3)."""
        return float(self.axes[0] / max(self.axes[1], 1e-9))

    @property
    def flatness(self) -> float:
        """Thinnest over middle principal extent (a plate: <= 0.3)."""
        return float(self.axes[2] / max(self.axes[1], 1e-9))

    @property
    def roundness(self) -> float:
        """Thinnest over longest (a blob: >= 0.4)."""
        return float(self.axes[2] / max(self.axes[0], 1e-9))

    def footprint(self) -> float:
        """One member's horizontal box area over the shape's."""
        a, b = self.horizontal
        whole = self.shape_extent[a] * self.shape_extent[b]
        return float(self.extent[a] * self.extent[b] / whole) if whole > 0 else 0.0

    def union_footprint(self) -> float:
        a, b = self.horizontal
        return float((self.hi[a] - self.lo[a]) * (self.hi[b] - self.lo[b]))

    def height_share(self) -> float:
        return float(self.extent[self.up] / self.shape_extent[self.up]) if self.shape_extent[self.up] > 0 else 0.0

    def end(self, axis: int) -> float:
        """How far every member sits towards one end of ``axis``: 0 at the middle, 1 at an end
        (the member nearest the middle counts; members at both ends count as ends too)."""
        c = self.centers[:, axis]
        return float(np.clip(np.min(np.abs(c - 0.5)) * 2.0, 0.0, 1.0))

    def both_ends(self, axis: int) -> float:
        """A mirrored pair or row: members at both ends of ``axis`` (0 for one member)."""
        c = self.centers[:, axis]
        if self.members < 2:
            return 0.0
        return float(ramp(0.5 - c.min(), 0.15, 0.3) * ramp(c.max() - 0.5, 0.15, 0.3))

    def corners(self) -> float:
        """Members spread to both ends of both horizontal axes (legs at the corners)."""
        a, b = self.horizontal
        return float(min(self.both_ends(a), self.both_ends(b)) if self.members >= 3 else 0.0)


def ramp(x: float, lo: float, hi: float) -> float:
    """0 below ``lo``, 1 above ``hi``, linear between."""
    return float(np.clip((x - lo) / (hi - lo), 0.0, 1.0))


def fall(x: float, lo: float, hi: float) -> float:
    """1 below ``lo``, 0 above ``hi``, linear between."""
    return 1.0 - ramp(x, lo, hi)


def evidence(vertices: np.ndarray, grouping, up: int, max_members: int = 400, max_groups: int = 200) -> list[Evidence]:
    """One :class:`Evidence` per non-degenerate group of ``grouping`` (a
    :class:`proctex.geometry.parts.Grouping`) on ``vertices (n, 3) float``, for the ``max_groups``
    largest by area (a bound on the pairwise contacts; the others name no part); contacts from the
    members' boxes (from each group's union box when the shape has over ``max_members`` parts)."""
    v = np.asarray(vertices, dtype=np.float64)
    parts = grouping.segmentation.parts
    groups = [g for g in grouping.groups if not g.degenerate]
    used = np.unique(np.concatenate([parts[m].vertices for g in groups for m in g.members] or [np.arange(len(v))]))
    lo, hi = v[used].min(0), v[used].max(0)
    span = hi - lo
    longest = float(span.max()) or 1.0
    safe = np.where(span > 0, span, 1.0)
    total = sum(parts[m].area for g in groups for m in g.members) or 1.0
    horizontal = tuple(i for i in range(3) if i != up)
    axis_up = np.eye(3)[up]
    boxes: list[np.ndarray] = []  # per group: (members, 2, 3) world boxes
    rows = []
    for g in groups:
        b = np.array([[v[parts[m].vertices].min(0), v[parts[m].vertices].max(0)] for m in g.members])
        boxes.append(b)
        pv = v[parts[g.members[0]].vertices]
        pc = pv - pv.mean(0)
        if len(pv) >= 3:
            _, _, vt = np.linalg.svd(pc, full_matrices=False)
            proj = pc @ vt.T
            ext = proj.max(0) - proj.min(0)
            order = np.argsort(-ext)
            axes, dirs = ext[order], vt[order]
        else:
            axes, dirs = np.zeros(3), np.eye(3)
        rows.append((g, b, axes / longest, float(abs(dirs[0] @ axis_up)), float(abs(dirs[2] @ axis_up)), float(sum(parts[m].area for m in g.members) / total), pv, dirs[0]))
    order = sorted(range(len(rows)), key=lambda i: -rows[i][5])
    rank = {rows[i][0].index: r for r, i in enumerate(order)}
    main_box = rows[order[0]][1] if rows else np.zeros((1, 2, 3))
    main_mid = (main_box[:, 0].min(0) + main_box[:, 1].max(0)) / 2
    keep = sorted(order[:max_groups])
    rows, groups, boxes = [rows[i] for i in keep], [groups[i] for i in keep], [boxes[i] for i in keep]
    # contacts: boxes within tol of each other; "rests on": my bottom near its top, overlapping across
    tol = 0.02 * longest
    n_members = sum(len(b) for b in boxes)
    coarse = n_members > max_members
    bx = [np.array([[b[:, 0].min(0), b[:, 1].max(0)]]) if coarse else b for b in boxes]
    rests: dict[int, set[int]] = {g.index: set() for g in groups}
    holds: dict[int, set[int]] = {g.index: set() for g in groups}
    touch: dict[int, set[int]] = {g.index: set() for g in groups}
    for i, gi in enumerate(groups):
        for j, gj in enumerate(groups):
            if j <= i:
                continue
            a, b = bx[i][:, None], bx[j][None, :]  # (ma, 1, 2, 3), (1, mb, 2, 3)
            gap = np.maximum(a[..., 0, :] - b[..., 1, :], b[..., 0, :] - a[..., 1, :])  # (ma, mb, 3): > 0 apart
            near = (gap <= tol).all(-1)
            if not near.any():
                continue
            touch[gi.index].add(gj.index)
            touch[gj.index].add(gi.index)
            across = (gap[..., list(horizontal)] < -tol).all(-1) & near  # overlapping across up
            a_lo, a_hi = a[..., 0, up], a[..., 1, up]
            b_lo, b_hi = b[..., 0, up], b[..., 1, up]
            # a rests on b: its middle above b's top, its bottom down to b's top, overlapping across
            a_on_b = across & ((a_lo + a_hi) / 2 >= b_hi - tol) & (a_lo <= b_hi + tol) & (a_lo >= b_lo)
            b_on_a = across & ((b_lo + b_hi) / 2 >= a_hi - tol) & (b_lo <= a_hi + tol) & (b_lo >= a_lo)
            if a_on_b.any():
                rests[gi.index].add(gj.index)
                holds[gj.index].add(gi.index)
            if b_on_a.any():
                rests[gj.index].add(gi.index)
                holds[gi.index].add(gj.index)
    out = []
    for g, b, axes, long_up, thin_up, share, pv, d in rows:
        rep = b[0]
        out.append(
            Evidence(
                group=g.index,
                members=len(g.members),
                up=up,
                horizontal=horizontal,  # type: ignore[arg-type]
                lo=(b[:, 0].min(0) - lo) / safe,
                hi=(b[:, 1].max(0) - lo) / safe,
                centers=((b[:, 0] + b[:, 1]) / 2 - lo) / safe,
                extent=(rep[1] - rep[0]) / longest,
                shape_extent=span / longest,
                axes=axes,
                long_up=long_up,
                thin_up=thin_up,
                area_share=share,
                rank=rank[g.index],
                rise=_rise(pv, d, main_mid, up, axes[0] * longest),
                rests_on=tuple(sorted(rests[g.index])),
                holds=tuple(sorted(holds[g.index])),
                touches=tuple(sorted(touch[g.index])),
            )
        )
    return out


def _rise(pv: np.ndarray, d: np.ndarray, mid: np.ndarray, up: int, length: float) -> float:
    """Up change from the inner to the outer end of ``pv (k, 3)`` along ``d (3,)``, over ``length``."""
    if length <= 0 or len(pv) < 2:
        return 0.0
    t = pv @ d
    k = max(1, len(t) // 20)
    idx = np.argsort(t)
    a, b = pv[idx[:k]].mean(0), pv[idx[-k:]].mean(0)
    across = [i for i in range(3) if i != up]
    if np.linalg.norm((b - mid)[across]) < np.linalg.norm((a - mid)[across]):
        a, b = b, a
    reach = float(np.linalg.norm((b - a)[across]))
    return float((b[up] - a[up]) / length * min(1.0, reach / length))


# ------------------------------------------------------------------------------ soft conditions
def bar(e: Evidence) -> float:
    return ramp(e.slender, 2.0, 3.5)


def upright_bar(e: Evidence) -> float:
    return bar(e) * ramp(e.long_up, 0.75, 0.92)


def lying_bar(e: Evidence) -> float:
    return bar(e) * fall(e.long_up, 0.3, 0.6)


def plate(e: Evidence) -> float:
    return fall(e.flatness, 0.3, 0.55) * fall(e.slender, 3.5, 6.0)


def flat_plate(e: Evidence) -> float:
    """A slab lying flat (a seat, a top, a mattress): thin along up."""
    a, b = e.horizontal
    thin = e.extent[e.up] <= 0.6 * min(e.extent[a], e.extent[b])
    return (fall(e.flatness, 0.45, 0.8) * ramp(e.thin_up, 0.7, 0.9)) if thin else 0.0


def upright_plate(e: Evidence) -> float:
    """A panel standing up (a back, a door, a headboard): thin across a horizontal axis."""
    return plate(e) * fall(e.thin_up, 0.3, 0.6)


def blob(e: Evidence) -> float:
    return ramp(e.roundness, 0.25, 0.45)


def wheel_disc(e: Evidence) -> float:
    """A round plate standing on edge (a wheel): two near-equal long axes, the thin one horizontal."""
    return fall(e.slender, 1.25, 1.6) * fall(e.flatness, 0.7, 0.95) * fall(e.thin_up, 0.3, 0.6)


def on_floor(e: Evidence) -> float:
    return fall(e.u_lo, 0.03, 0.1)


def off_floor(e: Evidence) -> float:
    return ramp(e.u_lo, 0.04, 0.12)


def at_top(e: Evidence) -> float:
    return ramp(e.u_hi, 0.85, 0.97)


def low(e: Evidence, top: float = 0.35) -> float:
    return fall(e.u_hi, top, top + 0.2)


def band(e: Evidence, lo: float, hi: float, soft: float = 0.1) -> float:
    """The group's middle height within [lo, hi] (soft edges)."""
    return ramp(e.u_mid, lo - soft, lo) * fall(e.u_mid, hi, hi + soft)


def small(e: Evidence, share: float = 0.08) -> float:
    return fall(e.area_share, share, 2.5 * share)


def main_mass(e: Evidence) -> float:
    return 1.0 if e.rank == 0 else 0.0


def not_main(e: Evidence) -> float:
    return 0.0 if e.rank == 0 else 1.0


def at_an_end(e: Evidence) -> float:
    return max(e.end(a) for a in e.horizontal)


def pair_at_ends(e: Evidence) -> float:
    return max(e.both_ends(a) for a in e.horizontal)


def holds_something(e: Evidence) -> float:
    return 1.0 if e.holds else 0.4


def rests(e: Evidence) -> float:
    return 1.0 if e.rests_on else 0.5


def by_id(all_: list[Evidence]) -> dict[int, Evidence]:
    return {x.group: x for x in all_}


def main_of(all_: list[Evidence]) -> Evidence:
    return min(all_, key=lambda x: x.rank)


def outside_main(e: Evidence, all_: list[Evidence]) -> float:
    """How far the group's box sticks out of the main mass's box across the horizontal axes."""
    m = main_of(all_)
    if m.group == e.group:
        return 0.0
    out = 0.0
    for a in e.horizontal:
        width = max(m.hi[a] - m.lo[a], 1e-9)
        out = max(out, (m.lo[a] - e.lo[a]) / width, (e.hi[a] - m.hi[a]) / width)
    return ramp(out, 0.02, 0.15)


def above_main(e: Evidence, all_: list[Evidence]) -> float:
    m = main_of(all_)
    return 0.0 if m.group == e.group else ramp(e.u_mid - m.hi[e.up], -0.05, 0.05)


def under(e: Evidence, all_: list[Evidence]) -> float:
    """Something larger stands on it."""
    ids = by_id(all_)
    return 1.0 if any(ids[h].area_share >= 0.5 * e.area_share for h in e.holds if h in ids) else 0.0


def largest_of(e: Evidence, all_: list[Evidence], fit: Callable[[Evidence], float], key: Callable[[Evidence], float]) -> float:
    """1 for the group with the largest ``key`` among those fitting ``fit`` (> 0.3), softly less for others."""
    cands = [x for x in all_ if fit(x) > 0.3]
    if not cands or e not in cands:
        return 0.0
    best = max(key(x) for x in cands)
    return 1.0 if key(e) >= best else 0.6


def lowest(e: Evidence, all_: list[Evidence]) -> float:
    return 1.0 if e.u_lo <= min(x.u_lo for x in all_) + 0.02 else 0.5


def longest(e: Evidence, all_: list[Evidence]) -> float:
    return 1.0 if e.axes[0] >= max(x.axes[0] for x in all_) - 1e-9 else 0.5
