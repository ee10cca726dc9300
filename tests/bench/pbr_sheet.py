"""Contact sheet of PBR materials: one built-in family's template painted with "brushed brass", "red
velvet" and "oak", each shown colour only (the old headlight shading, flat plastic) and with its PBR
maps (:mod:`proctex.texture.lighting`), and the fork with a region prompt.

    .venv/bin/python tests/bench/pbr_sheet.py --out out/pbr_sheet.png [--model chair --size 512 --view 320]

Prints, per prompt, the spread of pixel brightness on the object (the 5th to 95th percentile of
luma), colour only against PBR: metals gain highlights and reflections, fabrics stay matte.
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from proctex.geometry.parts import analyse
from proctex.models import get_model
from proctex.texture.paint_loop import paint_template
from proctex.texture.render import Tracer, render_grid, render_textured, save_png, three_quarter_camera

PROMPTS = ("brushed brass", "red velvet", "oak")
REGION = ("fork", "a dinner fork with a silver tip and a dark wood handle")


def _spread(img: np.ndarray) -> float:
    luma = img.astype(float) @ [0.2126, 0.7152, 0.0722]
    obj = luma[(img < 250).any(axis=2)]
    return float(np.percentile(obj, 95) - np.percentile(obj, 5)) if obj.size else 0.0


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--model", default="chair")
    ap.add_argument("--size", type=int, default=512, help="texture size")
    ap.add_argument("--view", type=int, default=320, help="image size")
    ap.add_argument("--out", default="out/pbr_sheet.png")
    args = ap.parse_args()
    images, labels = [], []
    jobs = [(args.model, p) for p in PROMPTS] + [REGION]
    for model, prompt in jobs:
        shape = get_model(model).generate(None)
        grouping = analyse(shape)
        t0 = time.perf_counter()
        tex = paint_template(shape, grouping, prompt, size=args.size)
        t_paint = time.perf_counter() - t0
        cam = three_quarter_camera(shape.vertices, "z", args.view, elevation=30.0 if model == "fork" else 25.0)
        tracer = Tracer(shape.vertices, shape.faces)
        flat = render_textured(shape.vertices, shape.faces, tex.uv.corner_uv, tex.uv.face_group, tex.images, cam, tracer)
        t0 = time.perf_counter()
        pbr = render_textured(shape.vertices, shape.faces, tex.uv.corner_uv, tex.uv.face_group, tex.images, cam, tracer, maps=tex.pbr)
        t_render = time.perf_counter() - t0
        images += [flat, pbr]
        short = prompt if len(prompt) < 24 else "fork, tip and handle"
        labels += [f"{short}: colour only", f"{short}: PBR"]
        print(f"{model:6s} {prompt!r:58s} luma spread colour-only {_spread(flat):5.1f}  PBR {_spread(pbr):5.1f}  (paint + maps {t_paint:.2f} s, PBR render {t_render:.2f} s)")
    save_png(args.out, render_grid(images, 2, labels))
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
