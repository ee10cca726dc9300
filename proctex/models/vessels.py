"""Round things: vase, mug, pumpkin, mushroom, cake, shell."""

from __future__ import annotations

import numpy as np

from .. import primitives as P
from ..params import ParamSpace, choice, continuous, integer
from ..shape import ProceduralModel, Shape, ShapeBuilder
from . import register


def vessel_profile(outer_r: np.ndarray, z: np.ndarray, wall: float, floor: float, n_lip: int = 4):
    """Closed profile of a thin-walled open vessel, for :func:`primitives.revolve`.

    Goes up the outside (``outer_r`` at heights ``z``), over a rounded lip, and back down the
    inside (``outer_r - wall``) to the inner floor at ``z[0] + floor``. Returns ``(radius, height,
    s)`` with canonical ``s`` in (0, 0.5) outside, (0.5, 1) inside, the lip around 0.5.
    """
    K = len(z)
    s_out = 0.45 * (np.arange(K) + 1) / K
    ang = np.linspace(0, np.pi, n_lip + 2)[1:-1]
    lip_r = outer_r[-1] - wall / 2 + (wall / 2) * np.cos(ang)
    lip_z = z[-1] + (wall / 2) * np.sin(ang)
    s_lip = 0.45 + 0.1 * (np.arange(n_lip) + 1) / (n_lip + 1)
    inner_z = np.maximum(z, z[0] + floor)
    keep = inner_z[::-1] > z[0] + floor - 1e-12
    in_r = (outer_r - wall)[::-1][keep]
    in_z = inner_z[::-1][keep]
    # Remove repeated floor heights (keep the first ring that reaches the floor).
    _, first = np.unique(np.round(in_z, 12), return_index=True)
    sel = np.sort(first)
    in_r, in_z = in_r[sel], in_z[sel]
    s_in = 0.55 + 0.45 * np.arange(len(in_z)) / len(in_z)
    r = np.concatenate([outer_r, lip_r, in_r])
    h = np.concatenate([z, lip_z, in_z])
    s = np.concatenate([s_out, s_lip, s_in])
    return r, h, s


@register
class Vase(ProceduralModel):
    name = "vase"
    description = "Thin-walled vase: a surface of revolution with belly, neck and flared lip."
    space = ParamSpace(
        (
            continuous("height", 0.2, 0.6, 0.35, "m", "overall height"),
            continuous("belly", 0.06, 0.16, 0.1, "m", "radius at the widest point"),
            continuous("belly_height", 0.25, 0.6, 0.4, "", "relative height of the belly"),
            continuous("neck", 0.025, 0.07, 0.04, "m", "radius of the neck"),
            continuous("lip", 0.03, 0.1, 0.055, "m", "radius at the lip"),
            continuous("wall", 0.004, 0.012, 0.006, "m", "wall thickness"),
        )
    )

    def expected_counts(self, params=None):
        return 1, 1

    def _build(self, p) -> Shape:
        t = np.linspace(0.0, 1.0, 24)
        base = 0.6 * p["belly"]
        bh = p["belly_height"]
        # Piecewise smooth outline through base, belly, neck and lip.
        knots_t = np.array([0.0, bh, 0.8, 1.0])
        knots_r = np.array([base, p["belly"], p["neck"], p["lip"]])
        r = np.interp(t, knots_t, knots_r)
        r = np.convolve(np.pad(r, 2, mode="edge"), np.ones(5) / 5, mode="valid")
        z = t * p["height"]
        rr, hh, s = vessel_profile(r, z, p["wall"], floor=0.02 * p["height"])
        return ShapeBuilder().add(P.revolve(rr, hh, s, n_theta=48), "body").build(p)


# ------------------------------------------------------------------------------------------- helpers
def _bent_path(length: float, bend: float, n: int) -> np.ndarray:
    """(n, 3) float64 centre line starting at the origin along +z and bending towards +x.

    The path is a circular arc of arc length ``length`` turning by ``bend`` (non-zero) radians in
    total.
    """
    l = np.linspace(0.0, length, n)
    k = bend / length
    return np.stack([(1.0 - np.cos(k * l)) / k, np.zeros(n), np.sin(k * l) / k], axis=1)


def _tilted_placement(azimuth: float, tilt: float, distance: float, foot_radius: float) -> tuple[np.ndarray, np.ndarray]:
    """Rotation (3, 3) and translation (3,) that lean a part standing at the origin outward by
    ``tilt`` radians and move it ``distance`` from the z axis at angle ``azimuth``.

    The part is lifted so that the rim of its flat foot (radius ``foot_radius``) rests on z=0.
    """
    R = P.rotation("z", azimuth) @ P.rotation("y", tilt)
    lift = foot_radius * np.sin(abs(tilt))
    return R, np.array([distance * np.cos(azimuth), distance * np.sin(azimuth), lift])


def _coil_tube(path: np.ndarray, radius: np.ndarray, n_sides: int, cap_offset: float) -> P.Part:
    """Closed tube along a coil around the z axis, like :func:`primitives.tube`, but with the
    cross-section angle origin (canonical phi = 0) always on the side facing away from the axis.

    ``primitives.tube`` uses rotation-minimising frames, whose twist accumulates with the path's
    torsion, so on a helix whose shape depends on the parameters the same canonical angle would
    land on different sides of the tube across the family.

    Args:
        path: (K, 3) centre line, never on the z axis nor tangent to the radial direction.
        radius: (K,) tube radii.
        n_sides: points per ring.
        cap_offset: how far beyond the end rings the poles sit, in end radii (negative: recessed).
    """
    tangent = np.gradient(path, axis=0)
    tangent /= np.linalg.norm(tangent, axis=1, keepdims=True)
    outward = path * [1.0, 1.0, 0.0]
    normal = outward - np.einsum("ij,ij->i", outward, tangent)[:, None] * tangent
    normal /= np.linalg.norm(normal, axis=1, keepdims=True)
    binormal = np.cross(tangent, normal)
    phi = np.arange(n_sides) * (2 * np.pi / n_sides)
    offsets = np.cos(phi)[None, :, None] * normal[:, None] + np.sin(phi)[None, :, None] * binormal[:, None]
    rings = path[:, None] + radius[:, None, None] * offsets
    s = (np.arange(len(path)) + 1.0) / (len(path) + 1.0)
    start = path[0] - tangent[0] * cap_offset * radius[0]
    end = path[-1] + tangent[-1] * cap_offset * radius[-1]
    return P.ring_surface(rings, s, start, end, phi=phi)


# ----------------------------------------------------------------------------------------------- mug
@register
class Mug(ProceduralModel):
    name = "mug"
    description = "Thin-walled, slightly tapered mug with a C-shaped handle."
    space = ParamSpace(
        (
            continuous("height", 0.07, 0.13, 0.095, "m", "body height"),
            continuous("radius", 0.03, 0.05, 0.04, "m", "outer radius at the base"),
            continuous("taper", -0.12, 0.2, 0.06, "", "relative radius change from base to rim"),
            continuous("wall", 0.003, 0.008, 0.005, "m", "wall thickness"),
            continuous("handle_span", 0.45, 0.75, 0.62, "", "handle height relative to the body height"),
            continuous("handle_reach", 0.018, 0.035, 0.026, "m", "how far the handle sticks out of the wall"),
            continuous("handle_thickness", 0.004, 0.007, 0.0055, "m", "radius of the handle's cross-section"),
        )
    )
    n_side = 20  # outer profile rings on the straight side
    n_bevel = 4  # outer profile rings on the rounded bottom edge
    bevel = 0.004  # radius of the rounded bottom edge (m)

    def expected_counts(self, params=None):
        self.space.validate(params)
        return 2, 2

    @staticmethod
    def outer_radius(p, z: np.ndarray | float) -> np.ndarray | float:
        """Outer body radius at height ``z`` (array or scalar, m), ignoring the bottom bevel."""
        return p["radius"] * (1.0 + p["taper"] * np.asarray(z) / p["height"])

    def _body(self, p) -> P.Part:
        b = self.bevel
        ang = np.arange(self.n_bevel) * (np.pi / 2 / self.n_bevel)
        z = np.concatenate([b - b * np.cos(ang), np.linspace(b, p["height"], self.n_side)])
        r = self.outer_radius(p, z)
        r[: self.n_bevel] -= b - b * np.sin(ang)
        # Floor halfway between the first two straight-side rings: the inner profile then always
        # has the same number of rings, so the canonical s values do not depend on the parameters.
        floor = z[self.n_bevel] + 0.5 * (z[self.n_bevel + 1] - z[self.n_bevel])
        rr, hh, s = vessel_profile(r, z, p["wall"], floor=floor)
        return P.revolve(rr, hh, s, n_theta=64)

    def _handle(self, p) -> P.Part:
        """C-shaped tube on the +x side; its ends sink into the wall (but not through it)."""
        u = np.linspace(0.0, np.pi, 40)
        half = 0.5 * p["handle_span"] * p["height"]
        z = 0.5 * p["height"] + half * np.cos(u)
        sink = 0.6 * p["wall"]
        x = self.outer_radius(p, z) - sink + (p["handle_reach"] + sink) * np.sin(u) ** 0.7
        path = np.stack([x, np.zeros_like(x), z], axis=1)
        return P.tube(path, p["handle_thickness"], n_sides=16, up=(0.0, 0.0, 1.0), scale_xy=(1.0, 0.7))

    def _build(self, p) -> Shape:
        return ShapeBuilder().add(self._body(p), "body").add(self._handle(p), "handle").build(p)


# ------------------------------------------------------------------------------------------- pumpkin
@register
class Pumpkin(ProceduralModel):
    name = "pumpkin"
    description = "Ribbed pumpkin with a bent stem and an optional curly tendril."
    space = ParamSpace(
        (
            continuous("radius", 0.08, 0.25, 0.14, "m", "equatorial radius"),
            continuous("squash", 0.45, 0.9, 0.65, "", "height / diameter"),
            integer("ribs", 5, 12, 8, "count", "number of lobes (changes the mesh resolution)"),
            continuous("rib_depth", 0.07, 0.16, 0.1, "", "depth of the creases relative to the radius"),
            continuous("stem_length", 0.03, 0.08, 0.05, "m", "length of the stem"),
            continuous("stem_radius", 0.008, 0.016, 0.011, "m", "radius of the stem"),
            continuous("stem_bend", 0.1, 0.9, 0.4, "rad", "how far the stem bends over"),
            choice("tendril", (True, False), True, "curly tendril winding away from the stem"),
        )
    )
    n_rings = 31  # odd, so s = 0.5 (the equator) is a ring
    points_per_rib = 8  # even, so every crease is sampled

    def expected_counts(self, params=None):
        p = self.space.validate(params)
        n = 3 if p["tendril"] else 2
        return n, n

    def _body_profile(self, p) -> tuple[np.ndarray, np.ndarray, np.ndarray, float, float]:
        """Profile of the oblate body with dimples at both poles.

        Returns ``(radius (K,), height (K,), s (K,), z_bottom, z_top)``; the lowest point is at z=0.
        """
        R = p["radius"]
        H = 2.0 * R * p["squash"]
        s = (np.arange(self.n_rings) + 1.0) / (self.n_rings + 1.0)
        a = np.pi * s
        r = R * np.sin(a)
        dimple = np.exp(-((r / (0.3 * R)) ** 2))
        z = 0.5 * H * (1.0 - np.cos(a)) + np.where(a < np.pi / 2, 0.04 * H, -0.12 * H) * dimple
        z_bottom, z_top = 0.04 * H, 0.88 * H
        low = min(z.min(), z_bottom)
        return r, z - low, s, z_bottom - low, z_top - low

    def _lobes(self, ribs: int, depth: float):
        """Radius multiplier ``f(theta (N,), s (K,)) -> (K, N)``: round lobes, sharp creases."""

        def radial(theta: np.ndarray, s: np.ndarray) -> np.ndarray:
            lobe = np.sqrt(np.abs(np.cos(0.5 * ribs * theta)))
            return np.broadcast_to(1.0 - depth * (1.0 - lobe), (len(s), len(theta)))

        return radial

    def _stem(self, p, base_z: float) -> P.Part:
        """Tapered stem with a flared foot, sunk into the top dimple and bending towards +x."""
        n = 16
        t = np.linspace(0.0, 1.0, n)
        path = _bent_path(p["stem_length"], p["stem_bend"], n) + [0.0, 0.0, base_z - 0.5 * p["stem_radius"]]
        radius = p["stem_radius"] * (1.0 + 0.6 * np.exp(-((t / 0.15) ** 2))) * (1.0 - 0.2 * t)
        return P.tube(path, radius, n_sides=10, up=(1.0, 0.0, 0.0))

    def _tendril(self, p, base_z: float) -> P.Part:
        """Thin coil starting inside the stem foot and winding up and away towards -x."""
        R = p["radius"]
        n = 120
        t = np.linspace(0.0, 1.0, n)
        axis = np.array([-1.0, 0.3, 0.8]) / np.linalg.norm([-1.0, 0.3, 0.8])
        e1 = np.cross(axis, [0.0, 1.0, 0.0])
        e1 /= np.linalg.norm(e1)
        e2 = np.cross(axis, e1)
        coil = 0.06 * R * np.minimum(1.0, t / 0.25)
        turn = 2 * np.pi * 3.5 * t
        path = (
            np.array([0.0, 0.0, base_z + 0.5 * p["stem_radius"]])
            + 0.5 * R * t[:, None] * axis
            + coil[:, None] * (np.cos(turn)[:, None] * e1 + np.sin(turn)[:, None] * e2)
        )
        return P.tube(path, 0.01 * R, n_sides=8, up=(0.0, 0.0, 1.0))

    def _build(self, p) -> Shape:
        r, z, s, z_bottom, z_top = self._body_profile(p)
        n_theta = self.points_per_rib * p["ribs"]
        body = P.revolve(r, z, s, n_theta=n_theta, z_bottom=z_bottom, z_top=z_top, radial=self._lobes(p["ribs"], p["rib_depth"]))
        builder = ShapeBuilder().add(body, "body").add(self._stem(p, z_top), "stem")
        if p["tendril"]:
            builder.add(self._tendril(p, z_top), "tendril")
        return builder.build(p)


# ------------------------------------------------------------------------------------------ mushroom
def _mushroom_cap(radius: float, dome: float, n_theta: int = 48) -> P.Part:
    """Closed mushroom cap standing on z=0, centred on the z axis.

    The profile runs from the bottom pole (the centre of the concave underside, where the stem
    enters) out along the gills, round the rim and over the dome to the top pole.

    Args:
        radius: cap radius (m).
        dome: dome height relative to ``radius``.
    Returns:
        Part; canonical ``s`` in (0, 0.3] underside, (0.3, 0.45] rim, (0.45, 1) dome.
    """
    rim = 0.12 * radius  # half thickness of the rounded rim
    inner = radius - rim
    rise = 0.15 * radius  # how much higher the underside's centre is than the rim
    t = np.linspace(0.15, 1.0, 8)
    under_r, under_z = inner * t, rise * (1.0 - t**2)
    a = np.linspace(-np.pi / 2, 0.0, 6)[1:]
    rim_r, rim_z = inner + rim * np.cos(a), rim + rim * np.sin(a)
    b = np.linspace(0.0, np.pi / 2, 15)[1:-1]
    dome_r, dome_z = radius * np.cos(b), rim + dome * radius * np.sin(b)
    s = np.concatenate([0.3 * (np.arange(8) + 1) / 8, 0.3 + 0.15 * (np.arange(5) + 1) / 5, 0.45 + 0.55 * (np.arange(13) + 1) / 14])
    r = np.concatenate([under_r, rim_r, dome_r])
    z = np.concatenate([under_z, rim_z, dome_z])
    return P.revolve(r, z, s, n_theta=n_theta, z_bottom=rise, z_top=rim + dome * radius)


MUSHROOM_FOOT = 1.35  # foot radius of a mushroom stem relative to its nominal radius


def _mushroom_stem(height: float, radius: float, n_theta: int = 24) -> P.Part:
    """Closed stem standing on z=0 with a bulbous foot (radius ``MUSHROOM_FOOT * radius``),
    slightly narrower at the top."""
    t = np.linspace(0.0, 1.0, 14)
    r = radius * (1.0 + (MUSHROOM_FOOT - 1.0) * np.exp(-((t / 0.15) ** 2))) * (1.0 - 0.2 * t)
    return P.revolve(r, height * t, n_theta=n_theta)


def _cap_seat(stem_height: float, cap_radius: float, dome: float) -> float:
    """z at which to put a cap so that the stem's top ends inside it (40% up its centre)."""
    rise, rim = 0.15 * cap_radius, 0.12 * cap_radius
    return stem_height - rise - 0.4 * (rim + dome * cap_radius - rise)


@register
class Mushroom(ProceduralModel):
    name = "mushroom"
    description = "Cluster of one large mushroom and up to three identical small button mushrooms."
    space = ParamSpace(
        (
            continuous("cap_radius", 0.03, 0.07, 0.045, "m", "radius of the main cap"),
            continuous("cap_dome", 0.35, 0.75, 0.5, "", "dome height of the main cap relative to its radius"),
            continuous("stem_height", 0.04, 0.1, 0.065, "m", "height of the main stem"),
            continuous("stem_radius", 0.007, 0.014, 0.01, "m", "radius of the main stem"),
            integer("n_small", 0, 3, 2, "count", "number of small mushrooms around the main one"),
            continuous("small_scale", 0.35, 0.6, 0.45, "", "size of the small mushrooms relative to the main one"),
        )
    )
    small_slots = (0.3, 2.45, 4.3)  # azimuths (rad) of the small mushrooms
    small_tilt = 0.3  # outward lean of the small mushrooms (rad)
    small_dome = 0.85  # small caps are rounder buttons than the main cap

    def expected_counts(self, params=None):
        p = self.space.validate(params)
        n = p["n_small"]
        return 2 + 2 * n, 2 + (2 if n > 0 else 0)

    def _build(self, p) -> Shape:
        builder = ShapeBuilder()
        seat = _cap_seat(p["stem_height"], p["cap_radius"], p["cap_dome"])
        builder.add(P.transform(_mushroom_cap(p["cap_radius"], p["cap_dome"]), t=(0.0, 0.0, seat)), "cap")
        builder.add(_mushroom_stem(p["stem_height"], p["stem_radius"]), "stem")
        # Small ones: relatively taller, stubbier stems and rounder caps than a scaled copy of the main one.
        k = p["small_scale"]
        small_cap_radius, small_stem_height = k * p["cap_radius"], 1.2 * k * p["stem_height"]
        small_cap = P.transform(
            _mushroom_cap(small_cap_radius, self.small_dome),
            t=(0.0, 0.0, _cap_seat(small_stem_height, small_cap_radius, self.small_dome)),
        )
        small_stem_radius = 1.5 * k * p["stem_radius"]
        small_stem = _mushroom_stem(small_stem_height, small_stem_radius)
        distance = p["stem_radius"] + 0.9 * small_cap_radius + 0.35 * p["cap_radius"]
        for azimuth in self.small_slots[: p["n_small"]]:
            R, t = _tilted_placement(azimuth, self.small_tilt, distance, MUSHROOM_FOOT * small_stem_radius)
            builder.add(P.transform(small_cap, R, t), "small_cap").add(P.transform(small_stem, R, t), "small_stem")
        return builder.build(p)


# ---------------------------------------------------------------------------------------------- cake
def _cake_tier(radius: float, height: float, n_theta: int = 72) -> P.Part:
    """Closed cylindrical tier standing on z=0 with a rounded, scalloped frosting edge on top.

    Canonical ``s``: (0, 0.2) bottom face, [0.2, 0.6] side, (0.6, 0.8) top edge, [0.8, 1) top face.
    """
    edge = 0.15 * height  # radius of the rounded top edge
    bottom_r = radius * np.array([0.3, 0.6, 0.9, 1.0])
    side_t = np.linspace(0.0, 1.0, 8)
    side_z = (height - edge) * side_t
    a = np.linspace(0.0, np.pi / 2, 6)[1:-1]
    edge_r, edge_z = radius - edge + edge * np.cos(a), height - edge + edge * np.sin(a)
    top_r = (radius - edge) * np.array([1.0, 0.75, 0.5, 0.25])
    r = np.concatenate([bottom_r[:-1], np.full(8, radius), edge_r, top_r])
    z = np.concatenate([np.zeros(3), side_z, edge_z, np.full(4, height)])
    s = np.concatenate(
        [0.2 * np.arange(1, 4) / 4, 0.2 + 0.4 * side_t, 0.6 + 0.2 * np.arange(1, 5) / 5, 0.8 + 0.2 * np.arange(4) / 4]
    )
    def scallops(theta: np.ndarray, s_: np.ndarray) -> np.ndarray:
        """Frosting ripple (K, N) on the top edge and the upper rim of the side."""
        bump = np.exp(-(((s_ - 0.62) / 0.06) ** 2))
        return 1.0 + 0.012 * bump[:, None] * np.cos(24 * theta)[None, :]

    return P.revolve(r, z, s, n_theta=n_theta, radial=scallops)


def _plate(radius: float, thickness: float, n_theta: int = 72) -> P.Part:
    """Closed flat plate standing on z=0: a foot ring, a shallow well and a raised rim."""
    r = radius * np.array([0.55, 0.6, 0.93, 1.0, 1.0, 0.96, 0.85, 0.7])
    z = thickness * np.array([0.0, 0.0, 0.35, 0.8, 1.0, 1.0, 0.7, 0.6])
    return P.revolve(r, z, n_theta=n_theta)


def _candle(radius: float, height: float) -> P.Part:
    """Closed candle standing on z=0: a wax stick, a thin wick and a teardrop flame on top."""
    wick, flame = 0.25 * radius, 3.0 * radius
    a = np.linspace(0.0, np.pi, 9)[1:-1]
    flame_r = 2.2 * radius * np.sin(a) * np.exp(-0.7 * a)
    flame_z = height + 0.8 * radius + flame * (1.0 - np.cos(a)) / 2
    r = np.concatenate([np.full(6, radius), [0.8 * radius, wick, wick], np.maximum(flame_r, 0.2 * wick)])
    z = np.concatenate([np.linspace(0.0, height, 6), [height, height, height + 0.8 * radius], flame_z])
    return P.revolve(r, z, n_theta=16, z_top=height + 0.8 * radius + flame)


def tier_label(i: int, tiers: int) -> str:
    """Semantic label of tier ``i`` (0 = bottom) of ``tiers``: its role, not its index, so a
    2-tier and a 3-tier cake agree on what the bottom and top tiers are. The top tier carries
    the candles; a single tier is a top tier."""
    if i == tiers - 1:
        return "tier_top"
    return "tier_bottom" if i == 0 else "tier_middle"


@register
class Cake(ProceduralModel):
    name = "cake"
    description = "Tiered round cake on a plate, with candles on the top tier."
    space = ParamSpace(
        (
            integer("tiers", 1, 3, 2, "count", "number of stacked tiers"),
            continuous("radius", 0.08, 0.16, 0.11, "m", "radius of the bottom tier"),
            continuous("tier_height", 0.04, 0.09, 0.06, "m", "height of each tier"),
            continuous("shrink", 0.6, 0.78, 0.7, "", "radius of a tier relative to the one below"),
            integer("candles", 0, 8, 5, "count", "number of candles on the top tier"),
            continuous("candle_height", 0.03, 0.07, 0.045, "m", "height of the candles' wax"),
            continuous("plate_margin", 0.015, 0.05, 0.03, "m", "how far the plate reaches beyond the bottom tier"),
        )
    )
    plate_thickness = 0.012
    candle_radius = 0.004
    candle_sink = 0.006  # how deep the candles are pushed into the cake

    def expected_counts(self, params=None):
        p = self.space.validate(params)
        return 1 + p["tiers"] + p["candles"], 1 + p["tiers"] + (1 if p["candles"] > 0 else 0)

    def _build(self, p) -> Shape:
        builder = ShapeBuilder().add(_plate(p["radius"] + p["plate_margin"], self.plate_thickness), "plate")
        z = 0.6 * self.plate_thickness  # the plate's well
        radii = p["radius"] * p["shrink"] ** np.arange(p["tiers"])
        for i, radius in enumerate(radii):
            builder.add(P.transform(_cake_tier(radius, p["tier_height"]), t=(0.0, 0.0, z)), tier_label(i, p["tiers"]))
            z += p["tier_height"]
        candle = _candle(self.candle_radius, p["candle_height"])
        ring = 0.6 * radii[-1]
        for k in range(p["candles"]):
            phi = 2 * np.pi * k / p["candles"]
            builder.add(P.transform(candle, t=(ring * np.cos(phi), ring * np.sin(phi), z - self.candle_sink)), "candle")
        return builder.build(p)


# --------------------------------------------------------------------------------------------- shell
@register
class Shell(ProceduralModel):
    name = "shell"
    description = "Spiral seashell: a tube of growing radius swept along a conical logarithmic helix."
    space = ParamSpace(
        (
            continuous("length", 0.04, 0.15, 0.08, "m", "largest dimension of the shell"),
            continuous("turns", 2.5, 5.5, 4.0, "turns", "number of whorls"),
            continuous("growth", 1.5, 2.6, 1.9, "", "whorl radius ratio per turn"),
            continuous("spire", 0.3, 1.6, 0.9, "", "height of the spire per unit of whorl radius"),
            continuous("aperture", 0.45, 0.75, 0.6, "", "tube radius relative to the whorl radius"),
            continuous("ribbing", 0.0, 0.08, 0.04, "", "relative height of the growth ribs"),
        )
    )
    n_rings = 300
    ribs_per_turn = 9

    def expected_counts(self, params=None):
        self.space.validate(params)
        return 1, 1

    def _spiral(self, p) -> tuple[np.ndarray, np.ndarray]:
        """Centre line (K, 3) and tube radii (K,) in units of the last whorl radius.

        The apex is on the coil (z) axis, the whorls grow downward and the last rings flare into a lip.
        Angles count back from the aperture, so the opening faces the same way for any number of
        turns and the body whorl keeps its place.
        """
        u = np.linspace(0.0, 1.0, self.n_rings)
        angle = 2 * np.pi * p["turns"] * (u - 1.0)
        rho = p["growth"] ** (p["turns"] * (u - 1.0))
        path = np.stack([rho * np.cos(angle), rho * np.sin(angle), -p["spire"] * rho], axis=1)
        ribs = 1.0 + p["ribbing"] * np.cos(self.ribs_per_turn * angle) ** 8
        lip = 1.0 + 0.2 * np.clip((u - 0.97) / 0.03, 0.0, 1.0) ** 2
        return path, p["aperture"] * rho * ribs * lip

    def _build(self, p) -> Shape:
        path, radius = self._spiral(p)
        lo = (path - radius[:, None]).min(axis=0)
        hi = (path + radius[:, None]).max(axis=0)
        scale = p["length"] / float((hi - lo).max())
        # The recessed end cap reads as the opening.
        part = _coil_tube(scale * path, scale * radius, n_sides=20, cap_offset=-0.6)
        # Stand the shell on z=0; the coil axis is the z axis.
        part = P.transform(part, t=(0.0, 0.0, -part.vertices[:, 2].min()))
        return ShapeBuilder().add(part, "shell").build(p)
