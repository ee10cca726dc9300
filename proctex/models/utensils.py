"""Utensils: fork.

Same conventions as the furniture models: metres, +z up, lying on z = 0, length along y with the
handle towards the front (-y) and the tines towards the back (+y), centred at x = y = 0.
"""

from __future__ import annotations

import numpy as np

from proctex.geometry import primitives as P
from proctex.geometry.shape import ProceduralModel, Shape, ShapeBuilder
from ..params import ParamSpace, continuous, integer
from .registry import register

HEAD_LENGTH = 0.028
HEAD_THICKNESS = 0.0022
TINE_THICKNESS = 0.0018
NECK = 0.45  # neck width as a fraction of the handle width
TINE_OVERLAP = 0.002  # how far each tine reaches back into the head
TINE_RINGS = 3.0  # adaptive: rings per width along a tine (it tapers and curls)


@register
class Fork(ProceduralModel):
    name = "fork"
    description = "Table fork: tapered, bent handle, flat head plate and 2-5 thin pointed tines touching it."
    edge_length = 0.0035  # target edge length (m) of the adaptive tessellation
    space = ParamSpace(
        (
            continuous("length", 0.16, 0.22, 0.19, "m", "overall length"),
            continuous("handle_width", 0.01, 0.016, 0.013, "m", "width of the handle at its end"),
            continuous("head_width", 0.018, 0.03, 0.024, "m", "width of the head at the tines"),
            integer("tines", 2, 5, 4, "count", "number of tines"),
            continuous("tine_length", 0.03, 0.05, 0.04, "m", "length of the tines"),
            continuous("handle_rise", 0.0, 0.02, 0.01, "m", "how far the handle end is bent up"),
        )
    )

    def expected_counts(self, params=None):
        p = self.space.validate(params)
        return 2 + p["tines"], 3

    def _build(self, p) -> Shape:
        length, tine_len, n = p["length"], p["tine_length"], p["tines"]
        y_butt = -length / 2
        y_neck = length / 2 - tine_len - HEAD_LENGTH
        y_head = y_neck + HEAD_LENGTH  # where the tines start
        e = self.target_edge
        sb = ShapeBuilder()
        sb.add(self._handle(p["handle_width"], y_butt, y_neck, p["handle_rise"], e), "handle")
        sb.add(self._head(NECK * p["handle_width"], p["head_width"], y_neck, e), "head")
        pitch = p["head_width"] / n
        tine_w = min(0.0035, 0.6 * pitch)
        tine = self._tine(tine_w, tine_len + TINE_OVERLAP, e)
        xs = (np.arange(n) - (n - 1) / 2) * pitch
        for part in P.translated(tine, [(x, y_head - TINE_OVERLAP, 0.0) for x in xs]):
            sb.add(part, "tine")
        return sb.build(p)

    @staticmethod
    def _handle(width: float, y_butt: float, y_neck: float, rise: float, e: float | None = None) -> P.Part:
        """Handle from the butt to the neck: narrows and thins towards the neck, butt bent up by ``rise``.

        Overlaps the head by 3 mm at the neck; bottom of the neck end at z = 0. ``e``: target edge
        length (m) of the adaptive tessellation, None for the fixed one.
        """
        length = y_neck - y_butt + 0.003
        thickness = 0.004
        r = 0.0012

        def shape(local: np.ndarray, canonical: np.ndarray) -> np.ndarray:
            to_neck = canonical[:, 1]  # 0 at the butt, 1 at the neck
            local[:, 0] *= 1.0 - (1.0 - NECK) * to_neck**1.5
            local[:, 2] = (local[:, 2] + thickness / 2) * (1.0 - 0.4 * to_neck)
            local[:, 2] += rise * (1.0 - to_neck) ** 2
            local[:, 1] += y_butt + length / 2
            return local

        rounding = (r, 0.0, r)  # round the four long edges
        size = (width, length, thickness)
        middle = None if e is None else P.rounded_box_middle(size, rounding, rounding, e)
        return P.rounded_box(size, (0.0, 0.0, 0.0), (5, 24, 3), rounding, rounding, 1, shape, middle)

    @staticmethod
    def _head(neck_width: float, head_width: float, y_neck: float, e: float | None = None) -> P.Part:
        """Flat trapezoidal plate widening from ``neck_width`` to ``head_width`` over HEAD_LENGTH
        (``e``: adaptive target edge length, m, or None)."""

        def widen(local: np.ndarray, canonical: np.ndarray) -> np.ndarray:
            flare = canonical[:, 1] ** 0.7
            local[:, 0] *= (neck_width + (head_width - neck_width) * flare) / head_width
            return local

        size = (head_width, HEAD_LENGTH, HEAD_THICKNESS)
        div = (6, 6, 1) if e is None else P.box_divisions(size, e)
        return P.box(size, (0.0, y_neck + HEAD_LENGTH / 2, HEAD_THICKNESS / 2), div, widen)

    @staticmethod
    def _tine(width: float, length: float, e: float | None = None) -> P.Part:
        """Thin tine with its base centred at the origin, running to +y, tapering to a point, tip
        curled up (``e``: adaptive target edge length, m, or None)."""

        def point(local: np.ndarray, canonical: np.ndarray) -> np.ndarray:
            along = canonical[:, 1]
            local[:, 0] *= 1.0 - 0.75 * along**2
            local[:, 2] *= 1.0 - 0.3 * along
            local[:, 1] += length / 2
            local[:, 2] += TINE_THICKNESS / 2 + 0.06 * length * along**2
            return local

        size = (width, length, TINE_THICKNESS)
        div = (1, 8, 1) if e is None else P.box_divisions(size, e, rings_per_width=TINE_RINGS)
        return P.box(size, (0.0, 0.0, 0.0), div, point)
