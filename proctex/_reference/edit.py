"""Slow, obviously correct references of :mod:`proctex.texture.edit` (loops over points, pixels or
texels), which the tests compare the shipped fast versions with; not used by the library."""

from __future__ import annotations

import colorsys
import math

import numpy as np


def shift_hsv_reference(texture, mask=None, hue_deg=0.0, saturation=1.0, value=1.0) -> np.ndarray:
    """Per-texel :mod:`colorsys` version of :func:`shift_hsv` (slow; float textures)."""
    t = np.asarray(texture, dtype=np.float64)
    out = t.copy()
    H, W = t.shape[:2]
    for i in range(H):
        for j in range(W):
            if mask is not None and not mask[i, j]:
                continue
            h, s, v = colorsys.rgb_to_hsv(*t[i, j, :3])
            h = (h + hue_deg / 360.0) % 1.0
            s = min(max(s * saturation, 0.0), 1.0)
            v = min(max(v * value, 0.0), 1.0)
            out[i, j, :3] = colorsys.hsv_to_rgb(h, s, v)
    return out


def place_image_reference(texture, overlay, center_uv, size_uv, rotation_deg=0.0, opacity=1.0, mask=None) -> np.ndarray:
    """Per-texel version of :func:`place_image` (slow; float RGB texture, no prefilter)."""
    t = np.asarray(texture, dtype=np.float64)
    o = np.asarray(overlay, dtype=np.float64)
    if o.shape[2] == 3:
        o = np.concatenate([o, np.ones(o.shape[:2] + (1,))], axis=2)
    h, w = o.shape[:2]
    out = t.copy()
    H, W = t.shape[:2]
    th = math.radians(rotation_deg)
    for i in range(H):
        for j in range(W):
            if mask is not None and not mask[i, j]:
                continue
            du = (j + 0.5) / W - center_uv[0]
            dv = 1.0 - (i + 0.5) / H - center_uv[1]
            x = (math.cos(th) * du + math.sin(th) * dv) / size_uv[0] + 0.5
            y = (-math.sin(th) * du + math.cos(th) * dv) / size_uv[1] + 0.5
            if not (0 <= x <= 1 and 0 <= y <= 1):
                continue
            row = min(max((1 - y) * h - 0.5, 0.0), h - 1)
            col = min(max(x * w - 0.5, 0.0), w - 1)
            r0, c0 = min(int(row), max(h - 2, 0)), min(int(col), max(w - 2, 0))
            r1, c1 = min(r0 + 1, h - 1), min(c0 + 1, w - 1)
            fr, fc = row - r0, col - c0

            def prem(rr, cc):
                return np.concatenate([o[rr, cc, :3] * o[rr, cc, 3], o[rr, cc, 3:]])

            top = prem(r0, c0) + (prem(r0, c1) - prem(r0, c0)) * fc
            bot = prem(r1, c0) + (prem(r1, c1) - prem(r1, c0)) * fc
            acc = top + (bot - top) * fr
            a = acc[3] * opacity
            if a <= 0:
                continue
            rgb = acc[:3] / acc[3]
            out[i, j, :3] = t[i, j, :3] * (1 - a) + rgb * a
    return out
