"""Part-level texture edits: HSV shift, logo placement, overlay loading (proctex.texture.edit)."""

import numpy as np
import pytest
from PIL import Image

from proctex._reference.edit import place_image_reference, shift_hsv_reference
from proctex.texture.edit import hsv_to_rgb, load_overlay, place_image, rgb_to_hsv, shift_hsv


def _texel_centres(H, W):
    ii, jj = np.mgrid[0:H, 0:W]
    return (jj + 0.5) / W, 1.0 - (ii + 0.5) / H


@pytest.fixture
def rng():
    return np.random.default_rng(0)


# ------------------------------------------------------------------------------------------- HSV
def test_hsv_conversions_match_colorsys_and_round_trip(rng):
    import colorsys

    rgb = rng.random((200, 3))
    rgb[:10] = rng.random((10, 1))  # greys
    rgb[10:20] = np.eye(3)[rng.integers(0, 3, 10)]  # primaries (ties in max)
    rgb[20] = 0.0
    hsv = rgb_to_hsv(rgb)
    ref = np.array([colorsys.rgb_to_hsv(*c) for c in rgb])
    np.testing.assert_allclose(hsv, ref, atol=1e-12)
    np.testing.assert_allclose(hsv_to_rgb(hsv), rgb, atol=1e-12)


def test_shift_hsv_matches_colorsys_reference(rng):
    tex = rng.random((12, 9, 3))
    mask = rng.random((12, 9)) < 0.6
    for hue, sat, val in ((40.0, 1.0, 1.0), (-123.0, 0.5, 1.3), (720.0 + 17.0, 2.0, 0.4)):
        fast = shift_hsv(tex, mask, hue_deg=hue, saturation=sat, value=val)
        np.testing.assert_allclose(fast, shift_hsv_reference(tex, mask, hue, sat, val), atol=1e-12)


def test_hue_rotation_is_exactly_invertible_and_keeps_greys(rng):
    tex = rng.random((16, 16, 3)).astype(np.float32)
    tex[..., 0] = 1.0  # saturated-ish colours
    tex[0] = 0.3  # a grey row
    back = shift_hsv(shift_hsv(tex, hue_deg=40.0), hue_deg=-40.0)
    np.testing.assert_allclose(back, tex, atol=2e-6)
    assert back.dtype == np.float32
    shifted = shift_hsv(tex, hue_deg=77.0, saturation=1.0)
    np.testing.assert_array_equal(shifted[0], tex[0])  # grey stays the same grey
    assert not np.allclose(shifted[1:], tex[1:], atol=1e-3)
    # pure red by +120 deg is pure green
    red = np.zeros((1, 1, 3)) + [1.0, 0.0, 0.0]
    np.testing.assert_allclose(shift_hsv(red, hue_deg=120.0), [[[0.0, 1.0, 0.0]]], atol=1e-12)


def test_shift_hsv_mask_saturation_value_and_dtypes(rng):
    tex = (rng.random((10, 10, 3)) * 255).astype(np.uint8)
    mask = np.zeros((10, 10), bool)
    mask[2:5, 3:8] = True
    out = shift_hsv(tex, mask, hue_deg=90.0, saturation=0.0, value=0.5)
    assert out.dtype == np.uint8 and out.shape == tex.shape
    np.testing.assert_array_equal(out[~mask], tex[~mask])  # bit-identical outside the mask
    inside = out[mask].astype(int)
    assert (inside.max(axis=1) - inside.min(axis=1) == 0).all()  # saturation 0 -> grey
    np.testing.assert_allclose(inside[:, 0], np.rint(tex[mask].max(axis=1) * 0.5), atol=1)
    # value scaling clips at 1; an RGBA texture keeps its alpha
    rgba = np.concatenate([rng.random((4, 4, 3)), np.full((4, 4, 1), 0.25)], axis=2)
    bright = shift_hsv(rgba, value=10.0)
    assert bright[..., :3].max(axis=2).min() == pytest.approx(1.0)
    np.testing.assert_array_equal(bright[..., 3], rgba[..., 3])


@pytest.mark.parametrize(
    "kwargs",
    [
        dict(texture=np.zeros((4, 4))),
        dict(texture=np.zeros((4, 4, 2))),
        dict(texture=np.full((4, 4, 3), np.nan)),
        dict(texture=np.full((4, 4, 3), 1.5)),
        dict(texture=np.zeros((4, 4, 3), np.int32)),
        dict(mask=np.ones((3, 4), bool)),
        dict(mask=np.full((4, 4), 2)),
        dict(hue_deg=np.inf),
        dict(saturation=-0.1),
        dict(value=np.nan),
        dict(value="bright"),
    ],
)
def test_shift_hsv_rejects_bad_input(kwargs):
    args = dict(texture=np.zeros((4, 4, 3)), mask=None)
    args.update(kwargs)
    with pytest.raises(ValueError):
        shift_hsv(**args)


# ------------------------------------------------------------------------------------ placement
def test_red_square_covers_exactly_its_uv_square():
    H, W = 64, 48
    tex = np.full((H, W, 3), 0.5, np.float32)
    logo = np.zeros((8, 8, 3), np.float32)
    logo[..., 0] = 1.0
    out = place_image(tex, logo, (0.25, 0.75), (0.2, 0.2))
    u, v = _texel_centres(H, W)
    inside = (np.abs(u - 0.25) <= 0.1) & (np.abs(v - 0.75) <= 0.1)
    assert inside.sum() > 50
    np.testing.assert_array_equal(out[inside], np.broadcast_to([1.0, 0.0, 0.0], (inside.sum(), 3)))
    np.testing.assert_array_equal(out[~inside], tex[~inside])
    ii, jj = np.nonzero(inside)  # v up: the top-left quadrant of the image
    assert ii.max() < H // 2 and jj.max() < W // 2
    assert out.dtype == np.float32


def test_logo_orientation_and_rotation_swaps_extent():
    H = W = 100
    tex = np.zeros((H, W, 3))
    logo = np.zeros((10, 20, 3))  # wide: left half green, right half blue
    logo[:, :10, 1] = 1.0
    logo[:, 10:, 2] = 1.0
    u, v = _texel_centres(H, W)
    flat = place_image(tex, logo, (0.5, 0.5), (0.4, 0.2))
    changed = (flat != 0).any(axis=2)
    ii, jj = np.nonzero(changed)
    assert (jj.max() - jj.min() + 1, ii.max() - ii.min() + 1) == (40, 20)
    assert flat[50, 35, 1] == 1.0 and flat[50, 65, 2] == 1.0  # left stays left
    top = np.zeros((10, 20, 3))
    top[:5, :, 0] = 1.0  # the logo's top half red
    up = place_image(tex, top, (0.5, 0.5), (0.4, 0.2))
    assert up[42, 50, 0] == 1.0 and up[57, 50, 0] == 0.0  # its top lands at high v (upper rows)
    rot = place_image(tex, logo, (0.5, 0.5), (0.4, 0.2), rotation_deg=90.0)
    changed = (rot != 0).any(axis=2)
    ii, jj = np.nonzero(changed)
    assert (jj.max() - jj.min() + 1, ii.max() - ii.min() + 1) == (20, 40)
    # counter-clockwise by 90 deg in (u right, v up): the logo's left end points down (low v, high rows)
    assert rot[65, 50, 1] == 1.0 and rot[35, 50, 2] == 1.0


def test_opacity_alpha_and_mask():
    tex = np.full((20, 20, 3), 0.2)
    logo = np.ones((4, 4, 3))
    half = place_image(tex, logo, (0.5, 0.5), (1.0, 1.0), opacity=0.5)
    np.testing.assert_allclose(half, 0.6)  # 0.2 * 0.5 + 1.0 * 0.5
    rgba = np.ones((4, 4, 4))
    rgba[:, :2, 3] = 0.0  # left half transparent
    rgba[:, 2:, 3] = 0.25
    out = place_image(tex, rgba, (0.5, 0.5), (1.0, 1.0), mask=None)
    np.testing.assert_array_equal(out[:, :8], tex[:, :8])  # fully transparent: untouched
    np.testing.assert_allclose(out[:, 12:], 0.2 * 0.75 + 0.25)
    mask = np.zeros((20, 20), bool)
    mask[:, 15:] = True
    masked = place_image(tex, logo, (0.5, 0.5), (1.0, 1.0), mask=mask)
    np.testing.assert_array_equal(masked[~mask], tex[~mask])
    np.testing.assert_array_equal(masked[mask], 1.0)


def test_place_image_matches_reference_and_handles_uint8(rng):
    tex = rng.random((40, 30, 3))
    logo = rng.random((9, 13, 4))
    mask = rng.random((40, 30)) < 0.8
    for rot in (0.0, 33.0, -120.0):
        fast = place_image(tex, logo, (0.45, 0.6), (0.5, 0.3), rotation_deg=rot, opacity=0.8, mask=mask)
        ref = place_image_reference(tex, logo, (0.45, 0.6), (0.5, 0.3), rotation_deg=rot, opacity=0.8, mask=mask)
        np.testing.assert_allclose(fast, ref, atol=1e-12)
    t8 = (tex * 255).astype(np.uint8)
    out8 = place_image(t8, (logo * 255).astype(np.uint8), (0.5, 0.5), (0.3, 0.3))
    assert out8.dtype == np.uint8
    changed = (out8 != t8).any(axis=2)
    assert changed.any() and not changed[:5].any()


def test_large_overlay_is_prefiltered_not_aliased():
    tex = np.zeros((16, 16, 3))
    logo = np.zeros((512, 512, 3))
    logo[::2] = 1.0  # one-pixel stripes: the area average is 0.5
    out = place_image(tex, logo, (0.5, 0.5), (1.0, 1.0))
    np.testing.assert_allclose(out, 0.5, atol=0.02)


def test_logo_outside_the_texture_is_clipped():
    tex = np.zeros((10, 10, 3))
    logo = np.ones((2, 2, 3))
    np.testing.assert_array_equal(place_image(tex, logo, (3.0, 3.0), (0.5, 0.5)), tex)
    part = place_image(tex, logo, (1.0, 0.0), (0.4, 0.4))  # bottom-right corner quarter
    ii, jj = np.nonzero(part[..., 0])
    assert ii.min() == 8 and jj.min() == 8 and len(ii) == 4


@pytest.mark.parametrize(
    "kwargs",
    [
        dict(overlay=np.ones((4, 4))),
        dict(overlay=np.ones((4, 4, 2))),
        dict(overlay=np.full((4, 4, 3), 2.0)),
        dict(overlay=np.zeros((0, 4, 3))),
        dict(center_uv=(0.5,)),
        dict(center_uv=(np.nan, 0.5)),
        dict(size_uv=(0.0, 0.2)),
        dict(size_uv=(-0.1, 0.2)),
        dict(rotation_deg=np.nan),
        dict(opacity=1.5),
        dict(opacity=-0.1),
        dict(mask=np.ones((5, 5), bool)),
        dict(texture=np.full((8, 8, 3), -0.5)),
    ],
)
def test_place_image_rejects_bad_input(kwargs):
    args = dict(texture=np.zeros((8, 8, 3)), overlay=np.ones((4, 4, 3)), center_uv=(0.5, 0.5), size_uv=(0.2, 0.2))
    args.update(kwargs)
    with pytest.raises(ValueError):
        place_image(**args)


# ---------------------------------------------------------------------------------------- files
def test_load_overlay_modes(tmp_path, rng):
    rgb = (rng.random((6, 5, 3)) * 255).astype(np.uint8)
    Image.fromarray(rgb).save(tmp_path / "a.png")
    a = load_overlay(tmp_path / "a.png")
    assert a.shape == (6, 5, 4) and a.dtype == np.float32
    np.testing.assert_allclose(a[..., :3], rgb / 255.0, atol=1e-6)
    assert (a[..., 3] == 1.0).all()
    rgba = (rng.random((4, 4, 4)) * 255).astype(np.uint8)
    Image.fromarray(rgba).save(tmp_path / "b.png")
    np.testing.assert_allclose(load_overlay(tmp_path / "b.png"), rgba / 255.0, atol=1e-6)
    Image.fromarray(rgb[..., 0]).save(tmp_path / "g.png")  # grey
    g = load_overlay(tmp_path / "g.png")
    np.testing.assert_allclose(g[..., 1], rgb[..., 0] / 255.0, atol=1e-6)
    Image.fromarray((rgb[..., 0].astype(np.uint16) * 257)).save(tmp_path / "g16.png")  # 16-bit grey
    np.testing.assert_allclose(load_overlay(tmp_path / "g16.png")[..., 0], rgb[..., 0] / 255.0, atol=1e-6)
    pal = Image.fromarray(rgb).convert("P")
    pal.save(tmp_path / "p.gif")
    assert load_overlay(tmp_path / "p.gif").shape == (6, 5, 4)


def test_load_overlay_rejects_unreadable(tmp_path):
    (tmp_path / "junk.png").write_bytes(b"not an image at all")
    for p in (tmp_path / "junk.png", tmp_path / "missing.png", tmp_path):
        with pytest.raises(ValueError):
            load_overlay(p)


def test_loaded_logo_places_on_texture(tmp_path):
    logo = np.zeros((4, 4, 4), np.uint8)
    logo[..., 2] = 255
    logo[..., 3] = 255
    Image.fromarray(logo).save(tmp_path / "logo.png")
    tex = np.zeros((32, 32, 3), np.float32)
    out = place_image(tex, load_overlay(tmp_path / "logo.png"), (0.75, 0.25), (0.25, 0.25))
    ii, jj = np.nonzero(out[..., 2] == 1.0)
    assert ii.min() >= 16 and jj.min() >= 16  # v = 0.25 is the lower half, u = 0.75 the right half
