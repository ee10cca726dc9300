"""Benchmark of template texturing (docs/texturing.md): surface painting, rendering, the multi-view loop.

    .venv/bin/python tests/bench/bench_paint.py --out out/bench_paint.json

Measures, median of ``--repeats`` runs:
- painting the sofa template (all groups) with the surface painter at ``--size`` (issue 4: < 10 s at 1024²),
  split into UV unwrapping, texel maps and painting;
- rendering one 512² view of the sofa with the Embree and the pure NumPy backends;
- the multi-view loop with the solid view painter (11 views), with its PSNR against the surface painter.
"""

from __future__ import annotations

import sys
import argparse
import json
import statistics
import time
from pathlib import Path

import numpy as np

from proctex.geometry.parts import analyse
from proctex.sources.files import FolderSource
from proctex.texture.metrics import coverage
from proctex.texture.paint import SolidViewPainter, paint_surface
from proctex.texture.paint_loop import paint_views
from proctex.texture.painters import SurfacePainter
from proctex.texture.render import (
    Tracer,
    bounding_sphere,
    embree_available,
    orbit_path,
    render_buffers,
)

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))  # the repository root (tests.data)
from tests.data import SOFA  # noqa: E402


def median_time(fn, repeats: int) -> tuple[float, object]:
    times, out = [], None
    for _ in range(repeats):
        t = time.perf_counter()
        out = fn()
        times.append(time.perf_counter() - t)
    return statistics.median(times), out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sofa", default=str(SOFA))
    ap.add_argument("--size", type=int, default=1024)
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--prompt", default="red velvet")
    ap.add_argument("--views", type=int, default=11)
    ap.add_argument("--view-size", type=int, default=512)
    ap.add_argument("--loop-size", type=int, default=512, help="texture size for the multi-view loop")
    ap.add_argument("--out")
    args = ap.parse_args(argv)

    src = FolderSource(args.sofa)
    shape = src.load(src.template_index())
    grouping = analyse(shape)
    painter = SurfacePainter(args.prompt, {"1": "dark walnut"})
    result: dict = {"sofa_faces": shape.n_faces, "groups": len(grouping.groups), "size": args.size}

    t, tex = median_time(lambda: paint_surface(shape, grouping, painter, size=args.size), args.repeats)
    result["surface_paint_s"] = t
    result["surface_paint_split_s"] = tex.stats["timings"]
    result["texels"] = int(sum(len(g.texels.face) for g in tex.groups))
    cov = coverage(shape.vertices, shape.faces, tex.uv.corner_uv, tex.uv.face_group, tex.painted_masks, up="y")
    result["surface_coverage"] = cov.share
    print(
        f"surface paint, sofa template, {len(grouping.groups)} groups at {args.size}²: {t:.2f} s "
        f"({result['texels']} texels; uv {tex.stats['timings']['uv']:.2f} s, texel maps {tex.stats['timings']['texels']:.2f} s, "
        f"paint {tex.stats['timings']['paint']:.2f} s); coverage {cov.share}"
    )

    # The PBR maps of the same texture (roughness, metalness, relief): what they add to the paint stage.
    from proctex.texture.paint import paint_material_maps

    painter.bind(shape, grouping, "y")
    t, _ = median_time(lambda: paint_material_maps(tex, painter), args.repeats)
    result["pbr_maps_s"] = t
    print(f"PBR maps (ORM + normal) of the same {len(grouping.groups)} groups at {args.size}²: {t:.2f} s")

    c, r = bounding_sphere(shape.vertices)
    cam = orbit_path(c, r, "y", 11, args.view_size)[1]
    for backend in ["raster"] + (["embree"] if embree_available() else []):
        tracer = Tracer(shape.vertices, shape.faces, backend)
        t, _ = median_time(lambda: render_buffers(tracer, cam, grouping.segmentation.face_part), max(args.repeats, 5))
        result[f"render_{backend}_s"] = t
        print(f"render buffers {args.view_size}², {backend}: {1000 * t:.1f} ms")
    if "render_embree_s" in result:
        result["render_embree_over_raster"] = result["render_embree_s"] / result["render_raster_s"]

    ref = paint_surface(shape, grouping, painter, size=args.loop_size)
    t0 = time.perf_counter()
    tv = paint_views(shape, grouping, SolidViewPainter(painter, grouping), args.prompt, {"1": "dark walnut"}, n_views=args.views, view_size=args.view_size, size=args.loop_size, up="y", uv=ref.uv)
    result["view_loop_s"] = time.perf_counter() - t0
    psnrs = {}
    for a, b in zip(ref.groups, tv.groups):
        if grouping.groups[a.group].degenerate or b.direct is None or not b.direct.any():
            continue
        ij = a.texels.ij[b.direct]
        mse = float(((a.image[ij[:, 0], ij[:, 1]] - b.image[ij[:, 0], ij[:, 1]]) ** 2).mean())
        psnrs[a.group] = 10 * np.log10(1 / max(mse, 1e-12))
    result["view_loop_psnr_db"] = psnrs
    result["view_loop_hidden_views"] = tv.stats["hidden_views"]
    cov = coverage(shape.vertices, shape.faces, tv.uv.corner_uv, tv.uv.face_group, tv.painted_masks, up="y")
    result["view_loop_coverage"] = cov.share
    print(
        f"multi-view loop ({args.views} views of {args.view_size}², {args.loop_size}² textures, + {tv.stats['hidden_views']} hidden-part views): "
        f"{result['view_loop_s']:.1f} s; PSNR vs surface painter on seen texels: " + ", ".join(f"g{k} {v:.1f} dB" for k, v in psnrs.items()) + f"; coverage {cov.share}"
    )
    if args.out:
        Path(args.out).parent.mkdir(parents=True, exist_ok=True)
        Path(args.out).write_text(json.dumps(result, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
