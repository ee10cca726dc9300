"""A tiny, randomly initialised diffusers pipeline built in code (:func:`build_tiny_pipeline`): the
same classes and folder layout as a real Stable Diffusion (ControlNet, inpainting or depth-to-image)
model, small enough for the tests and the demo to run the diffusion view painter offline."""

from __future__ import annotations

import json
from pathlib import Path

from .diffusion import _import_diffusers


def _bytes_to_unicode() -> list[str]:
    """GPT-2/CLIP byte -> printable unicode table (the base alphabet of the CLIP BPE vocabulary)."""
    bs = [*range(ord("!"), ord("~") + 1), *range(ord("¡"), ord("¬") + 1), *range(ord("®"), ord("ÿ") + 1)]
    cs = bs[:]
    n = 0
    for b in range(256):
        if b not in bs:
            bs.append(b)
            cs.append(256 + n)
            n += 1
    return [chr(c) for c in cs]


_TINY_MERGES = ("r e", "e d</w>", "o o", "w oo", "c h", "a i", "ch ai", "chai r</w>", "t a", "b l")


def _write_tiny_tokenizer_files(folder: Path) -> int:
    """Write a CLIP BPE ``vocab.json`` + ``merges.txt`` (bytes, bytes + '</w>', a few merges); return the vocab size."""
    chars = _bytes_to_unicode()
    tokens = ["<|startoftext|>", "<|endoftext|>"] + chars + [c + "</w>" for c in chars]
    for merge in _TINY_MERGES:
        merged = merge.replace(" ", "")
        if merged not in tokens:
            tokens.append(merged)
    folder.mkdir(parents=True, exist_ok=True)
    (folder / "vocab.json").write_text(json.dumps({t: i for i, t in enumerate(tokens)}, ensure_ascii=False))
    (folder / "merges.txt").write_text("#version: 0.2\n" + "\n".join(_TINY_MERGES) + "\n")
    return len(tokens)


def build_tiny_pipeline(out_dir: str | Path, seed: int = 0, kind: str = "controlnet_inpaint") -> Path:
    """Write a tiny random-weight pipeline to ``out_dir`` (built in code, nothing downloaded) and return it.

    ``kind``: "controlnet_inpaint" (a ``StableDiffusionControlNetInpaintPipeline``: 9-channel inpainting
    UNet + depth-style ControlNet), "inpaint" (``StableDiffusionInpaintPipeline``), "depth2img"
    (``StableDiffusionDepth2ImgPipeline`` with a 5-channel UNet, no DPT estimator) or "controlnet" (a
    ``ControlNetModel`` folder alone, for ``DiffusionViewPainter(controlnet_dir=...)``).

    The models: VAE with 4 blocks of 8 channels (scale factor 8, like SD), UNet/ControlNet with blocks
    (8, 16), one layer per block, cross-attention width 16, UNet ``sample_size`` 8 (so the default working
    resolution is 64), CLIP text encoder with hidden size 16 and 2 layers, a byte-level CLIP BPE tokenizer,
    a DDIM scheduler. The ControlNet's zero-initialised convolutions get random weights and its condition
    embedding a He init, so the depth image visibly influences the output. Deterministic in ``seed``
    (the global torch RNG is left untouched).
    """
    import torch

    diffusers = _import_diffusers()
    from transformers import CLIPTextConfig, CLIPTextModel, CLIPTokenizer

    kinds = ("controlnet_inpaint", "inpaint", "depth2img", "controlnet")
    if kind not in kinds:
        raise ValueError(f"kind must be one of {kinds}, got {kind!r}")
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)

    blocks = dict(
        block_out_channels=(8, 16),
        layers_per_block=1,
        down_block_types=("DownBlock2D", "CrossAttnDownBlock2D"),
        cross_attention_dim=16,
        attention_head_dim=2,
        norm_num_groups=4,
    )

    def make_controlnet():
        cn = diffusers.ControlNetModel(in_channels=4, conditioning_channels=3, conditioning_embedding_out_channels=(4, 4, 4, 4), **blocks)
        for mod in list(cn.controlnet_down_blocks) + [cn.controlnet_mid_block]:
            mod.reset_parameters()  # default init instead of zeros, so the ControlNet residuals are not 0
        for mod in cn.controlnet_cond_embedding.modules():  # He init, zero bias: the depth image matters
            if isinstance(mod, torch.nn.Conv2d):
                torch.nn.init.kaiming_normal_(mod.weight, nonlinearity="relu")
                torch.nn.init.zeros_(mod.bias)
        return cn

    with torch.random.fork_rng(devices=[]):
        torch.manual_seed(seed)
        if kind == "controlnet":
            make_controlnet().save_pretrained(out_dir)
            return out_dir
        in_ch = {"controlnet_inpaint": 9, "inpaint": 9, "depth2img": 5}[kind]
        unet = diffusers.UNet2DConditionModel(
            sample_size=8,
            in_channels=in_ch,
            out_channels=4,
            up_block_types=("CrossAttnUpBlock2D", "UpBlock2D"),
            **blocks,
        )
        vae = diffusers.AutoencoderKL(
            in_channels=3,
            out_channels=3,
            down_block_types=("DownEncoderBlock2D",) * 4,
            up_block_types=("UpDecoderBlock2D",) * 4,
            block_out_channels=(8, 8, 8, 8),
            layers_per_block=1,
            latent_channels=4,
            norm_num_groups=4,
            sample_size=64,
        )
        tok_src = out_dir / "_tokenizer_src"
        vocab_size = _write_tiny_tokenizer_files(tok_src)
        tokenizer = CLIPTokenizer.from_pretrained(str(tok_src), model_max_length=77)
        text_encoder = CLIPTextModel(
            CLIPTextConfig(
                vocab_size=vocab_size,
                hidden_size=16,
                intermediate_size=32,
                projection_dim=16,
                num_hidden_layers=2,
                num_attention_heads=2,
                max_position_embeddings=77,
                bos_token_id=0,
                eos_token_id=1,
                pad_token_id=1,
            )
        )
        scheduler = diffusers.DDIMScheduler(
            beta_start=0.00085,
            beta_end=0.012,
            beta_schedule="scaled_linear",
            clip_sample=False,
            set_alpha_to_one=False,
            steps_offset=1,
        )
        parts = dict(vae=vae, text_encoder=text_encoder, tokenizer=tokenizer, unet=unet, scheduler=scheduler)
        if kind == "controlnet_inpaint":
            pipe = diffusers.StableDiffusionControlNetInpaintPipeline(
                controlnet=make_controlnet(),
                safety_checker=None,
                feature_extractor=None,
                requires_safety_checker=False,
                **parts,
            )
        elif kind == "inpaint":
            pipe = diffusers.StableDiffusionInpaintPipeline(safety_checker=None, feature_extractor=None, requires_safety_checker=False, **parts)
        else:
            pipe = diffusers.StableDiffusionDepth2ImgPipeline(depth_estimator=None, feature_extractor=None, **parts)
        pipe.save_pretrained(out_dir, safe_serialization=True)

    # transformers >= 5 saves only tokenizer.json; keep the slow-tokenizer files too (transformers 4 reads them).
    tok_dir = out_dir / "tokenizer"
    for fname in ("vocab.json", "merges.txt"):
        if not (tok_dir / fname).exists():
            (tok_dir / fname).write_bytes((tok_src / fname).read_bytes())
    for f in tok_src.iterdir():
        f.unlink()
    tok_src.rmdir()
    return out_dir
