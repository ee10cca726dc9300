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

from collections.abc import Callable

import numpy as np

from . import noise as nz
from .patterns import PATTERN_FUNCS
from .prompt import MaterialSpec
from .shading import F32, TAU, Ctx, _offset, col, lerp, luma, relative, sheen, smoothstep

__all__ = ["shade", "MATERIAL_FUNCS"]


# --------------------------------------------------------------------------------------------------
# Small colour helpers on (3, n) / (3, 1) arrays
# --------------------------------------------------------------------------------------------------


# --------------------------------------------------------------------------------------------------
# Patterns: spec -> per-point albedo (3, n)
# --------------------------------------------------------------------------------------------------


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


def brick_mortar(ctx: Ctx) -> np.ndarray:
    """Mortar joints of running-bond bricks 0.22 x 0.075 (0.014 joints): ``(n,)`` in [0, 1], 1 in a joint."""
    return _bricks(ctx)[0]


def _bricks(ctx: Ctx) -> tuple[np.ndarray, np.ndarray]:
    key = ("bricks",)
    if key in ctx._cache:
        return ctx._cache[key]
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
    ctx._cache[key] = (mortar, tone)
    return mortar, tone


def mat_brick(ctx, spec, albedo):
    """Brick: running-bond bricks 0.22 x 0.075 with 0.014 mortar joints, per-brick tone."""
    mortar, tone = _bricks(ctx)
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


def hammer_dimples(ctx: Ctx) -> np.ndarray:
    """Hammered metal: round dimples from cellular noise (~0.06 across), ``(n,)`` in [-1, 0], -1 at a
    dimple's centre and 0 on the ridges between them."""
    f1, _, _ = ctx.cells("hammer", 16.0, jitter=0.85)
    return smoothstep(0.0, 0.7, f1) - F32(1.0)


def mat_metal(ctx, spec, albedo):
    """Metal: brushed streaks along x (anisotropic noise), soft blotches and a normal-driven reflection;
    hammered metal shows its dimples as soft light and dark facets."""
    brushed = ctx.noise("brushed", (1.0, 38.0, 38.0))
    polished = spec.finish in ("polished", "glossy") or spec.variant == "chrome"
    amp = 0.025 if polished else 0.08
    out = albedo * (F32(1.0) + F32(amp) * brushed + F32(0.07) * ctx.noise("low", 2.5, 2))
    if spec.finish == "hammered":
        out = out * (F32(1.0) + F32(0.12) * hammer_dimples(ctx) + F32(0.06))
    refl = F32(0.88) + F32(0.18) * smoothstep(-0.6, 1.0, ctx.nz)
    return out * refl + sheen(ctx, 0.1 if polished else 0.06)


def mat_rust(ctx, spec, albedo):
    """Rust: patches (fBm mask, ~half the surface) of mottled orange-brown over the metal."""
    metal = mat_metal(ctx, spec, albedo)
    return _rust_over(ctx, metal, col(spec.accent_color), coverage=0.55)


def rust_mask(ctx: Ctx, coverage: float) -> np.ndarray:
    """Where rust grows: fBm patches covering about ``coverage`` of the surface, ``(n,)`` in [0, 1]."""
    low = ctx.noise("rust-mask", 2.2, 4)
    return smoothstep(-0.08, 0.08, low + F32(0.22 * (coverage - 0.5)))


def _rust_over(ctx: Ctx, under: np.ndarray, rust: np.ndarray, coverage: float) -> np.ndarray:
    mask = rust_mask(ctx, coverage)
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


def fabric_weave(ctx: Ctx, spec: MaterialSpec) -> np.ndarray:
    """The fabric's weave field in [-1, 1], ``(n,)``: plain weave (twill for denim), period by variant."""
    key = ("weave", spec.variant)
    if key not in ctx._cache:
        period = {"linen": 0.034, "canvas": 0.032, "denim": 0.03}.get(spec.variant, 0.028)
        ctx._cache[key] = _weave(ctx, period, twill=(spec.variant == "denim"))
    return ctx._cache[key]


def mat_fabric(ctx, spec, albedo):
    """Fabric: a fine visible weave (period 0.03), slubby threads and soft blotches; linen coarser and
    irregular, denim a twill with white weft, wool / tweed fuzzy with flecks, silk smooth with sheen."""
    v = spec.variant
    low = ctx.noise("low", 2.5, 2)
    if v == "silk":
        return albedo * (F32(0.94) + F32(0.08) * low) + sheen(ctx, 0.1)
    weave = fabric_weave(ctx, spec)
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
        moss = _moss(ctx, col((0.36, 0.50, 0.18)), col((0.62, 0.70, 0.28)))
        return lerp(c, moss, moss_mask(ctx))
    return c


def moss_mask(ctx: Ctx) -> np.ndarray:
    """Where moss grows over a material, ``(n,)`` in [0, 1]."""
    return smoothstep(0.0, 0.2, ctx.noise("moss-mask", 2.0, 3) - F32(0.05))


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


def scratch_field(ctx: Ctx, spec: MaterialSpec) -> np.ndarray:
    """Scratches of a worn surface, ``(n,)`` in [0, 1]: thin lines in sparse clusters, scaled by the wear."""
    key = ("scratches", spec.wear)
    if key not in ctx._cache:
        line = np.maximum(_scratch_lines(ctx, (0.78, 0.49, 0.39), "scratch-a"), _scratch_lines(ctx, (-0.33, 0.52, -0.79), "scratch-b"))
        cluster = smoothstep(0.15, 0.4, ctx.noise("scratch-cluster", 1.8))
        ctx._cache[key] = line * cluster * F32(min(1.0, 0.9 * spec.wear + 0.2))
    return ctx._cache[key]


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
        c = lerp(c, c * F32(0.55) + F32(0.42), F32(0.75) * scratch_field(ctx, spec))
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
