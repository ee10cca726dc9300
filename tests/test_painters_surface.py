"""The offline surface painter: noise kernels vs slow references, colour table and modifiers, prompt
parsing, and painted colours (determinism, purity, statistics of the colours, input validation)."""

from __future__ import annotations

import colorsys

import numpy as np
import pytest

from proctex._reference import noise as nz_ref
from proctex.texture.painters import MaterialSpec, SurfacePainter, parse_prompt
from proctex.texture.painters import noise as nz
from proctex.texture.painters.colors import COLOR_TABLE, apply_modifier, hue_degrees, lightness, lookup_color, parse_color
from proctex.texture.painters.materials import MATERIAL_FUNCS
from proctex.texture.painters.patterns import PATTERN_FUNCS
from proctex.texture.painters.vocabulary import MATERIAL_KINDS, PATTERNS

RNG = np.random.default_rng(1234)


def sphere(n: int, seed: int = 0, radius: float = 0.9) -> tuple[np.ndarray, np.ndarray]:
    """(points, normals), each (n, 3) float64, uniform on a sphere."""
    rng = np.random.default_rng(seed)
    d = rng.normal(size=(n, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    return d * radius, d


def face(n: int, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """(points, normals) uniform on the front face y = -1 of the [-1, 1]^3 cube."""
    rng = np.random.default_rng(seed)
    uv = rng.uniform(-1, 1, size=(n, 2))
    p = np.stack([uv[:, 0], np.full(n, -1.0), uv[:, 1]], axis=1)
    nrm = np.zeros_like(p)
    nrm[:, 1] = -1.0
    return p, nrm


def mean_hsl(rgb: np.ndarray) -> tuple[float, float, float]:
    """(hue in degrees, lightness, saturation) of the mean colour."""
    h, l, s = colorsys.rgb_to_hls(*rgb.mean(0))
    return h * 360.0, l, s


def hue_dist(a: float, b: float) -> float:
    return abs((a - b + 180.0) % 360.0 - 180.0)


# ----------------------------------------------------------------------------------------------------
# noise
# ----------------------------------------------------------------------------------------------------

PTS = RNG.uniform(-3, 3, size=(150, 3))


@pytest.mark.parametrize("freq,seed", [(1.0, 0), (2.7, 5), ((1.0, 4.0, 0.5), -3)])
def test_perlin_matches_reference(freq, seed):
    fast = nz.perlin(PTS, freq=freq, seed=seed)
    ref = nz_ref.perlin_reference(PTS, freq=freq, seed=seed)
    assert fast.dtype == np.float32 and fast.shape == (len(PTS),)
    np.testing.assert_allclose(fast, ref, atol=2e-5)
    assert np.abs(ref).max() > 0.2  # not trivially zero


@pytest.mark.parametrize("name", ["fbm", "turbulence", "ridged"])
def test_fractals_match_reference(name):
    fast = getattr(nz, name)(PTS[:60], freq=1.7, octaves=3, seed=7)
    ref = getattr(nz_ref, f"{name}_reference")(PTS[:60], freq=1.7, octaves=3, seed=7)
    np.testing.assert_allclose(fast, ref, atol=2e-5)


@pytest.mark.parametrize("jitter", [1.0, 0.5])
def test_worley_matches_reference(jitter):
    f1, f2, cell = nz.worley(PTS[:60], freq=2.3, seed=11, jitter=jitter)
    r1, r2, rc = nz_ref.worley_reference(PTS[:60], freq=2.3, seed=11, jitter=jitter)
    np.testing.assert_allclose(f1, r1, atol=2e-5)
    np.testing.assert_allclose(f2, r2, atol=2e-5)
    assert (f2 >= f1).all()
    np.testing.assert_allclose(cell, rc, atol=1e-6)


def test_domain_warp_matches_reference():
    fast = nz.domain_warp(PTS[:40], freq=1.3, amount=0.7, octaves=2, seed=4)
    ref = nz_ref.domain_warp_reference(PTS[:40], freq=1.3, amount=0.7, octaves=2, seed=4)
    assert fast.shape == (40, 3)
    np.testing.assert_allclose(fast, ref, atol=3e-5)
    assert np.abs(fast - PTS[:40] * 1.3).max() > 0.05  # it does warp


NOISES = {
    "perlin": lambda p, s: nz.perlin(p, 3.0, seed=s),
    "fbm": lambda p, s: nz.fbm(p, 3.0, octaves=4, seed=s),
    "turbulence": lambda p, s: nz.turbulence(p, 3.0, octaves=4, seed=s),
    "ridged": lambda p, s: nz.ridged(p, 3.0, octaves=4, seed=s),
    "worley_f1": lambda p, s: nz.worley(p, 3.0, seed=s)[0],
    "worley_f2_f1": lambda p, s: (lambda r: r[1] - r[0])(nz.worley(p, 3.0, seed=s)),
    "warp": lambda p, s: nz.domain_warp(p, 3.0, seed=s)[:, 0] - np.float32(3.0) * p[:, 0].astype(np.float32),
}


@pytest.mark.parametrize("name", sorted(NOISES))
def test_noise_continuous_deterministic_and_seeded(name):
    fn = NOISES[name]
    p = RNG.uniform(-1, 1, size=(4000, 3))
    step = RNG.normal(size=p.shape)
    step *= 1e-4 / np.linalg.norm(step, axis=1, keepdims=True)
    a, b = fn(p, 3), fn(p + step, 3)
    assert np.isfinite(a).all()
    assert np.abs(a - b).max() < 0.01  # Lipschitz-like: a 1e-4 move changes little (freq 3, 4 octaves)
    np.testing.assert_array_equal(a, fn(p, 3))  # deterministic
    other = fn(p, 4)
    assert np.abs(a - other).mean() > 0.3 * a.std()  # another seed, another field
    assert np.corrcoef(a, other)[0, 1] < 0.5


def test_noise_ranges_and_lattice_zeros():
    p = RNG.uniform(-20, 20, size=(50000, 3))
    v = nz.perlin(p, seed=2)
    assert 0.15 < v.std() < 0.35 and np.abs(v).max() < 1.3
    grid = RNG.integers(-50, 50, size=(100, 3)).astype(float)
    np.testing.assert_allclose(nz.perlin(grid, seed=9), 0.0, atol=1e-6)  # gradient noise vanishes on the lattice
    t = nz.turbulence(p[:5000], octaves=3)
    r = nz.ridged(p[:5000], octaves=3)
    assert t.min() >= 0 and r.min() >= 0 and r.max() <= 1
    f1, f2, cell = nz.worley(p[:5000])
    assert (f1 >= 0).all() and (f2 >= f1).all() and (cell >= 0).all() and (cell < 1).all()


def test_noise_is_pointwise():
    p = RNG.uniform(-2, 2, size=(3000, 3))
    full = nz.fbm(p, 2.0, octaves=3, seed=1)
    idx = RNG.permutation(len(p))[:500]
    np.testing.assert_array_equal(full[idx], nz.fbm(p[idx], 2.0, octaves=3, seed=1))


def test_seeds_are_stable_ints():
    assert nz.derive_seed(3, "wood") == nz.derive_seed(3, "wood") != nz.derive_seed(3, "marble")
    with pytest.raises(ValueError):
        nz.seed_key(1.5)  # type: ignore[arg-type]
    with pytest.raises(ValueError):
        nz.perlin(np.zeros((4, 2)))


# ----------------------------------------------------------------------------------------------------
# colours
# ----------------------------------------------------------------------------------------------------


def test_colour_table_is_large_and_valid():
    assert len(COLOR_TABLE) > 900
    for name, rgb in COLOR_TABLE.items():
        assert name == name.lower().strip() and "  " not in name
        assert len(rgb) == 3 and all(0.0 <= c <= 1.0 for c in rgb), name
    for name in ("navy blue", "forest green", "burnt orange", "sky blue", "navajo white", "teal", "grey"):
        assert lookup_color(name) is not None, name
    assert lookup_color("Gray") == lookup_color("grey")
    assert lookup_color("Navy-Blue") == lookup_color("navy blue")


def test_colour_semantics_and_modifiers():
    navy = parse_color("navy")
    assert 200 <= hue_degrees(navy) <= 250 and lightness(navy) < 0.25
    blue = parse_color("blue")
    assert lightness(parse_color("light blue")) > lightness(blue) + 0.2
    for mod, sign in (("light", 1), ("pale", 1), ("pastel", 1), ("dark", -1), ("deep", -1)):
        changed = apply_modifier(blue, mod)
        assert sign * (lightness(changed) - lightness(blue)) > 0.05, mod
        assert hue_dist(hue_degrees(changed), hue_degrees(blue)) < 5, mod
    olive = parse_color("olive")
    sat = lambda c: colorsys.rgb_to_hls(*c)[2]  # noqa: E731
    assert sat(apply_modifier(olive, "muted")) < sat(olive) < sat(apply_modifier(olive, "vivid"))
    # intensifiers scale the next modifier
    teal = parse_color("teal")
    assert lightness(parse_color("very dark teal")) < lightness(parse_color("dark teal")) < lightness(teal)
    assert lightness(parse_color("slightly dark teal")) > lightness(parse_color("dark teal"))
    assert parse_color("#ff8000") == (1.0, 128 / 255, 0.0)
    with pytest.raises(ValueError):
        parse_color("blorple")
    with pytest.raises(ValueError):
        apply_modifier(blue, "sparkly")


# ----------------------------------------------------------------------------------------------------
# prompt parsing
# ----------------------------------------------------------------------------------------------------


def test_example_prompts_parse_sensibly():
    s = parse_prompt("red velvet")
    assert (s.material, s.pattern) == ("velvet", None) and hue_dist(hue_degrees(s.base_color), 0) < 15

    s = parse_prompt("dark walnut")
    assert (s.material, s.variant) == ("wood", "walnut")
    assert lightness(s.base_color) < lightness(parse_prompt("walnut").base_color) - 0.05

    s = parse_prompt("blue and white striped ceramic")
    assert (s.material, s.pattern) == ("ceramic", "stripes")
    assert s.pattern_colors[0] == lookup_color("blue") and s.pattern_colors[1] == lookup_color("white")

    s = parse_prompt("worn green leather")
    assert s.material == "leather" and s.wear > 0.3 and 90 < hue_degrees(s.base_color) < 150

    s = parse_prompt("gold")
    assert (s.material, s.variant) == ("metal", "gold") and 30 < hue_degrees(s.base_color) < 60

    s = parse_prompt("speckled pale pink granite")
    assert (s.material, s.pattern) == ("granite", "speckles")
    bg = s.pattern_colors[0]
    assert lightness(bg) > 0.75 and (hue_degrees(bg) > 300 or hue_degrees(bg) < 20)
    assert lightness(s.pattern_colors[1]) < lightness(bg) - 0.2  # darker specks

    for text in ("understood", "ignored"):
        assert isinstance(getattr(s, text), tuple)


@pytest.mark.parametrize(
    "prompt,kind,variant",
    [
        ("wood", "wood", "wood"), ("oak", "wood", "oak"), ("pine", "wood", "pine"), ("maple", "wood", "maple"),
        ("cherry", "wood", "cherry"), ("mahogany", "wood", "mahogany"), ("marble", "marble", "marble"),
        ("granite", "granite", "granite"), ("ceramic", "ceramic", "ceramic"), ("glazed", "ceramic", "glazed"),
        ("porcelain", "ceramic", "porcelain"), ("metal", "metal", "metal"), ("steel", "metal", "steel"),
        ("silver", "metal", "silver"), ("brass", "metal", "brass"), ("copper", "metal", "copper"),
        ("rust", "rust", "rust"), ("rusty steel", "rust", "rust"), ("fabric", "fabric", "fabric"),
        ("velvet", "velvet", "velvet"), ("leather", "leather", "leather"), ("linen", "fabric", "linen"),
        ("denim", "fabric", "denim"), ("stone", "stone", "stone"), ("brick", "brick", "brick"),
        ("concrete", "concrete", "concrete"), ("plastic", "plastic", "plastic"), ("rubber", "rubber", "rubber"),
        ("bark", "bark", "bark"), ("moss", "moss", "moss"), ("orange peel", "fruit", "orange"),
        ("apple", "fruit", "apple"), ("pumpkin skin", "fruit", "pumpkin"), ("fruit skin", "fruit", "orange"),
        ("mushroom", "mushroom", "mushroom"),
    ],
)  # fmt: skip
def test_material_vocabulary(prompt, kind, variant):
    s = parse_prompt(prompt)
    assert (s.material, s.variant) == (kind, variant)
    assert s.ignored == ()


@pytest.mark.parametrize(
    "word,pattern",
    [("stripes", "stripes"), ("striped", "stripes"), ("checks", "checks"), ("checkered", "checks"),
     ("plaid", "plaid"), ("tartan", "plaid"), ("polka dots", "dots"), ("dotted", "dots"),
     ("patchwork", "patchwork"), ("floral", "floral"), ("flowers", "floral"), ("speckles", "speckles"),
     ("speckled", "speckles")],
)  # fmt: skip
def test_pattern_vocabulary(word, pattern):
    s = parse_prompt(f"{word} cotton")
    assert s.pattern == pattern and len(s.pattern_colors) >= 2


@pytest.mark.parametrize("word", ["worn", "weathered", "old", "scratched", "dirty"])
def test_wear_vocabulary(word):
    s = parse_prompt(f"{word} leather")
    assert s.wear > 0.3 and s.wear_kinds
    assert parse_prompt(f"very {word} leather").wear > s.wear > parse_prompt(f"slightly {word} leather").wear


def test_ambiguous_words_and_colour_order():
    s = parse_prompt("gold velvet")  # the last colour/material word is the material
    assert s.material == "velvet" and 30 < hue_degrees(s.base_color) < 60
    s = parse_prompt("cherry leather")
    assert s.material == "leather" and "cherry" in s.color_names
    s = parse_prompt("green apple")
    assert s.material == "fruit" and 90 < hue_degrees(s.base_color) < 150
    s = parse_prompt("gold and white striped velvet")
    assert s.pattern_colors[:2] == (lookup_color("gold"), lookup_color("white"))
    s = parse_prompt("navy blue fabric with forest green stripes")
    assert s.pattern_colors[:2] == (lookup_color("navy blue"), lookup_color("forest green"))
    s = parse_prompt("red and black marble")  # two colours, no pattern: body and veins
    assert s.base_colors == (lookup_color("red"), lookup_color("black"))


def test_unknown_words_degrade_gracefully():
    s = parse_prompt("fluffy zorblax velvet sofa")
    assert s.material == "velvet"
    assert set(s.ignored) == {"fluffy", "zorblax", "sofa"}
    assert "zorblax" in s.notes and "velvet" in s.notes
    for empty in ("", "   ", "!!!", "qwerty uiop"):
        d = parse_prompt(empty)
        assert isinstance(d, MaterialSpec) and d.material == "plastic" and d.pattern is None
        assert "default" in d.notes
    for bad in (None, 3, b"red", ["red"]):
        with pytest.raises(ValueError):
            parse_prompt(bad)  # type: ignore[arg-type]


def test_every_kind_has_a_synthesiser():
    assert set(MATERIAL_KINDS) == set(MATERIAL_FUNCS)
    assert set(PATTERNS) == set(PATTERN_FUNCS)


# ----------------------------------------------------------------------------------------------------
# painting
# ----------------------------------------------------------------------------------------------------

ALL_PROMPTS = [
    "", "red velvet", "dark walnut", "white marble", "black marble", "speckled pale pink granite", "terrazzo",
    "stone", "slate", "sandstone", "concrete", "plaster", "brick", "blue and white striped ceramic",
    "porcelain", "glazed teal ceramic", "terracotta", "gold", "brushed steel", "polished copper",
    "rusty metal", "grey linen", "denim", "tweed", "silk", "worn green leather", "suede", "bark", "moss",
    "orange peel", "apple", "pumpkin", "peach skin", "banana peel", "mushroom", "toadstool", "red tartan",
    "yellow polka dot fabric", "red green and blue polka dots", "floral cotton", "patchwork quilt",
    "black and white checkered", "red white and blue stripes", "navy pinstripe wool",
    "vertical stripes", "diagonal stripes", "worn scratched dirty faded floral linen", "mossy brick",
    "rubber", "glossy red plastic", "large checks", "fine stripes",
]  # fmt: skip


def test_all_prompts_paint_valid_colours():
    p, n = sphere(3000)
    for prompt in ALL_PROMPTS:
        out = SurfacePainter(prompt, seed=3).paint(p, n)
        assert out.dtype == np.float32 and out.shape == (3000, 3), prompt
        assert np.isfinite(out).all() and out.min() >= 0.0 and out.max() <= 1.0, prompt
        assert out.std(0).max() > 1e-3, prompt  # every material varies a little


def test_deterministic_and_seeded():
    p, n = sphere(4000)
    for prompt in ("dark walnut", "blue and white striped ceramic", "patchwork quilt", "red velvet", "white marble"):
        a = SurfacePainter(prompt, seed=5).paint(p, n)
        np.testing.assert_array_equal(a, SurfacePainter(prompt, seed=5).paint(p, n))
        b = SurfacePainter(prompt, seed=6).paint(p, n)
        assert np.abs(a - b).mean() > 0.005, prompt


def test_colour_is_a_pure_function_of_point_and_normal():
    p, n = sphere(70000, seed=2)  # more than two chunks
    painter = SurfacePainter("worn blue and white striped wood", seed=1)
    full = painter.paint(p, n)
    idx = np.random.default_rng(0).permutation(len(p))[:3000]
    np.testing.assert_allclose(painter.paint(p[idx], n[idx]), full[idx], atol=1e-6)
    np.testing.assert_allclose(painter.paint(p[idx[:1]], n[idx[:1]]), full[idx[:1]], atol=1e-6)
    # the group does not change the texture unless it has its own prompt
    np.testing.assert_array_equal(painter.paint(p[:100], n[:100], group=3), full[:100])


@pytest.mark.parametrize(
    "prompt", ["dark walnut", "white marble", "speckled pale pink granite", "patchwork quilt", "brick",
               "blue and white striped ceramic", "floral cotton", "red tartan", "mushroom", "worn green leather"]
)  # fmt: skip
def test_colour_is_continuous(prompt):
    """Tiny moves of the point or the normal change the colour a little: no razor edges, no jumps."""
    p, n = sphere(20000, seed=4)
    painter = SurfacePainter(prompt, seed=0)
    a = painter.paint(p, n)
    step = np.random.default_rng(1).normal(size=p.shape)
    step *= 1e-4 / np.linalg.norm(step, axis=1, keepdims=True)
    assert np.abs(painter.paint(p + step, n) - a).max() < 0.06
    tilted = n + step * 10  # ~1e-3 rad
    tilted /= np.linalg.norm(tilted, axis=1, keepdims=True)
    assert np.abs(painter.paint(p, tilted) - a).max() < 0.06


def test_texture_survives_resampling():
    """Painting a texel grid and interpolating it bilinearly reproduces direct painting (PSNR >= 30 dB
    at 0.004 texels, about a 1024^2 atlas on a sofa): what the multi-view loop relies on."""
    res = 500
    h = 2.0 / res
    c = -1 + h * (np.arange(res) + 0.5)
    U, V = np.meshgrid(c, c, indexing="ij")
    grid = np.stack([U.ravel(), np.full(U.size, -1.0), V.ravel()], axis=1)
    nrm = np.tile([0.0, -1.0, 0.0], (len(grid), 1))
    q = np.random.default_rng(0).uniform(-1 + h, 1 - h, size=(5000, 2))
    fu, fv = (q[:, 0] + 1) / h - 0.5, (q[:, 1] + 1) / h - 0.5
    i, j = np.floor(fu).astype(int), np.floor(fv).astype(int)
    a, b = (fu - i)[:, None], (fv - j)[:, None]
    qp = np.stack([q[:, 0], np.full(len(q), -1.0), q[:, 1]], axis=1)
    for prompt in ("yellow polka dot fabric", "speckled pale pink granite", "worn scratched dirty floral linen", "red tartan"):
        painter = SurfacePainter(prompt, seed=0)
        tex = painter.paint(grid, nrm).reshape(res, res, 3)
        bil = (1 - a) * (1 - b) * tex[i, j] + a * (1 - b) * tex[i + 1, j] + (1 - a) * b * tex[i, j + 1] + a * b * tex[i + 1, j + 1]
        mse = float(((bil - painter.paint(qp, nrm[: len(qp)])) ** 2).mean())
        assert 10 * np.log10(1.0 / mse) >= 30.0, prompt


def test_mean_colours_match_prompts():
    p, n = sphere(20000)
    h, l, s = mean_hsl(SurfacePainter("red velvet").paint(p, n))
    assert hue_dist(h, 0) < 15 and s > 0.5
    h, l, s = mean_hsl(SurfacePainter("gold").paint(p, n))
    assert 35 < h < 60 and s > 0.4
    h, l, s = mean_hsl(SurfacePainter("navy blue plastic").paint(p, n))
    assert 200 < h < 250 and l < 0.3
    h, l, s = mean_hsl(SurfacePainter("worn green leather").paint(p, n))
    assert 90 < h < 150
    marble = SurfacePainter("white marble").paint(p, n)
    luma = marble @ np.array([0.2126, 0.7152, 0.0722])
    assert luma.mean() > 0.75 and luma.std() > 0.02
    assert np.percentile(luma, 1) < luma.mean() - 0.15  # darker veins
    walnut = SurfacePainter("walnut").paint(p, n).mean(0)
    assert SurfacePainter("dark walnut").paint(p, n).mean() < walnut.mean() - 0.05


def _bimodal(rgb: np.ndarray, c0, c1) -> tuple[float, float, float]:
    """Shares of colours near c0, near c1, and near neither (projection on the c0 -> c1 axis)."""
    c0, c1 = np.asarray(c0), np.asarray(c1)
    t = (rgb - c0) @ (c1 - c0) / np.dot(c1 - c0, c1 - c0)
    return float((t < 0.25).mean()), float((t > 0.75).mean()), float(((t >= 0.25) & (t <= 0.75)).mean())


def test_patterns_are_two_coloured():
    p, n = face(20000)
    blue, white = lookup_color("blue"), lookup_color("white")
    a, b, mid = _bimodal(SurfacePainter("blue and white striped ceramic").paint(p, n), blue, white)
    assert a > 0.3 and b > 0.3 and mid < 0.15
    a, b, mid = _bimodal(SurfacePainter("black and white checkered").paint(p, n), lookup_color("black"), white)
    assert a > 0.35 and b > 0.35 and mid < 0.15
    yellow, black = lookup_color("yellow"), lookup_color("black")
    a, b, mid = _bimodal(SurfacePainter("yellow and black polka dots").paint(p, n), yellow, black)
    assert a > 0.5 and b > 0.05 and mid < 0.15
    # stripes on a sphere too (triplanar blend keeps two colours)
    ps, ns = sphere(20000)
    a, b, mid = _bimodal(SurfacePainter("blue and white striped ceramic").paint(ps, ns), blue, white)
    assert a > 0.25 and b > 0.25 and mid < 0.25


def test_stripe_count_and_scale_words():
    z = np.linspace(-1, 1, 4001)
    p = np.stack([np.zeros_like(z), np.full_like(z, -1.0), z], axis=1)
    n = np.tile([0.0, -1.0, 0.0], (len(z), 1))

    def transitions(prompt):
        rgb = SurfacePainter(prompt).paint(p, n)
        t = (rgb[:, 1] > 0.5).astype(int)  # green separates white from red
        return int(np.abs(np.diff(t)).sum())

    k = transitions("red and white stripes")
    assert 15 <= k <= 30  # 10-20 stripes across [-1, 1]
    assert transitions("large red and white stripes") < k < transitions("thin red and white stripes")


def test_group_prompts_override():
    painter = SurfacePainter("red plastic", {"legs": "dark walnut", "2": "gold", 5: "blue velvet"}, seed=0)
    assert painter.spec_for().material == "plastic"
    assert painter.spec_for(label="legs").variant == "walnut"
    assert painter.spec_for(group=2).variant == "gold"
    assert painter.spec_for(group=5).material == "velvet"
    assert painter.spec_for(group=7).material == "plastic"
    assert painter.spec_for(group=2, label="legs").variant == "walnut"  # the label wins
    p, n = sphere(2000)
    glob, legs = painter.paint(p, n), painter.paint(p, n, label="legs")
    assert hue_dist(mean_hsl(glob)[0], 0) < 15 and mean_hsl(legs)[1] < mean_hsl(glob)[1]
    np.testing.assert_array_equal(painter.paint(p, n, group=2), SurfacePainter("gold", seed=0).paint(p, n))
    notes = SurfacePainter("shiny zorblax velvet", {"seat": "qwerty"}).notes()
    assert len(notes) == 2 and "zorblax" in notes[0] and "qwerty" in notes[1]


def test_paint_validates_input():
    painter = SurfacePainter("oak")
    p, n = sphere(10)
    empty = painter.paint(np.zeros((0, 3)), np.zeros((0, 3)))
    assert empty.shape == (0, 3) and empty.dtype == np.float32
    bad = [
        (p[:, :2], n), (p, n[:5]), (p.ravel(), n), (np.full((3, 3), np.nan), n[:3]), (p, np.full((10, 3), np.inf)),
        (np.array([["a", "b", "c"]]), n[:1]), (p * 1e6, n),
    ]  # fmt: skip
    for pts, nrm in bad:
        with pytest.raises(ValueError):
            painter.paint(pts, nrm)
    # zero normals are tolerated (equal triplanar weights)
    assert np.isfinite(painter.paint(p, np.zeros_like(n))).all()
    with pytest.raises(ValueError):
        SurfacePainter(None)  # type: ignore[arg-type]
    with pytest.raises(ValueError):
        SurfacePainter("oak", {"legs": 3})  # type: ignore[dict-item]
    with pytest.raises(ValueError):
        SurfacePainter("oak", seed=1.5)  # type: ignore[arg-type]


def test_pattern_background_after_on():
    """'yellow dots on white': white background (first pattern colour), yellow dots."""
    a = parse_prompt("yellow polka dots on white")
    b = parse_prompt("white with yellow polka dots")
    assert a.pattern == b.pattern == "dots"
    assert np.allclose(a.pattern_colors, b.pattern_colors)
    assert min(a.pattern_colors[0]) > 0.95  # white first
    c = parse_prompt("white flowers on navy")
    assert max(c.pattern_colors[0]) < 0.3  # navy background
