"""Prompt -> :class:`MaterialSpec`: what the offline surface painter understands of a text prompt.

The parser is a longest-phrase-first scan over a fixed vocabulary: colour names (the ~1,000-name table
of :mod:`.colors`, with modifiers such as "dark", "pale", "very light"), materials ("walnut", "marble",
"stainless steel", "orange peel", ...), patterns ("striped", "polka dots", "tartan", ...), wear
("worn", "scratched", ...), scale ("large", "fine"), finish ("glossy", "matte", "brushed") and pattern
direction ("vertical"). Words it does not know are listed in ``MaterialSpec.ignored``; an empty or
unparseable prompt gives a plain default material, never an error.

Ambiguous words that are both a colour and a material ("gold", "velvet", "brick", "rust", ...) are a
material when the prompt names no other material (the last one wins: "gold velvet" is gold-coloured
velvet), and a colour otherwise ("cherry leather" is cherry-red leather).
"""

from __future__ import annotations

import colorsys
import re
from dataclasses import dataclass, field

from .colors import (
    COLOR_TABLE,
    INTENSIFIERS,
    MAX_NAME_WORDS,
    MODIFIERS,
    RGB,
    apply_modifier,
    hex_to_rgb,
    hls,
    lightness,
    luminance,
    mix,
    normalise_name,
    scale_rgb,
)

__all__ = [
    "MaterialSpec",
    "parse_prompt",
    "MATERIAL_KINDS",
    "PATTERNS",
    "MATERIAL_WORDS",
    "PATTERN_WORDS",
    "WEAR_WORDS",
    "DEFAULT_MATERIAL",
]

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


@dataclass(frozen=True)
class MaterialSpec:
    """What to synthesise, as understood from a prompt.

    Attributes:
        prompt: the prompt as given.
        material: the material kind, one of :data:`MATERIAL_KINDS`.
        variant: the specific material ("walnut", "gold", "porcelain", "denim", ...); equals ``material``
            for the generic word.
        base_colors: ``(main, accent)`` RGB in [0, 1]: main body colour, and the accent the material uses
            for veins / rings / rust / mortar / spots (kept in contrast with ``main``).
        pattern: one of :data:`PATTERNS`, or None.
        pattern_colors: colours of the pattern (>= 2 when ``pattern`` is set, else empty); the order is
            the prompt's ("blue and white stripes": blue first). Floral: background, petals, centres.
        wear: 0 (new) .. 1 (very worn).
        wear_kinds: subset of ``("dirt", "scratches", "fade")``.
        scale: feature-size multiplier (2: features twice as large, 0.5: half).
        finish: "default", "glossy", "polished", "matte" or "brushed".
        pattern_axis: "horizontal", "vertical" or "diagonal" (stripes, plaid orientation).
        thin_pattern: pinstripes (thin lines instead of equal bands).
        overlay: "rust" or "moss" growing over the material, or None.
        color_names: the colour phrases of the prompt, in order (with their modifiers).
        user_colors: whether the main colour came from the prompt (vs the material's default).
        understood: the prompt's phrases that were used.
        ignored: the prompt's words that were not understood (stop words are neither).
        notes: one human-readable line: what was understood, what was ignored, which defaults applied.
    """

    prompt: str
    material: str = DEFAULT_MATERIAL
    variant: str = DEFAULT_MATERIAL
    base_colors: tuple[RGB, ...] = _DEFAULT_COLORS[DEFAULT_MATERIAL]
    pattern: str | None = None
    pattern_colors: tuple[RGB, ...] = ()
    wear: float = 0.0
    wear_kinds: tuple[str, ...] = ()
    scale: float = 1.0
    finish: str = "default"
    pattern_axis: str = "horizontal"
    thin_pattern: bool = False
    overlay: str | None = None
    color_names: tuple[str, ...] = ()
    user_colors: bool = False
    understood: tuple[str, ...] = ()
    ignored: tuple[str, ...] = ()
    notes: str = ""

    @property
    def base_color(self) -> RGB:
        """The main colour (``base_colors[0]``)."""
        return self.base_colors[0]

    @property
    def accent_color(self) -> RGB:
        """The accent colour (``base_colors[1]``)."""
        return self.base_colors[1]


# ----------------------------------------------------------------------------------------------------
# Tokenising and phrase matching
# ----------------------------------------------------------------------------------------------------

_HEX_RE = re.compile(r"#[0-9a-fA-F]{6}\b|#[0-9a-fA-F]{3}\b")


def _tokens(prompt: str) -> list[str]:
    """Normalised words; hex colours ("#ff8800") kept as single tokens."""
    hexes = _HEX_RE.findall(prompt)
    s = _HEX_RE.sub(" qxhexq ", prompt)
    s = normalise_name(s)
    s = re.sub(r"[^a-z0-9_&#\s]", " ", s)
    out, k = [], 0
    for w in s.split():
        if w == "qxhexq":
            out.append(hexes[k].lower())
            k += 1
        else:
            out.append(w)
    return out


_MAX_PHRASE = max(
    MAX_NAME_WORDS,
    *(len(p.split()) for d in (MATERIAL_WORDS, PATTERN_WORDS, WEAR_WORDS, _FINISH_WORDS) for p in d),
    *(len(p.split()) for p in _NO_WEAR_WORDS),
)
_MATERIAL_SINGLE = {p for p in MATERIAL_WORDS if " " not in p}


def _match(words: list[str], i: int) -> tuple[int, str, str]:
    """Longest known phrase starting at ``words[i]``: ``(length, category, phrase)``; (1, "unknown", w) if none.

    Categories: material, pattern, wear, nowear, overlay, finish, axis, scale, modifier, intensifier,
    color, hex, stop. A colour phrase of 2+ words whose last word is a material ("green apple",
    "dark gold") is not taken whole, so the material word stays a material.
    """
    for length in range(min(_MAX_PHRASE, len(words) - i), 0, -1):
        phrase = " ".join(words[i : i + length])
        if phrase in MATERIAL_WORDS:
            return length, "material", phrase
        if phrase in PATTERN_WORDS:
            return length, "pattern", phrase
        if phrase in WEAR_WORDS:
            return length, "wear", phrase
        if phrase in _NO_WEAR_WORDS:
            return length, "nowear", phrase
        if phrase in _FINISH_WORDS:
            return length, "finish", phrase
        if length == 1 and phrase in MODIFIERS:  # "dark", "pale" are XKCD colours too; as words they modify
            return 1, "modifier", phrase
        if phrase in COLOR_TABLE and not (length > 1 and words[i + length - 1] in _MATERIAL_SINGLE):
            return length, "color", phrase
    w = words[i]
    if w.startswith("#"):
        return 1, "hex", w
    for cat, table in (("overlay", OVERLAY_WORDS), ("axis", _AXIS_WORDS), ("scale", _SCALE_WORDS),
                       ("modifier", MODIFIERS), ("intensifier", INTENSIFIERS)):  # fmt: skip
        if w in table:
            return 1, cat, w
    if w in _STOP_WORDS:
        return 1, "stop", w
    return 1, "unknown", w


# ----------------------------------------------------------------------------------------------------
# Parsing
# ----------------------------------------------------------------------------------------------------


@dataclass
class _Scan:
    colors: list[tuple[int, str, RGB]] = field(default_factory=list)  # (position, phrase with modifiers, rgb)
    materials: list[tuple[int, str, str, str]] = field(default_factory=list)  # (position, phrase, kind, variant)
    material_mods: list[tuple[str, float]] = field(default_factory=list)  # modifiers not followed by a colour
    patterns: list[str] = field(default_factory=list)
    wear: list[tuple[str, float]] = field(default_factory=list)
    no_wear: bool = False
    finish: str = "default"
    axis: str = "horizontal"
    scale: float = 1.0
    overlay: str | None = None
    understood: list[str] = field(default_factory=list)
    ignored: list[str] = field(default_factory=list)


def _scan(words: list[str]) -> _Scan:
    """One left-to-right pass: longest phrases first; modifiers wait for the next colour or material."""
    sc = _Scan()
    mods: list[tuple[str, float]] = []  # pending modifiers (word, strength)
    mod_words: list[str] = []  # pending modifier and intensifier words, for the colour's display name
    strength = 1.0  # pending intensifier
    i = 0
    while i < len(words):
        pos = i
        length, cat, phrase = _match(words, i)
        if cat == "color" and strength != 1.0 and length > 1 and words[i] in MODIFIERS:
            length, cat, phrase = 1, "modifier", words[i]  # "very dark teal": "very" needs its "dark"
        i += length
        if cat == "stop":
            continue
        if cat == "unknown":
            sc.ignored.append(phrase)
            continue
        sc.understood.append(phrase)
        if cat == "intensifier":
            strength *= INTENSIFIERS[phrase]
            mod_words.append(phrase)
        elif cat == "modifier":
            mods.append((phrase, strength))
            mod_words.append(phrase)
            strength = 1.0
        elif cat in ("color", "hex"):
            rgb = COLOR_TABLE[phrase] if cat == "color" else hex_to_rgb(phrase)
            for mod, k in reversed(mods):
                rgb = apply_modifier(rgb, mod, k)
            sc.colors.append((pos, " ".join([*mod_words, phrase]), rgb))
            mods, mod_words, strength = [], [], 1.0
        elif cat == "material":
            kind, variant = MATERIAL_WORDS[phrase]
            sc.materials.append((pos, phrase, kind, variant))
            sc.material_mods.extend(mods)
            mods, mod_words, strength = [], [], 1.0
        elif cat == "pattern":
            sc.patterns.append(phrase)
        elif cat == "wear":
            sc.wear.append((phrase, strength))
            strength = 1.0
        elif cat == "nowear":
            sc.no_wear = True
        elif cat == "overlay":
            sc.overlay = OVERLAY_WORDS[phrase]
        elif cat == "finish":
            sc.finish = _FINISH_WORDS[phrase]
        elif cat == "axis":
            sc.axis = _AXIS_WORDS[phrase]
        elif cat == "scale":
            sc.scale *= _SCALE_WORDS[phrase] ** strength
            strength = 1.0
    sc.material_mods.extend(mods)  # trailing modifiers ("walnut, dark") tint the material
    return sc


def _resolve_material(sc: _Scan) -> tuple[str, str, list[str]]:
    """Pick (kind, variant); ambiguous colour/material words not chosen become colours (in prompt order).

    Returns ``(kind, variant, notes)``.
    """
    notes: list[str] = []
    if not sc.materials:
        return DEFAULT_MATERIAL, DEFAULT_MATERIAL, notes
    ambiguous = [m for m in sc.materials if m[1] in COLOR_TABLE]
    firm = [m for m in sc.materials if m[1] not in COLOR_TABLE]
    strong = [m for m in firm if m[1] not in _WEAK_MATERIALS]
    if strong:
        as_colors, chosen = ambiguous, strong
    elif ambiguous:  # the last ambiguous word is the head noun ("gold velvet" -> velvet)
        as_colors, chosen = ambiguous[:-1], ambiguous[-1:]
    else:
        as_colors, chosen = [], firm
    for pos, phrase, _, _ in as_colors:
        sc.colors.append((pos, phrase, COLOR_TABLE[phrase]))
        notes.append(f"'{phrase}' read as a colour")
    sc.colors.sort(key=lambda c: c[0])
    kind = chosen[-1][2]
    same = [m for m in chosen if m[2] == kind]
    specific = [m for m in same if m[3] != kind]
    variant = (specific or same)[-1][3]
    others = sorted({m[1] for m in sc.materials if m[2] != kind and m not in as_colors})
    if others:
        notes.append(f"also named {', '.join(others)}; using {kind}")
    if kind == "metal" and sc.overlay == "rust":
        kind, variant, sc.overlay = "rust", "rust", None
    return kind, variant, notes


def _contrast(main: RGB, accent: RGB, min_diff: float = 0.12) -> RGB:
    """``accent``, or a shade of ``main`` on the same side (darker / lighter) if the two are too close
    (in perceptual lightness and in RGB distance)."""
    dist = sum((a - b) ** 2 for a, b in zip(main, accent)) ** 0.5
    lm, la = lightness(main), lightness(accent)
    if abs(lm - la) >= min_diff or dist >= 0.3:
        return accent
    darker = la <= lm
    if darker and lm > 0.1 or lm > 0.85:
        return scale_rgb(main, 0.5)
    return mix(main, (1.0, 1.0, 1.0), 0.55)


def _partner(c: RGB) -> RGB:
    """A second pattern colour for a single given colour: off-white next to colours, ink next to light ones."""
    return _OFF_WHITE if luminance(c) < 0.6 else _INK


def _derive_palette(colors: list[RGB], n: int) -> tuple[RGB, ...]:
    """``colors`` extended to ``n`` by lighter, darker and hue-rotated versions."""
    out = list(colors)
    k = 0
    while len(out) < n:
        src = colors[k % len(colors)]
        step = k // len(colors)
        if step % 3 == 0:
            out.append(mix(src, (1.0, 1.0, 1.0), 0.45))
        elif step % 3 == 1:
            out.append(scale_rgb(src, 0.55))
        else:
            h, l, s = hls(src)
            out.append(tuple(colorsys.hls_to_rgb((h + 0.33) % 1.0, l, max(s, 0.35))))  # type: ignore[arg-type]
        k += 1
    return tuple(out[:n])


def _pattern_colors(pattern: str, user: list[RGB], main: RGB) -> tuple[RGB, ...]:
    if pattern == "floral":
        bg = user[0] if user else main
        petal = user[1] if len(user) > 1 else (_FLOWER_PETAL if luminance(bg) > 0.25 else _OFF_WHITE)
        centre = user[2] if len(user) > 2 else _FLOWER_CENTRE
        return bg, _contrast(bg, petal), centre
    if pattern == "patchwork":
        return _derive_palette(user, max(5, len(user))) if user else _PATCHWORK_DEFAULT
    if pattern == "plaid":
        if not user:
            return _PLAID_DEFAULT
        base = list(user)
        if len(base) == 1:
            base += [scale_rgb(base[0], 0.4), _partner(base[0])]
        elif len(base) == 2:
            base += [scale_rgb(base[0], 0.45)]
        return tuple(base[:6])
    if pattern == "speckles":
        bg = user[0] if user else main
        speck = user[1] if len(user) > 1 else (scale_rgb(bg, 0.35) if luminance(bg) > 0.2 else mix(bg, (1.0, 1.0, 1.0), 0.7))
        return bg, _contrast(bg, speck, 0.15)
    # stripes, checks, dots
    if len(user) >= 2:
        return tuple(user[:6])
    first = user[0] if user else main
    return first, _partner(first)


def _wear(sc: _Scan) -> tuple[float, tuple[str, ...]]:
    if sc.no_wear or not sc.wear:
        return 0.0, ()
    keep = 1.0
    kinds: set[str] = set()
    for phrase, k in sc.wear:
        level, ks = WEAR_WORDS[phrase]
        keep *= 1.0 - min(1.0, level * k)
        kinds.update(ks)
    return round(min(1.0, 1.0 - keep), 4), tuple(w for w in _ALL_WEAR if w in kinds)


def parse_prompt(prompt: str) -> MaterialSpec:
    """Parse a text prompt into a :class:`MaterialSpec`. Never fails on content; ValueError if not a str.

    >>> parse_prompt("blue and white striped ceramic").pattern
    'stripes'
    """
    if not isinstance(prompt, str):
        raise ValueError(f"prompt must be a string, got {type(prompt).__name__}")
    words = _tokens(prompt)
    sc = _scan(words)
    kind, variant, notes = _resolve_material(sc)
    default_main, default_accent = _DEFAULT_COLORS[variant]
    user = [rgb for _, _, rgb in sc.colors]
    pattern = PATTERN_WORDS[sc.patterns[0]] if sc.patterns else None
    if len(sc.patterns) > 1 and len({PATTERN_WORDS[p] for p in sc.patterns}) > 1:
        notes.append(f"several patterns named; using {pattern}")

    if pattern and not sc.materials and pattern in _TEXTILE_PATTERNS:
        kind = variant = "fabric"
        default_main, default_accent = _DEFAULT_COLORS[variant]
    if pattern and "on" in words and len(user) > 1:
        # "yellow dots on white": colours after "on" are the background, which comes first.
        on = words.index("on")
        after = [rgb for pos, _, rgb in sc.colors if pos > on]
        if after and len(after) < len(user):
            user = after + [rgb for pos, _, rgb in sc.colors if pos <= on]
    main = user[0] if user else default_main
    mod_words = " ".join(m for m, _ in sc.material_mods)
    if not user:
        for mod, k in sc.material_mods:
            main = apply_modifier(main, mod, k)
            default_accent = apply_modifier(default_accent, mod, k)
    elif sc.material_mods:
        notes.append(f"modifier(s) {mod_words} not followed by a colour: ignored")
    if kind in ("marble", "granite") and luminance(main) < 0.12 and not (len(user) > 1 and pattern is None):
        default_accent = (0.86, 0.85, 0.81)  # black marble: white veins
    accent = user[1] if (len(user) > 1 and pattern is None) else default_accent
    accent = _contrast(main, accent)
    pattern_colors = _pattern_colors(pattern, user, main) if pattern else ()
    wear, wear_kinds = _wear(sc)

    parts = []
    what = variant if variant == kind else f"{variant} ({kind})"
    parts.append(f"material: {what}" if sc.materials else f"material: none named, default {kind}")
    if sc.colors:
        parts.append("colours: " + ", ".join(name for _, name, _ in sc.colors))
    else:
        parts.append(f"colours: {variant} default" + (f" made {mod_words}" if mod_words else ""))
    if pattern:
        parts.append(f"pattern: {pattern}" + (f" ({sc.axis})" if pattern in ("stripes", "plaid") and sc.axis != "horizontal" else ""))
    if wear:
        parts.append(f"wear {wear:.2f} ({', '.join(wear_kinds)})")
    if sc.overlay:
        parts.append(f"{sc.overlay} overlay")
    if sc.scale != 1.0:
        parts.append(f"scale x{sc.scale:g}")
    if sc.finish != "default":
        parts.append(f"finish: {sc.finish}")
    parts.extend(notes)
    if sc.ignored:
        parts.append("ignored: " + ", ".join(sc.ignored))
    if not words or not sc.understood:
        parts.insert(0, "nothing understood; using a plain default material" if words else "empty prompt; using a plain default material")

    return MaterialSpec(
        prompt=prompt,
        material=kind,
        variant=variant,
        base_colors=(main, accent),
        pattern=pattern,
        pattern_colors=pattern_colors,
        wear=wear,
        wear_kinds=wear_kinds,
        scale=float(min(8.0, max(0.125, sc.scale))),
        finish=sc.finish,
        pattern_axis=sc.axis,
        thin_pattern=any(p in _THIN_STRIPES for p in sc.patterns),
        overlay=sc.overlay,
        color_names=tuple(name for _, name, _ in sc.colors),
        user_colors=bool(user),
        understood=tuple(sc.understood),
        ignored=tuple(sc.ignored),
        notes="; ".join(parts),
    )
