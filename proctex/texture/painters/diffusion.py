"""A view painter backed by a local diffusers pipeline: depth-conditioned inpainting, InTex style (docs/texturing.md).

The multi-view paint loop asks :class:`DiffusionViewPainter` to paint one rendered view at a time
(:class:`~proctex.texture.painters.base.ViewRequest`). The painter conditions a Stable-Diffusion-style model on

* the **depth** of the view (a MiDaS-style image, near = bright, background = 0; see
  :func:`depth_control_image`), through a depth ControlNet or a depth-to-image UNet;
* the **trimap**: GENERATE pixels are repainted from noise (``strength=1``), REFINE pixels are repainted
  starting from the current render with ``refine_strength`` (a second, shorter pass that sees the freshly
  generated pixels as context), KEEP and BACKGROUND pixels are kept;
* the current render ``rgb`` as the init image and inpainting context;
* a prompt (:func:`compose_prompt`).

Nothing is fetched at run time: ``model_dir`` is a local folder written by ``save_pretrained``, loaded with
``local_files_only=True`` and without the safety checker. Supported layouts (detected from
``model_index.json``'s ``_class_name``):

==========================================  =====================================================
``_class_name`` in ``model_index.json``      painter mode (``DiffusionViewPainter.mode``)
==========================================  =====================================================
StableDiffusionControlNetInpaintPipeline,    ``"controlnet_inpaint"``: depth ControlNet (sub-folder
StableDiffusionControlNetPipeline,           ``controlnet/`` or ``controlnet_dir``) + UNet, run as
StableDiffusionControlNetImg2ImgPipeline     ``StableDiffusionControlNetInpaintPipeline`` (9-channel
                                             inpainting UNets and plain 4-channel UNets both work)
StableDiffusionInpaintPipeline,              ``"controlnet_inpaint"`` when ``controlnet_dir`` names a
StableDiffusionPipeline,                     depth ControlNet folder, else ``"inpaint"`` (no depth
StableDiffusionImg2ImgPipeline               conditioning at all: mask + init image only)
StableDiffusionDepth2ImgPipeline             ``"depth2img"``: our depth replaces the DPT estimator
                                             (not loaded); no mask, so each pass repaints the whole
                                             image and only the requested pixels are used
==========================================  =====================================================

:func:`proctex.texture.painters.tiny_pipeline.build_tiny_pipeline` writes a tiny random-weight
pipeline of any of these layouts, for tests and smoke runs (a 64x64 view paints in well under a second on a CPU).
"""

from __future__ import annotations

import json
import math
import time
from pathlib import Path
from typing import Any, Sequence

import numpy as np
from PIL import Image

from .base import BACKGROUND, GENERATE, KEEP, REFINE, ViewRequest
from proctex.torch_kernels import resolve_vml

__all__ = [
    "DEFAULT_NEGATIVE_PROMPT",
    "DiffusionViewPainter",
    "compose_prompt",
    "depth_control_image",
    "detect_pipeline",
    "validate_request",
]

DEFAULT_NEGATIVE_PROMPT = "shadows, shading, specular highlights, reflections, lighting, blurry, low quality, text, watermark, signature, frame, border"

_CONTROLNET_CLASSES = (
    "StableDiffusionControlNetInpaintPipeline",
    "StableDiffusionControlNetPipeline",
    "StableDiffusionControlNetImg2ImgPipeline",
)
_PLAIN_CLASSES = ("StableDiffusionInpaintPipeline", "StableDiffusionPipeline", "StableDiffusionImg2ImgPipeline")
_DEPTH2IMG_CLASSES = ("StableDiffusionDepth2ImgPipeline",)
SUPPORTED_PIPELINES = _CONTROLNET_CLASSES + _PLAIN_CLASSES + _DEPTH2IMG_CLASSES


# --------------------------------------------------------------------------------------------------------------
# Conditioning helpers (pure numpy; usable without diffusers)
# --------------------------------------------------------------------------------------------------------------


def depth_control_image(depth: np.ndarray, foreground: np.ndarray | None = None, floor: float = 0.1) -> np.ndarray:
    """MiDaS-style depth conditioning image: near = bright, far = dark, background = 0.

    Args:
        depth: (H, W) float distance along the ray; ``inf`` (or any non-finite value) marks background.
        foreground: optional (H, W) bool; pixels outside it are background whatever their depth.
        floor: value of the farthest foreground pixel, > 0 so the silhouette stays visible against the
            black background (depth ControlNets were trained on MiDaS maps where the far scene is dark
            but not cut out).

    Returns:
        (H, W) float32 in [0, 1]: ``floor + (1 - floor) * (d_max - d) / (d_max - d_min)`` on the
        foreground (linear in depth, normalised per view), 0 on background. A flat foreground is all 1.
    """
    depth = np.asarray(depth)
    if depth.ndim != 2:
        raise ValueError(f"depth must be (H, W), got shape {depth.shape}")
    if not 0.0 <= floor < 1.0:
        raise ValueError(f"floor must be in [0, 1), got {floor}")
    depth = depth.astype(np.float64)
    fg = np.isfinite(depth)
    if foreground is not None:
        foreground = np.asarray(foreground, dtype=bool)
        if foreground.shape != depth.shape:
            raise ValueError(f"foreground must have the depth's shape {depth.shape}, got {foreground.shape}")
        fg &= foreground
    out = np.zeros(depth.shape, np.float32)
    if not fg.any():
        return out
    d = depth[fg]
    d_min, d_max = float(d.min()), float(d.max())
    if d_max - d_min <= 1e-12 * max(1.0, abs(d_max)):
        out[fg] = 1.0
    else:
        out[fg] = floor + (1.0 - floor) * (d_max - d) / (d_max - d_min)
    return out


def _dominant_group(request: ViewRequest) -> int | None:
    """Group id with the most GENERATE pixels (then REFINE, then any foreground pixels); None if none."""
    group = np.asarray(request.group)
    trimap = np.asarray(request.trimap)
    for sel in (trimap == GENERATE, trimap == REFINE, trimap != BACKGROUND):
        ids = group[sel & (group >= 0)]
        if ids.size:
            values, counts = np.unique(ids, return_counts=True)
            return int(values[np.argmax(counts)])  # ties: smallest id (np.unique sorts)
    return None


def compose_prompt(request: ViewRequest) -> str:
    """The prompt sent to the model for this view.

    The global prompt, plus the prompt of the *dominant group* (the group owning most GENERATE pixels of
    the view; REFINE pixels, then any foreground pixels, break the no-GENERATE case) when that group's
    prompt differs from the global one. A group prompt that already contains the global prompt replaces it
    (it is a refinement of it); one already contained in the global prompt adds nothing. Otherwise the
    result is ``"<global>, <group prompt>"``.

    Why one group only: a single text condition covers the whole image, and listing every group's
    prompt dilutes them all; the dominant group is what most of the repainted pixels belong to, and the
    global prompt keeps the style consistent across views. Other groups keep being painted consistently
    because they are mostly KEEP/REFINE context by the time they are small in a view.
    """
    base = (request.prompt or "").strip()
    gid = _dominant_group(request)
    if gid is None:
        return base
    extra = (request.group_prompts or {}).get(gid)
    extra = extra.strip() if isinstance(extra, str) else ""
    if not extra or extra.lower() == base.lower():
        return base
    if not base or base.lower() in extra.lower():
        return extra
    if extra.lower() in base.lower():
        return base
    return f"{base}, {extra}"


def _check_array(name: str, a: Any, shape: tuple, kinds: str, what: str) -> np.ndarray:
    if not isinstance(a, np.ndarray):
        raise ValueError(f"request.{name} must be a numpy array {what}, got {type(a).__name__}")
    if a.shape != shape:
        raise ValueError(f"request.{name} must have shape {shape} {what}, got {a.shape}")
    if a.dtype.kind not in kinds:
        raise ValueError(f"request.{name} must be {what}, got dtype {a.dtype}")
    return a


def validate_request(request: ViewRequest) -> None:
    """Raise ``ValueError`` unless ``request`` is a consistent :class:`ViewRequest` (see its docstring)."""
    if not isinstance(request, ViewRequest):
        raise ValueError(f"expected a ViewRequest, got {type(request).__name__}")
    if not isinstance(request.prompt, str):
        raise ValueError(f"request.prompt must be a str, got {type(request.prompt).__name__}")
    if not isinstance(request.group_prompts, dict):
        raise ValueError(f"request.group_prompts must be a dict[int, str], got {type(request.group_prompts).__name__}")
    for k, v in request.group_prompts.items():
        if not isinstance(v, str):
            raise ValueError(f"request.group_prompts[{k!r}] must be a str, got {type(v).__name__}")
    trimap = request.trimap
    if not isinstance(trimap, np.ndarray) or trimap.ndim != 2:
        raise ValueError("request.trimap must be an (H, W) integer array, got " + (f"shape {trimap.shape}" if isinstance(trimap, np.ndarray) else type(trimap).__name__))
    h, w = trimap.shape
    if h < 1 or w < 1:
        raise ValueError(f"request.trimap is empty: shape {trimap.shape}")
    if trimap.dtype.kind not in "iu":
        raise ValueError(f"request.trimap must be an integer array (uint8), got dtype {trimap.dtype}")
    bad = ~np.isin(trimap, (BACKGROUND, KEEP, REFINE, GENERATE))
    if bad.any():
        raise ValueError(f"request.trimap values must be BACKGROUND/KEEP/REFINE/GENERATE (0..3), found {np.unique(trimap[bad])[:5]}")
    rgb = _check_array("rgb", request.rgb, (h, w, 3), "f", "(H, W, 3) float in [0, 1]")
    if not np.isfinite(rgb).all():
        raise ValueError("request.rgb contains NaN or inf")
    if rgb.min() < -1e-3 or rgb.max() > 1 + 1e-3:
        raise ValueError(f"request.rgb must lie in [0, 1], got range [{rgb.min():.4g}, {rgb.max():.4g}]")
    depth = _check_array("depth", request.depth, (h, w), "f", "(H, W) float, inf on background")
    fg = trimap != BACKGROUND
    if np.isnan(depth).any():
        raise ValueError("request.depth contains NaN")
    if not np.isfinite(depth[fg]).all():
        raise ValueError("request.depth must be finite on foreground pixels (trimap != BACKGROUND)")
    for name in ("normal", "points"):
        a = _check_array(name, getattr(request, name), (h, w, 3), "f", "(H, W, 3) float")
        if not np.isfinite(a).all():
            raise ValueError(f"request.{name} contains NaN or inf")
    _check_array("group", request.group, (h, w), "iu", "(H, W) integer, -1 on background")
    if not isinstance(request.seed, (int, np.integer)) or isinstance(request.seed, bool):
        raise ValueError(f"request.seed must be an int, got {type(request.seed).__name__}")


# --------------------------------------------------------------------------------------------------------------
# Image helpers
# --------------------------------------------------------------------------------------------------------------


def _resize_float(img: np.ndarray, size: tuple[int, int], resample: int = Image.BICUBIC) -> np.ndarray:
    """Resize an (H, W) or (H, W, C) float image to ``size = (h, w)`` with Pillow ("F" mode per channel)."""
    h, w = size
    if img.shape[:2] == (h, w):
        return img.astype(np.float32, copy=True)
    chans = img[..., None] if img.ndim == 2 else img
    out = np.stack(
        [np.asarray(Image.fromarray(np.ascontiguousarray(chans[..., c], np.float32)).resize((w, h), resample)) for c in range(chans.shape[-1])],
        axis=-1,
    )
    return out[..., 0] if img.ndim == 2 else out


def _resize_mask(mask: np.ndarray, size: tuple[int, int]) -> np.ndarray:
    """Conservative resize of a bool mask: a target pixel is set if any source pixel under it is (no loss)."""
    if mask.shape == tuple(size):
        return mask.copy()
    soft = _resize_float(mask.astype(np.float32), size, Image.BILINEAR)
    if mask.shape[0] > size[0] or mask.shape[1] > size[1]:  # downscale: box filter sees every source pixel
        soft = np.maximum(soft, _resize_float(mask.astype(np.float32), size, Image.BOX))
    return soft > 1e-3


def _block_dilate(mask: np.ndarray, f: int) -> np.ndarray:
    """Grow ``mask`` to whole f x f blocks (the latent cells), so the latent mask misses no masked pixel."""
    if f <= 1:
        return mask.copy()
    h, w = mask.shape
    hb, wb = -(-h // f), -(-w // f)
    pad = np.zeros((hb * f, wb * f), bool)
    pad[:h, :w] = mask
    blocks = pad.reshape(hb, f, wb, f).any(axis=(1, 3))
    return np.repeat(np.repeat(blocks, f, 0), f, 1)[:h, :w]


# --------------------------------------------------------------------------------------------------------------
# Loading
# --------------------------------------------------------------------------------------------------------------


def _import_diffusers():
    try:
        import diffusers  # noqa: F401
        import torch  # noqa: F401
    except ImportError as e:  # pragma: no cover - exercised only without the extra
        raise ImportError("the diffusion view painter needs diffusers, transformers and safetensors (pip install 'proctex[diffusion]')") from e
    import diffusers

    return diffusers


def detect_pipeline(model_dir: str | Path) -> str:
    """``_class_name`` of the diffusers pipeline saved in ``model_dir``; ValueError if it is not one we support."""
    model_dir = Path(model_dir).expanduser()
    if not model_dir.exists():
        raise ValueError(f"model folder {str(model_dir)!r} does not exist")
    if not model_dir.is_dir():
        raise ValueError(f"model folder {str(model_dir)!r} is not a directory")
    index = model_dir / "model_index.json"
    if not index.is_file():
        raise ValueError(f"model folder {str(model_dir)!r} has no model_index.json: expected a diffusers pipeline folder written by save_pretrained (e.g. a StableDiffusionControlNetInpaintPipeline)")
    try:
        meta = json.loads(index.read_text())
    except (OSError, json.JSONDecodeError) as e:
        raise ValueError(f"cannot read {index}: {e}") from e
    name = meta.get("_class_name") if isinstance(meta, dict) else None
    if not isinstance(name, str):
        raise ValueError(f"{index} has no '_class_name' entry")
    if name not in SUPPORTED_PIPELINES:
        raise ValueError(f"unsupported pipeline class {name!r} in {index}; supported: {', '.join(SUPPORTED_PIPELINES)}")
    return name


def _loading_kwargs(dtype) -> dict:
    """``from_pretrained`` keywords: local files only, the dtype under the name this diffusers version wants."""
    import importlib.util

    try:  # newer diffusers (0.42 here) renamed torch_dtype -> dtype; torch_dtype warns
        from diffusers.utils.deprecation_utils import _resolve_dtype  # noqa: F401

        kw: dict[str, Any] = {"dtype": dtype}
    except ImportError:
        kw = {"torch_dtype": dtype}
    kw["local_files_only"] = True
    if importlib.util.find_spec("accelerate") is None:
        kw["low_cpu_mem_usage"] = False  # the default (True) only warns that accelerate is missing
    return kw


def _resolve_dtype(dtype: Any, device: str):
    import torch

    if dtype is None:
        return torch.float16 if str(device).startswith("cuda") else torch.float32
    if isinstance(dtype, torch.dtype):
        return dtype
    names = {"float32": torch.float32, "fp32": torch.float32, "float16": torch.float16, "fp16": torch.float16, "half": torch.float16, "bfloat16": torch.bfloat16, "bf16": torch.bfloat16}
    if isinstance(dtype, str) and dtype.lower() in names:
        return names[dtype.lower()]
    raise ValueError(f"dtype must be None, a torch.dtype or one of {sorted(names)}, got {dtype!r}")


class DiffusionViewPainter:
    """InTex-style view painter: depth-conditioned inpainting with a local diffusers pipeline.

    Args:
        model_dir: local diffusers pipeline folder (see the module docstring for the layouts).
        device: torch device string ("cpu", "cuda", "cuda:1", ...).
        dtype: torch dtype or name; None = float16 on CUDA, float32 elsewhere.
        steps: denoising steps of a GENERATE pass (a REFINE pass runs about ``steps * refine_strength``).
        guidance_scale: classifier-free guidance (<= 1 disables it and halves the cost).
        controlnet_scale: ControlNet conditioning scale (``"controlnet_inpaint"`` mode only).
        refine_strength: img2img strength of the REFINE pass in [0, 1]; 0 keeps REFINE pixels as rendered.
        negative_prompt: negative prompt (default discourages baked-in lighting and artefacts).
        resolution: working resolution: None = the UNet's ``sample_size * vae_scale_factor`` (512 for SD 1.5)
            for the longer side; an int = the longer side; ``(h, w)`` = exact size. Sides are rounded to a
            multiple of 8 (and of the VAE factor); the view is resized with Pillow to it and back.
        local_files_only: must stay True (nothing is downloaded); kept as a parameter for explicitness.
        controlnet_dir: optional separate local depth-ControlNet folder (``ControlNetModel.save_pretrained``
            output); it replaces the pipeline's own ControlNet, or adds one to a plain / inpainting SD folder.
        mask_dilation: extra dilation (working-resolution pixels) of the GENERATE mask; the masks are always
            grown to whole latent cells.

    Attributes:
        pipeline: the diffusers pipeline; mode: "controlnet_inpaint" | "inpaint" | "depth2img";
        source_class: ``_class_name`` read from ``model_index.json``; last_timings: seconds per pass of the
        last ``paint_view`` call.
    """

    def __init__(
        self,
        model_dir: str | Path,
        device: str = "cpu",
        dtype: Any = None,
        steps: int = 30,
        guidance_scale: float = 7.5,
        controlnet_scale: float = 1.0,
        refine_strength: float = 0.5,
        negative_prompt: str | None = DEFAULT_NEGATIVE_PROMPT,
        resolution: int | Sequence[int] | None = None,
        local_files_only: bool = True,
        controlnet_dir: str | Path | None = None,
        mask_dilation: int = 0,
    ) -> None:
        if not local_files_only:
            raise ValueError("local_files_only must be True: the painter never downloads models")
        if not isinstance(steps, (int, np.integer)) or isinstance(steps, bool) or steps < 1:
            raise ValueError(f"steps must be a positive int, got {steps!r}")
        if not (math.isfinite(guidance_scale) and guidance_scale >= 0):
            raise ValueError(f"guidance_scale must be finite and >= 0, got {guidance_scale!r}")
        if not (math.isfinite(controlnet_scale) and controlnet_scale >= 0):
            raise ValueError(f"controlnet_scale must be finite and >= 0, got {controlnet_scale!r}")
        if not 0.0 <= refine_strength <= 1.0:
            raise ValueError(f"refine_strength must be in [0, 1], got {refine_strength!r}")
        if not isinstance(mask_dilation, (int, np.integer)) or mask_dilation < 0:
            raise ValueError(f"mask_dilation must be an int >= 0, got {mask_dilation!r}")
        if resolution is not None:
            single = isinstance(resolution, (int, np.integer))
            res = (resolution,) if single else tuple(resolution)
            if (not single and len(res) != 2) or not all(isinstance(r, (int, np.integer)) and r >= 8 for r in res):
                raise ValueError(f"resolution must be None, an int >= 8 or (h, w) ints >= 8, got {resolution!r}")
        self.source_class = detect_pipeline(model_dir)
        if controlnet_dir is not None:
            cdir = Path(controlnet_dir).expanduser()
            if not (cdir / "config.json").is_file():
                raise ValueError(f"controlnet_dir {str(cdir)!r} is not a ControlNet folder (no config.json; expected ControlNetModel.save_pretrained output)")
        self.model_dir = Path(model_dir).expanduser()
        self.device = str(device)
        self.steps = int(steps)
        self.guidance_scale = float(guidance_scale)
        self.controlnet_scale = float(controlnet_scale)
        self.refine_strength = float(refine_strength)
        self.negative_prompt = negative_prompt or None
        self.resolution = resolution
        self.mask_dilation = int(mask_dilation)
        self.last_timings: dict[str, float] = {}

        import torch

        resolve_vml()
        self._torch = torch
        self.dtype = _resolve_dtype(dtype, self.device)
        self.pipeline, self.mode = self._load(controlnet_dir)
        self.pipeline.to(self.device)
        self.pipeline.set_progress_bar_config(disable=True)
        vae_cfg = self.pipeline.vae.config
        self.vae_scale_factor = 2 ** (len(vae_cfg.block_out_channels) - 1)
        ss = self.pipeline.unet.config.sample_size
        ss = ss if isinstance(ss, int) else int(max(ss))
        self.native_resolution = ss * self.vae_scale_factor

    # -- loading ----------------------------------------------------------------------------------------------

    def _load(self, controlnet_dir):
        diffusers = _import_diffusers()
        name, folder = self.source_class, str(self.model_dir)
        common = _loading_kwargs(self.dtype)
        no_safety = dict(safety_checker=None, feature_extractor=None, requires_safety_checker=False)
        if name in _DEPTH2IMG_CLASSES:
            if controlnet_dir is not None:
                raise ValueError("controlnet_dir cannot be combined with a StableDiffusionDepth2ImgPipeline folder")
            pipe = diffusers.StableDiffusionDepth2ImgPipeline.from_pretrained(folder, depth_estimator=None, feature_extractor=None, **common)
            return pipe, "depth2img"
        controlnet = None
        if controlnet_dir is not None:
            controlnet = diffusers.ControlNetModel.from_pretrained(str(Path(controlnet_dir).expanduser()), **common)
        elif name in _CONTROLNET_CLASSES and not (self.model_dir / "controlnet").is_dir():
            raise ValueError(f"{name} folder {folder!r} has no controlnet/ sub-folder; pass controlnet_dir= a local depth ControlNet folder")
        if name in _CONTROLNET_CLASSES or controlnet is not None:
            extra = {"controlnet": controlnet} if controlnet is not None else {}
            pipe = diffusers.StableDiffusionControlNetInpaintPipeline.from_pretrained(folder, **extra, **no_safety, **common)
            return pipe, "controlnet_inpaint"
        pipe = diffusers.StableDiffusionInpaintPipeline.from_pretrained(folder, **no_safety, **common)
        return pipe, "inpaint"

    # -- geometry of the working image -----------------------------------------------------------------------

    def working_size(self, height: int, width: int) -> tuple[int, int]:
        """(h, w) the model runs at for an (height, width) view."""
        m = math.lcm(8, self.vae_scale_factor)

        def rnd(x: float) -> int:
            return max(m, int(round(x / m)) * m)

        res = self.resolution
        if res is not None and not isinstance(res, (int, np.integer)):
            h, w = tuple(res)
            return rnd(h), rnd(w)
        long_side = int(res) if res is not None else self.native_resolution
        if height >= width:
            return rnd(long_side), rnd(long_side * width / height)
        return rnd(long_side * height / width), rnd(long_side)

    # -- painting --------------------------------------------------------------------------------------------

    def _run(self, prompt, init, mask, control, strength, generator, size):
        """One diffusion pass at working resolution; returns (h, w, 3) float32 in [0, 1]."""
        torch = self._torch
        h, w = size
        steps = self.steps
        if strength < 1.0:  # diffusers runs int(steps * strength) steps; keep at least one
            steps = max(steps, math.ceil(1.0 / strength))
        kw = dict(
            prompt=prompt,
            negative_prompt=self.negative_prompt if self.guidance_scale > 1.0 else None,
            num_inference_steps=steps,
            guidance_scale=self.guidance_scale,
            strength=float(strength),
            generator=generator,
            output_type="np",
        )
        if self.mode == "depth2img":
            # Tensor input: the numpy path of prepare_depth_map swaps height and width (diffusers 0.42 quirk).
            image = torch.from_numpy(np.ascontiguousarray(init.transpose(2, 0, 1)))[None]
            depth = torch.from_numpy(control)[None]
            if float(depth.max() - depth.min()) <= 0:  # the pipeline min-max normalises: avoid 0/0
                depth = depth.clone()
                depth[0, 0, 0] += 1e-3
            out = self.pipeline(image=image, depth_map=depth, **kw).images[0]
        else:
            kw.update(
                image=init[None],  # (1, h, w, 3): a batch of one (a bare (h, w, 3) array reads as a batch of h)
                mask_image=mask.astype(np.float32)[None, :, :, None],
                height=h,
                width=w,
            )
            if self.mode == "controlnet_inpaint":
                kw.update(
                    control_image=np.repeat(control[None, :, :, None], 3, axis=-1),
                    controlnet_conditioning_scale=self.controlnet_scale,
                )
            out = self.pipeline(**kw).images[0]
        return np.clip(np.asarray(out, dtype=np.float32), 0.0, 1.0)

    def _work_mask(self, mask: np.ndarray, size: tuple[int, int], dilate: int) -> np.ndarray:
        m = _resize_mask(mask, size)
        if dilate > 0:
            from scipy.ndimage import binary_dilation

            m = binary_dilation(m, iterations=dilate)
        return _block_dilate(m, self.vae_scale_factor)

    def paint_view(self, request: ViewRequest) -> np.ndarray:
        """Paint one view: (H, W, 3) float32 in [0, 1]; REFINE/GENERATE pixels painted, the rest = ``request.rgb``."""
        validate_request(request)
        torch = self._torch
        H, W = request.size
        trimap = np.asarray(request.trimap)
        rgb = np.clip(request.rgb, 0.0, 1.0).astype(np.float32)
        gen, ref = trimap == GENERATE, trimap == REFINE
        do_refine = bool(ref.any()) and self.refine_strength > 0.0
        result = rgb.copy()
        self.last_timings = {}
        if not gen.any() and not do_refine:
            return result

        size = self.working_size(H, W)
        init = _resize_float(rgb, size)
        init = np.clip(init, 0.0, 1.0)
        control = _resize_float(depth_control_image(request.depth, request.foreground), size, Image.BILINEAR)
        control = np.clip(control, 0.0, 1.0)
        prompt = compose_prompt(request)
        generator = torch.Generator(self.device).manual_seed(int(request.seed) % (2**63))

        with torch.inference_mode():
            if gen.any():
                t0 = time.perf_counter()
                mask = self._work_mask(gen, size, self.mask_dilation)
                out = self._run(prompt, init, mask, control, 1.0, generator, size)
                result[gen] = _resize_float(out, (H, W))[gen]
                # The refine pass sees the generated pixels as context (on the exact, undilated mask).
                init = np.where(_resize_mask(gen, size)[..., None], out, init)
                self.last_timings["generate"] = time.perf_counter() - t0
            if do_refine:
                t0 = time.perf_counter()
                mask = self._work_mask(ref, size, 0)
                out = self._run(prompt, init, mask, control, self.refine_strength, generator, size)
                result[ref] = _resize_float(out, (H, W))[ref]
                self.last_timings["refine"] = time.perf_counter() - t0
        return np.clip(result, 0.0, 1.0).astype(np.float32)

    def __repr__(self) -> str:
        return (
            f"DiffusionViewPainter({str(self.model_dir)!r}, mode={self.mode!r}, device={self.device!r}, "
            f"steps={self.steps}, guidance_scale={self.guidance_scale}, refine_strength={self.refine_strength})"
        )


# --------------------------------------------------------------------------------------------------------------
# Tiny random-weight pipelines (tests, smoke runs)
# --------------------------------------------------------------------------------------------------------------
