"""Part-level texture edits on one group texture (issue 5 item 5): pure functions, arrays in and out.

- :func:`shift_hsv`: hue rotation, saturation and value scaling inside a mask.
- :func:`place_image`: an RGB(A) image (a logo) placed at a UV spot, rotated, alpha-blended.
- :func:`load_overlay`: any image file Pillow reads -> (H, W, 4) float32 RGBA in [0, 1].

Textures follow :mod:`proctex.texture.uv`: ``(H, W, 3)`` (or ``(H, W, 4)``) float in [0, 1] or uint8, row 0 at
the top; UVs are OpenGL-style (u right, v up), texel (i, j) has its centre at ``u = (j + 0.5) / W``,
``v = 1 - (i + 0.5) / H``. Every edit returns a new array of the input's dtype and shape; texels outside
the mask (and, for :func:`place_image`, outside the overlay's footprint) are bit-identical to the input.
Edits apply to every shape of a family by re-baking from the edited group texture.

The tests compare it with slow, obviously correct per-texel versions (:mod:`proctex._reference.edit`).
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
from PIL import Image, UnidentifiedImageError


# ------------------------------------------------------------------------------------- validation
def _check_texture(texture, name: str = "texture", channels=(3, 4)) -> tuple[np.ndarray, np.ndarray]:
    """(original array, float64 working copy in [0, 1])."""
    t = np.asarray(texture)
    if t.ndim != 3 or t.shape[2] not in channels or t.shape[0] < 1 or t.shape[1] < 1:
        raise ValueError(f"{name} must be (H, W, C) with C in {channels}, got shape {t.shape}")
    if t.dtype == np.uint8:
        return t, t.astype(np.float64) / 255.0
    if not np.issubdtype(t.dtype, np.floating):
        raise ValueError(f"{name} must be uint8 or floating point, got dtype {t.dtype}")
    if not np.isfinite(t).all():
        raise ValueError(f"{name} contains NaN or inf")
    if t.min() < 0.0 or t.max() > 1.0:
        raise ValueError(f"{name} values must be in [0, 1], got [{float(t.min()):.4g}, {float(t.max()):.4g}]")
    return t, t.astype(np.float64)


def _check_mask(mask, shape: tuple[int, int]) -> np.ndarray:
    if mask is None:
        return np.ones(shape, bool)
    m = np.asarray(mask)
    if m.shape != shape:
        raise ValueError(f"mask must be (H, W) = {shape}, got shape {m.shape}")
    if m.dtype != bool:
        if not (np.issubdtype(m.dtype, np.integer) or np.issubdtype(m.dtype, np.floating)) or not np.isin(m, (0, 1)).all():
            raise ValueError(f"mask must be boolean, got dtype {m.dtype}")
        m = m.astype(bool)
    return m


def _finite(name: str, x, lo: float | None = None, hi: float | None = None, lo_open: bool = False) -> float:
    try:
        v = float(x)
    except (TypeError, ValueError):
        raise ValueError(f"{name} must be a number, got {x!r}") from None
    if not math.isfinite(v):
        raise ValueError(f"{name} must be finite, got {x!r}")
    if lo is not None and (v < lo or (lo_open and v == lo)):
        raise ValueError(f"{name} must be {'>' if lo_open else '>='} {lo}, got {x!r}")
    if hi is not None and v > hi:
        raise ValueError(f"{name} must be <= {hi}, got {x!r}")
    return v


def _vec2(name: str, x) -> np.ndarray:
    a = np.asarray(x, dtype=np.float64) if not isinstance(x, str) else np.array([np.nan])
    if a.shape != (2,):
        raise ValueError(f"{name} must be a pair (2,), got shape {a.shape}")
    if not np.isfinite(a).all():
        raise ValueError(f"{name} must be finite, got {x!r}")
    return a


def _store(orig: np.ndarray, work: np.ndarray, change: np.ndarray) -> np.ndarray:
    """Copy of ``orig`` with the texels in ``change`` taken from ``work`` (float64 in [0, 1])."""
    out = orig.copy()
    vals = np.clip(work[change], 0.0, 1.0)
    if orig.dtype == np.uint8:
        out[change] = np.rint(vals * 255.0).astype(np.uint8)
    else:
        out[change] = vals.astype(orig.dtype)
    return out


# ------------------------------------------------------------------------------------------- HSV
def rgb_to_hsv(rgb: np.ndarray) -> np.ndarray:
    """(..., 3) RGB in [0, 1] -> (..., 3) HSV, hue in [0, 1) turns, as :mod:`colorsys` (vectorised)."""
    rgb = np.asarray(rgb, dtype=np.float64)
    r, g, b = rgb[..., 0], rgb[..., 1], rgb[..., 2]
    maxc = rgb.max(axis=-1)
    minc = rgb.min(axis=-1)
    delta = maxc - minc
    safe = np.where(delta > 0, delta, 1.0)
    s = np.where(maxc > 0, delta / np.where(maxc > 0, maxc, 1.0), 0.0)
    h = np.where(
        maxc == r,
        (g - b) / safe,
        np.where(maxc == g, 2.0 + (b - r) / safe, 4.0 + (r - g) / safe),
    )
    h = np.where(delta > 0, (h / 6.0) % 1.0, 0.0)
    return np.stack([h, s, maxc], axis=-1)


def hsv_to_rgb(hsv: np.ndarray) -> np.ndarray:
    """(..., 3) HSV (hue in turns, any real; s, v in [0, 1]) -> (..., 3) RGB, as :mod:`colorsys`."""
    hsv = np.asarray(hsv, dtype=np.float64)
    h, s, v = hsv[..., 0] % 1.0, hsv[..., 1], hsv[..., 2]
    h6 = h * 6.0
    i = np.floor(h6)
    f = h6 - i
    i = i.astype(np.int64) % 6
    p = v * (1.0 - s)
    q = v * (1.0 - s * f)
    t = v * (1.0 - s * (1.0 - f))
    r = np.choose(i, [v, q, p, p, t, v])
    g = np.choose(i, [t, v, v, q, p, p])
    b = np.choose(i, [p, p, t, v, v, q])
    return np.stack([r, g, b], axis=-1)


def shift_hsv(
    texture: np.ndarray,
    mask: np.ndarray | None = None,
    hue_deg: float = 0.0,
    saturation: float = 1.0,
    value: float = 1.0,
) -> np.ndarray:
    """Rotate hue by ``hue_deg`` degrees and scale saturation and value (clipped to [0, 1]) inside ``mask``.

    Args:
        texture: (H, W, 3|4) float in [0, 1] or uint8 (an alpha channel is kept as is).
        mask: (H, W) bool texels to edit (default: all), e.g. the group's painted texels.
        hue_deg: any finite angle; saturation, value: finite scales >= 0.

    Returns:
        A new texture, same shape and dtype; texels outside ``mask`` are bit-identical. A pure hue
        rotation is inverted by the opposite rotation (up to float rounding; uint8 adds quantisation),
        and greys (r = g = b) stay grey under any hue shift.
    """
    orig, work = _check_texture(texture)
    m = _check_mask(mask, orig.shape[:2])
    hue = _finite("hue_deg", hue_deg)
    sat = _finite("saturation", saturation, lo=0.0)
    val = _finite("value", value, lo=0.0)
    whole = bool(m.all())  # the common case (no mask): no gathering and scattering of texels
    hsv = rgb_to_hsv(work[..., :3].reshape(-1, 3) if whole else work[m][:, :3])
    hsv[:, 0] = (hsv[:, 0] + hue / 360.0) % 1.0
    hsv[:, 1] = np.clip(hsv[:, 1] * sat, 0.0, 1.0)
    hsv[:, 2] = np.clip(hsv[:, 2] * val, 0.0, 1.0)
    if whole:
        work[..., :3] = hsv_to_rgb(hsv).reshape(work.shape[:2] + (3,))
        vals = np.clip(work, 0.0, 1.0)
        return np.rint(vals * 255.0).astype(np.uint8) if orig.dtype == np.uint8 else vals.astype(orig.dtype)
    work = work.copy()
    sub = work[m]
    sub[:, :3] = hsv_to_rgb(hsv)
    work[m] = sub
    return _store(orig, work, m)


# ------------------------------------------------------------------------------------ placement
def _overlay_rgba(overlay) -> np.ndarray:
    o = np.asarray(overlay)
    if o.ndim != 3 or o.shape[2] not in (3, 4) or o.shape[0] < 1 or o.shape[1] < 1:
        raise ValueError(f"overlay must be (h, w, 3) RGB or (h, w, 4) RGBA, got shape {o.shape}")
    _, work = _check_texture(o, "overlay")
    if work.shape[2] == 3:
        work = np.concatenate([work, np.ones(work.shape[:2] + (1,))], axis=2)
    return work


def _prefilter(rgba: np.ndarray, target_w: float, target_h: float) -> np.ndarray:
    """Area-downsample a premultiplied overlay much larger than its footprint (avoids aliasing)."""
    h, w = rgba.shape[:2]
    nw, nh = max(1, int(math.ceil(target_w))), max(1, int(math.ceil(target_h)))
    if w < 2 * nw and h < 2 * nh:
        return rgba
    nw, nh = min(nw, w), min(nh, h)
    chans = [np.asarray(Image.fromarray(np.ascontiguousarray(rgba[..., c], dtype=np.float32)).resize((nw, nh), Image.BOX)) for c in range(4)]
    return np.stack(chans, axis=-1).astype(np.float64)


def _footprint(shape, center, size, rotation_deg):
    """Texel rows/cols window covering the rotated rectangle, and its overlay coordinates (x, y)."""
    H, W = shape
    th = math.radians(rotation_deg)
    c, s = math.cos(th), math.sin(th)
    hx = 0.5 * (abs(c) * size[0] + abs(s) * size[1])
    hy = 0.5 * (abs(s) * size[0] + abs(c) * size[1])
    j0 = max(0, int(math.floor((center[0] - hx) * W - 0.5)))
    j1 = min(W - 1, int(math.ceil((center[0] + hx) * W - 0.5)))
    i0 = max(0, int(math.floor((1.0 - (center[1] + hy)) * H - 0.5)))
    i1 = min(H - 1, int(math.ceil((1.0 - (center[1] - hy)) * H - 0.5)))
    if j0 > j1 or i0 > i1:
        return None
    ii, jj = np.mgrid[i0 : i1 + 1, j0 : j1 + 1]
    du = (jj + 0.5) / W - center[0]
    dv = 1.0 - (ii + 0.5) / H - center[1]
    # rotate the texel offset by -theta into the overlay's frame; x right, y up, both in [0, 1] inside
    x = (c * du + s * dv) / size[0] + 0.5
    y = (-s * du + c * dv) / size[1] + 0.5
    return (slice(i0, i1 + 1), slice(j0, j1 + 1)), x, y


def _bilinear(img: np.ndarray, row: np.ndarray, col: np.ndarray) -> np.ndarray:
    h, w = img.shape[:2]
    row = np.clip(row, 0.0, h - 1)
    col = np.clip(col, 0.0, w - 1)
    r0 = np.minimum(np.floor(row).astype(np.int64), max(h - 2, 0))
    c0 = np.minimum(np.floor(col).astype(np.int64), max(w - 2, 0))
    r1 = np.minimum(r0 + 1, h - 1)
    c1 = np.minimum(c0 + 1, w - 1)
    fr = (row - r0)[..., None]
    fc = (col - c0)[..., None]
    top = img[r0, c0] + (img[r0, c1] - img[r0, c0]) * fc  # lerp form: exact on constant regions
    bot = img[r1, c0] + (img[r1, c1] - img[r1, c0]) * fc
    return top + (bot - top) * fr


def place_image(
    texture: np.ndarray,
    overlay: np.ndarray,
    center_uv,
    size_uv,
    rotation_deg: float = 0.0,
    opacity: float = 1.0,
    mask: np.ndarray | None = None,
) -> np.ndarray:
    """Alpha-blend an RGB(A) image onto a texture over a rotated UV rectangle.

    Args:
        texture: (H, W, 3|4) float in [0, 1] or uint8 (an RGBA texture is composited "over").
        overlay: (h, w, 3|4) float in [0, 1] or uint8; RGB counts as opaque. Its row 0 is its top, which
            lands at the high-v side of the rectangle (upright when the texture is shown row 0 on top).
        center_uv: (2,) rectangle centre (u, v). size_uv: (2,) its width and height in UV units, > 0.
        rotation_deg: counter-clockwise rotation in the UV plane (u right, v up) about the centre.
        opacity: in [0, 1], multiplies the overlay's alpha.
        mask: (H, W) bool texels allowed to change (e.g. the group's painted texels); default all.

    A texel changes iff its centre lies in the closed rectangle, it is in ``mask`` and the overlay's
    alpha x opacity there is > 0. The overlay is sampled bilinearly (premultiplied alpha, edge-clamped;
    area-prefiltered first when it is more than twice its footprint in texels); the rectangle's edge is
    hard (no antialiasing). Parts of the rectangle outside [0, 1]^2 are clipped (no wrapping).
    """
    orig, work = _check_texture(texture)
    H, W = orig.shape[:2]
    rgba = _overlay_rgba(overlay)
    center = _vec2("center_uv", center_uv)
    size = _vec2("size_uv", size_uv)
    if (size <= 0).any():
        raise ValueError(f"size_uv must be > 0, got {size_uv!r}")
    rot = _finite("rotation_deg", rotation_deg)
    op = _finite("opacity", opacity, lo=0.0, hi=1.0)
    m = _check_mask(mask, (H, W))
    fp = _footprint((H, W), center, size, rot)
    if fp is None or op == 0.0:
        return orig.copy()
    win, x, y = fp
    prem = rgba.copy()
    prem[..., :3] *= prem[..., 3:]
    prem = _prefilter(prem, size[0] * W, size[1] * H)
    h, w = prem.shape[:2]
    inside = (x >= 0.0) & (x <= 1.0) & (y >= 0.0) & (y <= 1.0) & m[win]
    s = _bilinear(prem, (1.0 - y[inside]) * h - 0.5, x[inside] * w - 0.5)
    a = s[:, 3] * op
    rgb = np.where(s[:, 3:] > 0, s[:, :3] / np.where(s[:, 3:] > 0, s[:, 3:], 1.0), 0.0)
    change = np.zeros((H, W), bool)
    sub_change = inside.copy()
    sub_change[inside] = a > 0
    change[win] = sub_change
    keep = a > 0
    a, rgb = a[keep, None], rgb[keep]
    work = work.copy()
    t = work[change]
    t[:, :3] = t[:, :3] * (1.0 - a) + rgb * a
    if t.shape[1] == 4:
        t[:, 3:] = a + t[:, 3:] * (1.0 - a)
    work[change] = t
    return _store(orig, work, change)


# ---------------------------------------------------------------------------------------- files
def load_overlay(path: str | Path) -> np.ndarray:
    """Read an image file into (H, W, 4) float32 RGBA in [0, 1].

    Any Pillow mode is accepted: palette/grey/CMYK/with or without alpha via RGBA conversion, 16- and
    32-bit integer greys scaled by 65535, float greys clipped to [0, 1]. Raises ``ValueError`` for a
    missing, unreadable or empty file.
    """
    p = Path(path)
    try:
        with Image.open(p) as im:
            im.load()
            if im.mode in ("I", "I;16", "I;16B", "I;16L", "I;16N", "F"):
                g = np.asarray(im, dtype=np.float64)
                g = g if im.mode == "F" else g / 65535.0
                g = np.clip(np.nan_to_num(g, nan=0.0), 0.0, 1.0)
                out = np.stack([g, g, g, np.ones_like(g)], axis=-1)
            else:
                out = np.asarray(im.convert("RGBA"), dtype=np.float64) / 255.0
    except (FileNotFoundError, IsADirectoryError, UnidentifiedImageError, OSError, ValueError, Image.DecompressionBombError) as e:
        raise ValueError(f"cannot read image {str(p)!r}: {e}") from None
    if out.shape[0] < 1 or out.shape[1] < 1:
        raise ValueError(f"image {str(p)!r} is empty")
    return out.astype(np.float32)
