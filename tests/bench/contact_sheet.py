"""Contact sheet: many prompts painted on a few templates, one labelled 3/4 view each.

    .venv/bin/python tests/bench/contact_sheet.py --out out/contact_sheet.png

Prompts run across (in blocks of ``--columns``), models down (built-in names, or mesh files such as a
sofa sample). It uses
the offline surface painter, so it runs anywhere in about a minute.
"""

from __future__ import annotations

import argparse
import os
import time
from pathlib import Path

import numpy as np
from PIL import Image, ImageDraw

from proctex.geometry.parts import analyse
from proctex.sources.files import resolve_shape
from proctex.texture.paint import paint_surface
from proctex.texture.painters import SurfacePainter
from proctex.texture.render import (
    Tracer,
    bounding_sphere,
    default_up,
    orbit_camera,
    render_buffers,
    save_png,
    shade,
    textured_albedo,
)

PROMPTS = [
    "red velvet",
    "dark walnut",
    "light oak wood",
    "white marble",
    "speckled grey granite",
    "glazed blue ceramic",
    "brushed steel",
    "gold",
    "rusty iron",
    "worn brown leather",
    "blue denim",
    "red and white checkered fabric",
    "green and navy plaid",
    "yellow polka dots on white",
    "pink floral fabric",
    "orange and teal patchwork",
    "mossy stone",
    "old red brick",
]
MODELS = ["chair", "vase", "sofa"]


def render_one(shape, grouping, prompt: str, seed: int, size: int, texture: int, up: str) -> np.ndarray:
    tex = paint_surface(shape, grouping, SurfacePainter(prompt, seed=seed), size=texture)
    c, r = bounding_sphere(shape.vertices)
    cam = orbit_camera(c, r, up, -35.0, 25.0, size, fov_deg=32.0)
    b = render_buffers(Tracer(shape.vertices, shape.faces), cam, face_group=tex.uv.face_group)
    return shade(b, textured_albedo(b, tex.uv.corner_uv, tex.uv.face_group, tex.images))


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", default="out/contact_sheet.png")
    ap.add_argument("--models", nargs="*", default=MODELS, help="built-in model names or mesh files")
    ap.add_argument("--prompts", nargs="*", default=PROMPTS)
    ap.add_argument("--size", type=int, default=192, help="view size")
    ap.add_argument("--texture", type=int, default=512, help="texture size per group")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--columns", type=int, default=6, help="prompts per row block")
    args = ap.parse_args(argv)
    t0 = time.perf_counter()
    shapes = []
    for m in args.models:
        s = resolve_shape(m)
        shapes.append((m, s, analyse(s), default_up(s.source)))
    # Blocks of ``--columns`` prompts: a header row of prompt names, then one row per model.
    cols, pad, head, label_w = args.columns, 4, 28, 90
    blocks = [args.prompts[i : i + cols] for i in range(0, len(args.prompts), cols)]
    cell = args.size + pad
    block_h = head + len(shapes) * cell
    sheet = Image.new("RGB", (label_w + cols * cell + pad, len(blocks) * block_h + pad), "white")
    draw = ImageDraw.Draw(sheet)
    done = 0
    for b, prompts in enumerate(blocks):
        y0 = b * block_h + pad
        for j, prompt in enumerate(prompts):
            draw.text((label_w + j * cell + 4, y0 + 8), prompt, fill="black")
        for m, (name, shape, grouping, up) in enumerate(shapes):
            y = y0 + head + m * cell
            draw.text((6, y + args.size // 2 - 6), f"{Path(name).parent.name}/{Path(name).stem}" if os.path.exists(name) else name, fill="black")
            for j, prompt in enumerate(prompts):
                img = render_one(shape, grouping, prompt, args.seed, args.size, args.texture, up)
                sheet.paste(Image.fromarray(img), (label_w + j * cell, y))
        done += len(prompts)
        print(f"{done}/{len(args.prompts)} prompts", flush=True)
    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    save_png(out, np.asarray(sheet))
    print(f"wrote {out} ({len(args.prompts)} prompts x {len(shapes)} models) in {time.perf_counter() - t0:.1f}s")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
