"""Procedural material, pattern and wear synthesis at 3D surface points.

Everything here works on one chunk of points held by a :class:`Ctx` (coordinates and normals as separate
contiguous ``(n,) float32`` arrays, cache-sized). Colours are component-major ``(3, n) float32`` arrays
(or ``(3, 1)`` constants that broadcast). The pipeline, driven by :func:`shade`:

1. the pattern (or the plain main colour) gives the per-point *albedo*;
2. the material modulates it (grain, veins, weave, ...), using the spec's accent colour;
3. overlays (rust, moss) and wear (dirt, fading, scratches) age it.

Every value depends only on (point, normal, spec, seed): no statistic of the batch is used, so a texel
and a rendered pixel at the same surface point get the same colour. Feature sizes are in the shape's
normalised frame ([-1, 1]^3); the finest detail has a wavelength of about 0.02 or more.
Patterns that need a 2D layout (stripes, dots, flowers, weave, bricks) are projected triplanarly: one
layout per axis-aligned plane, blended by smooth weights of the normal.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from functools import lru_cache

import numpy as np

from . import noise as nz
from .colors import RGB
from .prompt import MaterialSpec

__all__ = ["Ctx", "shade", "MATERIAL_FUNCS", "PATTERN_FUNCS"]

F32 = np.float32
TAU = F32(2.0 * math.pi)


@lru_cache(maxsize=4096)
def _derived(seed: int, name: str) -> int:
    return nz.derive_seed(seed, name)


@lru_cache(maxsize=4096)
def _offset(seed: int, name: str) -> tuple[float, float, float]:
    """A seeded domain offset in [0, 64)^3 lattice units (so regular patterns shift with the seed too)."""
    h = nz.seed_key(_derived(seed, name + "/offset"))
    return tuple(float(((h >> s) & 0x3FF) / 16.0) for s in (0, 10, 20))  # type: ignore[return-value]


class Ctx:
    """One chunk of points being shaded.

    Args:
        points: ``(n, 3) float32`` in the shape's normalised frame.
        normals: ``(n, 3) float32`` unit (zero rows allowed: equal triplanar weights).
        seed: texture seed.
        scale: feature-size multiplier of the spec (2: features twice as large).
    """

    def __init__(self, points: np.ndarray, normals: np.ndarray, seed: int, scale: float = 1.0):
        self.x, self.y, self.z = (np.ascontiguousarray(points[:, k], dtype=F32) for k in range(3))
        self.nx, self.ny, self.nz = (np.ascontiguousarray(normals[:, k], dtype=F32) for k in range(3))
        self.n = len(self.x)
        self.seed = int(seed)
        self.scale = float(scale)
        self._cache: dict = {}

    # -- coordinates and noise ------------------------------------------------------------------
    def seed_for(self, name: str) -> int:
        return _derived(self.seed, name)

    def coords(self, freq: float | tuple[float, float, float], name: str) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Points times ``freq / scale`` (per axis if a tuple) plus a seeded offset named ``name``."""
        f = freq if isinstance(freq, tuple) else (freq, freq, freq)
        o = _offset(self.seed, name)
        return tuple(c * F32(fk / self.scale) + F32(ok) for c, fk, ok in zip((self.x, self.y, self.z), f, o))  # type: ignore[return-value]

    def noise(self, name: str, freq, octaves: int = 1, kind: str = "fbm") -> np.ndarray:
        """Cached fractal noise ``(n,) float32`` named ``name`` (same name and args: same array)."""
        key = ("noise", name, freq, octaves, kind)
        if key not in self._cache:
            x, y, z = self.coords(freq, name)
            s = self.seed_for(name)
            if octaves == 1 and kind == "fbm":
                v = nz.perlin_xyz(x, y, z, s)
            else:
                fn = {"fbm": nz.fbm_xyz, "turbulence": nz.turbulence_xyz, "ridged": nz.ridged_xyz}[kind]
                v = fn(x, y, z, octaves=octaves, seed=s)
            self._cache[key] = v
        return self._cache[key]

    def cells(self, name: str, freq: float, jitter: float = 1.0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Cached cellular noise ``(f1, f2, cell)`` named ``name``."""
        key = ("cells", name, freq, jitter)
        if key not in self._cache:
            self._cache[key] = nz.worley_xyz(*self.coords(freq, name), seed=self.seed_for(name), jitter=jitter)
        return self._cache[key]

    def tri_weights(self, power: int = 4) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Triplanar weights ``|n_k|^power`` normalised to sum 1, each ``(n,) float32``."""
        key = ("tri", power)
        if key not in self._cache:
            ws = []
            for c in (self.nx, self.ny, self.nz):
                a = c * c
                w = a.copy()
                for _ in range(power // 2 - 1):
                    w *= a
                w += F32(1e-6)
                ws.append(w)
            total = ws[0] + ws[1] + ws[2]
            self._cache[key] = tuple(w / total for w in ws)
        return self._cache[key]

    def planes(self, axis: str = "horizontal") -> list[tuple[np.ndarray, np.ndarray]]:
        """In-plane coordinates ``(u, v)`` of the three projection planes (normal along x, y, z).

        ``v`` is the "across" coordinate of horizontal bands: height (z) on the side planes, y on the top
        plane (so bands wrap over a front edge). ``axis`` rotates that choice for vertical / diagonal
        patterns.
        """
        x, y, z = self.x, self.y, self.z
        planes = [(y, z), (x, z), (x, y)]
        if axis == "vertical":
            planes = [(z, y), (z, x), (y, x)]
        elif axis == "diagonal":
            r = F32(math.sqrt(0.5))
            planes = [((u - v) * r, (u + v) * r) for u, v in planes]
        return planes


# --------------------------------------------------------------------------------------------------
# Small colour helpers on (3, n) / (3, 1) arrays
# --------------------------------------------------------------------------------------------------


def col(rgb: RGB) -> np.ndarray:
    """A constant colour as a ``(3, 1) float32`` column."""
    return np.asarray(rgb, dtype=F32).reshape(3, 1)


def lerp(a: np.ndarray, b: np.ndarray, t: np.ndarray) -> np.ndarray:
    """``a + (b - a) t`` with colours ``(3, n|1)`` and weights ``t (n,)`` -> ``(3, n)``."""
    return a + (b - a) * t


def smoothstep(e0: float, e1: float, x: np.ndarray) -> np.ndarray:
    """Hermite step from 0 (x <= e0) to 1 (x >= e1), ``(n,) float32``."""
    t = (x - F32(e0)) * F32(1.0 / (e1 - e0))
    np.clip(t, F32(0.0), F32(1.0), out=t)
    return t * t * (F32(3.0) - F32(2.0) * t)


def luma(c: np.ndarray) -> np.ndarray:
    """Rec. 709 luma of ``(3, n)`` colours (gamma-encoded), ``(n,)``."""
    return F32(0.2126) * c[0] + F32(0.7152) * c[1] + F32(0.0722) * c[2]


def relative(spec: MaterialSpec, albedo: np.ndarray, strength: float = 1.0) -> np.ndarray:
    """The accent as a change of the main colour, applied to a per-point ``albedo`` (so the darker
    rings of wood follow the stripes under them). For a material's own colours the change is the
    per-channel ratio accent / main (wood rings get darker *and* redder); for colours from the prompt
    it is a plain darkening by 0.55. ``(3, n|1)``."""
    if spec.user_colors:
        ratio = np.full((3, 1), 0.55, dtype=F32)
    else:
        main = np.asarray(spec.base_color, dtype=F32)
        acc = np.asarray(spec.accent_color, dtype=F32)
        ratio = np.clip((acc + F32(0.02)) / (main + F32(0.02)), 0.15, 2.5).reshape(3, 1).astype(F32)
    return albedo * (F32(1.0) + (ratio - F32(1.0)) * F32(strength))


def sheen(ctx: Ctx, amount: float) -> np.ndarray:
    """A soft highlight on upward-facing surfaces (light from +z), ``(n,)``: mild and smooth in the normal."""
    return F32(amount) * smoothstep(0.3, 1.0, ctx.nz)


# --------------------------------------------------------------------------------------------------
# Patterns: spec -> per-point albedo (3, n)
# --------------------------------------------------------------------------------------------------


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


# --------------------------------------------------------------------------------------------------
# Materials: (ctx, spec, albedo (3, n|1)) -> colour (3, n)
# --------------------------------------------------------------------------------------------------


def mat_plastic(ctx, spec, albedo):
    """Plastic / paint: uniform with a faint low-frequency variation and a soft sheen."""
    low = ctx.noise("low", 2.5, 2)
    out = albedo * (F32(1.0) + F32(0.04) * low)
    return out + (sheen(ctx, 0.06) if spec.finish != "matte" else F32(0.0))


def mat_rubber(ctx, spec, albedo):
    """Rubber: matte, slightly mottled."""
    return albedo * (F32(1.0) + F32(0.06) * ctx.noise("low", 2.5, 2) + F32(0.04) * ctx.noise("grit", 30.0))


def mat_wood(ctx, spec, albedo):
    """Wood: growth rings around an axis along x (centre outside the shape, so long grain on most faces
    and arcs on end faces), perturbed by noise, plus fine fibres along the grain."""
    warp = ctx.noise("wood-warp", (0.6, 2.2, 2.2), 2)
    oy, oz, _ = _offset(ctx.seed, "wood-centre")
    yc, zc = F32(-2.2 - oy / 64.0), F32(-1.6 - oz / 64.0)
    dy, dz = ctx.y - yc, ctx.z - zc
    r = np.sqrt(dy * dy + dz * dz) + F32(0.09) * warp
    spacing = F32(0.085 * ctx.scale)
    g = F32(0.5) + F32(0.5) * np.cos(r * (TAU / spacing))
    band = g * g * g
    fibres = ctx.noise("wood-fibres", (1.2, 32.0, 32.0))
    dark = relative(spec, albedo)
    out = lerp(albedo, dark, F32(0.7) * band)
    out = out * (F32(1.0) + F32(0.09) * fibres + F32(0.06) * ctx.noise("low", 2.5, 2))
    return out + (sheen(ctx, 0.05) if spec.finish in ("glossy", "polished") else F32(0.0))


def mat_marble(ctx, spec, albedo):
    """Marble: veins along the zero crossings of sin(direction . p + 6 fBm(p)), on a domain-warped p,
    with a little turbulence for crackle; faint secondary veins; cloudy body."""
    x, y, z = ctx.coords(1.2, "marble")
    s = ctx.seed_for("marble")
    wx, wy, wz = nz.domain_warp_xyz(x, y, z, amount=0.6, octaves=1, seed=s)
    t = nz.fbm_xyz(wx, wy, wz, octaves=4, seed=nz.derive_seed(s, "fbm"))
    t += F32(0.5) * nz.turbulence_xyz(wx * F32(2.0), wy * F32(2.0), wz * F32(2.0), octaves=2, seed=nz.derive_seed(s, "turb"))
    phase = (F32(0.62) * wx + F32(0.35) * wy + F32(0.70) * wz) * F32(1.8 / ctx.scale)
    v1 = F32(1.0) - np.abs(np.sin(phase + F32(6.0) * t))
    v2 = F32(1.0) - np.abs(np.sin(phase * F32(2.3) + F32(10.0) * t + F32(1.3)))
    v1 = v1 * v1 * v1 * v1 * v1  # ^5: thin veins
    v2 = v2 * v2
    v2 = v2 * v2
    v2 = v2 * v2 * v2  # ^12: fainter, thinner
    vein = np.minimum(F32(0.85) * v1 + F32(0.3) * v2, F32(1.0))
    cloud = albedo * (F32(1.0) - F32(0.06) * t)
    out = lerp(cloud, col(spec.accent_color), vein)
    return out + (sheen(ctx, 0.05) if spec.finish != "matte" else F32(0.0))


def mat_granite(ctx, spec, albedo):
    """Granite / terrazzo: multi-colour crystals from cellular noise (~0.055), edges blended, fine grit."""
    freq = 18.0 if spec.variant != "terrazzo" else 9.0
    f1, f2, cell = ctx.cells("granite", freq, jitter=0.9)
    dark = col(spec.accent_color)
    quartz = np.clip(albedo * F32(0.3) + F32(0.68), 0, 1)
    mid = albedo * F32(0.72)
    grain = np.where(cell < F32(0.2), dark, np.where(cell < F32(0.32), quartz, np.where(cell < F32(0.6), mid, albedo)))
    edge = smoothstep(0.0, 0.25, f2 - f1)  # ~0.01 wide transitions: no razor edges
    out = lerp(albedo * F32(0.85), grain, edge)
    return out * (F32(1.0) + F32(0.07) * ctx.noise("grit", 40.0)) + sheen(ctx, 0.04)


def mat_stone(ctx, spec, albedo):
    """Stone: broad fBm tone variation, small pits, fine grit; slate and sandstone get strata."""
    low = ctx.noise("low4", 2.5, 4)
    out = albedo * (F32(1.0) + F32(0.32) * low)
    if spec.variant in ("sandstone", "slate", "limestone"):
        strata = F32(0.5) + F32(0.5) * np.sin(ctx.z * F32(TAU / (0.07 * ctx.scale)) + F32(6.0) * low)
        out = lerp(out, relative(spec, out), F32(0.35) * strata)
    pits = smoothstep(0.45, 0.6, ctx.noise("pits", 16.0))
    out = out * (F32(1.0) - F32(0.35) * pits)
    return out * (F32(1.0) + F32(0.07) * ctx.noise("grit", 42.0))


def mat_concrete(ctx, spec, albedo):
    """Concrete / plaster: soft blotches, fine grit and (concrete only) small dark air holes."""
    out = albedo * (F32(1.0) + F32(0.14) * ctx.noise("low", 2.5, 3) + F32(0.05) * ctx.noise("grit", 45.0))
    if spec.variant != "plaster":
        holes = smoothstep(0.5, 0.62, ctx.noise("holes", 20.0))
        out = out * (F32(1.0) - F32(0.35) * holes)
    return out


def mat_brick(ctx, spec, albedo):
    """Brick: running-bond bricks 0.22 x 0.075 with 0.014 mortar joints, per-brick tone."""
    L, H, m = 0.22 * ctx.scale, 0.075 * ctx.scale, 0.014 * ctx.scale
    ou, ov, _ = _offset(ctx.seed, "brick")
    mortar = tone = None
    for i, (w, (u, v)) in enumerate(zip(ctx.tri_weights(6), ctx.planes())):
        cv = v * F32(1.0 / H) + F32(ov)
        row = np.floor(cv)
        cu = u * F32(1.0 / L) + F32(ou) + F32(0.5) * (row - F32(2.0) * np.floor(row * F32(0.5)))
        colu = np.floor(cu)
        fu, fv = cu - colu, cv - row
        d = np.minimum(np.minimum(fu, F32(1.0) - fu) * F32(L), np.minimum(fv, F32(1.0) - fv) * F32(H))
        mo = (F32(1.0) - smoothstep(m * 0.5 - 0.005, m * 0.5 + 0.005, d)) * w
        to = nz.hash_unit(nz.cell_hash(colu, row, i, ctx.seed_for("brick"))) * w
        mortar = mo if mortar is None else mortar + mo
        tone = to if tone is None else tone + to
    low = ctx.noise("low", 2.5, 2)
    brick = albedo * (F32(0.8) + F32(0.35) * tone + F32(0.12) * low)
    brick = brick * (F32(1.0) + F32(0.08) * ctx.noise("grit", 38.0))
    return lerp(brick, col(spec.accent_color) * (F32(1.0) + F32(0.06) * low), mortar)


def mat_ceramic(ctx, spec, albedo):
    """Ceramic / porcelain / glazed: nearly uniform, glaze pooling, glossy sheen; terracotta is matte."""
    low = ctx.noise("low", 2.5, 3)
    if spec.variant == "terracotta":
        return albedo * (F32(1.0) + F32(0.1) * low + F32(0.06) * ctx.noise("grit", 40.0))
    amp = 0.02 if spec.variant == "porcelain" else 0.05
    out = albedo * (F32(1.0) + F32(amp) * low)
    if spec.variant == "glazed":
        out = out * (F32(1.0) - F32(0.12) * smoothstep(0.05, 0.35, low))  # pooled, darker glaze
    return out + (sheen(ctx, 0.08) if spec.finish != "matte" else F32(0.0))


def mat_metal(ctx, spec, albedo):
    """Metal: brushed streaks along x (anisotropic noise), soft blotches and a normal-driven reflection."""
    brushed = ctx.noise("brushed", (1.0, 38.0, 38.0))
    polished = spec.finish in ("polished", "glossy") or spec.variant == "chrome"
    amp = 0.025 if polished else 0.08
    out = albedo * (F32(1.0) + F32(amp) * brushed + F32(0.07) * ctx.noise("low", 2.5, 2))
    refl = F32(0.88) + F32(0.18) * smoothstep(-0.6, 1.0, ctx.nz)
    return out * refl + sheen(ctx, 0.1 if polished else 0.06)


def mat_rust(ctx, spec, albedo):
    """Rust: patches (fBm mask, ~half the surface) of mottled orange-brown over the metal."""
    metal = mat_metal(ctx, spec, albedo)
    return _rust_over(ctx, metal, col(spec.accent_color), coverage=0.55)


def _rust_over(ctx: Ctx, under: np.ndarray, rust: np.ndarray, coverage: float) -> np.ndarray:
    low = ctx.noise("rust-mask", 2.2, 4)
    mask = smoothstep(-0.08, 0.08, low + F32(0.22 * (coverage - 0.5)))
    mottle = ctx.noise("rust-mottle", 14.0, 2)
    flecks = smoothstep(0.3, 0.5, ctx.noise("rust-flecks", 30.0))
    r = rust * (F32(0.8) + F32(0.5) * mottle)
    r = lerp(r, col((0.74, 0.42, 0.16)), F32(0.5) * flecks)
    rim = F32(4.0) * mask * (F32(1.0) - mask)  # darker at the patch borders
    return lerp(under, r * (F32(1.0) - F32(0.3) * rim), mask)


def _weave(ctx: Ctx, period: float, twill: bool) -> np.ndarray:
    """Triplanar weave field in [-1, 1]: product of two orthogonal sinusoids (plain weave), or diagonal
    ridges (twill). ``(n,)``."""
    k = F32(TAU / (period * ctx.scale))
    out = None
    for w, (u, v) in zip(ctx.tri_weights(4), ctx.planes()):
        f = np.sin((u + v) * k) if twill else np.sin(u * k) * np.sin(v * k)
        f *= w
        out = f if out is None else out + f
    return out


def mat_fabric(ctx, spec, albedo):
    """Fabric: a fine visible weave (period 0.03), slubby threads and soft blotches; linen coarser and
    irregular, denim a twill with white weft, wool / tweed fuzzy with flecks, silk smooth with sheen."""
    v = spec.variant
    low = ctx.noise("low", 2.5, 2)
    if v == "silk":
        return albedo * (F32(0.94) + F32(0.08) * low) + sheen(ctx, 0.1)
    period = {"linen": 0.034, "canvas": 0.032, "denim": 0.03}.get(v, 0.028)
    weave = _weave(ctx, period, twill=(v == "denim"))
    slub = ctx.noise("slub", (18.0, 18.0, 18.0))
    if v == "denim":
        out = lerp(albedo, col(spec.accent_color), F32(0.16) * smoothstep(0.0, 1.0, weave))
        fade = smoothstep(-0.1, 0.3, low)
        out = lerp(out, out * F32(0.7) + F32(0.3), F32(0.25) * fade)
        return out * (F32(1.0) + F32(0.06) * slub)
    amp_w = {"wool": 0.04, "tweed": 0.05, "linen": 0.1}.get(v, 0.09)
    amp_s = {"linen": 0.09, "wool": 0.08, "tweed": 0.06}.get(v, 0.04)
    out = albedo * (F32(0.93) + F32(amp_w) * weave + F32(amp_s) * slub + F32(0.05) * low)
    if v == "tweed":
        flecks = smoothstep(0.4, 0.55, ctx.noise("flecks", 30.0))
        out = lerp(out, relative(spec, albedo), F32(0.6) * flecks)
    return out


def mat_velvet(ctx, spec, albedo):
    """Velvet / suede: soft low-frequency variation (crushed pile) and darker shading away from the light."""
    low = ctx.noise("low", 2.0, 3)
    crush = ctx.noise("crush", 5.0, 2)
    out = albedo * (F32(0.86) + F32(0.25) * low + F32(0.12) * crush)
    if spec.variant == "suede":
        out = out * (F32(1.0) + F32(0.05) * ctx.noise("nap", 24.0))
    return out * (F32(0.8) + F32(0.2) * smoothstep(-1.0, 1.0, ctx.nz))


def mat_leather(ctx, spec, albedo):
    """Leather: cellular grain (creases where F2 - F1 is small, cells ~0.045), pores, tone blotches."""
    f1, f2, _ = ctx.cells("leather", 22.0)
    crease = F32(1.0) - smoothstep(0.0, 0.22, f2 - f1)
    low = ctx.noise("low", 2.2, 3)
    out = albedo * (F32(1.0) + F32(0.18) * low) * (F32(1.0) - F32(0.22) * crease)
    out = out * (F32(1.0) + F32(0.04) * ctx.noise("grit", 40.0))
    return out + (sheen(ctx, 0.06) if spec.finish != "matte" else F32(0.0))


def mat_bark(ctx, spec, albedo):
    """Bark: vertical ridges (ridged noise stretched along z) with dark crevices."""
    rid = ctx.noise("bark", (5.0, 5.0, 1.0), 3, "ridged")
    fine = ctx.noise("bark-fine", (20.0, 20.0, 6.0))
    crevice = relative(spec, albedo)
    out = lerp(crevice, albedo * (F32(1.0) + F32(0.15) * fine), smoothstep(0.45, 0.8, rid))
    return out * (F32(1.0) + F32(0.1) * ctx.noise("low", 2.5, 2))


def mat_moss(ctx, spec, albedo):
    """Moss: green fBm clumps (dark hollows, light tips) and fine fibres."""
    return _moss(ctx, albedo, col(spec.accent_color))


def _moss(ctx: Ctx, albedo: np.ndarray, tips: np.ndarray) -> np.ndarray:
    clump = ctx.noise("moss", 5.0, 4)
    out = lerp(albedo * F32(0.5), albedo, smoothstep(-0.25, 0.25, clump))
    out = lerp(out, tips, F32(0.45) * smoothstep(0.2, 0.5, ctx.noise("moss-tips", 24.0)))
    return out * (F32(1.0) + F32(0.1) * ctx.noise("grit", 42.0))


def mat_fruit(ctx, spec, albedo):
    """Fruit skin: fine dimples (cellular, ~0.03) for citrus, streaks for apples, ribs for pumpkins,
    a blush gradient for peaches, sugar spots for bananas; glossy for apple and tomato."""
    v = spec.variant
    acc = col(spec.accent_color)
    low = ctx.noise("low", 2.5, 2)
    out = albedo * (F32(1.0) + F32(0.06) * low)
    if v in ("orange", "lemon", "lime"):
        f1, _, _ = ctx.cells("pores", 32.0)
        out = out * (F32(0.9) + F32(0.1) * smoothstep(0.0, 0.45, f1))
        out = lerp(out, acc, F32(0.2) * smoothstep(0.1, 0.5, low))
    elif v == "apple":
        streak = ctx.noise("streaks", (12.0, 12.0, 2.5), 2)
        out = lerp(out, acc, F32(0.55) * smoothstep(-0.05, 0.35, streak - F32(0.15) * ctx.z))
        out = lerp(out, acc, F32(0.5) * smoothstep(0.5, 0.62, ctx.noise("lenticels", 36.0)))
    elif v == "pumpkin":
        theta = np.arctan2(ctx.y, ctx.x)
        groove = F32(1.0) - smoothstep(0.0, 0.45, np.abs(np.sin(theta * F32(5.0))))
        out = lerp(out, acc, F32(0.55) * groove)
    elif v == "peach":
        out = lerp(out, acc, F32(0.7) * smoothstep(-0.1, 0.4, low + F32(0.25) * ctx.x))
        out = out * (F32(1.0) + F32(0.04) * ctx.noise("fuzz", 36.0))
    elif v == "banana":
        out = lerp(out, acc, F32(0.8) * smoothstep(0.5, 0.62, ctx.noise("sugar", 18.0)))
    if v in ("apple", "tomato"):
        out = out + sheen(ctx, 0.08)
    return out


def mat_mushroom(ctx, spec, albedo):
    """Mushroom: cap colour on the upper part of the shape fading to a pale stem below; pale cap spots
    from cellular noise (spacing ~0.2)."""
    stem = col(spec.accent_color) * (F32(1.0) + F32(0.05) * ctx.noise("grit", 30.0))
    low = ctx.noise("low", 2.5, 2)
    cap_t = smoothstep(-0.3, 0.05, ctx.z + F32(0.1) * low)
    cap = albedo * (F32(1.0) - F32(0.18) * smoothstep(0.3, 1.0, ctx.z) + F32(0.06) * low)
    out = lerp(stem, cap, cap_t)
    f1, f2, cell = ctx.cells("spots", 5.0, jitter=0.8)
    spot = (F32(1.0) - smoothstep(0.2, 0.27, f1)) * (cell < F32(0.75)) * smoothstep(0.0, 0.1, f2 - f1)
    return lerp(out, col(spec.accent_color), spot * cap_t)


MATERIAL_FUNCS: dict[str, Callable[[Ctx, MaterialSpec, np.ndarray], np.ndarray]] = {
    "plastic": mat_plastic,
    "rubber": mat_rubber,
    "wood": mat_wood,
    "marble": mat_marble,
    "granite": mat_granite,
    "stone": mat_stone,
    "concrete": mat_concrete,
    "brick": mat_brick,
    "ceramic": mat_ceramic,
    "metal": mat_metal,
    "rust": mat_rust,
    "fabric": mat_fabric,
    "velvet": mat_velvet,
    "leather": mat_leather,
    "bark": mat_bark,
    "moss": mat_moss,
    "fruit": mat_fruit,
    "mushroom": mat_mushroom,
}


# --------------------------------------------------------------------------------------------------
# Wear and overlays
# --------------------------------------------------------------------------------------------------


def apply_overlay(ctx: Ctx, spec: MaterialSpec, c: np.ndarray) -> np.ndarray:
    """Rust or moss patches over the material."""
    if spec.overlay == "rust":
        return _rust_over(ctx, c, col((0.56, 0.26, 0.10)), coverage=0.35)
    if spec.overlay == "moss":
        mask = smoothstep(0.0, 0.2, ctx.noise("moss-mask", 2.0, 3) - F32(0.05))
        moss = _moss(ctx, col((0.36, 0.50, 0.18)), col((0.62, 0.70, 0.28)))
        return lerp(c, moss, mask)
    return c


def _scratch_lines(ctx: Ctx, across: tuple[float, float, float], name: str) -> np.ndarray:
    """Thin (~0.012 wide), long, slightly wavy lines: where a noise that varies fast along ``across``
    (unit vector) and slowly along the other directions crosses zero. ``(n,)`` in [0, 1]."""
    a = np.asarray(across, dtype=np.float64)
    b = np.cross(a, (0.0, 0.0, 1.0) if abs(a[2]) < 0.9 else (1.0, 0.0, 0.0))
    b /= np.linalg.norm(b)
    c = np.cross(a, b)
    o = _offset(ctx.seed, name)
    sk = 1.0 / ctx.scale
    coords = []
    for axis, f, off in ((a, 14.0, o[0]), (b, 0.5, o[1]), (c, 0.9, o[2])):
        coords.append((ctx.x * F32(axis[0] * f * sk) + ctx.y * F32(axis[1] * f * sk)) + ctx.z * F32(axis[2] * f * sk) + F32(off))
    s = nz.perlin_xyz(*coords, ctx.seed_for(name))
    return F32(1.0) - smoothstep(0.03, 0.1, np.abs(s))


def apply_wear(ctx: Ctx, spec: MaterialSpec, c: np.ndarray) -> np.ndarray:
    """Dirt (darker brownish fBm patches), fading (desaturated, lighter blotches) and scratches (thin
    light lines where a stretched noise crosses zero, in sparse clusters), scaled by ``spec.wear``."""
    w = spec.wear
    if w <= 0:
        return c
    kinds = spec.wear_kinds
    if "dirt" in kinds:
        dirt = ctx.noise("dirt", 2.4, 3)
        m = smoothstep(0.0, 0.35, dirt + F32(0.3 * (w - 0.5))) * F32(0.6 * w)
        c = lerp(c, c * col((0.55, 0.48, 0.40)), m)
    if "fade" in kinds:
        f = smoothstep(-0.25, 0.3, ctx.noise("fade", 1.5, 2)) * F32(0.45 * w)
        grey = luma(c) * F32(0.85) + F32(0.12)
        c = lerp(c, grey, f)
    if "scratches" in kinds:
        line = np.maximum(_scratch_lines(ctx, (0.78, 0.49, 0.39), "scratch-a"), _scratch_lines(ctx, (-0.33, 0.52, -0.79), "scratch-b"))
        cluster = smoothstep(0.15, 0.4, ctx.noise("scratch-cluster", 1.8))
        t = line * cluster * F32(min(1.0, 0.9 * w + 0.2))
        c = lerp(c, c * F32(0.55) + F32(0.42), F32(0.75) * t)
    return c


def shade(ctx: Ctx, spec: MaterialSpec) -> np.ndarray:
    """Colour of the chunk's points for ``spec``: ``(3, n) float32`` clipped to [0, 1]."""
    albedo = PATTERN_FUNCS[spec.pattern](ctx, spec) if spec.pattern else col(spec.base_color)
    c = MATERIAL_FUNCS[spec.material](ctx, spec, albedo)
    c = apply_overlay(ctx, spec, c)
    c = apply_wear(ctx, spec, c)
    c = np.broadcast_to(c, (3, ctx.n)).astype(F32, copy=True)
    np.clip(c, F32(0.0), F32(1.0), out=c)
    return c
