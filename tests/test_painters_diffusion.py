"""The diffusers view painter, on tiny random-weight pipelines built in code (nothing downloaded)."""

from __future__ import annotations

import dataclasses
import json

import numpy as np
import pytest

pytest.importorskip("diffusers")
pytest.importorskip("transformers")

from proctex.texture.painters.base import BACKGROUND, GENERATE, KEEP, REFINE, ViewPainter, ViewRequest  # noqa: E402
from proctex.texture.painters.diffusion import (
    DiffusionViewPainter,
    _block_dilate,
    _resize_mask,
    compose_prompt,
    depth_control_image,
    detect_pipeline,
)
from proctex.texture.painters.tiny_pipeline import build_tiny_pipeline

STEPS = 4


def sphere_request(h: int = 64, w: int = 64, seed: int = 0, radius: float = 0.8, cam: float = 3.0) -> ViewRequest:
    """Orthographic view of a sphere of ``radius`` at the origin, camera on +z at distance ``cam``.

    Trimap: KEEP on the left, REFINE on the right, GENERATE in the middle, BACKGROUND outside; two groups
    (lower half 0, upper half 1).
    """
    ys, xs = np.mgrid[0:h, 0:w]
    s = max(h, w)
    u = (xs + 0.5 - w / 2) / s * 2
    v = (h / 2 - ys - 0.5) / s * 2
    r2 = u**2 + v**2
    fg = r2 < radius**2
    z = np.sqrt(np.clip(radius**2 - r2, 0.0, None))
    depth = np.where(fg, cam - z, np.inf).astype(np.float32)
    points = (np.stack([u, v, z], -1) * fg[..., None]).astype(np.float32)
    normal = (points / radius).astype(np.float32)
    trimap = np.full((h, w), BACKGROUND, np.uint8)
    trimap[fg] = GENERATE
    trimap[fg & (u < -0.3)] = KEEP
    trimap[fg & (u > 0.3)] = REFINE
    group = np.where(fg, (v > 0).astype(np.int64), -1)
    rgb = np.full((h, w, 3), 0.5, np.float32)
    rgb[trimap == KEEP] = (0.8, 0.2, 0.1)
    rgb[trimap == REFINE] = (0.1, 0.3, 0.9)
    return ViewRequest(
        prompt="a wooden chair",
        group_prompts={0: "dark oak legs", 1: "a wooden chair"},
        rgb=rgb,
        trimap=trimap,
        depth=depth,
        normal=normal,
        points=points,
        group=group,
        center=np.zeros(3),
        scale=1.0,
        seed=seed,
    )


@pytest.fixture(scope="module", autouse=True)
def _one_torch_thread():
    """Tiny models run fastest on one thread, and OpenMP spin-waits make 2+ threads crawl (x40) when
    another process loads the CPU; restore the setting afterwards."""
    import torch

    before = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(before)


@pytest.fixture(scope="module")
def tiny_dirs(tmp_path_factory):
    root = tmp_path_factory.mktemp("tiny_sd")
    kinds = ("controlnet_inpaint", "inpaint", "depth2img", "controlnet")
    return {k: build_tiny_pipeline(root / k, seed=0, kind=k) for k in kinds}


@pytest.fixture(scope="module")
def painter(tiny_dirs):
    return DiffusionViewPainter(tiny_dirs["controlnet_inpaint"], steps=STEPS)


# ---------------------------------------------------------------------------------------------------------------
# Painting
# ---------------------------------------------------------------------------------------------------------------


def test_tiny_pipeline_layout(tiny_dirs):
    d = tiny_dirs["controlnet_inpaint"]
    meta = json.loads((d / "model_index.json").read_text())
    assert meta["_class_name"] == "StableDiffusionControlNetInpaintPipeline"
    for sub in ("unet", "controlnet", "vae", "text_encoder", "tokenizer", "scheduler"):
        assert (d / sub).is_dir(), sub
    assert not (d / "safety_checker").exists()
    assert detect_pipeline(d) == "StableDiffusionControlNetInpaintPipeline"


def test_paint_sphere(painter):
    req = sphere_request()
    assert {BACKGROUND, KEEP, REFINE, GENERATE} <= set(np.unique(req.trimap).tolist())
    out = painter.paint_view(req)
    assert isinstance(out, np.ndarray) and out.shape == (64, 64, 3) and out.dtype == np.float32
    assert np.isfinite(out).all() and out.min() >= 0.0 and out.max() <= 1.0
    assert painter.mode == "controlnet_inpaint"
    assert set(painter.last_timings) == {"generate", "refine"}
    # Pixels not asked for come back as rendered; painted ones changed.
    keep = req.trimap <= KEEP
    np.testing.assert_array_equal(out[keep], req.rgb[keep])
    for value in (REFINE, GENERATE):
        sel = req.trimap == value
        assert np.abs(out[sel] - req.rgb[sel]).max() > 1e-3


def test_paint_deterministic_in_seed(painter, tiny_dirs):
    a = painter.paint_view(sphere_request(seed=3))
    b = painter.paint_view(sphere_request(seed=3))
    np.testing.assert_array_equal(a, b)
    # A fresh painter from the same folder paints the same image.
    c = DiffusionViewPainter(tiny_dirs["controlnet_inpaint"], steps=STEPS).paint_view(sphere_request(seed=3))
    np.testing.assert_array_equal(a, c)
    d = painter.paint_view(sphere_request(seed=4))
    paint = sphere_request().paint_mask
    assert np.abs(a[paint] - d[paint]).max() > 1e-3


def test_depth_conditioning_reaches_the_model(painter):
    req = sphere_request()
    far_is_near = np.where(np.isfinite(req.depth), 6.0 - req.depth, np.inf).astype(np.float32)
    flipped = dataclasses.replace(req, depth=far_is_near)
    a, b = painter.paint_view(req), painter.paint_view(flipped)
    assert np.abs(a - b).max() > 1e-3


def test_non_square_view_and_resolution(tiny_dirs):
    p = DiffusionViewPainter(tiny_dirs["controlnet_inpaint"], steps=2, guidance_scale=1.0)
    assert p.native_resolution == 64 and p.vae_scale_factor == 8
    assert p.working_size(64, 64) == (64, 64)
    assert p.working_size(48, 80) == (40, 64)  # longer side 64, multiples of 8
    out = p.paint_view(sphere_request(48, 80))
    assert out.shape == (48, 80, 3) and out.dtype == np.float32 and np.isfinite(out).all()
    p2 = DiffusionViewPainter(tiny_dirs["controlnet_inpaint"], steps=2, resolution=(32, 40))
    assert p2.working_size(100, 7) == (32, 40)
    out = p2.paint_view(sphere_request(50, 30))  # resized down to the model and back up
    assert out.shape == (50, 30, 3) and np.isfinite(out).all()


def test_refine_strength_zero_keeps_refine_pixels(tiny_dirs):
    p = DiffusionViewPainter(tiny_dirs["controlnet_inpaint"], steps=STEPS, refine_strength=0.0)
    req = sphere_request()
    out = p.paint_view(req)
    ref = req.trimap == REFINE
    np.testing.assert_array_equal(out[ref], req.rgb[ref])
    assert set(p.last_timings) == {"generate"}


def test_nothing_to_paint_returns_render(painter):
    req = sphere_request()
    trimap = np.where(req.trimap == BACKGROUND, BACKGROUND, KEEP).astype(np.uint8)
    out = painter.paint_view(dataclasses.replace(req, trimap=trimap))
    np.testing.assert_array_equal(out, req.rgb)
    assert painter.last_timings == {}


@pytest.mark.parametrize("kind", ["inpaint", "depth2img", "separate_controlnet"])
def test_other_layouts(tiny_dirs, kind):
    if kind == "separate_controlnet":  # an inpainting folder + a depth ControlNet folder
        p = DiffusionViewPainter(tiny_dirs["inpaint"], controlnet_dir=tiny_dirs["controlnet"], steps=2)
        assert p.mode == "controlnet_inpaint"
    else:
        p = DiffusionViewPainter(tiny_dirs[kind], steps=2)
        assert p.mode == kind
    req = sphere_request()
    out = p.paint_view(req)
    assert out.shape == (64, 64, 3) and out.dtype == np.float32 and np.isfinite(out).all()
    assert 0.0 <= out.min() and out.max() <= 1.0
    np.testing.assert_array_equal(out, p.paint_view(req))
    keep = ~req.paint_mask
    np.testing.assert_array_equal(out[keep], req.rgb[keep])


def test_is_a_view_painter(painter):
    assert isinstance(painter, ViewPainter)


# ---------------------------------------------------------------------------------------------------------------
# Errors
# ---------------------------------------------------------------------------------------------------------------


def test_missing_folder(tmp_path):
    with pytest.raises(ValueError, match="does not exist"):
        DiffusionViewPainter(tmp_path / "nope")


def test_folder_without_model_index(tmp_path):
    (tmp_path / "unet").mkdir()
    with pytest.raises(ValueError, match="model_index.json"):
        DiffusionViewPainter(tmp_path)


def test_unsupported_pipeline_class(tmp_path):
    (tmp_path / "model_index.json").write_text(json.dumps({"_class_name": "FluxPipeline"}))
    with pytest.raises(ValueError, match="unsupported pipeline class 'FluxPipeline'"):
        DiffusionViewPainter(tmp_path)
    (tmp_path / "model_index.json").write_text("{not json")
    with pytest.raises(ValueError, match="cannot read"):
        DiffusionViewPainter(tmp_path)


def test_controlnet_pipeline_without_controlnet(tmp_path):
    (tmp_path / "model_index.json").write_text(json.dumps({"_class_name": "StableDiffusionControlNetInpaintPipeline"}))
    with pytest.raises(ValueError, match="controlnet"):
        DiffusionViewPainter(tmp_path)


@pytest.mark.parametrize(
    "kwargs, match",
    [
        (dict(steps=0), "steps"),
        (dict(refine_strength=1.5), "refine_strength"),
        (dict(guidance_scale=float("nan")), "guidance_scale"),
        (dict(resolution=4), "resolution"),
        (dict(resolution=(64,)), "resolution"),
        (dict(local_files_only=False), "local_files_only"),
        (dict(dtype="float8"), "dtype"),
    ],
)
def test_bad_painter_arguments(tiny_dirs, kwargs, match):
    with pytest.raises(ValueError, match=match):
        DiffusionViewPainter(tiny_dirs["controlnet_inpaint"], **kwargs)


@pytest.mark.parametrize(
    "field, make, match",
    [
        ("rgb", lambda r: r.rgb[:, :32], "rgb must have shape"),
        ("rgb", lambda r: (r.rgb * 255).astype(np.uint8), "rgb must be"),
        ("rgb", lambda r: r.rgb * 3, r"rgb must lie in \[0, 1\]"),
        ("rgb", lambda r: np.where(r.foreground[..., None], np.nan, r.rgb).astype(np.float32), "NaN"),
        ("trimap", lambda r: r.trimap.astype(np.float32), "integer"),
        ("trimap", lambda r: np.where(r.foreground, 7, 0).astype(np.uint8), "BACKGROUND/KEEP/REFINE/GENERATE"),
        ("trimap", lambda r: r.trimap[0], r"\(H, W\)"),
        ("depth", lambda r: np.full(r.depth.shape, np.inf, np.float32), "finite on foreground"),
        ("depth", lambda r: np.where(r.foreground, np.nan, np.inf).astype(np.float32), "NaN"),
        ("depth", lambda r: r.depth[None], "depth must have shape"),
        ("normal", lambda r: r.normal[..., :2], "normal must have shape"),
        ("points", lambda r: r.points.tolist(), "points must be a numpy array"),
        ("group", lambda r: r.group.astype(np.float64), "group must be"),
        ("prompt", lambda r: None, "prompt must be a str"),
        ("group_prompts", lambda r: {0: 3}, "group_prompts"),
        ("seed", lambda r: 1.5, "seed must be an int"),
    ],
)
def test_malformed_request(painter, field, make, match):
    req = sphere_request()
    bad = dataclasses.replace(req, **{field: make(req)})
    with pytest.raises(ValueError, match=match):
        painter.paint_view(bad)


# ---------------------------------------------------------------------------------------------------------------
# Helpers
# ---------------------------------------------------------------------------------------------------------------


def test_depth_control_image_near_is_bright():
    req = sphere_request()
    img = depth_control_image(req.depth)
    assert img.shape == req.depth.shape and img.dtype == np.float32
    fg = req.foreground
    assert (img[~fg] == 0).all()
    assert img[fg].min() == pytest.approx(0.1) and img[fg].max() == pytest.approx(1.0)
    # The sphere's centre (nearest point) is the brightest; brightness decreases with depth.
    assert img[32, 32] == img.max()
    order = np.argsort(req.depth[fg])
    assert (np.diff(img[fg][order]) <= 1e-6).all()
    # An explicit foreground mask overrides finite depth; a flat foreground is all white.
    depth = np.array([[1.0, 2.0], [3.0, np.inf]], np.float32)
    np.testing.assert_allclose(depth_control_image(depth, floor=0.0), [[1.0, 0.5], [0.0, 0.0]])
    only_first = np.array([[1, 0], [0, 0]], bool)
    np.testing.assert_allclose(depth_control_image(depth, foreground=only_first), [[1, 0], [0, 0]])
    assert (depth_control_image(np.full((3, 3), np.inf)) == 0).all()
    with pytest.raises(ValueError, match=r"\(H, W\)"):
        depth_control_image(np.zeros((2, 2, 1)))


def test_compose_prompt():
    req = sphere_request()
    # Group 0 ("dark oak legs") owns most GENERATE pixels.
    group = np.where(req.foreground, 0, -1)
    group[:10] = np.where(req.foreground[:10], 1, -1)
    assert compose_prompt(dataclasses.replace(req, group=group)) == "a wooden chair, dark oak legs"
    # Dominant group whose prompt is the global one: nothing appended.
    assert compose_prompt(dataclasses.replace(req, group=np.where(req.foreground, 1, -1))) == "a wooden chair"
    # A group prompt refining the global prompt replaces it; one contained in it adds nothing.
    gp = {0: "a wooden chair with oak legs", 1: "a wooden chair"}
    assert compose_prompt(dataclasses.replace(req, group=group, group_prompts=gp)) == "a wooden chair with oak legs"
    gp = {0: "wooden", 1: "a wooden chair"}
    assert compose_prompt(dataclasses.replace(req, group=group, group_prompts=gp)) == "a wooden chair"
    # No foreground: the global prompt.
    empty = dataclasses.replace(req, trimap=np.zeros_like(req.trimap))
    assert compose_prompt(empty) == "a wooden chair"


def test_mask_helpers_are_conservative():
    m = np.zeros((64, 64), bool)
    m[10, 13] = True
    small = _resize_mask(m, (16, 16))
    assert small.sum() >= 1 and small[2, 3]
    big = _block_dilate(m, 8)
    assert big.sum() == 64 and big[8:16, 8:16].all()
    np.testing.assert_array_equal(_block_dilate(m, 1), m)
