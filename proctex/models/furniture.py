"""Furniture: desk, sofa, chair, stair, table.

Conventions shared by every model here: metres, +z up, x = width (left/right), y = depth with the
front towards -y, standing on z = 0 and roughly centred at x = y = 0. Repeated parts are built once
and placed with :func:`primitives.transform`; mirrored (chiral) parts are built once and reflected
with :func:`primitives.mirror`, so parts sharing a label are exactly congruent.

Builders take ``edge``: ``None`` for the fixed tessellation (the segment counts written in the code),
else the target edge length (m) of the adaptive tessellation, whose counts follow the part's size.
"""

from __future__ import annotations

from typing import Callable, Sequence

import numpy as np

from proctex.geometry import primitives as P
from proctex.geometry import sweeps as S
from proctex.geometry.shape import ProceduralModel, Shape, ShapeBuilder
from ..params import ParamSpace, choice, continuous, integer
from .registry import register

Warp = Callable[[np.ndarray, np.ndarray], np.ndarray]


# ------------------------------------------------------------------------------------------- helpers
def slab(
    lo: Sequence[float],
    hi: Sequence[float],
    divisions: Sequence[int] = (1, 1, 1),
    warp: Warp | None = None,
    edge: float | None = None,
    rings_per_width: float = 2.0,
) -> P.Part:
    """Box spanning the axis-aligned extents ``lo`` to ``hi`` (each (3,) metres).

    ``divisions`` (3,) are the fixed tessellation's; with a target ``edge`` (m) they follow the size
    (:func:`primitives.box_divisions`, with ``rings_per_width``).
    """
    lo, hi = np.asarray(lo, dtype=float), np.asarray(hi, dtype=float)
    if edge is not None:
        divisions = P.box_divisions(hi - lo, edge, rings_per_width=rings_per_width)
    return P.box(hi - lo, (lo + hi) / 2, divisions, warp)


def rounded_slab(
    size: Sequence[float],
    center: Sequence[float],
    divisions: Sequence[int],
    round_lo: Sequence[float] = (0.0, 0.0, 0.0),
    round_hi: Sequence[float] = (0.0, 0.0, 0.0),
    edge_segments: int = 2,
    warp: Warp | None = None,
    edge: float | None = None,
    rings_per_width: float = 2.0,
) -> P.Part:
    """:func:`primitives.rounded_box`; with a target ``edge`` (m) the segments between the rounding
    bands follow the size (the bands keep their canonical extent from ``divisions``;
    ``rings_per_width`` as in :func:`primitives.box_divisions`)."""
    middle = None
    if edge is not None:
        middle = P.rounded_box_middle(size, round_lo, round_hi, edge, rings_per_width=rings_per_width)
    return P.rounded_box(size, center, divisions, round_lo, round_hi, edge_segments, warp, middle)


def about_pivot(part: P.Part, R: np.ndarray, pivot: Sequence[float]) -> P.Part:
    """``part`` rotated by the (3, 3) matrix ``R`` about the point ``pivot`` (3,)."""
    pivot = np.asarray(pivot, dtype=float)
    return P.transform(part, R=R, t=pivot - R @ pivot)


def tapered_cylinder(height: float, r_top: float, r_bottom: float, n_theta: int = 16, n_rings: int = 6, edge: float | None = None) -> P.Part:
    """Closed tapered cylinder standing on z = 0 with flat ends, axis along z (canonical: sphere).

    Fixed tessellation: ``n_rings`` rings of ``n_theta`` points. With a target ``edge`` (m): points
    per ring by the widest circumference (at least 8) and rings by the height.
    """
    if edge is None:
        z = np.linspace(0.0, height, n_rings)
        r = np.interp(z, [0.0, height], [r_bottom, r_top])
        return S.revolve(r, z, n_theta=n_theta, z_bottom=0.0, z_top=height)
    n_theta, along = P.revolve_resolution(max(r_top, r_bottom), edge, minimum=8)
    u = np.linspace(0.0, 1.0, P.segment_count(height, along, 2) + 1)
    z = u * height
    r = np.interp(z, [0.0, height], [r_bottom, r_top])
    return S.revolve(r, z, P.uniform_s(n_rings, u), n_theta=n_theta, z_bottom=0.0, z_top=height)


def superellipse_radius(theta: np.ndarray, a: float, b: float, power: float) -> np.ndarray:
    """Radius (N,) of the superellipse ``|x/a|^p + |y/b|^p = 1`` in the directions ``theta`` (N,)."""
    c, s = np.abs(np.cos(theta)), np.abs(np.sin(theta))
    return 1.0 / ((c / a) ** power + (s / b) ** power) ** (1.0 / power)


# ---------------------------------------------------------------------------------------------- desk
DESK_INSET = 0.02  # legs' distance from the top's edges
PEDESTAL_WIDTH = 0.4
DRAWER_PITCH = 0.15
DRAWER_FRONT = 0.02  # thickness of a drawer front


def knob(radius: float, edge: float | None = None) -> P.Part:
    """Mushroom knob (a surface of revolution) with its stem base at the origin, pointing to -y.

    With a target ``edge`` (m) the profile's spans are subdivided and the points per ring follow
    the circumference (at least 16).
    """
    z = np.array([0.0, 0.4, 0.55, 0.75, 0.95]) * 1.6 * radius
    r = np.array([0.45, 0.45, 0.9, 1.0, 0.7]) * radius
    if edge is None:
        part = S.revolve(r, z, n_theta=16, z_bottom=0.0, z_top=1.6 * radius)
    else:
        n_theta, along = P.revolve_resolution(radius, edge, minimum=16)
        s = (np.arange(len(r)) + 1.0) / (len(r) + 1.0)
        r, z, s = P.subdivide_profile(r, z, s, 0.0, 1.6 * radius, along)
        part = S.revolve(r, z, s, n_theta=n_theta, z_bottom=0.0, z_top=1.6 * radius)
    return P.transform(part, R=P.rotation("x", np.pi / 2))


@register
class Desk(ProceduralModel):
    name = "desk"
    description = "Writing desk: top on four legs with a pedestal of 0-4 drawers (each with a knob)."
    edge_length = 0.1  # target edge length (m) of the adaptive tessellation
    space = ParamSpace(
        (
            continuous("width", 1.0, 1.8, 1.4, "m", "width of the top"),
            continuous("depth", 0.5, 0.8, 0.65, "m", "depth of the top"),
            continuous("height", 0.7, 0.8, 0.75, "m", "height of the top surface"),
            continuous("top_thickness", 0.02, 0.05, 0.03, "m", "thickness of the top"),
            continuous("leg_size", 0.03, 0.06, 0.045, "m", "side of the square legs"),
            integer("drawers", 0, 4, 3, "count", "drawers in the pedestal (0: no pedestal)"),
        )
    )

    def expected_counts(self, params=None):
        p = self.space.validate(params)
        n = p["drawers"]
        pedestal = 1 if n > 0 else 0
        return 5 + pedestal + 2 * n, 2 + 3 * pedestal

    def _build(self, p) -> Shape:
        w, d, h, t, leg = p["width"], p["depth"], p["height"], p["top_thickness"], p["leg_size"]
        e = self.target_edge
        sb = ShapeBuilder().add(slab((-w / 2, -d / 2, h - t), (w / 2, d / 2, h), (8, 4, 1), edge=e), "top")
        leg_part = slab((-leg / 2, -leg / 2, 0.0), (leg / 2, leg / 2, h - t), (1, 1, 6), edge=e)
        lx, ly = w / 2 - DESK_INSET - leg / 2, d / 2 - DESK_INSET - leg / 2
        for part in P.translated(leg_part, [(sx * lx, sy * ly, 0.0) for sy in (-1, 1) for sx in (-1, 1)]):
            sb.add(part, "leg")
        if p["drawers"] > 0:
            self._add_pedestal(sb, p, e)
        return sb.build(p)

    @staticmethod
    def _add_pedestal(sb: ShapeBuilder, p, e: float | None) -> None:
        """Pedestal carcass hanging from the top at the right, drawer fronts and knobs in front."""
        w, d, h, t, leg, n = p["width"], p["depth"], p["height"], p["top_thickness"], p["leg_size"], p["drawers"]
        x1 = w / 2 - DESK_INSET - leg
        x0 = x1 - PEDESTAL_WIDTH
        y0 = -d / 2 + DESK_INSET + 0.01
        z1 = h - t
        z0 = z1 - n * DRAWER_PITCH - 0.04
        sb.add(slab((x0, y0, z0), (x1, d / 2 - DESK_INSET - 0.01, z1), (4, 4, 2 * n), edge=e), "pedestal")
        # A drawer front with its back face centred at the origin; 1.2 cm gaps between fronts.
        half_w, half_h = PEDESTAL_WIDTH / 2 - 0.01, DRAWER_PITCH / 2 - 0.006
        front = slab((-half_w, -DRAWER_FRONT, -half_h), (half_w, 0.0, half_h), (4, 1, 2), edge=e)
        knob_part = knob(0.014, e)
        xc = (x0 + x1) / 2
        y_front = y0 + 0.001  # fronts overlap the carcass by 1 mm
        centers = [(xc, y_front, z1 - 0.02 - (i + 0.5) * DRAWER_PITCH) for i in range(n)]
        for part in P.translated(front, centers):
            sb.add(part, "drawer")
        for part in P.translated(knob_part, [(x, y - DRAWER_FRONT + 0.002, z) for x, y, z in centers]):
            sb.add(part, "knob")


# ---------------------------------------------------------------------------------------------- sofa
SOFA_LEG_HEIGHT = 0.1
SOFA_BACK_THICKNESS = 0.08
SOFA_BASE_RECESS = 0.06  # the base sits this far behind the front of the seat cushions


def sloped_arm(size: Sequence[float], center: Sequence[float], drop: float, edge: float | None = None) -> P.Part:
    """Chiral armrest block: its outer (+x) top edge is rounded and its top slopes down to the front.

    Args:
        size: (3,) width (x), depth (y), height (z) before the slope.
        center: (3,) centre of the unsloped block.
        drop: how much lower the top is at the front (-y) than at the back.
        edge: target edge length (m) of the adaptive tessellation, None for the fixed one.

    The rounding breaks the x mirror, the slope the y mirror and the flat bottom the z mirror, so
    the part has no symmetry at all: its mirror image is congruent to it only by a reflection.
    """
    size = np.asarray(size, dtype=float)
    r = 0.4 * size[0]

    def slope(local: np.ndarray, canonical: np.ndarray) -> np.ndarray:
        up = (local[:, 2] + size[2] / 2) / size[2]
        local[:, 2] -= drop * (1.0 - canonical[:, 1]) * up
        return local

    return rounded_slab(size, center, (5, 8, 8), round_hi=(r, 0.0, r), edge_segments=3, warp=slope, edge=edge)


@register
class Sofa(ProceduralModel):
    name = "sofa"
    description = "Sofa: frame on four legs, 1-3 seat and back cushions, back panel, two mirrored sloped arms."
    edge_length = 0.07  # target edge length (m) of the adaptive tessellation
    space = ParamSpace(
        (
            integer("seats", 1, 3, 3, "count", "number of seat (and back) cushions"),
            continuous("seat_width", 0.5, 0.7, 0.6, "m", "width of one seat cushion"),
            continuous("depth", 0.85, 1.05, 0.92, "m", "overall depth"),
            continuous("seat_height", 0.4, 0.5, 0.44, "m", "height of the seat cushions' top"),
            continuous("back_height", 0.75, 1.0, 0.85, "m", "height of the back panel"),
            continuous("cushion_thickness", 0.11, 0.2, 0.15, "m", "seat cushion thickness"),
            continuous("arm_height", 0.55, 0.7, 0.62, "m", "height of the armrests at the back"),
            continuous("arm_width", 0.12, 0.25, 0.18, "m", "width of each armrest"),
        )
    )

    def expected_counts(self, params=None):
        p = self.space.validate(params)
        return 8 + 2 * p["seats"], 6

    def _build(self, p) -> Shape:
        n, sw, d = p["seats"], p["seat_width"], p["depth"]
        seat_h, back_h, ct = p["seat_height"], p["back_height"], p["cushion_thickness"]
        arm_h, aw = p["arm_height"], p["arm_width"]
        inner = n * sw
        w = inner + 2 * aw
        y_back = d / 2 - SOFA_BACK_THICKNESS  # front face of the back panel
        base_top = seat_h - ct
        e = self.target_edge
        sb = ShapeBuilder()
        # The base runs under the arms, stopping 1 cm short of their outer faces.
        base_lo = (-w / 2 + 0.01, -d / 2 + SOFA_BASE_RECESS, SOFA_LEG_HEIGHT)
        sb.add(slab(base_lo, (w / 2 - 0.01, y_back, base_top), (2 * n + 2, 4, 2), edge=e), "base")
        back = rounded_slab(
            (inner, SOFA_BACK_THICKNESS, back_h - SOFA_LEG_HEIGHT),
            (0.0, y_back + SOFA_BACK_THICKNESS / 2, (back_h + SOFA_LEG_HEIGHT) / 2),
            (4 * n, 5, 6),
            round_lo=(0.0, 0.02, 0.0),
            round_hi=(0.0, 0.02, 0.03),
            edge=e,
        )
        sb.add(back, "back")
        xs = [(i - (n - 1) / 2) * sw for i in range(n)]
        # Back cushions are always thicker than seat cushions, so the two never look alike.
        bct = 1.25 * ct + 0.02
        seat_depth = y_back - 0.6 * bct + d / 2
        cushion = rounded_slab((sw - 0.01, seat_depth, ct), (0.0, 0.0, 0.0), (10, 8, 5), (0.03,) * 3, (0.03,) * 3, edge=e)
        for part in P.translated(cushion, [(x, -d / 2 + seat_depth / 2, base_top + ct / 2) for x in xs]):
            sb.add(part, "seat_cushion")
        bch = back_h - seat_h - 0.02
        back_cushion = rounded_slab((sw - 0.01, bct, bch), (0.0, 0.0, 0.0), (10, 5, 8), (0.04,) * 3, (0.04,) * 3, edge=e)
        back_cushion = P.transform(back_cushion, R=P.rotation("x", -np.radians(10.0)))
        yc, zc = y_back - bct / 2 - 0.02, seat_h + bch / 2 - 0.01
        for part in P.translated(back_cushion, [(x, yc, zc) for x in xs]):
            sb.add(part, "back_cushion")
        arm_center = (inner / 2 + aw / 2, 0.0, (arm_h + SOFA_LEG_HEIGHT) / 2)
        right = sloped_arm((aw, d, arm_h - SOFA_LEG_HEIGHT), arm_center, drop=0.05, edge=e)
        sb.add(right, "armrest").add(P.mirror(right, axis=0), "armrest")
        leg = tapered_cylinder(SOFA_LEG_HEIGHT + 0.005, 0.028, 0.018, edge=e)
        lx, ly = w / 2 - 0.07, d / 2 - 0.07
        for part in P.translated(leg, [(sx * lx, sy * ly, 0.0) for sy in (-1, 1) for sx in (-1, 1)]):
            sb.add(part, "leg")
        return sb.build(p)


# --------------------------------------------------------------------------------------------- chair
SLAT_THICKNESS = 0.018
CHAIR_TILT = np.radians(8.0)  # backward tilt of the backrest
ARM_WIDTH, ARM_THICKNESS, ARM_BEND = 0.05, 0.025, 0.045
CHAIR_BAR_RINGS = 3.0  # adaptive: rings per width along the tapered legs and the bent arms


def bent_arm(length: float, drop: float, center_x: float, y_back: float, z_top: float, edge: float | None = None) -> P.Part:
    """Chiral chair arm: a bar running forward from ``y_back`` that bends down to the seat.

    Args:
        length: horizontal reach of the bar's centre line (to the vertical part's centre line).
        drop: vertical length of the centre line from the horizontal part down to its foot.
        center_x: x of the bar's centre plane.
        y_back: y of the back end.
        z_top: height of the bar's top surface.
        edge: target edge length (m) of the adaptive tessellation, None for the fixed one.

    The bar's outer (+x) top edge is rounded, which breaks its only mirror symmetry; the straight
    parts have different lengths, so no diagonal mirror appears either.
    """
    straight_v = drop - ARM_BEND
    arc = np.pi / 2 * ARM_BEND
    total = straight_v + arc + length - ARM_BEND
    # Centre of the bend's arc in (y, z); the foot of the centre line is at (y_back - length, zc - drop).
    zc = z_top - ARM_THICKNESS / 2
    bend_y, bend_z = y_back - length + ARM_BEND, zc - ARM_BEND

    def bend(local: np.ndarray, canonical: np.ndarray) -> np.ndarray:
        # Arc length u from the foot (canonical y = 0) up the vertical part, round the bend, back.
        u = canonical[:, 1] * total
        theta = np.pi - np.clip((u - straight_v) / arc, 0.0, 1.0) * np.pi / 2  # pi: down, pi/2: level
        normal = np.stack([np.cos(theta), np.sin(theta)], axis=1)  # outward normal in (y, z)
        center = np.array([bend_y, bend_z]) + ARM_BEND * normal
        center[:, 1] += np.minimum(u - straight_v, 0.0)  # down the vertical part
        center[:, 0] += np.maximum(u - straight_v - arc, 0.0)  # back along the horizontal part
        out = np.empty_like(local)
        out[:, 0] = local[:, 0] + center_x
        out[:, 1:] = center + local[:, 2:3] * normal
        return out

    r = 0.4 * ARM_THICKNESS
    size = (ARM_WIDTH, total, ARM_THICKNESS)
    return rounded_slab(size, (0.0, 0.0, 0.0), (4, 40, 4), (0.0, 0.0, 0.0), (r, 0.0, r), 2, bend, edge, CHAIR_BAR_RINGS)


@register
class Chair(ProceduralModel):
    name = "chair"
    description = "Dining chair: seat on four legs, tilted back of two posts and 2-6 slats, optional mirrored arms."
    edge_length = 0.04  # target edge length (m) of the adaptive tessellation
    space = ParamSpace(
        (
            continuous("seat_width", 0.4, 0.55, 0.46, "m", "seat width"),
            continuous("seat_depth", 0.38, 0.5, 0.44, "m", "seat depth"),
            continuous("seat_height", 0.42, 0.5, 0.45, "m", "height of the seat top"),
            continuous("seat_thickness", 0.025, 0.05, 0.035, "m", "seat thickness"),
            continuous("back_height", 0.35, 0.55, 0.45, "m", "backrest height above the seat"),
            continuous("leg_thickness", 0.03, 0.05, 0.038, "m", "side of the square legs"),
            integer("slats", 2, 6, 3, "count", "horizontal backrest slats"),
            choice("arms", (True, False), True, "whether the chair has armrests"),
            continuous("arm_height", 0.18, 0.26, 0.22, "m", "armrest height above the seat"),
        )
    )

    def expected_counts(self, params=None):
        p = self.space.validate(params)
        arms = 2 if p["arms"] else 0
        return 7 + p["slats"] + arms, 4 + (1 if arms else 0)

    def _build(self, p) -> Shape:
        sw, sd, sh = p["seat_width"], p["seat_depth"], p["seat_height"]
        st, lt = p["seat_thickness"], p["leg_thickness"]
        e = self.target_edge
        sb = ShapeBuilder()
        r = 0.3 * st
        seat = rounded_slab((sw, sd, st), (0.0, 0.0, sh - st / 2), (8, 8, 3), (r, r, 0.0), (r, r, r), 1, edge=e)
        sb.add(seat, "seat")

        def taper(local: np.ndarray, canonical: np.ndarray) -> np.ndarray:
            local[:, :2] *= (0.75 + 0.25 * canonical[:, 2])[:, None]
            return local

        leg = slab((-lt / 2, -lt / 2, 0.0), (lt / 2, lt / 2, sh - st), (1, 1, 4), taper, e, CHAIR_BAR_RINGS)
        lx, ly = sw / 2 - lt / 2 - 0.01, sd / 2 - lt / 2 - 0.01
        for part in P.translated(leg, [(sx * lx, sy * ly, 0.0) for sy in (-1, 1) for sx in (-1, 1)]):
            sb.add(part, "leg")
        self._add_back(sb, p, lx, ly, e)
        if p["arms"]:
            ah = p["arm_height"]
            y_back = ly + np.tan(CHAIR_TILT) * ah  # the tilted back post at arm height
            right = bent_arm(y_back + ly, ah - ARM_THICKNESS / 2 + 0.005, lx, y_back, sh + ah, e)
            sb.add(right, "armrest").add(P.mirror(right, axis=0), "armrest")
        return sb.build(p)

    @staticmethod
    def _add_back(sb: ShapeBuilder, p, lx: float, ly: float, e: float | None) -> None:
        """Two back posts above the back legs and the slats between them, tilted back together."""
        sh, st, bh, lt, n = p["seat_height"], p["seat_thickness"], p["back_height"], p["leg_thickness"], p["slats"]
        pt = 0.75 * lt  # posts are always slimmer than legs
        tilt = P.rotation("x", -CHAIR_TILT)
        pivot = np.array([0.0, ly, sh - st])
        post = slab((-pt / 2, -pt / 2, 0.0), (pt / 2, pt / 2, st + bh), (1, 1, 6), edge=e)
        for sx in (-1, 1):
            sb.add(about_pivot(P.transform(post, t=(sx * lx, ly, sh - st)), tilt, pivot), "post")
        zone_lo, zone_hi = sh + 0.3 * bh, sh + bh - 0.02
        slat_h = min(0.07, 0.55 * (zone_hi - zone_lo) / n)
        slat = slab((-lx, -SLAT_THICKNESS / 2, -slat_h / 2), (lx, SLAT_THICKNESS / 2, slat_h / 2), (6, 1, 1), edge=e)
        zs = zone_lo + (zone_hi - zone_lo - slat_h) * np.arange(n) / (n - 1) + slat_h / 2
        for z in zs:
            sb.add(about_pivot(P.transform(slat, t=(0.0, ly, z)), tilt, pivot), "slat")


# --------------------------------------------------------------------------------------------- stair
STRINGER_THICKNESS = 0.05
RISER_THICKNESS = 0.02
NOSING = 0.02
POST_SIZE, POST_HEIGHT, RAIL_RADIUS = 0.04, 0.9, 0.03


@register
class Stair(ProceduralModel):
    name = "stair"
    description = "Straight stair rising to the back: 3-12 treads and risers between two stringers, optional handrail."
    edge_length = 0.09  # target edge length (m) of the adaptive tessellation
    space = ParamSpace(
        (
            integer("steps", 3, 12, 6, "count", "number of treads"),
            continuous("width", 0.6, 1.4, 0.9, "m", "clear width between the stringers"),
            continuous("rise", 0.15, 0.2, 0.175, "m", "height of one step"),
            continuous("run", 0.22, 0.32, 0.27, "m", "horizontal depth of one step"),
            continuous("tread_thickness", 0.03, 0.05, 0.04, "m", "thickness of the treads"),
            choice("handrail", (True, False), True, "posts on every tread and a rail on the right"),
        )
    )

    def expected_counts(self, params=None):
        p = self.space.validate(params)
        n, rail = p["steps"], bool(p["handrail"])
        return 2 * n + 2 + (n + 1 if rail else 0), 3 + (2 if rail else 0)

    def _build(self, p) -> Shape:
        n, w, rise, run, tt = p["steps"], p["width"], p["rise"], p["run"], p["tread_thickness"]
        y0 = -n * run / 2  # front face of the first riser
        e = self.target_edge
        sb = ShapeBuilder()
        tread = slab((-w / 2, -NOSING, -tt), (w / 2, run, 0.0), (8, 3, 1), edge=e)
        riser = slab((-w / 2, 0.0, 0.0), (w / 2, RISER_THICKNESS, rise - tt), (8, 1, 2), edge=e)
        for part in P.translated(tread, [(0.0, y0 + i * run, (i + 1) * rise) for i in range(n)]):
            sb.add(part, "step")
        for part in P.translated(riser, [(0.0, y0 + i * run, i * rise) for i in range(n)]):
            sb.add(part, "riser")
        for part in P.translated(self._stringer(p, e), [(sx * (w + STRINGER_THICKNESS) / 2, 0.0, 0.0) for sx in (-1, 1)]):
            sb.add(part, "stringer")
        if p["handrail"]:
            self._add_handrail(sb, p, y0, e)
        return sb.build(p)

    @staticmethod
    def _stringer(p, e: float | None = None) -> P.Part:
        """Parallelogram slab centred on x = 0: horizontal floor and top cuts, sides along the pitch.

        Its upper sloped edge runs 4 cm above the tread nosings; its horizontal depth is two runs.
        """
        n, rise, run = p["steps"], p["rise"], p["run"]
        height = n * rise + 0.04
        depth = 2 * run
        y_front_at_floor = -n * run / 2 - NOSING - (rise + 0.04) * run / rise

        def shear(local: np.ndarray, canonical: np.ndarray) -> np.ndarray:
            local[:, 1] += y_front_at_floor + depth / 2 + canonical[:, 2] * height * run / rise
            local[:, 2] += height / 2
            return local

        size = (STRINGER_THICKNESS, depth, height)
        div = (1, 2, 2 * n)
        if e is not None:  # counts by the sheared (sloped) length, the real edge length along the pitch
            div = P.box_divisions((STRINGER_THICKNESS, depth, height * np.hypot(1.0, run / rise)), e)
        return P.box(size, (0.0, 0.0, 0.0), div, shear)

    @staticmethod
    def _add_handrail(sb: ShapeBuilder, p, y0: float, e: float | None = None) -> None:
        """A post on the right end of every tread and a round rail over their tops."""
        n, w, rise, run = p["steps"], p["width"], p["rise"], p["run"]
        x = w / 2 - POST_SIZE
        # Straight, unwarped and of a fixed size: square quads along the posts are enough.
        half = POST_SIZE / 2
        post = slab((-half, -half, 0.0), (half, half, POST_HEIGHT), (1, 1, 6), edge=e, rings_per_width=1.0)
        tops = np.array([(x, y0 + (i + 0.5) * run, (i + 1) * rise + POST_HEIGHT) for i in range(n)])
        for part in P.translated(post, tops - [0.0, 0.0, POST_HEIGHT]):
            sb.add(part, "post")
        direction = (tops[-1] - tops[0]) / np.linalg.norm(tops[-1] - tops[0])
        start, end = tops[0] - 0.1 * direction, tops[-1] + 0.1 * direction
        if e is None:
            path = start + np.linspace(0.0, 1.0, 2 * n)[:, None] * (end - start)
            sb.add(S.tube(path, RAIL_RADIUS, n_sides=12, up=(0.0, 0.0, 1.0)), "rail")
            return
        # A straight rail needs no rings for its shape: they follow its length at the target edge.
        n_sides = P.ring_points(RAIL_RADIUS, e, minimum=8)
        u = np.linspace(0.0, 1.0, P.segment_count(np.linalg.norm(end - start), e, 2) + 1)
        path = start + u[:, None] * (end - start)
        sb.add(S.tube(path, RAIL_RADIUS, n_sides=n_sides, s=P.uniform_s(2 * n, u), up=(0.0, 0.0, 1.0)), "rail")


# --------------------------------------------------------------------------------------------- table
APRON_HEIGHT, APRON_WALL = 0.09, 0.02
LEG_INSET = 0.09  # distance of the leg axes from the top's rim


@register
class Table(ProceduralModel):
    name = "table"
    description = "Table with a round (revolved) or rectangular top on 3-6 legs around the rim, optional apron."
    edge_length = 0.06  # target edge length (m) of the adaptive tessellation
    space = ParamSpace(
        (
            choice("top_shape", ("round", "rect"), "rect", "round disc or rectangular board"),
            continuous("width", 0.8, 1.8, 1.2, "m", "width (the diameter of a round top)"),
            continuous("depth", 0.6, 1.0, 0.8, "m", "depth of a rectangular top (unused when round)"),
            continuous("height", 0.68, 0.78, 0.74, "m", "height of the top surface"),
            continuous("top_thickness", 0.025, 0.05, 0.035, "m", "thickness of the top"),
            integer("legs", 3, 6, 4, "count", "legs, evenly spaced around the rim"),
            continuous("leg_radius", 0.02, 0.04, 0.03, "m", "radius of the legs at the top"),
            choice("apron", (True, False), True, "skirt under the top joining the legs"),
        )
    )

    def expected_counts(self, params=None):
        p = self.space.validate(params)
        apron = 1 if p["apron"] else 0
        return 1 + p["legs"] + apron, 2 + apron

    def _build(self, p) -> Shape:
        h, t = p["height"], p["top_thickness"]
        a, b, power = self._rim(p)
        e = self.target_edge
        sb = ShapeBuilder()
        if p["top_shape"] == "round":
            # Box-frame canonical coordinates, comparable with the rectangular top's.
            sb.add(P.with_box_canonical(self._round_top(a, h, t, e)), "top")
        else:
            sb.add(slab((-a, -b, h - t), (a, b, h), (10, 8, 1), edge=e), "top")
        n = p["legs"]
        theta = -np.pi / 2 + np.pi / n + 2 * np.pi * np.arange(n) / n
        rho = superellipse_radius(theta, a - LEG_INSET, b - LEG_INSET, power)
        leg = tapered_cylinder(h - t + 0.002, p["leg_radius"], 0.7 * p["leg_radius"], n_theta=16, n_rings=8, edge=e)
        for part in P.translated(leg, np.stack([rho * np.cos(theta), rho * np.sin(theta), np.zeros(n)], axis=1)):
            sb.add(part, "leg")
        if p["apron"]:
            sb.add(self._apron(a - LEG_INSET, b - LEG_INSET, power, h - t, e), "apron")
        return sb.build(p)

    @staticmethod
    def _rim(p) -> tuple[float, float, float]:
        """Half extents (a, b) of the top and the superellipse power describing its outline."""
        if p["top_shape"] == "round":
            return p["width"] / 2, p["width"] / 2, 2.0
        return p["width"] / 2, p["depth"] / 2, 8.0

    @staticmethod
    def _round_top(radius: float, h: float, t: float, e: float | None = None) -> P.Part:
        """Revolved disc of ``radius`` with a half-round rim, top surface at ``h``.

        Adaptive (target edge ``e``): points per ring by the circumference (a multiple of 4, so the
        bounding box, hence the box-frame canonical coordinates, stay exact) and rings by the rim's
        arc length; the flat faces stay triangle fans, as a cylinder's caps often are.
        """
        if e is None:
            phi = np.linspace(-np.pi / 2, np.pi / 2, 7)
            r = radius - t / 2 + t / 2 * np.cos(phi)
            z = h - t / 2 + t / 2 * np.sin(phi)
            return S.revolve(r, z, n_theta=64, z_bottom=h - t, z_top=h)
        n_theta, along = P.revolve_resolution(radius, e, minimum=32, multiple=4)
        u = np.linspace(0.0, 1.0, P.segment_count(np.pi * t / 2, along, 4) + 1)
        phi = -np.pi / 2 + np.pi * u
        r = radius - t / 2 + t / 2 * np.cos(phi)
        z = h - t / 2 + t / 2 * np.sin(phi)
        return S.revolve(r, z, P.uniform_s(7, u), n_theta=n_theta, z_bottom=h - t, z_top=h)

    @staticmethod
    def _apron(a: float, b: float, power: float, z_top: float, e: float | None = None) -> P.Part:
        """Skirt under the top through the leg axes: an upside-down tray with an outline like the top's.

        A closed surface of revolution (ceiling, inner wall, lower lip, outer wall, lid) whose rings
        follow superellipses with half axes ``(a, b) +- APRON_WALL / 2``. Adaptive (target edge
        ``e``): points per ring by the outline's perimeter (a multiple of 4), the walls and the lip
        subdivided; a ring's offset from the mid outline is a fixed function of its ``s``.
        """
        z_bot = z_top - APRON_HEIGHT
        offsets = np.array([-1.0, -1.0, 1.0, 1.0]) * APRON_WALL / 2
        heights = np.array([z_top - APRON_WALL, z_bot, z_bot, z_top])
        if e is None:

            def outline(theta: np.ndarray, s: np.ndarray) -> np.ndarray:
                return np.stack([superellipse_radius(theta, a + o, b + o, power) / (a + o) for o in offsets])

            return S.revolve(a + offsets, heights, n_theta=64, z_bottom=z_top - APRON_WALL, z_top=z_top, radial=outline)
        s_ref = (np.arange(4) + 1.0) / 5.0
        theta = np.linspace(0.0, 2 * np.pi, 721)
        rim = superellipse_radius(theta, a, b, power)
        perimeter = P.polyline_length(np.stack([rim * np.cos(theta), rim * np.sin(theta)], axis=1))
        n_theta = 4 * P.segment_count(perimeter / 4, e, 8)
        along = min(e, perimeter / n_theta)
        counts = [P.segment_count(length, along, 1) for length in (APRON_HEIGHT - APRON_WALL, APRON_WALL, APRON_HEIGHT)]
        s = P.split_spans(s_ref, counts)
        prof = P.resample(np.stack([offsets, heights], 1), s_ref, s)

        def outline_s(theta: np.ndarray, s_: np.ndarray) -> np.ndarray:
            return np.stack([superellipse_radius(theta, a + o, b + o, power) / (a + o) for o in prof[:, 0]])

        z_ceiling = z_top - APRON_WALL
        return S.revolve(a + prof[:, 0], prof[:, 1], s, n_theta=n_theta, z_bottom=z_ceiling, z_top=z_top, radial=outline_s)
