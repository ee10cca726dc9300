"""Textile and print patterns (stripes, checks, plaid, dots, patchwork, floral, speckles): the albedo a
prompt's pattern gives a chunk of points, before the material modulates it
(:data:`PATTERN_FUNCS`)."""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np

from . import noise as nz
from .prompt import MaterialSpec
from .shading import F32, TAU, Ctx, _offset, col, lerp, smoothstep


def _palette(spec: MaterialSpec) -> np.ndarray:
    return np.asarray(spec.pattern_colors, dtype=F32).T  # (3, k)


def _bands(c: np.ndarray, widths: np.ndarray, colors: np.ndarray, edge: float) -> np.ndarray:
    """Repeating colour bands along a coordinate ``c`` (in repeats). ``widths (m,)`` sum to 1, ``colors
    (3, m)``; each band blends into the next over ``edge`` (in repeats). Returns ``(3, n)``."""
    r = c - np.floor(c)
    ends = np.cumsum(widths).astype(F32)
    ends[-1] = F32(1.0) + F32(1e-6)
    idx = np.searchsorted(ends, r, side="right")
    np.minimum(idx, len(widths) - 1, out=idx)
    t = smoothstep(0.0, 1.0, (r - (ends[idx] - F32(edge))) * F32(1.0 / edge))
    nxt = (idx + 1) % len(widths)
    a = colors[:, idx]
    return a + (colors[:, nxt] - a) * t


def pattern_stripes(ctx: Ctx, spec: MaterialSpec) -> np.ndarray:
    """Stripes: ~20 bands across the shape (period 0.2 per colour pair); pinstripes are thin lines."""
    pal = _palette(spec)
    k = pal.shape[1]
    period = 0.2 * ctx.scale if not spec.thin_pattern else 0.12 * ctx.scale
    ph = _offset(ctx.seed, "stripes")[0]
    ws = ctx.tri_weights(6)
    planes = ctx.planes(spec.pattern_axis)
    if k == 2:
        f = sum(w * np.cos(TAU * (v * F32(1.0 / period) + F32(ph))) for w, (_, v) in zip(ws, planes))
        t = smoothstep(0.78, 0.93, f) if spec.thin_pattern else smoothstep(-0.2, 0.2, f)
        return lerp(pal[:, :1], pal[:, 1:2], t)
    widths = np.full(k, 1.0 / k)
    edge = 0.012 / (period * k / 2)
    return sum(w * _bands(v * F32(2.0 / (period * k)) + F32(ph), widths, pal, edge) for w, (_, v) in zip(ws, planes))


def pattern_checks(ctx: Ctx, spec: MaterialSpec) -> np.ndarray:
    """Checkerboard of the first two pattern colours, squares 0.16 wide (12 across)."""
    pal = _palette(spec)
    s = F32(math.pi / (0.16 * ctx.scale))
    ox, oy, _ = _offset(ctx.seed, "checks")
    ws = ctx.tri_weights(6)
    f = sum(w * np.sin(u * s + F32(ox)) * np.sin(v * s + F32(oy)) for w, (u, v) in zip(ws, ctx.planes(spec.pattern_axis)))
    return lerp(pal[:, :1], pal[:, 1:2], smoothstep(-0.12, 0.12, f))


# Tartan sett: (palette slot, width units); slot 3 is the thin over-check line.
_SETT = ((0, 8.0), (1, 3.0), (0, 1.5), (2, 4.0), (0, 1.5), (1, 3.0), (3, 0.8))


def pattern_plaid(ctx: Ctx, spec: MaterialSpec) -> np.ndarray:
    """Tartan: warp and weft bands (repeat 0.45) averaged, with a twill diagonal deciding which shows."""
    pal = _palette(spec)[:, :4]
    while pal.shape[1] < 3:  # hand-made specs: extend with a darker main colour
        pal = np.concatenate([pal, pal[:, :1] * F32(0.45)], axis=1)
    if pal.shape[1] < 4:  # the thin over-check line: a light version of the main colour
        pal = np.concatenate([pal[:, :3], np.clip(pal[:, :1] * F32(0.4) + F32(0.6), 0, 1)], axis=1)
    colors = pal[:, [s for s, _ in _SETT]]
    widths = np.array([w for _, w in _SETT])
    widths = widths / widths.sum()
    period = 0.45 * ctx.scale
    edge = 0.01 / period
    ou, ov, _ = _offset(ctx.seed, "plaid")
    twill_k = F32(TAU / (0.03 * ctx.scale))
    out = None
    for w, (u, v) in zip(ctx.tri_weights(6), ctx.planes(spec.pattern_axis)):
        warp = _bands(u * F32(1.0 / period) + F32(ou), widths, colors, edge)
        weft = _bands(v * F32(1.0 / period) + F32(ov), widths, colors, edge)
        twill = F32(0.5) + F32(0.3) * np.sin((u + v) * twill_k)
        c = lerp(weft, warp, twill) * w
        out = c if out is None else out + c
    return out


def pattern_dots(ctx: Ctx, spec: MaterialSpec) -> np.ndarray:
    """Polka dots: staggered rows, spacing 0.16, radius ~0.045; third+ colours vary dot by dot."""
    pal = _palette(spec)
    k = pal.shape[1]
    S = 0.16 * ctx.scale
    R = 0.28
    ou, ov, _ = _offset(ctx.seed, "dots")
    field = None
    dot_col = None
    for i, (w, (u, v)) in enumerate(zip(ctx.tri_weights(6), ctx.planes())):
        cv = v * F32(1.0 / S) + F32(ov)
        row = np.floor(cv)
        cu = u * F32(1.0 / S) + F32(ou) + F32(0.5) * (row - F32(2.0) * np.floor(row * F32(0.5)))
        colu = np.floor(cu)
        du = cu - colu - F32(0.5)
        dv = cv - row - F32(0.5)
        r = np.sqrt(du * du + dv * dv)
        d = (F32(1.0) - smoothstep(R - 0.08, R + 0.08, r)) * w
        field = d if field is None else field + d
        if k > 2:
            pick = 1 + (nz.cell_hash(colu, row, i, ctx.seed_for("dots")) % np.uint32(k - 1)).astype(np.intp)
            c = pal[:, pick] * d
            dot_col = c if dot_col is None else dot_col + c
    t = smoothstep(0.3, 0.7, field)
    if k > 2:
        dots = dot_col / np.maximum(field, F32(1e-6))
        return lerp(pal[:, :1], dots, t)
    return lerp(pal[:, :1], pal[:, 1:2], t)


def pattern_patchwork(ctx: Ctx, spec: MaterialSpec) -> np.ndarray:
    """Patchwork: cellular patches (~0.33 across) of palette colours, some with fine stripes or checks,
    sewn together with dark seams."""
    pal = _palette(spec)
    k = pal.shape[1]
    f1, f2, cell = ctx.cells("patch", 3.0, jitter=0.85)
    idx = np.minimum((cell * F32(k)).astype(np.intp), k - 1)
    base = pal[:, idx]
    kind = (cell * F32(37.0)) % F32(3.0)  # 0..3: plain, striped, checked (per patch)
    x, _, z = ctx.coords(1.0, "patch-inner")
    sk = F32(TAU / (0.06 * ctx.scale))
    stripes = F32(0.5) + F32(0.5) * np.cos(z * sk)
    checks = F32(0.5) + F32(0.5) * np.sin(x * sk) * np.sin(z * sk)
    inner = np.where(kind < 1, F32(0.0), np.where(kind < 2, smoothstep(0.4, 0.6, stripes), smoothstep(0.4, 0.6, checks)))
    base = base * (F32(1.0) - F32(0.28) * inner)
    seam = F32(1.0) - smoothstep(0.03, 0.06, f2 - f1)
    thread = col(tuple(0.35 * c for c in spec.pattern_colors[0]))  # one seam colour: continuous across patches
    return lerp(base, thread, seam)


def pattern_floral(ctx: Ctx, spec: MaterialSpec) -> np.ndarray:
    """Floral-like rosettes: five-petal flowers on a jittered grid (spacing 0.3), with buds between."""
    bg, petal, centre = (col(c) for c in spec.pattern_colors[:3])
    S = 0.3 * ctx.scale
    ou, ov, _ = _offset(ctx.seed, "floral")
    pet = cen = bud = None
    e = F32(0.03)
    for i, (w, (u, v)) in enumerate(zip(ctx.tri_weights(6), ctx.planes())):
        cu, cv = u * F32(1.0 / S) + F32(ou), v * F32(1.0 / S) + F32(ov)
        iu, iv = np.floor(cu), np.floor(cv)
        h = nz.cell_hash(iu, iv, i, ctx.seed_for("floral"))
        du = cu - iu - F32(0.5) - (nz.hash_unit(h, 0) - F32(0.5)) * F32(0.2)
        dv = cv - iv - F32(0.5) - (nz.hash_unit(h, 1) - F32(0.5)) * F32(0.2)
        ang = nz.hash_unit(h, 2) * TAU
        ca, sa = np.cos(ang), np.sin(ang)
        a, b = du * ca - dv * sa, du * sa + dv * ca
        r2 = a * a + b * b + F32(1e-8)
        r = np.sqrt(r2)
        a2, b2 = a * a, b * b
        cos5 = a * (a2 * a2 - F32(10.0) * a2 * b2 + F32(5.0) * b2 * b2) / (r2 * r2 * r)  # cos(5 theta)
        size = F32(0.8) + F32(0.2) * nz.hash_unit(h, 1)
        R = size * (F32(0.27) + F32(0.12) * cos5)
        p_i = (F32(1.0) - smoothstep(0.0, 1.0, (r - R + e) / (F32(2.0) * e))) * w
        c_i = (F32(1.0) - smoothstep(0.0, 1.0, (r - size * F32(0.075) + e) / (F32(2.0) * e))) * w
        bu, bv = cu - np.floor(cu), cv - np.floor(cv)  # buds at the grid corners
        rb = np.sqrt(np.minimum(bu, F32(1.0) - bu) ** 2 + np.minimum(bv, F32(1.0) - bv) ** 2)
        b_i = (F32(1.0) - smoothstep(0.05, 0.09, rb)) * w
        pet = p_i if pet is None else pet + p_i
        cen = c_i if cen is None else cen + c_i
        bud = b_i if bud is None else bud + b_i
    petal_shaded = petal * (F32(0.85) + F32(0.15) * smoothstep(0.3, 0.7, pet))
    out = lerp(bg, petal_shaded, smoothstep(0.3, 0.7, pet))
    out = lerp(out, lerp(bg, petal, F32(0.7)), smoothstep(0.3, 0.7, bud))
    return lerp(out, centre, smoothstep(0.3, 0.7, cen))


def pattern_speckles(ctx: Ctx, spec: MaterialSpec) -> np.ndarray:
    """Speckles: irregular flecks (~0.02–0.05) of the second colour over the first, ~8% cover."""
    pal = _palette(spec)
    fine = ctx.noise("speckle-fine", 20.0)
    big = ctx.noise("speckle-big", 10.0)
    t = np.maximum(smoothstep(0.36, 0.56, fine), smoothstep(0.45, 0.65, big))
    return lerp(pal[:, :1], pal[:, 1:2], t)


PATTERN_FUNCS: dict[str, Callable[[Ctx, MaterialSpec], np.ndarray]] = {
    "stripes": pattern_stripes,
    "checks": pattern_checks,
    "plaid": pattern_plaid,
    "dots": pattern_dots,
    "patchwork": pattern_patchwork,
    "floral": pattern_floral,
    "speckles": pattern_speckles,
}
