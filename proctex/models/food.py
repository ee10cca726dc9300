"""Food-like families: ``pumpkin`` (ribbed body, curled stem), ``mushroom`` (caps on stems, a
cluster whose count varies) and ``cake`` (tiers on a plate, candles). Each registers itself with
:mod:`proctex.models.registry`."""

from __future__ import annotations

import numpy as np

from proctex.geometry import primitives as P
from proctex.geometry import sweeps as S
from proctex.geometry.shape import ProceduralModel, Shape, ShapeBuilder

from ..params import ParamSpace, choice, continuous, integer
from .registry import register
from .vessels import _bent_path, _tilted_placement


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
    edge_length = 0.012  # target edge length (m) of the adaptive tessellation
    detail_edge = 0.004  # the stem and the tendril, separate small objects, have their own finer resolution

    def expected_counts(self, params=None):
        p = self.space.validate(params)
        n = 3 if p["tendril"] else 2
        return n, n

    def _body_profile(self, p, s_new: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray, float, float]:
        """Profile of the oblate body with dimples at both poles, a fixed function of ``s``.

        Returns ``(radius (K,), height (K,), s (K,), z_bottom, z_top)`` at the fixed tessellation's
        ``s`` or at ``s_new`` (K,) in (0, 1); the fixed profile's lowest point is at z=0.
        """
        R = p["radius"]
        H = 2.0 * R * p["squash"]
        s = (np.arange(self.n_rings) + 1.0) / (self.n_rings + 1.0)

        def curve(s_: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
            a = np.pi * s_
            r = R * np.sin(a)
            dimple = np.exp(-((r / (0.3 * R)) ** 2))
            return r, 0.5 * H * (1.0 - np.cos(a)) + np.where(a < np.pi / 2, 0.04 * H, -0.12 * H) * dimple

        r, z = curve(s)
        z_bottom, z_top = 0.04 * H, 0.88 * H
        low = min(z.min(), z_bottom)
        if s_new is not None:
            s = np.asarray(s_new, dtype=float)
            r, z = curve(s)
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
        offset = np.array([0.0, 0.0, base_z - 0.5 * p["stem_radius"]])
        e = self.target_edge
        if e is None:
            t = np.linspace(0.0, 1.0, n)
            path = _bent_path(p["stem_length"], p["stem_bend"], n) + offset
            n_sides, s = 10, None
        else:
            n_sides, along = P.revolve_resolution(1.6 * p["stem_radius"], self.detail_edge, minimum=10)

            def meridian(u: np.ndarray) -> np.ndarray:
                """(k, 4) centre line and radius: its length is the surface's along the stem."""
                return np.column_stack([_bent_path(p["stem_length"], p["stem_bend"], len(u), u), self._stem_radius(p, u)])

            # The flared foot (t < 0.3) is sampled on its own.
            t = P.curve_parameters(meridian, (0.0, 0.3, 1.0), along, (3, 3))
            path = _bent_path(p["stem_length"], p["stem_bend"], len(t), t) + offset
            s = P.uniform_s(n, t)
        return S.tube(path, self._stem_radius(p, t), n_sides=n_sides, s=s, up=(1.0, 0.0, 0.0))

    @staticmethod
    def _stem_radius(p, t: np.ndarray) -> np.ndarray:
        """Stem radii (k,) at curve parameters ``t`` (k,) in [0, 1]: flared foot, thinner tip."""
        return p["stem_radius"] * (1.0 + 0.6 * np.exp(-((t / 0.15) ** 2))) * (1.0 - 0.2 * t)

    def _tendril(self, p, base_z: float) -> P.Part:
        """Thin coil starting inside the stem foot and winding up and away towards -x."""
        R = p["radius"]
        n = 120
        if self.adaptive:
            # Rings by the coil's length at the tendril's own resolution (at least 6 per turn).
            length = P.polyline_length(self._tendril_path(p, base_z, np.linspace(0.0, 1.0, 4 * n)))
            t = np.linspace(0.0, 1.0, P.segment_count(length, self.detail_edge, 24) + 1)
            n_sides = P.ring_points(0.01 * R, self.detail_edge, minimum=8)
            # The angle origin follows the fixed tessellation's frames (the coil winds in 3D).
            normals = S.resampled_normals(self._tendril_path(p, base_z, np.linspace(0.0, 1.0, n)), t)
            path = self._tendril_path(p, base_z, t)
            return S.tube(path, 0.01 * R, n_sides=n_sides, s=P.uniform_s(n, t), normals=normals)
        t = np.linspace(0.0, 1.0, n)
        return S.tube(self._tendril_path(p, base_z, t), 0.01 * R, n_sides=8, up=(0.0, 0.0, 1.0))

    @staticmethod
    def _tendril_path(p, base_z: float, t: np.ndarray) -> np.ndarray:
        """Tendril centre line (k, 3) at curve parameters ``t`` (k,) in [0, 1]."""
        R = p["radius"]
        axis = np.array([-1.0, 0.3, 0.8]) / np.linalg.norm([-1.0, 0.3, 0.8])
        e1 = np.cross(axis, [0.0, 1.0, 0.0])
        e1 /= np.linalg.norm(e1)
        e2 = np.cross(axis, e1)
        coil = 0.06 * R * np.minimum(1.0, t / 0.25)
        turn = 2 * np.pi * 3.5 * t
        return np.array([0.0, 0.0, base_z + 0.5 * p["stem_radius"]]) + 0.5 * R * t[:, None] * axis + coil[:, None] * (np.cos(turn)[:, None] * e1 + np.sin(turn)[:, None] * e2)

    def _build(self, p) -> Shape:
        e = self.target_edge
        if e is None:
            r, z, s, z_bottom, z_top = self._body_profile(p)
            n_theta = self.points_per_rib * p["ribs"]
        else:
            # Points per rib even (every crease sampled), an odd number of rings (the equator is one).
            ribs = p["ribs"]
            n_theta, along = P.revolve_resolution(p["radius"], e, minimum=4 * ribs, multiple=2 * ribs)
            r0, z0, _, _, _ = self._body_profile(p)
            K = P.segment_count(P.polyline_length(np.stack([r0, z0], 1)), along, 9)
            K += 1 - K % 2
            r, z, s, z_bottom, z_top = self._body_profile(p, (np.arange(K) + 1.0) / (K + 1.0))
        body = S.revolve(r, z, s, n_theta=n_theta, z_bottom=z_bottom, z_top=z_top, radial=self._lobes(p["ribs"], p["rib_depth"]))
        builder = ShapeBuilder().add(body, "body").add(self._stem(p, z_top), "stem")
        if p["tendril"]:
            builder.add(self._tendril(p, z_top), "tendril")
        return builder.build(p)


# ------------------------------------------------------------------------------------------ mushroom
def _mushroom_cap_curve(radius: float, dome: float, s: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Cap profile ``(radius (k,), z (k,))`` at canonical ``s`` (k,) in [0.0375, 1): the fixed
    function of ``s`` that :func:`_mushroom_cap` samples (underside linear in ``s``, rim and dome
    linear in their angles)."""
    rim, rise = 0.12 * radius, 0.15 * radius
    inner = radius - rim
    s = np.asarray(s, dtype=float)
    t = 0.15 + 0.85 * (8.0 * s / 0.3 - 1.0) / 7.0
    a = -np.pi / 2 + (np.pi / 2) * (s - 0.3) / 0.15
    b = (np.pi / 2) * (s - 0.45) / 0.55
    r = np.select([s <= 0.3, s <= 0.45], [inner * t, inner + rim * np.cos(a)], radius * np.cos(b))
    z = np.select([s <= 0.3, s <= 0.45], [rise * (1.0 - t**2), rim + rim * np.sin(a)], rim + dome * radius * np.sin(b))
    return r, z


def _mushroom_cap(radius: float, dome: float, n_theta: int = 48, edge: float | None = None) -> P.Part:
    """Closed mushroom cap standing on z=0, centred on the z axis.

    The profile runs from the bottom pole (the centre of the concave underside, where the stem
    enters) out along the gills, round the rim and over the dome to the top pole.

    Args:
        radius: cap radius (m).
        dome: dome height relative to ``radius``.
        edge: target edge length (m) of the adaptive tessellation, None for the fixed one.
    Returns:
        Part; canonical ``s`` in (0, 0.3] underside, (0.3, 0.45] rim, (0.45, 1) dome.
    """
    if edge is not None:
        n_theta, along = P.revolve_resolution(radius, edge, minimum=16)

        def curve(s_: np.ndarray) -> np.ndarray:
            return np.stack(_mushroom_cap_curve(radius, dome, s_), axis=1)

        # The dome's rings stop short of the top pole by one step, as in the fixed tessellation.
        s = P.curve_parameters(curve, (0.0375, 0.3, 0.45, 1.0), along, (3, 2, 4))[:-1]
        r, z = _mushroom_cap_curve(radius, dome, s)
        return S.revolve(r, z, s, n_theta=n_theta, z_bottom=0.15 * radius, z_top=0.12 * radius + dome * radius)
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
    return S.revolve(r, z, s, n_theta=n_theta, z_bottom=rise, z_top=rim + dome * radius)


MUSHROOM_FOOT = 1.35  # foot radius of a mushroom stem relative to its nominal radius


def _mushroom_stem(height: float, radius: float, n_theta: int = 24, edge: float | None = None) -> P.Part:
    """Closed stem standing on z=0 with a bulbous foot (radius ``MUSHROOM_FOOT * radius``),
    slightly narrower at the top (``edge``: adaptive target edge length, m, or None)."""
    if edge is None:
        t = np.linspace(0.0, 1.0, 14)
        r = radius * (1.0 + (MUSHROOM_FOOT - 1.0) * np.exp(-((t / 0.15) ** 2))) * (1.0 - 0.2 * t)
        return S.revolve(r, height * t, n_theta=n_theta)
    n_theta, along = P.revolve_resolution(MUSHROOM_FOOT * radius, edge, minimum=12)

    def profile(u: np.ndarray) -> np.ndarray:
        r = radius * (1.0 + (MUSHROOM_FOOT - 1.0) * np.exp(-((u / 0.15) ** 2))) * (1.0 - 0.2 * u)
        return np.stack([r, height * u], axis=1)

    t = P.curve_parameters(profile, (0.0, 0.3, 1.0), along, (3, 3))  # the bulbous foot on its own
    r, z = profile(t).T
    return S.revolve(r, z, P.uniform_s(14, t), n_theta=n_theta)


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
    edge_length = 0.004  # target edge length (m) of the adaptive tessellation

    def expected_counts(self, params=None):
        p = self.space.validate(params)
        n = p["n_small"]
        return 2 + 2 * n, 2 + (2 if n > 0 else 0)

    def _build(self, p) -> Shape:
        e = self.target_edge
        builder = ShapeBuilder()
        seat = _cap_seat(p["stem_height"], p["cap_radius"], p["cap_dome"])
        builder.add(P.transform(_mushroom_cap(p["cap_radius"], p["cap_dome"], edge=e), t=(0.0, 0.0, seat)), "cap")
        builder.add(_mushroom_stem(p["stem_height"], p["stem_radius"], edge=e), "stem")
        # Small ones: relatively taller, stubbier stems and rounder caps than a scaled copy of the main one.
        k = p["small_scale"]
        small_cap_radius, small_stem_height = k * p["cap_radius"], 1.2 * k * p["stem_height"]
        small_cap = P.transform(
            _mushroom_cap(small_cap_radius, self.small_dome, edge=e),
            t=(0.0, 0.0, _cap_seat(small_stem_height, small_cap_radius, self.small_dome)),
        )
        small_stem_radius = 1.5 * k * p["stem_radius"]
        small_stem = _mushroom_stem(small_stem_height, small_stem_radius, edge=e)
        distance = p["stem_radius"] + 0.9 * small_cap_radius + 0.35 * p["cap_radius"]
        for azimuth in self.small_slots[: p["n_small"]]:
            R, t = _tilted_placement(azimuth, self.small_tilt, distance, MUSHROOM_FOOT * small_stem_radius)
            builder.add(P.transform(small_cap, R, t), "small_cap").add(P.transform(small_stem, R, t), "small_stem")
        return builder.build(p)


# ---------------------------------------------------------------------------------------------- cake
def _cake_tier_curve(radius: float, height: float, s: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Tier profile ``(radius (k,), z (k,))`` at canonical ``s`` (k,) in [0, 1]: the fixed function of
    ``s`` that :func:`_cake_tier` samples (piecewise linear on the faces and the side, linear in the
    angle on the rounded edge)."""
    edge = 0.15 * height
    s = np.asarray(s, dtype=float)
    bottom = np.interp(s, [0.0, 0.05, 0.1, 0.15, 0.2], radius * np.array([0.0, 0.3, 0.6, 0.9, 1.0]))
    a = (np.pi / 2) * (s - 0.6) / 0.2
    top = (radius - edge) * (1.0 - (s - 0.8) / 0.2)
    r = np.select([s <= 0.2, s <= 0.6, s <= 0.8], [bottom, np.full_like(s, radius), radius - edge + edge * np.cos(a)], top)
    side = (height - edge) * (s - 0.2) / 0.4
    rounded = height - edge + edge * np.sin(a)
    z = np.select([s <= 0.2, s <= 0.6, s <= 0.8], [np.zeros_like(s), side, rounded], np.full_like(s, height))
    return r, z


def _cake_tier(radius: float, height: float, n_theta: int = 72, e: float | None = None) -> P.Part:
    """Closed cylindrical tier standing on z=0 with a rounded, scalloped frosting edge on top.

    Canonical ``s``: (0, 0.2) bottom face, [0.2, 0.6] side, (0.6, 0.8) top edge, [0.8, 1) top face.
    ``e``: target edge length (m) of the adaptive tessellation, None for the fixed one.
    """

    def scallops(theta: np.ndarray, s_: np.ndarray) -> np.ndarray:
        """Frosting ripple (K, N) on the top edge and the upper rim of the side."""
        bump = np.exp(-(((s_ - 0.62) / 0.06) ** 2))
        return 1.0 + 0.012 * bump[:, None] * np.cos(24 * theta)[None, :]

    if e is not None:
        n_theta, along = P.revolve_resolution(radius, e, minimum=48)

        def curve(s_: np.ndarray) -> np.ndarray:
            return np.stack(_cake_tier_curve(radius, height, s_), axis=1)

        s = P.curve_parameters(curve, (0.0, 0.15, 0.2, 0.6, 0.8, 1.0), along, (2, 1, 2, 3, 2))[1:-1]
        r, z = _cake_tier_curve(radius, height, s)
        return S.revolve(r, z, s, n_theta=n_theta, radial=scallops)
    edge = 0.15 * height  # radius of the rounded top edge
    bottom_r = radius * np.array([0.3, 0.6, 0.9, 1.0])
    side_t = np.linspace(0.0, 1.0, 8)
    side_z = (height - edge) * side_t
    a = np.linspace(0.0, np.pi / 2, 6)[1:-1]
    edge_r, edge_z = radius - edge + edge * np.cos(a), height - edge + edge * np.sin(a)
    top_r = (radius - edge) * np.array([1.0, 0.75, 0.5, 0.25])
    r = np.concatenate([bottom_r[:-1], np.full(8, radius), edge_r, top_r])
    z = np.concatenate([np.zeros(3), side_z, edge_z, np.full(4, height)])
    s = np.concatenate([0.2 * np.arange(1, 4) / 4, 0.2 + 0.4 * side_t, 0.6 + 0.2 * np.arange(1, 5) / 5, 0.8 + 0.2 * np.arange(4) / 4])
    return S.revolve(r, z, s, n_theta=n_theta, radial=scallops)


def _plate(radius: float, thickness: float, n_theta: int = 72, e: float | None = None) -> P.Part:
    """Closed flat plate standing on z=0: a foot ring, a shallow well and a raised rim (``e``:
    adaptive target edge length, m, or None: then every span of the profile is subdivided)."""
    r = radius * np.array([0.55, 0.6, 0.93, 1.0, 1.0, 0.96, 0.85, 0.7])
    z = thickness * np.array([0.0, 0.0, 0.35, 0.8, 1.0, 1.0, 0.7, 0.6])
    if e is None:
        return S.revolve(r, z, n_theta=n_theta)
    n_theta, along = P.revolve_resolution(radius, e, minimum=48)
    s = (np.arange(len(r)) + 1.0) / (len(r) + 1.0)
    r, z, s = P.subdivide_profile(r, z, s, z[0], z[-1], along)
    return S.revolve(r, z, s, n_theta=n_theta)


def _candle_curve(radius: float, height: float, kappa: np.ndarray) -> np.ndarray:
    """Candle profile (k, 2) of ``(radius, z)`` at ring parameters ``kappa`` (k,) in [0, 15]; the
    integers are the fixed tessellation's 16 rings: wax 0-5, straight spans over the top and up the
    wick 5-8, a straight span 8-9 to the first flame ring, the flame 9-15 linear in its angle."""
    wick, flame = 0.25 * radius, 3.0 * radius
    kappa = np.asarray(kappa, dtype=float)
    base = height + 0.8 * radius

    def flame_at(a: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        return np.maximum(2.2 * radius * np.sin(a) * np.exp(-0.7 * a), 0.2 * wick), base + flame * (1.0 - np.cos(a)) / 2

    fr, fz = flame_at(np.pi * (kappa - 8.0) / 8.0)
    first_r, first_z = flame_at(np.array(np.pi / 8.0))
    table = [5.0, 6.0, 7.0, 8.0, 9.0]
    r_tab = np.interp(kappa, table, [radius, 0.8 * radius, wick, wick, float(first_r)])
    z_tab = np.interp(kappa, table, [height, height, height, base, float(first_z)])
    r = np.select([kappa <= 5, kappa <= 9], [np.full_like(kappa, radius), r_tab], fr)
    z = np.select([kappa <= 5, kappa <= 9], [height * kappa / 5, z_tab], fz)
    return np.stack([r, z], axis=1)


def _candle(radius: float, height: float, e: float | None = None) -> P.Part:
    """Closed candle standing on z=0: a wax stick, a thin wick and a teardrop flame on top
    (``e``: adaptive target edge length, m, or None)."""
    wick, flame = 0.25 * radius, 3.0 * radius
    if e is not None:
        n_theta, along = P.revolve_resolution(radius, e, minimum=12)
        knots, mins = (0, 5, 6, 7, 8, 9, 15), (2, 1, 1, 1, 1, 3)
        kappa = P.curve_parameters(lambda k: _candle_curve(radius, height, k), knots, along, mins)
        prof = _candle_curve(radius, height, kappa)
        return S.revolve(prof[:, 0], prof[:, 1], (kappa + 1.0) / 17.0, n_theta=n_theta, z_top=height + 0.8 * radius + flame)
    a = np.linspace(0.0, np.pi, 9)[1:-1]
    flame_r = 2.2 * radius * np.sin(a) * np.exp(-0.7 * a)
    flame_z = height + 0.8 * radius + flame * (1.0 - np.cos(a)) / 2
    r = np.concatenate([np.full(6, radius), [0.8 * radius, wick, wick], np.maximum(flame_r, 0.2 * wick)])
    z = np.concatenate([np.linspace(0.0, height, 6), [height, height, height + 0.8 * radius], flame_z])
    return S.revolve(r, z, n_theta=16, z_top=height + 0.8 * radius + flame)


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
    edge_length = 0.012  # target edge length (m) of the adaptive tessellation

    def expected_counts(self, params=None):
        p = self.space.validate(params)
        return 1 + p["tiers"] + p["candles"], 1 + p["tiers"] + (1 if p["candles"] > 0 else 0)

    def _build(self, p) -> Shape:
        e = self.target_edge
        builder = ShapeBuilder().add(_plate(p["radius"] + p["plate_margin"], self.plate_thickness, e=e), "plate")
        z = 0.6 * self.plate_thickness  # the plate's well
        radii = p["radius"] * p["shrink"] ** np.arange(p["tiers"])
        for i, radius in enumerate(radii):
            builder.add(P.transform(_cake_tier(radius, p["tier_height"], e=e), t=(0.0, 0.0, z)), tier_label(i, p["tiers"]))
            z += p["tier_height"]
        candle = _candle(self.candle_radius, p["candle_height"], e)
        ring = 0.6 * radii[-1]
        for k in range(p["candles"]):
            phi = 2 * np.pi * k / p["candles"]
            builder.add(P.transform(candle, t=(ring * np.cos(phi), ring * np.sin(phi), z - self.candle_sink)), "candle")
        return builder.build(p)
