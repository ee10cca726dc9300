"""Round things: vase, mug, pumpkin, mushroom, cake, shell.

Builders take ``edge``: ``None`` for the fixed tessellation (the counts written in the code), else
the target edge length (m) of the adaptive tessellation. Adaptive profiles are continuous curves
whose canonical parameter ``s`` is the same fixed function of the curve parameter as in the fixed
tessellation, sampled with counts that follow the part's size.
"""

from __future__ import annotations

from typing import Callable, Sequence

import numpy as np

from proctex.geometry import primitives as P
from proctex.geometry.shape import ProceduralModel, Shape, ShapeBuilder
from ..params import ParamSpace, choice, continuous, integer
from .registry import register


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


def vessel_profile_curve(
    outer: Callable[[np.ndarray], tuple[np.ndarray, np.ndarray]],
    breaks: Sequence[float],
    wall: float,
    floor: float,
    edge: float,
    min_outer: Sequence[int] | int = 1,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Adaptive counterpart of :func:`vessel_profile` for an outer profile given as a curve.

    ``outer(kappa (k,)) -> (radius (k,), z (k,))`` is defined on ``[0, K - 1]``; at the integers it
    gives the fixed tessellation's ``K`` outer rings, so ``vessel_profile(*outer(arange(K)), wall,
    floor)`` is the fixed profile. This one samples the same surface with the same canonical ``s``
    (outside ``s = 0.45 (kappa + 1) / K``, lip linear in its angle, inside linear in ``kappa`` down
    to the fixed profile's floor ring, joined to it by the same straight chord) at counts that
    follow the lengths (target ``edge``, m).

    Args:
        breaks: (b,) increasing knots from 0 to ``K - 1`` (corners of the outer curve, kept as rings).
        min_outer: minimum segments per outer interval between breaks.
    Returns:
        ``(radius, height, s)``, each (k,) float64, as :func:`vessel_profile`.
    """
    breaks = np.asarray(breaks, dtype=float)
    K = int(round(breaks[-1])) + 1
    if breaks[0] != 0.0 or K < 3:
        raise ValueError(f"breaks must run from 0 to K - 1 >= 2, got {breaks}")

    def curve(kappa: np.ndarray) -> np.ndarray:
        return np.stack(outer(np.asarray(kappa, dtype=float)), axis=1)

    ring_r, ring_z = outer(np.arange(K, dtype=float))
    level = ring_z[0] + floor
    # The fixed profile's floor ring: the highest outer ring at or below the floor (moved up to it).
    k_f = int(np.nonzero(np.round(np.maximum(ring_z, level), 12) == np.round(level, 12))[0].max())
    if k_f >= K - 1:
        raise ValueError("the floor is above the rim")
    n_in = K - k_f
    # Outside, up.
    k_out = P.curve_parameters(curve, breaks, edge, min_outer)
    r_out, z_out = outer(k_out)
    s_out = 0.45 * (k_out + 1) / K
    # Lip: half circle over the wall, s linear in its angle.
    n_lip = P.segment_count(np.pi * wall / 2, edge, 3)
    ang = np.pi * np.arange(1, n_lip) / n_lip
    r_lip = r_out[-1] - wall / 2 + (wall / 2) * np.cos(ang)
    z_lip = z_out[-1] + (wall / 2) * np.sin(ang)
    s_lip = 0.45 + 0.1 * ang / np.pi
    # Inside, down to the ring above the floor, then the straight chord to the floor ring.
    knots_in = np.concatenate([[k_f + 1.0], breaks[breaks > k_f + 1]])
    k_in = P.curve_parameters(curve, knots_in, edge)[::-1]
    r_in, z_in = outer(k_in)
    r_in = r_in - wall
    top = np.array([ring_r[k_f + 1] - wall, ring_z[k_f + 1]])
    bottom = np.array([ring_r[k_f] - wall, level])
    n_chord = P.segment_count(float(np.linalg.norm(top - bottom)), edge, 1)
    lam = np.arange(1, n_chord + 1) / n_chord
    chord = top + lam[:, None] * (bottom - top)
    k_all = np.concatenate([k_in, k_f + 1.0 - lam])
    s_in = 0.55 + 0.45 * (K - 1 - k_all) / n_in
    r = np.concatenate([r_out, r_lip, r_in, chord[:, 0]])
    h = np.concatenate([z_out, z_lip, z_in, chord[:, 1]])
    return r, h, np.concatenate([s_out, s_lip, s_in])


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
    edge_length = 0.012  # target edge length (m) of the adaptive tessellation

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
        e = self.target_edge
        if e is None:
            rr, hh, s = vessel_profile(r, z, p["wall"], floor=0.02 * p["height"])
            return ShapeBuilder().add(P.revolve(rr, hh, s, n_theta=48), "body").build(p)
        # Adaptive: the smoothed 24-sample outline is the reference polyline, resampled.
        n_theta, along = P.revolve_resolution(float(r.max()), e, minimum=16)
        ring = np.arange(len(t), dtype=float)

        def outer(kappa: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
            return np.interp(kappa, ring, r), np.interp(kappa, ring, z)

        rr, hh, s = vessel_profile_curve(outer, (0.0, len(t) - 1.0), p["wall"], 0.02 * p["height"], along, min_outer=6)
        return ShapeBuilder().add(P.revolve(rr, hh, s, n_theta=n_theta), "body").build(p)


# ------------------------------------------------------------------------------------------- helpers
def _bent_path(length: float, bend: float, n: int, u: np.ndarray | None = None) -> np.ndarray:
    """(n, 3) float64 centre line starting at the origin along +z and bending towards +x.

    The path is a circular arc of arc length ``length`` turning by ``bend`` (non-zero) radians in
    total, sampled at ``n`` uniform arc lengths, or at the fractions ``u`` (n,) of it when given.
    """
    l = np.linspace(0.0, length, n) if u is None else np.asarray(u, dtype=float) * length
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


def _coil_tube(path: np.ndarray, radius: np.ndarray, n_sides: int, cap_offset: float, s: np.ndarray | None = None) -> P.Part:
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
        s: (K,) canonical profile parameters (default ``(k + 1) / (K + 1)``).
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
    if s is None:
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
    edge_length = 0.005  # target edge length (m) of the adaptive tessellation

    def expected_counts(self, params=None):
        self.space.validate(params)
        return 2, 2

    @staticmethod
    def outer_radius(p, z: np.ndarray | float) -> np.ndarray | float:
        """Outer body radius at height ``z`` (array or scalar, m), ignoring the bottom bevel."""
        return p["radius"] * (1.0 + p["taper"] * np.asarray(z) / p["height"])

    def _outer(self, p, kappa: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Outer profile ``(radius (k,), z (k,))`` at ring parameters ``kappa`` (k,) in [0, K - 1]:
        the bevel on [0, n_bevel], the straight side after it; the integers are the fixed rings."""
        b, nb, K = self.bevel, self.n_bevel, self.n_bevel + self.n_side
        kappa = np.asarray(kappa, dtype=float)
        ang = np.minimum(kappa, nb) * (np.pi / 2 / nb)
        side = np.maximum(kappa - nb, 0.0) / (K - 1 - nb)
        z = np.where(kappa < nb, b - b * np.cos(ang), b + (p["height"] - b) * side)
        r = self.outer_radius(p, z) - np.where(kappa < nb, b - b * np.sin(ang), 0.0)
        return r, z

    def _body(self, p) -> P.Part:
        e = self.target_edge
        if e is not None:
            K = self.n_bevel + self.n_side
            _, z = self._outer(p, np.arange(K, dtype=float))
            floor = z[self.n_bevel] + 0.5 * (z[self.n_bevel + 1] - z[self.n_bevel])
            widest = max(self.outer_radius(p, 0.0), self.outer_radius(p, p["height"]))
            n_theta, along = P.revolve_resolution(float(widest), e, minimum=16)
            rr, hh, s = vessel_profile_curve(
                lambda k: self._outer(p, k), (0.0, float(self.n_bevel), K - 1.0), p["wall"], floor, along, (2, 4)
            )
            return P.revolve(rr, hh, s, n_theta=n_theta)
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

    def _handle_path(self, p, u: np.ndarray) -> np.ndarray:
        """Handle centre line (k, 3) at angles ``u`` (k,) in [0, pi] from its top end."""
        half = 0.5 * p["handle_span"] * p["height"]
        z = 0.5 * p["height"] + half * np.cos(u)
        sink = 0.6 * p["wall"]
        x = self.outer_radius(p, z) - sink + (p["handle_reach"] + sink) * np.sin(u) ** 0.7
        return np.stack([x, np.zeros_like(x), z], axis=1)

    def _handle(self, p) -> P.Part:
        """C-shaped tube on the +x side; its ends sink into the wall (but not through it)."""
        e = self.target_edge
        if e is None:
            path = self._handle_path(p, np.linspace(0.0, np.pi, 40))
            return P.tube(path, p["handle_thickness"], n_sides=16, up=(0.0, 0.0, 1.0), scale_xy=(1.0, 0.7))
        n_sides, along = P.revolve_resolution(p["handle_thickness"], e, minimum=8)
        u = P.curve_parameters(lambda t: self._handle_path(p, np.pi * t), (0.0, 1.0), along, 8)
        path = self._handle_path(p, np.pi * u)
        s = P.uniform_s(40, u)
        return P.tube(path, p["handle_thickness"], n_sides=n_sides, s=s, up=(0.0, 0.0, 1.0), scale_xy=(1.0, 0.7))

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
        return P.tube(path, self._stem_radius(p, t), n_sides=n_sides, s=s, up=(1.0, 0.0, 0.0))

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
            normals = P.resampled_normals(self._tendril_path(p, base_z, np.linspace(0.0, 1.0, n)), t)
            path = self._tendril_path(p, base_z, t)
            return P.tube(path, 0.01 * R, n_sides=n_sides, s=P.uniform_s(n, t), normals=normals)
        t = np.linspace(0.0, 1.0, n)
        return P.tube(self._tendril_path(p, base_z, t), 0.01 * R, n_sides=8, up=(0.0, 0.0, 1.0))

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
        return (
            np.array([0.0, 0.0, base_z + 0.5 * p["stem_radius"]])
            + 0.5 * R * t[:, None] * axis
            + coil[:, None] * (np.cos(turn)[:, None] * e1 + np.sin(turn)[:, None] * e2)
        )

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
        body = P.revolve(r, z, s, n_theta=n_theta, z_bottom=z_bottom, z_top=z_top, radial=self._lobes(p["ribs"], p["rib_depth"]))
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
        return P.revolve(r, z, s, n_theta=n_theta, z_bottom=0.15 * radius, z_top=0.12 * radius + dome * radius)
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


def _mushroom_stem(height: float, radius: float, n_theta: int = 24, edge: float | None = None) -> P.Part:
    """Closed stem standing on z=0 with a bulbous foot (radius ``MUSHROOM_FOOT * radius``),
    slightly narrower at the top (``edge``: adaptive target edge length, m, or None)."""
    if edge is None:
        t = np.linspace(0.0, 1.0, 14)
        r = radius * (1.0 + (MUSHROOM_FOOT - 1.0) * np.exp(-((t / 0.15) ** 2))) * (1.0 - 0.2 * t)
        return P.revolve(r, height * t, n_theta=n_theta)
    n_theta, along = P.revolve_resolution(MUSHROOM_FOOT * radius, edge, minimum=12)

    def profile(u: np.ndarray) -> np.ndarray:
        r = radius * (1.0 + (MUSHROOM_FOOT - 1.0) * np.exp(-((u / 0.15) ** 2))) * (1.0 - 0.2 * u)
        return np.stack([r, height * u], axis=1)

    t = P.curve_parameters(profile, (0.0, 0.3, 1.0), along, (3, 3))  # the bulbous foot on its own
    r, z = profile(t).T
    return P.revolve(r, z, P.uniform_s(14, t), n_theta=n_theta)


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
        return P.revolve(r, z, s, n_theta=n_theta, radial=scallops)
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
    return P.revolve(r, z, s, n_theta=n_theta, radial=scallops)


def _plate(radius: float, thickness: float, n_theta: int = 72, e: float | None = None) -> P.Part:
    """Closed flat plate standing on z=0: a foot ring, a shallow well and a raised rim (``e``:
    adaptive target edge length, m, or None: then every span of the profile is subdivided)."""
    r = radius * np.array([0.55, 0.6, 0.93, 1.0, 1.0, 0.96, 0.85, 0.7])
    z = thickness * np.array([0.0, 0.0, 0.35, 0.8, 1.0, 1.0, 0.7, 0.6])
    if e is None:
        return P.revolve(r, z, n_theta=n_theta)
    n_theta, along = P.revolve_resolution(radius, e, minimum=48)
    s = (np.arange(len(r)) + 1.0) / (len(r) + 1.0)
    r, z, s = P.subdivide_profile(r, z, s, z[0], z[-1], along)
    return P.revolve(r, z, s, n_theta=n_theta)


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
        return P.revolve(prof[:, 0], prof[:, 1], (kappa + 1.0) / 17.0, n_theta=n_theta, z_top=height + 0.8 * radius + flame)
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
    canonical_turns = 5.5  # the most turns the space allows: canonical s runs over this many whorls
    ribs_per_turn = 9
    edge_length = 0.0025  # target edge length (m) of the adaptive tessellation

    def expected_counts(self, params=None):
        self.space.validate(params)
        return 1, 1

    def _spiral(self, p, u: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
        """Centre line (K, 3) and tube radii (K,) in units of the last whorl radius, at the curve
        parameters ``u`` (K,) in [0, 1] (default: the fixed tessellation's ``n_rings`` uniform ones).

        The apex is on the coil (z) axis, the whorls grow downward and the last rings flare into a lip.
        Angles count back from the aperture, so the opening faces the same way for any number of
        turns and the body whorl keeps its place.
        """
        if u is None:
            u = np.linspace(0.0, 1.0, self.n_rings)
        angle = 2 * np.pi * p["turns"] * (u - 1.0)
        rho = p["growth"] ** (p["turns"] * (u - 1.0))
        path = np.stack([rho * np.cos(angle), rho * np.sin(angle), -p["spire"] * rho], axis=1)
        ribs = 1.0 + p["ribbing"] * np.cos(self.ribs_per_turn * angle) ** 8
        lip = 1.0 + 0.2 * np.clip((u - 0.97) / 0.03, 0.0, 1.0) ** 2
        return path, p["aperture"] * rho * ribs * lip

    def _canonical_s(self, p, u: np.ndarray) -> np.ndarray:
        """Canonical profile parameters (K,) of the rings at curve parameters ``u`` (K,): whorls
        counted back from the aperture, ``1 - turns (1 - u) / max turns`` in the fixed rings'
        convention (:func:`primitives.uniform_s`). Shells with more or fewer turns grow or lose
        whorls at the apex, so a point one turn behind the lip is the same point on every shell (a
        fraction of the whole coil would pair a short shell's body whorl with a long one's spire)."""
        return P.uniform_s(self.n_rings, 1.0 - p["turns"] * (1.0 - np.asarray(u, dtype=float)) / self.canonical_turns)

    def _build(self, p) -> Shape:
        path, radius = self._spiral(p)
        lo = (path - radius[:, None]).min(axis=0)
        hi = (path + radius[:, None]).max(axis=0)
        scale = p["length"] / float((hi - lo).max())
        # The recessed end cap reads as the opening.
        part = _coil_tube(scale * path, scale * radius, n_sides=20, cap_offset=-0.6, s=self._canonical_s(p, np.linspace(0.0, 1.0, self.n_rings)))
        # Stand the shell on z=0; the coil axis is the z axis.
        lift = -part.vertices[:, 2].min()
        e = self.target_edge
        if e is not None:
            # Adaptive: same surface (scale and lift come from the fixed reference above), rings by the
            # coil's length, sides by the aperture's circumference.
            n_sides, along = P.revolve_resolution(scale * float(radius.max()), e, minimum=8)
            length = scale * P.polyline_length(path)
            u = np.linspace(0.0, 1.0, P.segment_count(length, along, 60) + 1)
            path_a, radius_a = self._spiral(p, u)
            part = _coil_tube(scale * path_a, scale * radius_a, n_sides=n_sides, cap_offset=-0.6, s=self._canonical_s(p, u))
        part = P.transform(part, t=(0.0, 0.0, lift))
        return ShapeBuilder().add(part, "shell").build(p)
