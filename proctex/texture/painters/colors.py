"""Named colours and colour modifiers.

The table (:data:`COLOR_TABLE`, ~1,000 names) is the XKCD colour survey plus the CSS4/X11 names, committed
as data in :mod:`proctex.texture.painters._color_table`. Names are looked up after :func:`normalise_name`
("Navy-Blue" -> "navy blue", "gray" -> "grey"). Modifiers (light, dark, pale, deep, bright, pastel,
muted, vivid, ...) act in HLS space, optionally scaled by an intensifier ("very", "slightly").

Colours are ``RGB = tuple[float, float, float]`` in [0, 1] (sRGB, gamma-encoded, like texture values).
"""

from __future__ import annotations

import colorsys
import re

from ._color_table import COLOR_TABLE as _HEX_TABLE

RGB = tuple[float, float, float]

__all__ = [
    "RGB",
    "COLOR_TABLE",
    "MODIFIERS",
    "INTENSIFIERS",
    "MAX_NAME_WORDS",
    "normalise_name",
    "hex_to_rgb",
    "lookup_color",
    "apply_modifier",
    "parse_color",
    "luminance",
    "lightness",
    "hls",
    "hue_degrees",
    "mix",
    "scale_rgb",
]


def hex_to_rgb(code: str) -> RGB:
    """``"#rrggbb"`` or ``"#rgb"`` -> RGB in [0, 1]. Raises ValueError on anything else."""
    s = code.strip().lstrip("#")
    if len(s) == 3:
        s = "".join(ch * 2 for ch in s)
    if len(s) != 6 or not re.fullmatch(r"[0-9a-fA-F]{6}", s):
        raise ValueError(f"not a hex colour: {code!r}")
    return tuple(int(s[i : i + 2], 16) / 255.0 for i in (0, 2, 4))  # type: ignore[return-value]


#: name -> RGB in [0, 1] for every table entry.
COLOR_TABLE: dict[str, RGB] = {name: hex_to_rgb(code) for name, code in _HEX_TABLE.items()}
#: longest name in words (phrase matching in the prompt parser looks this far ahead).
MAX_NAME_WORDS: int = max(len(name.split()) for name in COLOR_TABLE)


def normalise_name(text: str) -> str:
    """Lower case, "gray" -> "grey", "colour" spelling folded, "/", "-" and "_" as spaces, single spaces."""
    s = text.lower().replace("gray", "grey").replace("'", "")
    s = re.sub(r"[/\-_]", " ", s)
    return " ".join(s.split())


def lookup_color(name: str) -> RGB | None:
    """RGB of a table name (after normalisation), or None. No modifiers: see :func:`parse_color`."""
    return COLOR_TABLE.get(normalise_name(name))


def hls(rgb: RGB) -> tuple[float, float, float]:
    """(hue in [0, 1), lightness, saturation) of ``rgb``."""
    return colorsys.rgb_to_hls(*rgb)


def hue_degrees(rgb: RGB) -> float:
    """Hue angle in degrees [0, 360)."""
    return hls(rgb)[0] * 360.0


def luminance(rgb: RGB) -> float:
    """Relative luminance (Rec. 709 weights on linearised sRGB), in [0, 1]."""
    lin = [c / 12.92 if c <= 0.04045 else ((c + 0.055) / 1.055) ** 2.4 for c in rgb]
    return 0.2126 * lin[0] + 0.7152 * lin[1] + 0.0722 * lin[2]


def lightness(rgb: RGB) -> float:
    """Perceptual lightness: CIE L* / 100, in [0, 1] (0.5 is a mid grey, unlike luminance)."""
    y = luminance(rgb)
    f = y ** (1.0 / 3.0) if y > 0.008856 else 7.787 * y + 16.0 / 116.0
    return max(0.0, 1.16 * f - 0.16)


def _clip(v: float) -> float:
    return min(1.0, max(0.0, v))


def mix(a: RGB, b: RGB, t: float) -> RGB:
    """Linear blend ``a + t (b - a)``."""
    return tuple(_clip(x + t * (y - x)) for x, y in zip(a, b))  # type: ignore[return-value]


def scale_rgb(a: RGB, f: float) -> RGB:
    """``a * f`` clipped to [0, 1]."""
    return tuple(_clip(x * f) for x in a)  # type: ignore[return-value]


# Modifier -> function (h, l, s, strength) -> (h, l, s); strength 1 is the plain word.
def _light(h, l, s, k):
    return h, l + (1 - l) * 0.45 * k, s


def _dark(h, l, s, k):
    return h, l * (1 - 0.45 * k), s


def _pale(h, l, s, k):
    return h, l + (1 - l) * 0.55 * k, s * (1 - 0.35 * k)


def _pastel(h, l, s, k):
    return h, l + (0.86 - l) * k if l < 0.86 else l, s * (1 - 0.3 * k)


def _deep(h, l, s, k):
    return h, l * (1 - 0.3 * k), s + (1 - s) * 0.3 * k


def _bright(h, l, s, k):
    return h, l + (0.55 - l) * 0.35 * k, s + (1 - s) * 0.5 * k


def _vivid(h, l, s, k):
    return h, l + (0.5 - l) * 0.2 * k, s + (1 - s) * 0.7 * k


def _muted(h, l, s, k):
    return h, l, s * (1 - 0.5 * k)


def _soft(h, l, s, k):
    return h, l + (0.72 - l) * 0.35 * k, s * (1 - 0.35 * k)


def _dim(h, l, s, k):
    return h, l * (1 - 0.25 * k), s * (1 - 0.2 * k)


def _warm(h, l, s, k):
    d = ((0.08 - h + 0.5) % 1.0) - 0.5  # signed hue distance to orange
    return (h + 0.25 * k * d) % 1.0, l, s


def _cool(h, l, s, k):
    d = ((0.58 - h + 0.5) % 1.0) - 0.5  # signed hue distance to azure
    return (h + 0.25 * k * d) % 1.0, l, s


#: modifier word -> HLS transform ``(h, l, s, strength) -> (h, l, s)``.
MODIFIERS = {
    "light": _light,
    "lighter": _light,
    "pale": _pale,
    "pastel": _pastel,
    "dark": _dark,
    "darker": _dark,
    "deep": _deep,
    "rich": _deep,
    "bright": _bright,
    "brilliant": _bright,
    "vivid": _vivid,
    "saturated": _vivid,
    "intense": _vivid,
    "strong": _vivid,
    "neon": _vivid,
    "muted": _muted,
    "dull": _muted,
    "desaturated": _muted,
    "greyish": _muted,
    "subdued": _muted,
    "soft": _soft,
    "dim": _dim,
    "warm": _warm,
    "cool": _cool,
}

#: intensifier word -> strength multiplier of the next modifier (or wear word).
INTENSIFIERS = {
    "very": 1.6,
    "really": 1.6,
    "extremely": 2.0,
    "super": 1.6,
    "heavily": 1.6,
    "highly": 1.6,
    "slightly": 0.5,
    "somewhat": 0.6,
    "mildly": 0.5,
    "lightly": 0.5,
    "faintly": 0.4,
    "barely": 0.3,
}


def apply_modifier(rgb: RGB, modifier: str, strength: float = 1.0) -> RGB:
    """``rgb`` changed by a modifier word (a key of :data:`MODIFIERS`), in HLS space.

    ``strength`` scales the effect (1: the plain word; "very" is 1.6). Raises ValueError on unknown words.
    """
    fn = MODIFIERS.get(modifier.lower())
    if fn is None:
        raise ValueError(f"unknown colour modifier {modifier!r}; known: {sorted(MODIFIERS)}")
    h, l, s = colorsys.rgb_to_hls(*rgb)
    h, l, s = fn(h, l, s, float(strength))
    return tuple(_clip(c) for c in colorsys.hls_to_rgb(h % 1.0, _clip(l), _clip(s)))  # type: ignore[return-value]


def parse_color(text: str) -> RGB:
    """A colour phrase -> RGB: ``"navy blue"``, ``"very light green"``, ``"pale pink"``, ``"#ff8800"``.

    Leading modifiers (and intensifiers) are applied right to left onto the longest table name that ends
    the phrase ("dark navy blue" is the XKCD "dark navy blue" itself), except that an intensifier keeps
    its modifier ("slightly dark teal" is "teal" darkened by half, not the XKCD "dark teal").
    Raises ValueError if the phrase does not end in a known colour.
    """
    if not isinstance(text, str):
        raise ValueError(f"colour must be a string, got {type(text).__name__}")
    s = text.strip()
    if s.startswith("#"):
        return hex_to_rgb(s)
    words = normalise_name(s).split()
    if not words:
        raise ValueError("empty colour name")
    for start in range(len(words)):  # longest suffix first
        name = " ".join(words[start:])
        if start and words[start - 1] in INTENSIFIERS and words[start] in MODIFIERS and name != words[start]:
            continue  # "very dark teal" is "teal" made very dark, not "very" + XKCD "dark teal"
        if name in COLOR_TABLE:
            rgb = COLOR_TABLE[name]
            strength = 1.0
            mods: list[tuple[str, float]] = []
            for w in words[:start]:
                if w in INTENSIFIERS:
                    strength *= INTENSIFIERS[w]
                elif w in MODIFIERS:
                    mods.append((w, strength))
                    strength = 1.0
                else:
                    raise ValueError(f"{w!r} in colour {text!r} is neither a modifier nor an intensifier")
            for w, k in reversed(mods):
                rgb = apply_modifier(rgb, w, k)
            return rgb
    raise ValueError(f"unknown colour {text!r}")
