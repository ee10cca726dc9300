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
