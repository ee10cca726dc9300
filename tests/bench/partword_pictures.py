"""One picture per kind of object for the README's part words (issue 51).

For each kind of the part corpus (:mod:`partcorpus`), the first development object of that kind,
unlabelled, painted by the surface painter from a prompt naming every one of its parts with its own
material (the benchmark's composer, all parts), and rendered from a raised three-quarter view with
the prompt written under it: ``partwords_<kind>.png`` (at most 150 KB each) in ``--out``.

    python tests/bench/partword_pictures.py --out docs/img
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np
from PIL import Image, ImageDraw

from proctex.geometry.parts import analyse
from proctex.texture.paint_loop import paint_template
from proctex.texture.render import Tracer, bounding_sphere, orbit_camera, render_buffers, shade, textured_albedo

try:
    from . import bench_partwords as B
    from . import partcorpus as C
except ImportError:  # run as a script
    import bench_partwords as B  # type: ignore[no-redef]
    import partcorpus as C  # type: ignore[no-redef]

MAX_BYTES = 150_000


def picture(obj: C.CorpusObject, size: int = 320, texture: int = 128) -> tuple[Image.Image, str]:
    """The painted, rendered ``obj`` with its prompt under it, and the prompt."""
    roles = [r for r in obj.shape.label_names if r in C.FORMS]
    rng = np.random.default_rng(obj.seed)
    mats = B.distinct_materials(len(roles), rng)
    parts = [f"{m} {C.FORMS[r][0]}" for r, m in zip(roles, mats)]
    prompt = f"a {obj.noun} with " + (parts[0] if len(parts) == 1 else ", ".join(parts[:-1]) + " and " + parts[-1])
    shape = C.unlabelled(obj.shape)
    tex = paint_template(shape, analyse(shape), prompt, size=texture, up=obj.up, maps=False)
    c, r = bounding_sphere(shape.vertices)
    cam = orbit_camera(c, r, obj.up, 35.0, 25.0, size)
    b = render_buffers(Tracer(shape.vertices, shape.faces), cam, face_group=tex.uv.face_group)
    image = Image.fromarray(shade(b, textured_albedo(b, tex.uv.corner_uv, tex.uv.face_group, tex.images)))
    canvas = Image.new("RGB", (size, size + 44), "white")
    canvas.paste(image, (0, 0))
    draw = ImageDraw.Draw(canvas)
    words, lines, line = prompt.split(), [], ""
    for w in words:  # wrap the prompt to the picture's width
        if draw.textlength(f"{line} {w}".strip()) > size - 8:
            lines.append(line)
            line = w
        else:
            line = f"{line} {w}".strip()
    lines.append(line)
    for i, text in enumerate(lines[:3]):
        draw.text((4, size + 2 + 13 * i), text, fill=(20, 20, 20))
    return canvas, prompt


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--out", default="docs/img")
    ap.add_argument("--kinds", default=",".join(C.KINDS), help="comma-separated kinds (default all)")
    args = ap.parse_args(argv)
    kinds = [k for k in args.kinds.split(",") if k]
    unknown = sorted(set(kinds) - set(C.KINDS))
    if unknown:
        raise SystemExit(f"unknown kinds: {', '.join(unknown)}; known: {', '.join(C.KINDS)}")
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    for kind in kinds:
        obj = next(o for o in map(C.make_object, C.seeds("development")) if o.kind == kind)
        image, prompt = picture(obj)
        path = out / f"partwords_{kind}.png"
        image.save(path, optimize=True)
        if path.stat().st_size > MAX_BYTES:
            image.quantize(colors=128).save(path, optimize=True)
        print(f"{path} ({path.stat().st_size // 1000} KB): {prompt}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
