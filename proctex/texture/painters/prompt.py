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
from .vocabulary import (
    _ALL_WEAR,
    _AXIS_WORDS,
    _DEFAULT_COLORS,
    _FINISH_WORDS,
    _FLOWER_CENTRE,
    _FLOWER_PETAL,
    _INK,
    _NO_WEAR_WORDS,
    _OFF_WHITE,
    _PATCHWORK_DEFAULT,
    _PLAID_DEFAULT,
    _SCALE_WORDS,
    _STOP_WORDS,
    _TEXTILE_PATTERNS,
    _THIN_STRIPES,
    _WEAK_MATERIALS,
    DEFAULT_MATERIAL,
    MATERIAL_KINDS,
    MATERIAL_WORDS,
    OVERLAY_WORDS,
    PATTERN_WORDS,
    PATTERNS,
    WEAR_WORDS,
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
        finish: "default", "glossy", "polished", "matte", "brushed" or "hammered".
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
