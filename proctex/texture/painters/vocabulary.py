"""The prompt parser's vocabulary (data): material, pattern, overlay, wear, scale, finish and axis
words, stop words, and each material's default colours."""

from __future__ import annotations

from .colors import (
    RGB,
)

#: every material kind the synthesiser implements.
MATERIAL_KINDS = (
    "plastic", "rubber", "wood", "marble", "granite", "stone", "concrete", "brick", "ceramic", "metal",
    "rust", "fabric", "velvet", "leather", "bark", "moss", "fruit", "mushroom",
)  # fmt: skip


#: every pattern kind.
PATTERNS = ("stripes", "checks", "plaid", "dots", "patchwork", "floral", "speckles")


#: kind of an empty / material-less prompt.
DEFAULT_MATERIAL = "plastic"


# phrase -> (kind, variant). Variants pick default colours and small synthesis differences.
MATERIAL_WORDS: dict[str, tuple[str, str]] = {
    # wood
    **{w: ("wood", "wood") for w in ("wood", "wooden", "timber", "hardwood", "plywood", "woodgrain", "wood grain")},
    **{w: ("wood", w) for w in ("oak", "walnut", "pine", "maple", "cherry", "mahogany", "teak", "birch", "ebony", "bamboo", "cedar", "beech", "rosewood")},
    "oaken": ("wood", "oak"),
    # stones
    "marble": ("marble", "marble"), "marbled": ("marble", "marble"),
    "granite": ("granite", "granite"), "terrazzo": ("granite", "terrazzo"),
    "stone": ("stone", "stone"), "rock": ("stone", "stone"), "stony": ("stone", "stone"),
    "slate": ("stone", "slate"), "sandstone": ("stone", "sandstone"), "limestone": ("stone", "limestone"),
    "cobblestone": ("stone", "stone"),
    "concrete": ("concrete", "concrete"), "cement": ("concrete", "concrete"),
    "plaster": ("concrete", "plaster"), "stucco": ("concrete", "plaster"),
    "brick": ("brick", "brick"), "bricks": ("brick", "brick"), "brickwork": ("brick", "brick"),
    # ceramics
    "ceramic": ("ceramic", "ceramic"), "ceramics": ("ceramic", "ceramic"), "pottery": ("ceramic", "ceramic"),
    "porcelain": ("ceramic", "porcelain"), "china": ("ceramic", "porcelain"),
    "glazed": ("ceramic", "glazed"), "glaze": ("ceramic", "glazed"), "enamel": ("ceramic", "glazed"),
    "enamelled": ("ceramic", "glazed"), "enameled": ("ceramic", "glazed"),
    "terracotta": ("ceramic", "terracotta"), "clay": ("ceramic", "terracotta"), "earthenware": ("ceramic", "terracotta"),
    # metals
    "metal": ("metal", "metal"), "metallic": ("metal", "metal"),
    "steel": ("metal", "steel"), "stainless": ("metal", "steel"), "stainless steel": ("metal", "steel"),
    "silver": ("metal", "silver"), "gold": ("metal", "gold"), "golden": ("metal", "gold"), "gilded": ("metal", "gold"),
    "brass": ("metal", "brass"), "copper": ("metal", "copper"), "bronze": ("metal", "bronze"),
    "iron": ("metal", "iron"), "cast iron": ("metal", "iron"), "aluminium": ("metal", "aluminium"),
    "aluminum": ("metal", "aluminium"), "chrome": ("metal", "chrome"), "chromed": ("metal", "chrome"),
    "pewter": ("metal", "pewter"), "titanium": ("metal", "steel"), "tin": ("metal", "aluminium"),
    "rust": ("rust", "rust"), "corroded metal": ("rust", "rust"),
    # textiles
    **{w: ("fabric", "fabric") for w in ("fabric", "cloth", "textile", "upholstery", "upholstered", "cotton", "knit", "knitted", "woven", "weave")},
    "wool": ("fabric", "wool"), "woolen": ("fabric", "wool"), "woollen": ("fabric", "wool"), "felt": ("fabric", "wool"),
    "tweed": ("fabric", "tweed"), "linen": ("fabric", "linen"), "burlap": ("fabric", "linen"), "jute": ("fabric", "linen"),
    "hessian": ("fabric", "linen"), "canvas": ("fabric", "canvas"), "denim": ("fabric", "denim"), "jeans": ("fabric", "denim"),
    "silk": ("fabric", "silk"), "satin": ("fabric", "silk"),
    "velvet": ("velvet", "velvet"), "velour": ("velvet", "velvet"), "plush": ("velvet", "velvet"),
    "crushed velvet": ("velvet", "velvet"), "suede": ("velvet", "suede"),
    "leather": ("leather", "leather"), "leathery": ("leather", "leather"), "faux leather": ("leather", "leather"),
    # others
    "plastic": ("plastic", "plastic"), "acrylic": ("plastic", "plastic"), "vinyl": ("plastic", "plastic"),
    "resin": ("plastic", "plastic"), "painted": ("plastic", "plastic"), "paint": ("plastic", "plastic"),
    "rubber": ("rubber", "rubber"), "rubbery": ("rubber", "rubber"), "silicone": ("rubber", "rubber"), "latex": ("rubber", "rubber"),
    "bark": ("bark", "bark"), "tree bark": ("bark", "bark"),
    "moss": ("moss", "moss"), "lichen": ("moss", "moss"),
    "orange peel": ("fruit", "orange"), "orange skin": ("fruit", "orange"), "citrus": ("fruit", "orange"),
    "citrus peel": ("fruit", "orange"), "lemon peel": ("fruit", "lemon"), "lemon skin": ("fruit", "lemon"),
    "lime peel": ("fruit", "lime"), "lime skin": ("fruit", "lime"),
    "apple": ("fruit", "apple"), "apple skin": ("fruit", "apple"), "apple peel": ("fruit", "apple"),
    "pumpkin": ("fruit", "pumpkin"), "pumpkin skin": ("fruit", "pumpkin"), "gourd": ("fruit", "pumpkin"),
    "peach skin": ("fruit", "peach"), "tomato skin": ("fruit", "tomato"), "banana peel": ("fruit", "banana"),
    "banana skin": ("fruit", "banana"), "fruit": ("fruit", "orange"), "fruit skin": ("fruit", "orange"),
    "peel": ("fruit", "orange"),
    "mushroom": ("mushroom", "mushroom"), "fungus": ("mushroom", "mushroom"), "toadstool": ("mushroom", "toadstool"),
    "fly agaric": ("mushroom", "toadstool"), "amanita": ("mushroom", "toadstool"),
}  # fmt: skip


# Material words that only count when no other material is named ("painted wood" is wood).
_WEAK_MATERIALS = {"painted", "paint", "metallic", "woven", "weave", "upholstery", "upholstered", "fruit", "peel", "textile"}


# Words that mark rust / moss growing over another material ("rusty steel", "mossy stone").
OVERLAY_WORDS = {"rusty": "rust", "rusted": "rust", "corroded": "rust", "mossy": "moss", "overgrown": "moss"}


PATTERN_WORDS: dict[str, str] = {
    **{w: "stripes" for w in ("stripes", "stripe", "striped", "stripey", "stripy", "banded", "bands", "pinstripe", "pinstripes", "pinstriped", "pin striped")},
    **{w: "checks" for w in ("checks", "check", "checked", "checkered", "chequered", "checker", "checkerboard", "chequerboard", "gingham")},
    **{w: "plaid" for w in ("plaid", "tartan", "flannel")},
    **{w: "dots" for w in ("polka dots", "polka dot", "polka dotted", "polka", "dots", "dot", "dotted", "spots", "spotted", "spotty")},
    **{w: "patchwork" for w in ("patchwork", "patches", "patched", "quilt", "quilted")},
    **{w: "floral" for w in ("floral", "flowers", "flower", "flowery", "flowered", "rosettes", "blossoms", "botanical")},
    **{w: "speckles" for w in ("speckles", "speckle", "speckled", "flecks", "flecked", "fleck", "freckled", "spattered", "splattered", "sprinkled")},
}  # fmt: skip


_TEXTILE_PATTERNS = {"stripes", "checks", "plaid", "dots", "patchwork", "floral"}


_THIN_STRIPES = {"pinstripe", "pinstripes", "pinstriped", "pin striped"}


# wear word -> (level, kinds)
_ALL_WEAR = ("dirt", "scratches", "fade")


WEAR_WORDS: dict[str, tuple[float, tuple[str, ...]]] = {
    "worn": (0.5, _ALL_WEAR), "worn out": (0.7, _ALL_WEAR), "well worn": (0.65, _ALL_WEAR),
    "weathered": (0.6, ("dirt", "fade")), "old": (0.45, _ALL_WEAR), "aged": (0.5, _ALL_WEAR),
    "ancient": (0.7, _ALL_WEAR), "antique": (0.4, ("dirt", "fade")), "vintage": (0.35, ("fade", "scratches")),
    "scratched": (0.5, ("scratches",)), "scratchy": (0.4, ("scratches",)), "scuffed": (0.45, ("scratches", "dirt")),
    "dirty": (0.55, ("dirt",)), "grimy": (0.6, ("dirt",)), "stained": (0.45, ("dirt",)), "dusty": (0.4, ("dirt", "fade")),
    "muddy": (0.6, ("dirt",)), "faded": (0.5, ("fade",)), "sun bleached": (0.6, ("fade",)), "bleached": (0.5, ("fade",)),
    "distressed": (0.7, _ALL_WEAR), "battered": (0.7, _ALL_WEAR), "damaged": (0.6, _ALL_WEAR), "used": (0.3, _ALL_WEAR),
    "rustic": (0.35, ("dirt", "fade")), "shabby": (0.6, _ALL_WEAR), "tattered": (0.7, _ALL_WEAR),
}  # fmt: skip


_NO_WEAR_WORDS = {"new", "brand new", "clean", "pristine", "fresh", "spotless", "immaculate", "mint condition"}


_SCALE_WORDS = {
    **{w: 2.0 for w in ("large", "big", "huge", "wide", "broad", "chunky", "bold", "giant", "oversized", "coarse", "thick")},
    **{w: 0.5 for w in ("small", "fine", "tiny", "thin", "narrow", "dense", "micro", "delicate", "little")},
}


_FINISH_WORDS = {
    **{w: "glossy" for w in ("glossy", "gloss", "shiny", "lacquered", "varnished", "lustrous", "sleek")},
    **{w: "polished" for w in ("polished", "mirror", "burnished")},
    **{w: "matte" for w in ("matte", "matt", "flat", "unglazed", "raw", "rough")},
    **{w: "brushed" for w in ("brushed", "satin finish", "hairline")},
    **{w: "hammered" for w in ("hammered", "beaten", "dimpled", "planished")},
}


_AXIS_WORDS = {"horizontal": "horizontal", "horizontally": "horizontal", "vertical": "vertical",
               "vertically": "vertical", "diagonal": "diagonal", "diagonally": "diagonal", "bias": "diagonal"}  # fmt: skip


_STOP_WORDS = {
    "a", "an", "the", "with", "and", "&", "or", "of", "in", "on", "made", "from", "texture", "textured",
    "material", "surface", "style", "styled", "pattern", "patterned", "colour", "color", "coloured", "colored",
    "finish", "finished", "look", "looking", "like", "ish", "tone", "toned", "tones", "effect", "some",
    "its", "it", "is", "that", "this", "has", "having", "covered", "by", "to", "for", "as",
}  # fmt: skip


# variant -> (main colour, accent colour). The accent is the vein / ring / rust / spot / stitch colour.
_DEFAULT_COLORS: dict[str, tuple[RGB, RGB]] = {
    "plastic": ((0.78, 0.78, 0.77), (0.55, 0.55, 0.55)),
    "rubber": ((0.16, 0.16, 0.17), (0.30, 0.30, 0.30)),
    "wood": ((0.66, 0.47, 0.29), (0.40, 0.25, 0.13)),
    "oak": ((0.72, 0.54, 0.33), (0.47, 0.32, 0.17)),
    "walnut": ((0.40, 0.26, 0.16), (0.22, 0.13, 0.08)),
    "pine": ((0.87, 0.72, 0.49), (0.66, 0.45, 0.24)),
    "maple": ((0.90, 0.78, 0.60), (0.72, 0.55, 0.36)),
    "cherry": ((0.62, 0.31, 0.18), (0.40, 0.17, 0.09)),
    "mahogany": ((0.47, 0.18, 0.10), (0.28, 0.09, 0.05)),
    "teak": ((0.63, 0.44, 0.24), (0.42, 0.27, 0.13)),
    "birch": ((0.92, 0.84, 0.69), (0.76, 0.64, 0.46)),
    "ebony": ((0.17, 0.12, 0.10), (0.07, 0.05, 0.04)),
    "bamboo": ((0.87, 0.77, 0.52), (0.68, 0.56, 0.32)),
    "cedar": ((0.70, 0.42, 0.26), (0.48, 0.25, 0.14)),
    "beech": ((0.86, 0.67, 0.47), (0.66, 0.47, 0.30)),
    "rosewood": ((0.42, 0.17, 0.12), (0.22, 0.08, 0.06)),
    "marble": ((0.93, 0.92, 0.90), (0.38, 0.38, 0.41)),
    "granite": ((0.60, 0.58, 0.56), (0.12, 0.12, 0.13)),
    "terrazzo": ((0.88, 0.86, 0.82), (0.45, 0.42, 0.40)),
    "stone": ((0.57, 0.55, 0.51), (0.33, 0.32, 0.30)),
    "slate": ((0.34, 0.37, 0.40), (0.20, 0.22, 0.24)),
    "sandstone": ((0.80, 0.67, 0.49), (0.62, 0.47, 0.31)),
    "limestone": ((0.84, 0.81, 0.72), (0.64, 0.61, 0.53)),
    "concrete": ((0.63, 0.62, 0.59), (0.40, 0.40, 0.38)),
    "plaster": ((0.90, 0.88, 0.84), (0.70, 0.68, 0.64)),
    "brick": ((0.63, 0.27, 0.18), (0.78, 0.76, 0.70)),  # accent: mortar
    "ceramic": ((0.93, 0.91, 0.87), (0.75, 0.73, 0.70)),
    "porcelain": ((0.96, 0.96, 0.95), (0.82, 0.84, 0.88)),
    "glazed": ((0.90, 0.89, 0.86), (0.70, 0.68, 0.64)),
    "terracotta": ((0.76, 0.41, 0.26), (0.58, 0.28, 0.16)),
    "metal": ((0.62, 0.63, 0.65), (0.42, 0.43, 0.45)),
    "steel": ((0.64, 0.66, 0.68), (0.43, 0.45, 0.47)),
    "silver": ((0.80, 0.80, 0.82), (0.58, 0.58, 0.60)),
    "gold": ((0.86, 0.68, 0.26), (0.62, 0.45, 0.13)),
    "brass": ((0.79, 0.66, 0.34), (0.56, 0.45, 0.20)),
    "copper": ((0.78, 0.46, 0.30), (0.53, 0.28, 0.16)),
    "bronze": ((0.62, 0.45, 0.26), (0.40, 0.28, 0.15)),
    "iron": ((0.42, 0.42, 0.43), (0.26, 0.26, 0.27)),
    "aluminium": ((0.78, 0.79, 0.80), (0.60, 0.61, 0.62)),
    "chrome": ((0.76, 0.77, 0.79), (0.45, 0.46, 0.48)),
    "pewter": ((0.58, 0.58, 0.56), (0.40, 0.40, 0.39)),
    "rust": ((0.45, 0.44, 0.43), (0.56, 0.26, 0.10)),  # main: the metal under the rust; accent: rust
    "fabric": ((0.58, 0.57, 0.54), (0.44, 0.43, 0.41)),
    "wool": ((0.74, 0.71, 0.65), (0.55, 0.52, 0.47)),
    "tweed": ((0.50, 0.45, 0.37), (0.30, 0.26, 0.20)),
    "linen": ((0.85, 0.80, 0.70), (0.70, 0.64, 0.53)),
    "canvas": ((0.80, 0.74, 0.60), (0.62, 0.56, 0.43)),
    "denim": ((0.22, 0.33, 0.52), (0.80, 0.82, 0.85)),  # accent: the white weft
    "silk": ((0.88, 0.84, 0.78), (0.70, 0.66, 0.60)),
    "velvet": ((0.46, 0.07, 0.15), (0.25, 0.03, 0.07)),
    "suede": ((0.60, 0.45, 0.31), (0.42, 0.30, 0.20)),
    "leather": ((0.45, 0.27, 0.15), (0.26, 0.14, 0.07)),
    "bark": ((0.37, 0.28, 0.21), (0.16, 0.12, 0.09)),
    "moss": ((0.36, 0.50, 0.18), (0.62, 0.70, 0.28)),  # accent: sunlit tips
    "orange": ((0.96, 0.55, 0.10), (0.99, 0.68, 0.22)),
    "lemon": ((0.98, 0.86, 0.25), (0.90, 0.78, 0.18)),
    "lime": ((0.46, 0.72, 0.16), (0.62, 0.80, 0.25)),
    "apple": ((0.72, 0.09, 0.10), (0.86, 0.76, 0.28)),  # accent: yellow streaks
    "pumpkin": ((0.93, 0.50, 0.10), (0.74, 0.34, 0.05)),
    "peach": ((0.98, 0.72, 0.50), (0.90, 0.36, 0.30)),
    "tomato": ((0.86, 0.15, 0.08), (0.95, 0.40, 0.15)),
    "banana": ((0.98, 0.85, 0.30), (0.45, 0.33, 0.15)),
    "mushroom": ((0.62, 0.37, 0.23), (0.95, 0.92, 0.84)),  # accent: spots and stem
    "toadstool": ((0.80, 0.10, 0.07), (0.97, 0.95, 0.90)),
}


_OFF_WHITE: RGB = (0.95, 0.93, 0.88)


_INK: RGB = (0.12, 0.14, 0.24)


_FLOWER_PETAL: RGB = (0.86, 0.36, 0.46)


_FLOWER_CENTRE: RGB = (0.96, 0.80, 0.26)


_PATCHWORK_DEFAULT: tuple[RGB, ...] = (
    (0.72, 0.32, 0.28), (0.86, 0.77, 0.57), (0.30, 0.45, 0.60), (0.48, 0.58, 0.35), (0.82, 0.60, 0.30),
)  # fmt: skip


_PLAID_DEFAULT: tuple[RGB, ...] = ((0.66, 0.11, 0.12), (0.10, 0.28, 0.18), (0.10, 0.13, 0.30), (0.93, 0.82, 0.38))


_RUST_COLOR: RGB = _DEFAULT_COLORS["rust"][1]


_MOSS_COLOR: RGB = _DEFAULT_COLORS["moss"][0]


# ------------------------------------------------------------------------------- sampled prompts
#: Words :func:`random_prompts` draws from, by what they may be combined with (each one the parser
#: above understands: a test parses every sampled prompt back).
RANDOM_WOODS = ("oak", "walnut", "pine", "maple", "cherry", "mahogany", "teak", "birch", "ebony", "bamboo")
RANDOM_STONES = ("marble", "granite", "slate", "sandstone", "limestone", "concrete", "terrazzo")
RANDOM_METALS = ("steel", "brass", "copper", "bronze", "gold", "silver", "iron", "chrome", "pewter")
RANDOM_CERAMICS = ("ceramic", "porcelain", "terracotta", "glazed ceramic")
RANDOM_TEXTILES = ("linen", "wool", "velvet", "leather", "denim", "silk", "tweed", "cotton", "canvas")
RANDOM_COLORS = ("red", "navy", "teal", "olive", "mustard", "burgundy", "charcoal", "cream", "ivory", "forest green", "sky blue", "rust orange", "plum", "sand", "black", "white")
RANDOM_PATTERNS = ("striped", "checked", "plaid", "polka dot", "floral", "patchwork")
RANDOM_FINISHES = {"wood": ("polished", "matte", "glossy"), "stone": ("polished", "matte"), "metal": ("brushed", "polished", "hammered"), "ceramic": ("glossy", "matte")}


def random_prompts(n: int, seed: int = 0) -> list[str]:
    """``n`` prompts sampled (``seed``) from the painter's vocabulary: a finished wood, stone or
    metal ("polished walnut"), a coloured ceramic ("matte teal porcelain"), or a textile in one or
    two colours, maybe patterned ("navy and cream striped linen"); different from each other while
    the vocabulary allows."""
    import numpy as np

    if isinstance(n, bool) or not isinstance(n, int) or not 0 <= n <= 1024:
        raise ValueError(f"n must be an integer in 0..1024, got {n!r}")
    rng = np.random.default_rng(seed)
    pick = lambda words: str(words[int(rng.integers(len(words)))])  # noqa: E731
    out: list[str] = []
    while len(out) < n:
        kind = pick(("wood", "stone", "metal", "ceramic", "textile", "textile"))
        if kind in ("wood", "stone", "metal"):
            words = {"wood": RANDOM_WOODS, "stone": RANDOM_STONES, "metal": RANDOM_METALS}[kind]
            prompt = f"{pick(RANDOM_FINISHES[kind])} {pick(words)}"
        elif kind == "ceramic":
            prompt = f"{pick(RANDOM_FINISHES['ceramic'])} {pick(RANDOM_COLORS)} {pick(RANDOM_CERAMICS)}"
        else:
            colors = pick(RANDOM_COLORS)
            if rng.random() < 0.5:
                second = pick([c for c in RANDOM_COLORS if c != colors])
                prompt = f"{colors} and {second} {pick(RANDOM_PATTERNS)} {pick(RANDOM_TEXTILES)}"
            else:
                prompt = f"{colors} {pick(RANDOM_TEXTILES)}"
        if prompt not in out or len(out) > 200:  # distinct while it is easy to be
            out.append(prompt)
    return out
