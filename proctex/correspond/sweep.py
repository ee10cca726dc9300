"""Correspondence of tube-like parts through their sweep charts (:mod:`proctex.geometry.chart`).

A coil with four turns and its template with three, or a rail that grew a bend, are the same
tube swept along different curves. A cage around the part's bounding volume cannot follow that (it
maps the third turn of one coil onto the second of the other: the surfaces coincide in space, not
along the part), but both parts' charts can: a source point at arc-length position ``s`` and angle
``theta`` goes to the template point at the same ``s`` and ``theta``, its offset from the centre
line scaled by the ratio of the two parts' mean radii.

:func:`sweep_field` builds the map of one pair (both parts in their normalised frames); the
correspondence code uses it for parts that are both tube-like and keeps the cage's result unless
the chart's fits the template better (:attr:`proctex.correspond.cage.CageConfig.sweep`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from proctex.geometry.chart import SweepChart, sweep_chart
from proctex.geometry.surface import SurfaceIndex, interpolate


@dataclass
class SweepField:
    """The chart-to-chart map of one source part onto one template part.

    Attributes:
        source, template: the two charts (the source's angles measured from the template's
            reference direction).
        flip: the source's ``s`` runs the other way along the part from the template's.
        scale: template radius over source radius.
        source_index: the source part surface (its normalised frame), to chart arbitrary points.
        source_s: (j,) the source chart's ``s`` per source vertex.
        center, radius: the source part's normalised frame (world points -> chart frame).
    """

    source: SweepChart
    template: SweepChart
    flip: bool
    scale: float
    source_index: SurfaceIndex
    source_s: np.ndarray
    center: np.ndarray
    radius: float

    def map_normalised(self, points: np.ndarray, s: np.ndarray | None = None) -> np.ndarray:
        """Where source points ``(k, 3)`` (source normalised frame, on or near the part) go, in the
        template part's normalised frame. ``s``: their chart positions when known (samples)."""
        p = np.asarray(points, dtype=np.float64)
        if s is None:
            hit = self.source_index.query(p, exact=False)
            s = interpolate(self.source_s[:, None], self.source_index.faces, hit.faces, hit.bary)[:, 0]
        c, t, n, b = self.source.frame(s)
        d = p - c
        a_t, a_n, a_b = np.einsum("kd,kd->k", d, t), np.einsum("kd,kd->k", d, n), np.einsum("kd,kd->k", d, b)
        s_t = 1.0 - s if self.flip else s
        if self.flip:  # the tangent turns round, and with it the binormal (t x n)
            a_t, a_b = -a_t, -a_b
        c2, t2, n2, b2 = self.template.frame(s_t)
        return c2 + self.scale * (a_t[:, None] * t2 + a_n[:, None] * n2 + a_b[:, None] * b2)

    def transform_world(self, points: np.ndarray) -> np.ndarray:
        """Source world points -> template normalised frame."""
        return self.map_normalised((np.asarray(points, dtype=np.float64) - self.center) / self.radius)


def sweep_field(src_vertices: np.ndarray, src_faces: np.ndarray, tpl_chart: SweepChart, align: np.ndarray, center: np.ndarray, radius: float) -> SweepField:
    """The sweep map of a source part (``src_vertices (j, 3)`` in its normalised frame,
    ``src_faces (k, 3)``) onto a template part whose chart is ``tpl_chart`` (its normalised frame).

    ``align (3, 4)``: the pre-alignment ``[A | t]`` between the two frames, used only to tell which
    end of the source is which (the Fiedler vector's sign is arbitrary). ``center, radius``: the
    source's normalised frame, kept for :meth:`SweepField.transform_world`.

    Raises:
        ValueError: the source cannot be charted (:func:`proctex.geometry.chart.sweep_chart`).
    """
    src = sweep_chart(src_vertices, src_faces, reference=tpl_chart.reference)
    align = np.asarray(align, dtype=np.float64)
    a0, a1 = align[:, :3] @ src.centerline[0] + align[:, 3], align[:, :3] @ src.centerline[-1] + align[:, 3]
    b0, b1 = tpl_chart.centerline[0], tpl_chart.centerline[-1]
    flip = bool(np.linalg.norm(a0 - b1) + np.linalg.norm(a1 - b0) < np.linalg.norm(a0 - b0) + np.linalg.norm(a1 - b1))
    s_vert = np.nan_to_num(src.s, nan=0.0)
    return SweepField(src, tpl_chart, flip, float(tpl_chart.radius / max(src.radius, 1e-300)), SurfaceIndex(src_vertices, src_faces), s_vert, np.asarray(center, dtype=np.float64), float(radius))


_CHARTS: dict[tuple[int, int, bytes], SweepChart | None] = {}
_CHARTS_MAX = 64


def template_chart(vertices: np.ndarray, faces: np.ndarray) -> SweepChart | None:
    """The sweep chart of a template part (normalised frame), or None when it cannot be charted
    (several pieces, too large); cached by content, since every pair of a group charts the same
    template part."""
    import hashlib

    v = np.ascontiguousarray(vertices, dtype=np.float64)
    f = np.ascontiguousarray(faces, dtype=np.int64)
    key = (len(v), len(f), hashlib.blake2b(v.tobytes() + f.tobytes(), digest_size=16).digest())
    if key not in _CHARTS:
        try:
            chart: SweepChart | None = sweep_chart(v, f)
        except ValueError:
            chart = None
        if len(_CHARTS) >= _CHARTS_MAX:
            _CHARTS.pop(next(iter(_CHARTS)))
        _CHARTS[key] = chart
    return _CHARTS[key]
