"""Benchmark: dense correspondence methods (cage, nearest, CPD) on built-in models and sofa pairs.

For every built-in model the template is the default parameter setting and the shapes are random
parameter settings (seeded); every matched, non-degenerate group pair is solved by each method and
scored against the ground truth (canonical coordinates). Sofa pairs (real exported meshes) are
scored against vertex-index truth (the export keeps one vertex order; ``sofa_gt_*``) and report
residuals and seconds. Runs single-threaded (torch and BLAS) unless ``--threads``.

    python tests/bench/bench_correspond.py --out out/bench_correspond.json
    python tests/bench/bench_correspond.py --models mug,desk --shapes 1 --methods cage --level 2
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))  # the repository root (tests.data)
from tests.data import SOFA  # noqa: E402

THIN_WALLED = ("mug", "vase")
DEFAULT_MODELS = "mug,vase,desk,chair,stair,fork,table,mushroom"


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--models", default=DEFAULT_MODELS)
    ap.add_argument("--shapes", type=int, default=2, help="random shapes per model")
    ap.add_argument("--methods", default="cage,nearest,cpd")
    ap.add_argument("--points", type=int, default=2000)
    ap.add_argument("--level", type=int, default=None, help="cage subdivision level (default: the solver's)")
    ap.add_argument("--sofa-dir", default=str(SOFA))
    ap.add_argument("--sofa-pairs", type=int, default=3)
    ap.add_argument("--chamfer", default=None, choices=("point", "plane"), help="cage Chamfer term (default: the solver's)")
    ap.add_argument("--cpd-beta", type=float, default=None)
    ap.add_argument("--cpd-lambda", type=float, default=None)
    ap.add_argument("--cage-set", action="append", default=[], metavar="KEY=VALUE", help="a CageConfig field, e.g. w_rest=0.5 (repeatable)")
    ap.add_argument("--tessellation", default="fixed", choices=("fixed", "adaptive"))
    ap.add_argument("--threads", type=int, default=1)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--out", default="")
    args = ap.parse_args(argv)

    os.environ.setdefault("OMP_NUM_THREADS", str(args.threads))
    import numpy as np
    import torch

    torch.set_num_threads(args.threads)
    from proctex.correspond.cage import CageConfig
    from proctex.correspond.dense import correspond_shapes
    from proctex.geometry.parts import analyse
    from proctex.models import get_model
    from proctex.sources.files import FolderSource

    cage = CageConfig() if args.level is None else CageConfig(level=args.level)
    if args.chamfer is not None:
        cage.chamfer = args.chamfer
    for item in args.cage_set:
        key, _, value = item.partition("=")
        if not hasattr(cage, key):
            raise SystemExit(f"--cage-set: CageConfig has no field {key!r}")
        kind = type(getattr(cage, key))
        setattr(cage, key, value.lower() in ("1", "true", "yes") if kind is bool else kind(value))
    cage.validate()
    methods = [m for m in args.methods.split(",") if m]
    opts = {}
    if args.cpd_beta is not None:
        opts["cpd_beta"] = args.cpd_beta
    if args.cpd_lambda is not None:
        opts["cpd_lambda"] = args.cpd_lambda
    rows: list[dict] = []

    def record(kind: str, model: str, shape_id: str, method: str, res) -> None:
        for g in res.groups:
            row = {"kind": kind, "model": model, "shape": shape_id, "method": method, **g.to_dict()}
            rows.append(row)
            gt = row["gt_error"]
            gt_s = f"gt {gt['mean']:.4f} p95 {gt['p95']:.3f} flip {gt['flipped']:.3f}" if gt else ""
            print(f"{model:9s} {shape_id:6s} {method:8s} g{row['group']:<2d} {row['seconds']:6.2f}s res {row['residual']:.4f} {gt_s}", file=sys.stderr, flush=True)

    for name in [m for m in args.models.split(",") if m]:
        model = get_model(name, tessellation=args.tessellation)
        template = model.generate()
        tg = analyse(template)
        for k, params in enumerate(model.space.sample(args.shapes, seed=args.seed + 17)):
            shape = model.generate(params)
            sg = analyse(shape)
            for method in methods:
                res = correspond_shapes(shape, template, method=method, n_points=args.points, seed=args.seed, cage=cage, grouping=sg, template_grouping=tg, **opts)
                record("builtin", name, f"s{k}", method, res)

    sofa = Path(args.sofa_dir)
    if args.sofa_pairs > 0 and sofa.is_dir():
        src = FolderSource(sofa)
        ti = src.template_index()
        template = src.load(ti)
        # vertex-index truth: the export keeps one vertex order, so shape vertex i is template vertex
        # i; the template's positions serve as canonical coordinates on both.
        template.canonical = template.vertices.copy()
        tg = analyse(template)
        others = [i for i in src.indices("train") if i != ti][: args.sofa_pairs]
        for i in others:
            shape = src.load(i)
            if len(shape.vertices) == len(template.vertices):
                shape.canonical = template.canonical
            sg = analyse(shape)
            for method in methods:
                res = correspond_shapes(shape, template, method=method, n_points=args.points, seed=args.seed, cage=cage, grouping=sg, template_grouping=tg, **opts)
                record("sofa", "sofa_data", f"#{i}", method, res)

    summary: dict[str, dict] = {}
    for method in methods:
        b = [r for r in rows if r["method"] == method and r["kind"] == "builtin" and r["gt_error"]]
        sg = [r for r in rows if r["method"] == method and r["kind"] == "sofa" and r["gt_error"]]
        thin = [r for r in b if r["model"] in THIN_WALLED]
        s = [r for r in rows if r["method"] == method and r["kind"] == "sofa"]
        summary[method] = {
            "builtin_pairs": len(b),
            "gt_mean": float(np.mean([r["gt_error"]["mean"] for r in b])) if b else None,
            "gt_p95_mean": float(np.mean([r["gt_error"]["p95"] for r in b])) if b else None,
            "gt_max": float(np.max([r["gt_error"]["max"] for r in b])) if b else None,
            "thin_flipped": float(np.mean([r["gt_error"]["flipped"] for r in thin])) if thin else None,
            "all_flipped": float(np.mean([r["gt_error"]["flipped"] for r in b])) if b else None,
            "builtin_seconds_median": float(np.median([r["seconds"] for r in b])) if b else None,
            "sofa_pairs": len(s),
            "sofa_residual_mean": float(np.mean([r["residual"] for r in s])) if s else None,
            "sofa_seconds_median": float(np.median([r["seconds"] for r in s])) if s else None,
            "sofa_gt_mean": float(np.mean([r["gt_error"]["mean"] for r in sg])) if sg else None,
            "sofa_gt_max": float(np.max([r["gt_error"]["max"] for r in sg])) if sg else None,
            "sofa_flipped": float(np.mean([r["gt_error"]["flipped"] for r in sg])) if sg else None,
            "per_model_gt_mean": {m: float(np.mean([r["gt_error"]["mean"] for r in b if r["model"] == m])) for m in sorted({r["model"] for r in b})},
        }
    if "cage" in summary and "nearest" in summary and summary["nearest"]["gt_mean"]:
        summary["cage_over_nearest"] = summary["cage"]["gt_mean"] / summary["nearest"]["gt_mean"]
    if "cage" in summary and "cpd" in summary and summary["cpd"]["gt_mean"]:
        summary["cage_over_cpd"] = summary["cage"]["gt_mean"] / summary["cpd"]["gt_mean"]
    out = {
        "benchmark": "correspond",
        "settings": {**vars(args), "cage": vars(cage), "torch": torch.__version__, "time": time.strftime("%Y-%m-%d %H:%M:%S")},
        "summary": summary,
        "pairs": rows,
    }
    text = json.dumps(out, indent=1, default=float)
    if args.out:
        Path(args.out).parent.mkdir(parents=True, exist_ok=True)
        Path(args.out).write_text(text)
    print(json.dumps(summary, indent=1, default=float))
    return 0


if __name__ == "__main__":
    sys.exit(main())
