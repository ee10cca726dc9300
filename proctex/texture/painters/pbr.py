"""Physically based material properties at 3D surface points: roughness, metallic and relief.

:func:`surface_props` is the twin of :func:`.materials.shade`: for one chunk of points (a
:class:`.shading.Ctx`) and a :class:`.prompt.MaterialSpec` it returns the perceptual roughness and the
metalness (``(n,) float32`` in [0, 1], glTF's metallic-roughness model) and a *height* field (``(n,)
float32``, in the shape's normalised frame units: 0.002 is a relief of 0.1 % of the shape's size).
The height is made from the same named noise fields as the colour (``ctx.noise("wood-fibres", ...)``
here and in the wood shader are the same array), so the grain, weave, leather creases, brick mortar,
scratches and hammered dimples that colour the surface also give it relief; the normal map is the
height's surface gradient (:mod:`proctex.texture.pbr`).

Base values follow measured materials: conductors have metalness 1 (rust and moss over them 0),
everything else 0; polished metal and glazed ceramic are smooth (roughness 0.05-0.15), fabrics,
velvet, bark and moss rough (0.85-1). Finish words move the roughness ("glossy", "polished", "matte",
"brushed", "hammered"); wear roughens (dirt, fading) and scratches metal.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from .materials import brick_mortar, fabric_weave, hammer_dimples, moss_mask, rust_mask, scratch_field
from .prompt import MaterialSpec
from .shading import F32, TAU, Ctx, _offset, smoothstep

__all__ = ["surface_props", "height", "base_props", "PROPS"]

#: kind -> (roughness, metallic) of the plain material with the default finish.
PROPS: dict[str, tuple[float, float]] = {
    "plastic": (0.42, 0.0), "rubber": (0.9, 0.0), "wood": (0.62, 0.0), "marble": (0.18, 0.0),
    "granite": (0.32, 0.0), "stone": (0.86, 0.0), "concrete": (0.9, 0.0), "brick": (0.86, 0.0),
    "ceramic": (0.12, 0.0), "metal": (0.28, 1.0), "rust": (0.28, 1.0), "fabric": (0.92, 0.0),
    "velvet": (0.96, 0.0), "leather": (0.55, 0.0), "bark": (0.95, 0.0), "moss": (1.0, 0.0),
    "fruit": (0.5, 0.0), "mushroom": (0.62, 0.0),
}  # fmt: skip

#: variant -> roughness, where a variant differs from its kind.
_VARIANT_ROUGHNESS = {
    "porcelain": 0.1, "glazed": 0.06, "terracotta": 0.85, "chrome": 0.06, "silver": 0.2, "gold": 0.22,
    "iron": 0.5, "silk": 0.35, "suede": 0.9, "apple": 0.3, "tomato": 0.28, "slate": 0.7,
}  # fmt: skip

#: finish -> roughness for dielectrics (metals: see :func:`base_props`).
_FINISH_ROUGHNESS = {"glossy": 0.18, "polished": 0.1, "matte": 0.8, "brushed": 0.4, "hammered": 0.3}


def base_props(spec: MaterialSpec) -> tuple[float, float]:
    """``(roughness, metallic)`` of ``spec``'s plain material: its kind's, its variant's, then its finish."""
    rough, metal = PROPS[spec.material]
    rough = _VARIANT_ROUGHNESS.get(spec.variant, rough)
    if spec.finish != "default":
        if metal > 0:  # metals: polished mirror-like, brushed a satin sheen, matte a bead-blast
            rough = {"glossy": 0.12, "polished": 0.06, "matte": 0.6, "brushed": 0.38, "hammered": 0.3}[spec.finish]
        elif spec.material not in ("fabric", "velvet", "moss", "bark") or spec.finish == "matte":
            rough = _FINISH_ROUGHNESS[spec.finish]
    return float(rough), float(metal)


# ------------------------------------------------------------------------------------ relief per kind
# Each returns (height (n,) in normalised units, roughness change (n,) or 0). Noise names and
# frequencies are the colour shader's, so relief and colour line up.


def _rel_plastic(ctx, spec):
    return F32(0.0004) * ctx.noise("low", 2.5, 2), F32(0.0)


def _rel_rubber(ctx, spec):
    return F32(0.0008) * ctx.noise("grit", 30.0), F32(0.05) * ctx.noise("grit", 30.0)


def _rel_wood(ctx, spec):
    oy, oz, _ = _offset(ctx.seed, "wood-centre")
    warp = ctx.noise("wood-warp", (0.6, 2.2, 2.2), 2)
    dy, dz = ctx.y - F32(-2.2 - oy / 64.0), ctx.z - F32(-1.6 - oz / 64.0)
    r = np.sqrt(dy * dy + dz * dz) + F32(0.09) * warp
    g = F32(0.5) + F32(0.5) * np.cos(r * (TAU / F32(0.085 * ctx.scale)))
    band = g * g * g
    fibres = ctx.noise("wood-fibres", (1.2, 32.0, 32.0))
    varnished = spec.finish in ("glossy", "polished")
    depth = 0.3 if varnished else 1.0  # varnish fills the grain
    h = F32(depth) * (F32(-0.0012) * band + F32(0.0009) * fibres)
    return h, F32(0.0 if varnished else 0.12) * band  # latewood (dark rings) a little rougher


def _rel_marble(ctx, spec):
    return F32(0.0002) * ctx.noise("low", 2.5, 2), F32(0.0)


def _rel_granite(ctx, spec):
    f1, f2, _ = ctx.cells("granite", 18.0 if spec.variant != "terrazzo" else 9.0, jitter=0.9)
    edge = F32(1.0) - smoothstep(0.0, 0.25, f2 - f1)
    return F32(-0.0006) * edge + F32(0.0003) * ctx.noise("grit", 40.0), F32(0.15) * edge


def _rel_stone(ctx, spec):
    pits = smoothstep(0.45, 0.6, ctx.noise("pits", 16.0))
    h = F32(0.004) * ctx.noise("low4", 2.5, 4) - F32(0.0018) * pits + F32(0.0005) * ctx.noise("grit", 42.0)
    return h, F32(0.08) * pits


def _rel_concrete(ctx, spec):
    h = F32(0.0005) * ctx.noise("grit", 45.0) + F32(0.0015) * ctx.noise("low", 2.5, 3)
    if spec.variant != "plaster":
        h = h - F32(0.0015) * smoothstep(0.5, 0.62, ctx.noise("holes", 20.0))
    return h, F32(0.0)


def _rel_brick(ctx, spec):
    mortar = brick_mortar(ctx)
    return F32(-0.004) * mortar + F32(0.0005) * ctx.noise("grit", 38.0), F32(0.1) * mortar


def _rel_ceramic(ctx, spec):
    if spec.variant == "terracotta":
        return F32(0.0005) * ctx.noise("grit", 40.0), F32(0.0)
    return F32(0.0002) * ctx.noise("low", 2.5, 3), F32(0.0)


def _rel_metal(ctx, spec):
    if spec.finish == "hammered":
        return F32(0.004) * hammer_dimples(ctx), F32(0.0)
    polished = spec.finish in ("polished", "glossy") or spec.variant == "chrome"
    brushed = ctx.noise("brushed", (1.0, 38.0, 38.0))
    amp = 0.00006 if polished else 0.0008
    return F32(amp) * brushed, F32(0.0 if polished else 0.08) * brushed


def _rel_rust(ctx, spec):
    return _rel_metal(ctx, spec)  # the rust patches are added by the overlay pass


def _rel_fabric(ctx, spec):
    if spec.variant == "silk":
        return F32(0.0002) * ctx.noise("low", 2.5, 2), F32(0.0)
    weave = fabric_weave(ctx, spec)
    slub = ctx.noise("slub", (18.0, 18.0, 18.0))
    depth = {"linen": 0.0012, "canvas": 0.0011, "denim": 0.0009}.get(spec.variant, 0.0008)
    return F32(depth) * weave + F32(0.0004) * slub, F32(0.0)


def _rel_velvet(ctx, spec):
    return F32(0.0006) * ctx.noise("crush", 5.0, 2), F32(-0.05) * ctx.noise("crush", 5.0, 2)


def _rel_leather(ctx, spec):
    f1, f2, _ = ctx.cells("leather", 22.0)
    crease = F32(1.0) - smoothstep(0.0, 0.22, f2 - f1)
    return F32(-0.0015) * crease + F32(0.0003) * ctx.noise("grit", 40.0), F32(0.15) * crease


def _rel_bark(ctx, spec):
    rid = ctx.noise("bark", (5.0, 5.0, 1.0), 3, "ridged")
    return F32(0.008) * smoothstep(0.3, 0.9, rid) + F32(0.0008) * ctx.noise("bark-fine", (20.0, 20.0, 6.0)), F32(0.0)


def _rel_moss(ctx, spec):
    return F32(0.004) * ctx.noise("moss", 5.0, 4) + F32(0.0006) * ctx.noise("grit", 42.0), F32(0.0)


def _rel_fruit(ctx, spec):
    if spec.variant in ("orange", "lemon", "lime"):
        f1, _, _ = ctx.cells("pores", 32.0)
        return F32(0.0008) * smoothstep(0.0, 0.45, f1), F32(0.0)
    if spec.variant == "pumpkin":
        theta = np.arctan2(ctx.y, ctx.x)
        return F32(-0.004) * (F32(1.0) - smoothstep(0.0, 0.45, np.abs(np.sin(theta * F32(5.0))))), F32(0.0)
    return F32(0.0003) * ctx.noise("low", 2.5, 2), F32(0.0)


def _rel_mushroom(ctx, spec):
    return F32(0.0006) * ctx.noise("grit", 30.0), F32(0.0)


_RELIEF: dict[str, Callable[[Ctx, MaterialSpec], tuple[np.ndarray, np.ndarray]]] = {
    "plastic": _rel_plastic, "rubber": _rel_rubber, "wood": _rel_wood, "marble": _rel_marble,
    "granite": _rel_granite, "stone": _rel_stone, "concrete": _rel_concrete, "brick": _rel_brick,
    "ceramic": _rel_ceramic, "metal": _rel_metal, "rust": _rel_rust, "fabric": _rel_fabric,
    "velvet": _rel_velvet, "leather": _rel_leather, "bark": _rel_bark, "moss": _rel_moss,
    "fruit": _rel_fruit, "mushroom": _rel_mushroom,
}  # fmt: skip


def height(ctx: Ctx, spec: MaterialSpec) -> np.ndarray:
    """The relief of the chunk's points for ``spec`` (material, overlay and wear), ``(n,) float32`` in
    normalised-frame units. A pure function of (point, normal, spec, seed), like the colour. (The
    normal map evaluates it four times per texel, so it computes nothing but the relief.)"""
    return _props(ctx, spec, with_props=False)[2]


def surface_props(ctx: Ctx, spec: MaterialSpec) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(roughness, metallic, height)`` of the chunk's points for ``spec``, each ``(n,) float32``;
    roughness and metallic are clipped to [0, 1] (roughness to at least 0.03)."""
    return _props(ctx, spec, with_props=True)


def _props(ctx: Ctx, spec: MaterialSpec, with_props: bool) -> tuple[np.ndarray | None, np.ndarray | None, np.ndarray]:
    """``(roughness, metallic, height)``; without ``with_props`` only the height (the others None)."""
    rough0, metal0 = base_props(spec)
    h, dr = _RELIEF[spec.material](ctx, spec)
    h = np.broadcast_to(h, (ctx.n,)).astype(F32, copy=True)
    rough = np.full(ctx.n, F32(rough0), dtype=F32) + dr if with_props else None
    metal = np.full(ctx.n, F32(metal0), dtype=F32) if with_props else None
    # Overlays: rust (the kind "rust" or a "rusty" overlay) and moss are dielectric and rough.
    overlays = []
    if spec.material == "rust" or spec.overlay == "rust":
        mask = rust_mask(ctx, 0.55 if spec.material == "rust" else 0.35)
        h += mask * (F32(0.0012) + F32(0.0012) * ctx.noise("rust-mottle", 14.0, 2))
        overlays.append((mask, 0.9))
    if spec.overlay == "moss":
        mask = moss_mask(ctx)
        h += mask * (F32(0.003) * ctx.noise("moss", 5.0, 4))
        overlays.append((mask, 1.0))
    scratches = scratch_field(ctx, spec) if spec.wear > 0 and "scratches" in spec.wear_kinds else None
    if scratches is not None:
        h -= F32(0.0008) * scratches
    if not with_props:
        return None, None, h
    for mask, r in overlays:
        rough = rough + (F32(r) - rough) * mask
        metal = metal * (F32(1.0) - mask)
    if spec.wear > 0:
        w = spec.wear
        if "dirt" in spec.wear_kinds:
            m = smoothstep(0.0, 0.35, ctx.noise("dirt", 2.4, 3) + F32(0.3 * (w - 0.5))) * F32(0.6 * w)
            rough = rough + (F32(0.95) - rough) * m * F32(0.6)
        if "fade" in spec.wear_kinds:
            f = smoothstep(-0.25, 0.3, ctx.noise("fade", 1.5, 2)) * F32(0.45 * w)
            rough = rough + (F32(0.9) - rough) * f * F32(0.4)
        if scratches is not None:
            rough = rough + (F32(0.75) - rough) * scratches * F32(0.7 if metal0 > 0 else 0.3)
    np.clip(rough, F32(0.03), F32(1.0), out=rough)
    np.clip(metal, F32(0.0), F32(1.0), out=metal)
    return rough, metal, h
