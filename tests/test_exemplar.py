"""Looks from photos (issue 53): reading photos safely, histogram-preserving synthesis that never
repeats, photos placed on parts (scale, grain, rotation), the maps made from them, and the look
command. Every photo here is made in code."""

from __future__ import annotations

import io
import json
import shutil
import struct
import zlib
from pathlib import Path

import numpy as np
import pytest
from PIL import Image
from scipy.ndimage import gaussian_filter

from proctex.geometry.parts import analyse
from proctex.models import get_model
from proctex.texture import exemplar as E
from proctex.texture.paint_loop import paint_template


def blobs(seed: int, colour=(1.0, 1.0, 1.0), size: int = 128, sigma: float = 3.0) -> np.ndarray:
    """A stochastic texture made in code: smoothed noise tinted ``colour``, (size, size, 3) in [0, 1]."""
    r = np.random.default_rng(seed)
    img = np.stack([gaussian_filter(r.random((size, size)), sigma, mode="wrap") for _ in range(3)], axis=2)
    img = (img - img.min()) / np.ptp(img)
    return np.clip(0.55 * img + 0.45 * np.asarray(colour), 0, 1).astype(np.float32)


def stripes(size: int = 128, period: float = 8.0, seed: int = 0) -> np.ndarray:
    """A grain made in code: dark and light bands across the columns (the grain runs along x), with noise."""
    r = np.random.default_rng(seed)
    y = np.arange(size)[:, None] * np.ones((1, size))
    band = 0.5 + 0.4 * np.sin(2 * np.pi * y / period)
    img = band[..., None] * np.array([0.8, 0.55, 0.3]) + 0.03 * r.standard_normal((size, size, 1))
    return np.clip(img, 0, 1).astype(np.float32)


def png(rgb: np.ndarray, mode: str = "RGB", **save) -> bytes:
    buf = io.BytesIO()
    im = Image.fromarray(np.round(np.clip(rgb, 0, 1) * 255).astype(np.uint8), "RGB")
    if mode != "RGB":
        im = im.convert(mode)
    im.save(buf, "PNG", **save)
    return buf.getvalue()


# ------------------------------------------------------------------------------------------ reading
def test_a_png_reads_back_exactly():
    rgb = blobs(0)
    photo = E.read_photo(png(rgb), name="blobs.png")
    assert photo.rgb.shape == rgb.shape and photo.rgb.dtype == np.float32 and photo.notes == ()
    assert np.array_equal(np.round(photo.rgb * 255), np.round(rgb * 255))
    assert E.read_photo(photo.png()).rgb.tobytes() == photo.rgb.tobytes()  # the stored copy is the photo


def test_alpha_cmyk_sixteen_bit_palettes_and_profiles_are_converted_and_said(tmp_path):
    rgb = blobs(1)
    rgba = np.concatenate([rgb, np.ones((*rgb.shape[:2], 1), np.float32)], axis=2)
    rgba[:10, :, 3] = 0.0
    buf = io.BytesIO()
    Image.fromarray(np.round(rgba * 255).astype(np.uint8), "RGBA").save(buf, "PNG")
    assert any("alpha dropped" in n for n in E.read_photo(buf.getvalue()).notes)
    buf = io.BytesIO()
    Image.fromarray(np.round(rgb * 255).astype(np.uint8), "RGB").convert("CMYK").save(buf, "JPEG")
    cmyk = E.read_photo(buf.getvalue())
    assert any("CMYK" in n for n in cmyk.notes) and cmyk.rgb.shape == rgb.shape
    buf = io.BytesIO()
    Image.fromarray((np.linspace(0, 65535, 64 * 64).reshape(64, 64)).astype(np.uint16)).save(buf, "PNG")
    grey = E.read_photo(buf.getvalue())
    assert any("16-bit" in n for n in grey.notes)
    assert grey.rgb[0, 0, 0] == 0.0 and grey.rgb[-1, -1, 0] == 1.0  # the full 16-bit range, not clipped at 255
    assert any("palette" in n for n in E.read_photo(png(rgb, "P")).notes)
    from PIL import ImageCms

    buf = io.BytesIO()
    icc = ImageCms.ImageCmsProfile(ImageCms.createProfile("sRGB")).tobytes()
    Image.fromarray(np.round(rgb * 255).astype(np.uint8), "RGB").save(buf, "PNG", icc_profile=icc)
    assert any("colour profile converted" in n for n in E.read_photo(buf.getvalue()).notes)
    big = np.repeat(np.repeat(rgb, 5, axis=0), 5, axis=1)  # 640 px a side: resampled to the working size
    read = E.read_photo(png(big))
    assert read.rgb.shape == (E.WORK_SIDE, E.WORK_SIDE, 3) and any("resampled from 640 x 640" in n for n in read.notes)


def _png_header_only(width: int, height: int) -> bytes:
    """A PNG's signature and IHDR claiming ``width`` x ``height`` RGB pixels, no pixel data."""
    ihdr = struct.pack(">IIBBBBB", width, height, 8, 2, 0, 0, 0)
    chunk = struct.pack(">I", len(ihdr)) + b"IHDR" + ihdr + struct.pack(">I", zlib.crc32(b"IHDR" + ihdr))
    data = zlib.compress(b"\x00" * 64)
    idat = struct.pack(">I", len(data)) + b"IDAT" + data + struct.pack(">I", zlib.crc32(b"IDAT" + data))
    return b"\x89PNG\r\n\x1a\n" + chunk + idat


def test_bad_photos_are_refused_by_name_before_decoding(tmp_path):
    with pytest.raises(ValueError, match="bomb.png.*over the limit.*before decoding"):
        E.read_photo(_png_header_only(100_000, 100_000), name="bomb.png")  # 30 GB of pixels never decoded
    with pytest.raises(ValueError, match="8000 x 8000 pixels, over the limit of 40,000,000.*before decoding"):
        E.read_photo(_png_header_only(8000, 8000), name="big.png")  # under Pillow's own bomb limit, over ours
    with pytest.raises(ValueError, match="over the limit of 1,000"):
        E.read_photo(png(blobs(0)), max_pixels=1000)
    with pytest.raises(ValueError, match="over the limit of 100"):
        E.read_photo(png(blobs(0)), max_bytes=100)
    with pytest.raises(ValueError, match="corrupt or truncated"):
        E.read_photo(png(blobs(0))[:600])
    with pytest.raises(ValueError, match="not an image ProcTex reads"):
        E.read_photo(b"%!PS-Adobe-3.0 EPSF-3.0\n%%BoundingBox: 0 0 10 10\n")  # EPS would run Ghostscript
    with pytest.raises(ValueError, match="not an image ProcTex reads"):
        E.read_photo(np.random.default_rng(0).bytes(5000))
    frames = [Image.fromarray(np.full((32, 32, 3), 40 * k, np.uint8)) for k in range(3)]
    buf = io.BytesIO()
    frames[0].save(buf, "PNG", save_all=True, append_images=frames[1:])
    with pytest.raises(ValueError, match="animated"):
        E.read_photo(buf.getvalue(), name="anim.png")
    buf = io.BytesIO()
    frames[0].save(buf, "GIF", save_all=True, append_images=frames[1:])
    with pytest.raises(ValueError, match="not an image ProcTex reads"):
        E.read_photo(buf.getvalue())
    with pytest.raises(ValueError, match="at least 16 a side"):
        E.read_photo(png(blobs(0)[:8, :8]))
    with pytest.raises(ValueError, match="empty"):
        E.read_photo(b"")
    with pytest.raises(ValueError, match="cannot read photo"):
        E.read_photo(tmp_path / "missing.jpg")
    with pytest.raises(ValueError, match="not a file"):
        E.read_photo(tmp_path)


def test_lengths_are_read_in_the_familys_units():
    assert E.parse_length("50cm") == pytest.approx(0.5)
    assert E.parse_length("2 in") == pytest.approx(0.0508)
    assert E.parse_length("0.5m", units="cm") == pytest.approx(50.0)
    assert E.parse_length(0.25) == 0.25 and E.parse_length("3") == 3.0
    for bad in ("-1", "0", "nan", "inf", "1e9", "fast", "5 parsecs", True):
        with pytest.raises(ValueError):
            E.parse_length(bad)
    with pytest.raises(ValueError, match="units must be one of"):
        E.parse_length("1", units="furlong")


# ---------------------------------------------------------------------------------------- synthesis
def _plane(n: int = 384, span: float = 1536.0) -> np.ndarray:
    """A grid of n x n positions over ``span`` photo pixels (several photo widths)."""
    t = (np.arange(n) + 0.5) * span / n
    x, y = np.meshgrid(t, t)
    return np.stack([x.ravel(), y.ravel()], axis=1)


def _repeat_peak(image: np.ndarray, exclude: int = 24) -> float:
    """The highest normalised autocorrelation of ``image``'s luminance (n, n, 3) away from zero shift
    (beyond ``exclude`` pixels): near 1 when the image repeats."""
    lum = image @ np.array([0.2126, 0.7152, 0.0722])
    lum = lum - lum.mean()
    f = np.fft.rfft2(lum)
    ac = np.fft.irfft2(f * np.conj(f), s=lum.shape)
    ac = np.fft.fftshift(ac / ac.flat[0])
    c = np.array(lum.shape) // 2
    yy, xx = np.ogrid[: lum.shape[0], : lum.shape[1]]
    ac[(yy - c[0]) ** 2 + (xx - c[1]) ** 2 < exclude**2] = 0.0
    return float(ac.max())


def test_synthesis_keeps_the_photos_colours_and_never_repeats_where_tiling_does():
    rgb = blobs(3, (0.9, 0.5, 0.2))
    ex = E.prepare(rgb, 1.0)
    uv = _plane()
    out = E.synthesise(ex, uv, seed=5).reshape(384, 384, 3)
    flat = rgb.reshape(-1, 3)
    # histogram kept: the channel quantiles agree with the photo's (measured: within 0.03 at
    # 5..95 %; the photo's own quantiles span 0.4)
    qs = [5, 25, 50, 75, 95]
    assert np.abs(np.percentile(out.reshape(-1, 3), qs, axis=0) - np.percentile(flat, qs, axis=0)).max() < 0.06
    # no repeats: the synthesised plane's autocorrelation away from zero stays low (measured 0.25),
    # the photo tiled (the wrong way) peaks at its period (measured 0.99)
    tiled = E.tiled(ex, uv).reshape(384, 384, 3)
    peak, peak_tiled = _repeat_peak(out), _repeat_peak(tiled)
    assert peak < 0.5 < 0.9 < peak_tiled, (peak, peak_tiled)
    # a seed is a texture: the same again, another one different
    assert np.array_equal(E.synthesise(ex, uv[:1000], seed=5), out.reshape(-1, 3)[:1000])
    assert np.abs(E.synthesise(ex, uv[:1000], seed=6) - out.reshape(-1, 3)[:1000]).mean() > 0.02


def test_the_blend_keeps_unit_variance_wherever_the_weights_fall():
    """Inside a triangle, at its edges and at its vertices the blended Gaussian channels have unit
    variance (a plain average would shrink it by up to 1/sqrt(3) at the centroids: washed out)."""
    ex = E.prepare(blobs(4, size=256, sigma=2.0), 1.0)
    rng = np.random.default_rng(0)
    cell = E.CELL * min(ex.shape)
    # many points at one place of the grid (the same barycentric weights), far apart
    lattice = rng.integers(-200, 200, size=(20000, 2)).astype(float)
    for bary_skew in ((0.0, 0.0), (1 / 3, 1 / 3), (0.5, 0.0), (0.1, 0.7)):
        skew = lattice + np.array(bary_skew)
        uv = skew @ np.linalg.inv(E._SKEW).T * cell
        g = E.tile_blend(ex, uv, seed=1, channels=E.COLOUR)
        # measured within 0.035 of 1; a plain average (weights summing to 1) would give 0.58 at the centroid
        assert np.allclose(g.std(axis=0), 1.0, atol=0.1), (bary_skew, g.std(axis=0))


def test_patches_stay_inside_the_photo(monkeypatch):
    """Every read of the photo lands inside it before any clamping (patches keep a margin of the
    triangle's size), over many photo widths and seeds: no edge of the photo is ever shown."""
    ex = E.prepare(blobs(5, size=96), 1.0)
    seen = []
    real = E._bilinear

    def spy(q, shape, x, y):
        seen.append((float(np.min(x)), float(np.max(x)), float(np.min(y)), float(np.max(y))))
        return real(q, shape, x, y)

    monkeypatch.setattr(E, "_bilinear", spy)
    for seed in range(4):
        E.synthesise(ex, _plane(128, 5000.0) - 2500.0, seed=seed)
    h, w = ex.shape
    lo_x, hi_x, lo_y, hi_y = min(s[0] for s in seen), max(s[1] for s in seen), min(s[2] for s in seen), max(s[3] for s in seen)
    assert 0.0 <= lo_x and hi_x <= w - 1 and 0.0 <= lo_y and hi_y <= h - 1, (lo_x, hi_x, lo_y, hi_y)
    # and the reads cover the photo, not only its middle: within 8 % of each border (measured 2-5 %)
    assert lo_x < 0.08 * w and hi_x > 0.92 * (w - 1) and lo_y < 0.08 * h and hi_y > 0.92 * (h - 1)


# ----------------------------------------------------------------------------------------- on parts
@pytest.fixture(scope="module")
def chair():
    shape = get_model("chair").generate()
    return shape, analyse(shape)


def _mean_colour(tex, group: int) -> np.ndarray:
    gt = tex.groups[group]
    return gt.image[gt.texels.ij[:, 0], gt.texels.ij[:, 1]].mean(axis=0)


def test_each_part_takes_its_own_photo_and_swapping_the_photos_swaps_the_parts(chair):
    shape, grouping = chair
    leg = next(g.index for g in grouping.groups if g.label == "leg")
    red, blue = E.Photo(blobs(6, (1.0, 0.1, 0.1)), "red"), E.Photo(blobs(7, (0.1, 0.1, 1.0)), "blue")

    def look(a, b):
        return paint_template(shape, grouping, "a chair", size=64, maps=False, photos={"leg": E.PhotoLayer(a), "*": E.PhotoLayer(b)}, under_prompt=False)

    first, swapped = look(red, blue), look(blue, red)
    means = {"red": red.rgb.reshape(-1, 3).mean(0), "blue": blue.rgb.reshape(-1, 3).mean(0)}
    for tex, leg_photo, rest_photo in ((first, "red", "blue"), (swapped, "blue", "red")):
        for g in grouping.groups:
            want = leg_photo if g.index == leg else rest_photo
            other = rest_photo if g.index == leg else leg_photo
            m = _mean_colour(tex, g.index)
            # measured: within 0.05 of its photo's mean, over 0.6 from the other's
            assert np.linalg.norm(m - means[want]) < 0.12 < 0.4 < np.linalg.norm(m - means[other]), (g.index, m)
    assert first.groups[leg].prompt == "photo red" and swapped.groups[leg].prompt == "photo blue"


def test_the_prompts_named_parts_keep_their_clauses_under_the_photo_of_the_rest(chair):
    shape, grouping = chair
    leg = next(g.index for g in grouping.groups if g.label == "leg")
    photo = E.Photo(blobs(8, (0.1, 0.9, 0.1)), "green")
    tex = paint_template(shape, grouping, "a chair with black metal legs", size=64, maps=False, photos={"*": E.PhotoLayer(photo)})
    assert np.linalg.norm(_mean_colour(tex, leg) - photo.rgb.reshape(-1, 3).mean(0)) > 0.4  # the clause's black metal
    assert all(np.linalg.norm(_mean_colour(tex, g.index) - photo.rgb.reshape(-1, 3).mean(0)) < 0.12 for g in grouping.groups if g.index != leg)
    over = paint_template(shape, grouping, "a chair with black metal legs", size=64, maps=False, photos={"*": E.PhotoLayer(photo)}, under_prompt=False)
    assert np.linalg.norm(_mean_colour(over, leg) - photo.rgb.reshape(-1, 3).mean(0)) < 0.12


def test_the_groups_without_a_photo_are_painted_as_the_prompt_alone_paints_them(chair):
    """A photo on the legs changes nothing else: every other group's texture and maps equal a
    prompt-only paint's, texel for texel (gutter included)."""
    shape, grouping = chair
    leg = next(g.index for g in grouping.groups if g.label == "leg")
    prompt = "a chair with a red velvet seat"
    plain = paint_template(shape, grouping, prompt, size=64)
    photo = paint_template(shape, grouping, prompt, size=64, photos={"leg": E.PhotoLayer(E.Photo(blobs(15), "p"))})
    for a, b in zip(plain.groups, photo.groups):
        same = np.array_equal(a.image, b.image) and np.array_equal(a.pbr.orm, b.pbr.orm) and np.array_equal(a.pbr.normal, b.pbr.normal)
        assert same == (a.group != leg), a.group


def test_groups_painted_side_by_side_give_the_same_textures_and_maps_as_one_at_a_time(chair, monkeypatch):
    """Two threads painting groups (proctex.texture.paint.per_group) change no texel of a photo
    look or a prompt look, colour or maps: the painters' caches hold values independent of order,
    and each photographed group's kept contrast and relief reach its own maps."""
    from proctex.texture import paint as P

    shape, grouping = chair
    photos = {"leg": E.PhotoLayer(E.Photo(blobs(15), "p")), "*": E.PhotoLayer(E.Photo(blobs(16, (0.2, 0.5, 0.9)), "q"))}
    looks = {}
    for threads in (1, 2):
        monkeypatch.setattr(P, "PAINT_THREADS", threads)
        looks[threads] = [paint_template(shape, grouping, "a chair with black metal legs", size=64, photos=photos), paint_template(shape, grouping, "a chair with a red velvet seat", size=64)]
    for one, two in zip(looks[1], looks[2]):
        for a, b in zip(one.groups, two.groups):
            assert np.array_equal(a.image, b.image) and np.array_equal(a.painted, b.painted), a.group
            assert np.array_equal(a.pbr.orm, b.pbr.orm) and np.array_equal(a.pbr.normal, b.pbr.normal), a.group
    # and two threads did paint side by side: both wait at one barrier (one thread would time out)
    import threading

    barrier, names = threading.Barrier(2, timeout=30), []

    def meet(a, b):
        barrier.wait()
        names.append(threading.current_thread().name)
        return a + b

    assert P.per_group(meet, [(1, 2), (3, 4)], threads=2) == [3, 7] and len(set(names)) == 2


def _grain_axis(shape, grouping, group: int, layer) -> float:
    """On a patch through the group's centre across its shortest axis, the mean luminance step along
    the group's long axis over the step along its second axis (small: the grain runs along the long
    axis)."""
    painter = E.PhotoPainter(_plain(), {group: layer}).bind(shape, grouping)
    b = painter._bound[group]
    centre, axes = b.centre, b.axes
    # points on the plane through the part's centre across its shortest axis, normal along it
    t = np.linspace(-0.02, 0.02, 41)
    u, v = np.meshgrid(t, t)
    pts = centre + u.ravel()[:, None] * axes[0] + v.ravel()[:, None] * axes[1]
    c0, r = painter._frame
    cols = painter.paint((pts - c0) / r, np.repeat(axes[2][None], len(pts), 0), group=group)
    lum = (cols @ np.array([0.2126, 0.7152, 0.0722])).reshape(41, 41)
    along0 = np.abs(np.diff(lum, axis=1)).mean()  # steps along axes[0]
    along1 = np.abs(np.diff(lum, axis=0)).mean()
    return along0 / along1


class _plain:
    """A prompt painter stub for the groups without a photo (never asked here)."""

    def bind(self, *a, **k):
        return self

    def notes(self):
        return []


def test_the_grain_runs_along_the_parts_long_axis_unless_turned(chair):
    shape, grouping = chair
    seat = next(g.index for g in grouping.groups if g.label == "seat")
    photo = E.Photo(stripes(), "grain")
    along = _grain_axis(shape, grouping, seat, E.PhotoLayer(photo, scale=0.05))
    turned = _grain_axis(shape, grouping, seat, E.PhotoLayer(photo, scale=0.05, rotate=90))
    # the bands run along the photo's width: little change along the long axis, much across it
    # (measured ratios 0.15 and 6.3); turned 90 degrees, the other way
    assert along < 0.4 < 2.5 < turned, (along, turned)


def test_scale_is_physical_and_the_default_follows_the_part(chair):
    shape, grouping = chair
    seat = next(g.index for g in grouping.groups if g.label == "seat")
    photo = E.Photo(stripes(period=8.0), "grain")
    for scale in (0.05, 0.2):
        p = E.PhotoPainter(_plain(), {seat: E.PhotoLayer(photo, scale=scale)}).bind(shape, grouping)
        assert p._bound[seat].scale == scale
        assert p._bound[seat].ex.pixel * p._bound[seat].ex.shape[1] == pytest.approx(scale, rel=1e-9)
    p = E.PhotoPainter(_plain(), {seat: E.PhotoLayer(photo)}).bind(shape, grouping)
    rep = grouping.parts[grouping.groups[seat].representative]
    v = shape.vertices[rep.vertices]
    longest = np.ptp((v - v.mean(0)) @ p._bound[seat].axes.T, axis=0).max()
    assert p._bound[seat].scale == pytest.approx(longest / 2.0)


def test_maps_from_a_photo_relief_roughness_and_the_prompts_metalness(chair):
    shape, grouping = chair
    leg = next(g.index for g in grouping.groups if g.label == "leg")
    photo = E.Photo(blobs(9, (0.6, 0.6, 0.6), sigma=1.5), "rough")

    def maps(**layer):
        tex = paint_template(shape, grouping, "a chair with brushed steel legs", size=64, photos={"leg": E.PhotoLayer(photo, **layer)})
        gt = tex.groups[leg]
        ij = gt.texels.ij
        return gt.pbr.normal[ij[:, 0], ij[:, 1]] * 2 - 1, gt.pbr.roughness[ij[:, 0], ij[:, 1]], gt.pbr.metallic[ij[:, 0], ij[:, 1]]

    n1, r1, m1 = maps()
    n0, r0, m0 = maps(normal=0.0, roughness=0.0)
    tex = paint_template(shape, grouping, "a chair with brushed steel legs", size=64)  # no photo
    ij = tex.groups[leg].texels.ij
    r_prompt, m_prompt = tex.groups[leg].pbr.roughness[ij[:, 0], ij[:, 1]], tex.groups[leg].pbr.metallic[ij[:, 0], ij[:, 1]]
    tilt = lambda n: float(np.degrees(np.arccos(np.clip(n[:, 2], -1, 1))).mean())  # noqa: E731
    assert tilt(n0) < 1.0 < 5.0 < tilt(n1), (tilt(n0), tilt(n1))  # measured 0.0 and 17 degrees
    # strength 0: the prompt's roughness exactly; strength 1: the photo's contrast moves it (measured std 0.05)
    assert np.array_equal(r0, r_prompt) and (r1 - r0).std() > 0.025, (r1 - r0).std()
    assert m1.mean() > 0.8 and np.array_equal(m1, m_prompt) and np.array_equal(m0, m_prompt)  # metal: the prompt's words alone


def test_photo_settings_are_checked():
    with pytest.raises(ValueError, match="at most 64 photos"):
        E.check_images({str(i): {"file": "a.png"} for i in range(65)})
    with pytest.raises(ValueError, match="its file must be a path"):
        E.check_images({"seat": {"scale": 1.0}})
    with pytest.raises(ValueError, match="unknown settings"):
        E.check_images({"seat": {"file": "a.png", "colour": 1}})
    with pytest.raises(ValueError, match="normal strength"):
        E.check_images({"seat": {"file": "a.png", "normal": 11}})
    with pytest.raises(ValueError, match="rotate"):
        E.check_images({"seat": {"file": "a.png", "rotate": float("nan")}})
    with pytest.raises(ValueError, match="length"):
        E.check_images({"seat": {"file": "a.png", "scale": -2}})
    assert E.check_images({"seat": {"file": "a.png", "scale": "50cm"}})["seat"]["scale"] == pytest.approx(0.5)


# ------------------------------------------------------------------------------------ the command
@pytest.fixture()
def mug(painted_mug_root, tmp_path):
    from proctex.store.layout import FamilyStore

    shutil.copytree(painted_mug_root / "mug", tmp_path / "mug")
    return FamilyStore(tmp_path / "mug")


def _files(folder: Path) -> dict[str, bytes]:
    return {str(p.relative_to(folder)): p.read_bytes() for p in sorted(folder.rglob("*")) if p.is_file() and ".lock" not in p.name}


def test_look_add_from_photos_stores_them_and_paints_each_part_from_its_own(mug, tmp_path, capsys):
    from proctex.cli import main

    base = Path(mug.base)
    (tmp_path / "red.png").write_bytes(png(blobs(10, (1.0, 0.1, 0.1))))
    (tmp_path / "green.png").write_bytes(png(blobs(11, (0.1, 1.0, 0.1))))
    assert (
        main(
            [
                "look",
                "add",
                str(base),
                "photos",
                "--image",
                f"handle={tmp_path / 'red.png'}",
                "--image",
                str(tmp_path / "green.png"),
                "--image-scale",
                "handle=5cm",
                "--image-rotate",
                "handle=90",
                "--json",
            ]
        )
        == 0
    )
    record = json.loads(capsys.readouterr().out)["look"]
    images = record["paint"]["images"]
    assert record["paint"]["prompt"] == "blue ceramic"  # no --prompt: the build's, for what no photo covers
    assert set(images) == {"handle", "*"} and images["handle"]["scale"] == pytest.approx(0.05) and images["handle"]["rotate"] == 90.0
    assert images["*"]["under_prompt"] is False
    for key, entry in images.items():  # each photo is kept in the look, and its entry names it
        assert entry["file"].startswith("looks/photos/photo-") and (base / entry["file"]).is_file()
    assert E.read_photo(base / images["handle"]["file"]).rgb.tobytes() == E.read_photo(tmp_path / "red.png").rgb.tobytes()
    paint = json.loads((base / "looks/photos/paint.json").read_text())
    by_label = {g["label"]: g for g in paint["groups"]}
    assert by_label["handle"]["prompt"] == "photo red.png" and by_label["body"]["prompt"] == "photo green.png"
    from proctex.store.layout import StoreLayout

    look = StoreLayout.look("photos")
    for label, (a, b) in (("handle", (0, 1)), ("body", (1, 0))):  # the handle red, the body green
        g = by_label[label]
        img = np.asarray(Image.open(base / look.texture(g["group"], label)).convert("RGB"), float) / 255
        painted = np.load(base / look.PAINTED)[f"g{g['group']}"]
        assert img[painted][:, a].mean() > img[painted][:, b].mean() + 0.3, label


def test_look_add_refuses_bad_photos_and_flags_and_writes_nothing(mug, tmp_path, capsys):
    from proctex.cli import main

    base = Path(mug.base)
    before = _files(base)
    (tmp_path / "ok.png").write_bytes(png(blobs(12)))
    (tmp_path / "broken.png").write_bytes(png(blobs(12))[:300])
    (tmp_path / "bomb.png").write_bytes(_png_header_only(100_000, 100_000))
    cases = [
        (["--image", f"handle={tmp_path / 'broken.png'}"], "corrupt or truncated"),
        (["--image", f"handle={tmp_path / 'bomb.png'}"], "over the limit"),
        (["--image", f"handle={tmp_path / 'missing.png'}"], "cannot read photo"),
        (["--image", f"cushion={tmp_path / 'ok.png'}"], "unknown group 'cushion'"),
        (["--image", f"handle={tmp_path / 'ok.png'}", "--image-scale", "body=1"], "which no --image gives a photo"),
        (["--image", f"handle={tmp_path / 'ok.png'}", "--image-scale", "handle=-3cm"], "positive"),
        (["--image", f"handle={tmp_path / 'ok.png'}", "--image-rotate", "handle=sideways"], "degrees"),
        (["--image", f"handle={tmp_path / 'ok.png'}", "--normal-strength", "50"], "normal strength"),
        (["--image", f"handle={tmp_path / 'ok.png'}", "--image", f"handle={tmp_path / 'ok.png'}"], "twice"),
        (["--image", f"handle={tmp_path / 'ok.png'}", "--painter", "views"], "surface painter"),
        ([], "needs --prompt, --image, or both"),
    ]
    for extra, message in cases:
        assert main(["look", "add", str(base), "bad", *extra]) != 0, extra
        err = capsys.readouterr().err
        assert message in err and "Traceback" not in err, (extra, err)
    assert _files(base) == before


def test_a_look_from_photos_over_http_multipart_with_bounds(mug, tmp_path):
    """``POST .../looks`` multipart: a ``look`` JSON field and ``image.<part>`` files; served at once;
    bad photos and fields are a 422 naming the problem and write nothing."""
    import asyncio

    httpx = pytest.importorskip("httpx")
    from proctex.serve.catalog import Catalog
    from workers.http import MAX_LOOK_PHOTOS, create_app

    cat = Catalog(str(Path(mug.base).parent), check_every=0)
    app = create_app(lambda: cat, edit_token="photo-token-1")
    token = {"X-ProcTex-Token": "photo-token-1"}
    red, green = png(blobs(13, (1.0, 0.1, 0.1))), png(blobs(14, (0.1, 1.0, 0.1)))
    look = json.dumps({"name": "photos", "images": {"handle": {"scale": "4cm", "rotate": 45}}})

    async def run():
        async with httpx.AsyncClient(transport=httpx.ASGITransport(app=app), base_url="http://t", timeout=60) as c:
            before = _files(Path(mug.base))
            bad = [
                await c.post("/v1/families/mug/looks", data=d, files=f, headers=token)
                for d, f in (
                    ({"look": look}, {"image.handle": ("x.png", red[:200], "image/png")}),  # truncated
                    ({"look": look}, {"image.handle": ("bomb.png", _png_header_only(100_000, 100_000), "image/png")}),
                    ({"look": look}, {"image.body": ("g.png", green, "image/png")}),  # settings for a part sent no photo
                    ({"look": "{nope"}, {"image.handle": ("r.png", red, "image/png")}),
                    ({}, {"image.handle": ("r.png", red, "image/png")}),
                    ({"look": look, "other": "1"}, {"image.handle": ("r.png", red, "image/png")}),
                    ({"look": json.dumps({"name": "photos"})}, {"image.cushion": ("r.png", red, "image/png")}),
                    ({"look": look}, {f"image.{k}": ("r.png", red, "image/png") for k in range(MAX_LOOK_PHOTOS + 1)}),
                )
            ]
            nothing = _files(Path(mug.base)) == before
            denied = await c.post("/v1/families/mug/looks", data={"look": look}, files={"image.handle": ("r.png", red, "image/png")})
            added = await c.post("/v1/families/mug/looks", data={"look": look}, files={"image.handle": ("red.png", red, "image/png"), "image.*": ("green.png", green, "image/png")}, headers=token)
            served = await c.post("/v1/families/mug/transfer?look=photos", json={"params": {}})
            return bad, nothing, denied, added, served

    bad, nothing, denied, added, served = asyncio.run(run())
    assert [r.status_code for r in bad] == [422] * len(bad), [(r.status_code, r.text[:200]) for r in bad]
    for r, message in zip(
        bad, ("corrupt or truncated", "over the limit", "sent no photo", "must be JSON", "needs a 'look' field", "unknown multipart field", "unknown group 'cushion'", "at most 8 photos")
    ):
        assert message in r.json()["error"], (message, r.json())
    assert nothing
    assert denied.status_code == 401
    assert added.status_code == 200, added.text
    images = added.json()["look"]["paint"]["images"]
    assert images["handle"]["scale"] == pytest.approx(0.04) and images["handle"]["rotate"] == 45.0 and images["*"]["under_prompt"] is False
    assert added.json()["look"]["paint"]["prompt"] == "blue ceramic" and served.status_code == 200


# ------------------------------------------------------------------- chart borders and smooth normals
def test_ring_texels_carry_the_surface_past_a_charts_edge_so_borders_read_true_colours():
    """A linear colour field painted on a two-triangle chart: with the ring, bilinear reads anywhere
    inside the chart, borders included, give the field exactly (it is linear in the plane); the
    gutter's nearest-texel copies alone miss it at the borders."""
    from proctex.texture.uv import pad_seams, ring_texels, sample_texture, texel_map

    v = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [1.0, 1.0, 0.0], [0.0, 1.0, 0.0]])
    f = np.array([[0, 1, 2], [0, 2, 3]])
    uv = np.array([[[0.2, 0.2], [0.7, 0.2], [0.7, 0.7]], [[0.2, 0.2], [0.7, 0.7], [0.2, 0.7]]])
    size = 64
    tx = texel_map(v, f, uv, size)
    field = lambda p: np.stack([p[:, 0], p[:, 1], 0.5 * p[:, 0] + 0.25], axis=1)  # noqa: E731
    img = np.zeros((size, size, 3))
    img[tx.ij[:, 0], tx.ij[:, 1]] = field(tx.points)
    plain = pad_seams(img, tx.mask, 8)[0]
    ring = ring_texels(tx, v, f, uv, 2)
    assert len(ring.face) > 0 and not tx.mask[ring.ij[:, 0], ring.ij[:, 1]].any()
    assert np.abs(ring.points[:, 2]).max() == 0.0  # on the triangles' plane
    ringed = img.copy()
    ringed[ring.ij[:, 0], ring.ij[:, 1]] = field(ring.points)
    held = tx.mask.copy()
    held[ring.ij[:, 0], ring.ij[:, 1]] = True
    ringed = pad_seams(ringed, held, 8)[0]
    r = np.random.default_rng(0)
    s = r.random((4000, 2))
    q = 0.2 + 0.5 * s  # UVs anywhere in the chart; the surface point is linear in them
    pts = np.stack([s[:, 0], s[:, 1], np.zeros(len(s))], axis=1)
    err_ring = np.abs(sample_texture(ringed, q)[:, :3] - field(pts)).max()
    err_plain = np.abs(sample_texture(plain, q)[:, :3] - field(pts)).max()
    assert err_ring < 1e-9 < 0.005 < err_plain, (err_ring, err_plain)  # measured 4e-16 and 0.022


def test_blend_normals_are_continuous_across_split_vertices_and_exact_on_a_plane():
    """A unit cube exported with its vertices split per face (as UV seams split them): face normals
    jump 90 degrees at every edge; the blend normals of texels on either side of an edge agree
    (vertices welded, neighbours averaged), and on a plane they are its normal exactly."""
    import trimesh

    from proctex.geometry.shape import Shape
    from proctex.texture.paint import blend_normals
    from proctex.texture.uv import texel_map

    box = trimesh.creation.box()
    v = box.vertices[box.faces].reshape(-1, 3)  # every face its own three vertices
    f = np.arange(len(v)).reshape(-1, 3)
    shape = Shape(v, f)
    # a chart per face: each face in its own UV square (all that matters is where texels are)
    uv = np.zeros((len(f), 3, 2))
    for i in range(len(f)):
        x, y = (i % 4) * 0.25, (i // 4) * 0.25
        uv[i] = [[x + 0.02, y + 0.02], [x + 0.23, y + 0.02], [x + 0.02, y + 0.23]]
    tx = texel_map(v, f, uv, 256)
    n = blend_normals(shape, np.arange(len(f)), tx)
    assert np.allclose(np.linalg.norm(n, axis=1), 1.0)
    # texels near an edge, on the two faces meeting there (points within 0.05 of the edge x = y = 0.5)
    near = (np.abs(tx.points[:, 0] - 0.5) < 0.05) & (np.abs(tx.points[:, 1] - 0.5) < 0.05)
    fn = tx.normals[near]
    on_x, on_y = near.nonzero()[0][np.abs(fn[:, 0]) > 0.9], near.nonzero()[0][np.abs(fn[:, 1]) > 0.9]
    assert len(on_x) and len(on_y)
    gap_face = np.degrees(np.arccos(np.clip(tx.normals[on_x].mean(0) @ tx.normals[on_y].mean(0), -1, 1)))
    mx, my = n[on_x].mean(0), n[on_y].mean(0)
    gap_blend = np.degrees(np.arccos(np.clip(mx @ my / np.linalg.norm(mx) / np.linalg.norm(my), -1, 1)))
    assert gap_face > 89 and gap_blend < 30, (gap_face, gap_blend)  # measured 90 and 3.6 degrees
    plane = Shape(np.array([[0.0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0]]), np.array([[0, 1, 2], [0, 2, 3]]))
    ptx = texel_map(plane.vertices, plane.faces, np.array([[[0.1, 0.1], [0.9, 0.1], [0.9, 0.9]], [[0.1, 0.1], [0.9, 0.9], [0.1, 0.9]]]), 32)
    assert np.array_equal(blend_normals(plane, np.arange(2), ptx), np.tile([0.0, 0.0, 1.0], (len(ptx.face), 1)))


def test_the_seam_measure_matches_distances_on_the_surface_and_still_sees_a_colour_step():
    """The benchmark's seam measure (tests/bench/bench_photolooks.py) on a hand-built view: a smooth
    colour field over a plane whose pixels lie twice as far apart around every chart seam (as where
    charts are cut, at bends seen at a slant). The plain ratio calls the continuous field a seam (2.2
    measured); matched by distance it is 1 (0.998). A step of 0.1 per channel across the seams, a
    visible seam, moves the matched ratio to 1.37."""
    from types import SimpleNamespace

    from tests.bench import bench_photolooks as B

    H, W = 80, 400
    col = np.arange(W)
    near = np.isin(col % 20, (16, 17, 18, 19, 0, 1, 2, 3))  # the slant around each seam (seams every 20 columns)
    x = np.cumsum(np.where(near, 2.0, 1.0))[None, :].repeat(H, 0)
    y = np.arange(H, dtype=float)[:, None].repeat(W, 1)
    pts = np.stack([x, y, np.zeros_like(x)], -1)
    face = (col // 2)[None, :].repeat(H, 0)  # faces two pixels wide
    view = SimpleNamespace(face=face, points=pts, normal=np.broadcast_to([0.0, 0.0, 1.0], pts.shape))
    charts, groups = (np.arange(W // 2) * 2 // 20).astype(np.int64), np.zeros(W // 2, np.int64)
    rng = np.random.default_rng(0)
    field = 0.5 + sum(0.08 * np.sin(f * x + g * y + p)[..., None] * rng.random(3) for f, g, p in zip(rng.uniform(0.5, 1.2, 6), rng.uniform(-0.4, 0.4, 6), rng.uniform(0, 6.3, 6)))
    smooth = B.seam_ratio([view], [field], charts, groups)
    seam = B.seam_ratio([view], [field + 0.1 * (charts[face] % 2)[..., None]], charts, groups)
    assert smooth["ratio"] > 1.8 and abs(smooth["ratio_matched"] - 1.0) < 0.05, smooth  # measured 2.20, 0.998
    assert seam["ratio_matched"] > 1.25 > 1.2, seam  # measured 1.37
    assert smooth["pairs_across"] == seam["pairs_across"] == 19 * H  # 19 seams, one pair per row
