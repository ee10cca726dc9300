"""Benchmark of the in-process real-time transfer: sofa mesh file in, textured GLB bytes out.

    .venv/bin/python tests/bench/bench_transfer.py --out out/bench_transfer.json [--family out/sofa_family]

Per inference shape (median over shapes and repeats): read + clean the OBJ, segment, assign parts
to template slots, ProcCorrNet per part (context samples + vertices), per-face UVs into the template
textures, GLB assembly (the template PNGs are encoded once, not per request). Without ``--family``
the template is painted here and the networks are freshly initialised (same cost as trained ones).
Also times, in the same run, the networks in float32 (``--autocast`` picks the measured mapper's:
"auto" is bfloat16 on CPUs with native bfloat16) and the identity mapper (no network) as baselines,
and baking into the shape's own 512² atlas for comparison.
"""

from __future__ import annotations

import sys
import argparse
import json
import statistics
import time
from pathlib import Path

import numpy as np
import torch

from proctex.geometry.meshio import load_mesh
from proctex.geometry.parts import analyse
from proctex.sources.files import FolderSource
from proctex.texture.paint import paint_surface
from proctex.texture.painters import SurfacePainter
from proctex.transfer.apply import bake, glb, transfer
from proctex.transfer.assets import prepare_template
from proctex.transfer.mappers import IdentityMapper, NetworkMapper

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))  # the repository root (tests.data)
from tests.data import SOFA  # noqa: E402


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sofa", default=str(SOFA))
    ap.add_argument("--family", help="a built sofa family (trained networks); default: paint + untrained networks here")
    ap.add_argument("--texture", type=int, default=512)
    ap.add_argument("--shapes", type=int, default=10)
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--threads", type=int, default=2, help="torch threads")
    ap.add_argument("--context", type=int, default=None, help="ProcCorrNet context points (default: as trained)")
    ap.add_argument("--autocast", default="auto", help="NetworkMapper autocast (auto: bfloat16 on CPUs with native bfloat16)")
    ap.add_argument("--out")
    args = ap.parse_args(argv)
    torch.set_num_threads(args.threads)

    src = FolderSource(args.sofa)
    if args.family:
        from proctex.store.layout import FamilyStore
        from proctex.store.networks import load_models
        from proctex.transfer.assets import load_assets

        store = FamilyStore(args.family)
        assets = load_assets(store)
        models = load_models(store)
    else:
        from proctex.correspond.corrnet import CorrNetConfig, build_model

        template = src.load(src.template_index())
        grouping = analyse(template)
        tex = paint_surface(template, grouping, SurfacePainter("red velvet", {"1": "dark walnut"}), size=args.texture)
        assets = prepare_template(template, grouping, tex.uv.corner_uv, [g.uint8() for g in tex.groups])
        models = {g.group: build_model(CorrNetConfig(seed=g.group)).eval() for g in assets.groups if not g.degenerate}
    mapper = NetworkMapper(models, context=args.context, autocast=args.autocast)
    exact = NetworkMapper(models, context=args.context, autocast="none")  # float32 networks, in the same run
    paths = [src.samples[i].mesh_path for i in src.indices("test")[: args.shapes]]

    def once(path, m):
        t0 = time.perf_counter()
        shape, _ = load_mesh(path)
        t1 = time.perf_counter()
        r = transfer(shape, assets, m)
        t2 = time.perf_counter()
        data = glb(shape, r, assets)
        t3 = time.perf_counter()
        return t3 - t0, {"load": t1 - t0, **r.timings, "glb": t3 - t2}, len(data), shape, r

    for p in paths[:2]:  # warm up (imports, torch kernels)
        once(p, mapper)
    totals, base, fp32, stages, sizes = [], [], [], {}, []
    for _ in range(args.repeats):
        for p in paths:
            t, parts, n, _, _ = once(p, mapper)
            totals.append(t)
            sizes.append(n)
            for k, v in parts.items():
                stages.setdefault(k, []).append(v)
            base.append(once(p, IdentityMapper())[0])
            fp32.append(once(p, exact)[0])
    med = statistics.median(totals)
    result = {
        "shapes": len(paths),
        "repeats": args.repeats,
        "threads": args.threads,
        "texture": args.texture,
        "median_s": med,
        "p90_s": float(np.quantile(totals, 0.9)),
        "identity_median_s": statistics.median(base),
        "float32_median_s": statistics.median(fp32),
        "autocast": args.autocast,
        "network_share": 1 - statistics.median(base) / med,
        "stages_median_s": {k: statistics.median(v) for k, v in stages.items()},
        "glb_bytes_median": int(statistics.median(sizes)),
        "trained": bool(args.family),
    }
    _, _, _, shape, r = once(paths[0], mapper)
    t = time.perf_counter()
    bake(shape, r, assets, size=args.texture)
    result["bake_s"] = time.perf_counter() - t
    print(
        f"transfer, sofa mesh file -> GLB bytes ({args.texture}² textures, {args.threads} threads, autocast {args.autocast}): median {1000 * med:.0f} ms, "
        f"p90 {1000 * result['p90_s']:.0f} ms; float32 networks {1000 * result['float32_median_s']:.0f} ms; "
        f"identity mapper {1000 * result['identity_median_s']:.0f} ms; "
        f"bake into own atlas {result['bake_s']:.2f} s"
    )
    print("stages (median ms): " + ", ".join(f"{k} {1000 * v:.1f}" for k, v in result["stages_median_s"].items()))
    if args.out:
        Path(args.out).parent.mkdir(parents=True, exist_ok=True)
        Path(args.out).write_text(json.dumps(result, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
