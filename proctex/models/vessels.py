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
from proctex.geometry import sweeps as S
from proctex.geometry.shape import ProceduralModel, Shape, ShapeBuilder

from ..params import ParamSpace, continuous
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
            return ShapeBuilder().add(S.revolve(rr, hh, s, n_theta=48), "body").build(p)
        # Adaptive: the smoothed 24-sample outline is the reference polyline, resampled.
        n_theta, along = P.revolve_resolution(float(r.max()), e, minimum=16)
        ring = np.arange(len(t), dtype=float)

        def outer(kappa: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
            return np.interp(kappa, ring, r), np.interp(kappa, ring, z)

        rr, hh, s = vessel_profile_curve(outer, (0.0, len(t) - 1.0), p["wall"], 0.02 * p["height"], along, min_outer=6)
        return ShapeBuilder().add(S.revolve(rr, hh, s, n_theta=n_theta), "body").build(p)


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
    return S.ring_surface(rings, s, start, end, phi=phi)


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
            rr, hh, s = vessel_profile_curve(lambda k: self._outer(p, k), (0.0, float(self.n_bevel), K - 1.0), p["wall"], floor, along, (2, 4))
            return S.revolve(rr, hh, s, n_theta=n_theta)
        b = self.bevel
        ang = np.arange(self.n_bevel) * (np.pi / 2 / self.n_bevel)
        z = np.concatenate([b - b * np.cos(ang), np.linspace(b, p["height"], self.n_side)])
        r = self.outer_radius(p, z)
        r[: self.n_bevel] -= b - b * np.sin(ang)
        # Floor halfway between the first two straight-side rings: the inner profile then always
        # has the same number of rings, so the canonical s values do not depend on the parameters.
        floor = z[self.n_bevel] + 0.5 * (z[self.n_bevel + 1] - z[self.n_bevel])
        rr, hh, s = vessel_profile(r, z, p["wall"], floor=floor)
        return S.revolve(rr, hh, s, n_theta=64)

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
            return S.tube(path, p["handle_thickness"], n_sides=16, up=(0.0, 0.0, 1.0), scale_xy=(1.0, 0.7))
        n_sides, along = P.revolve_resolution(p["handle_thickness"], e, minimum=8)
        u = P.curve_parameters(lambda t: self._handle_path(p, np.pi * t), (0.0, 1.0), along, 8)
        path = self._handle_path(p, np.pi * u)
        s = P.uniform_s(40, u)
        return S.tube(path, p["handle_thickness"], n_sides=n_sides, s=s, up=(0.0, 0.0, 1.0), scale_xy=(1.0, 0.7))

    def _build(self, p) -> Shape:
        return ShapeBuilder().add(self._body(p), "body").add(self._handle(p), "handle").build(p)


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
