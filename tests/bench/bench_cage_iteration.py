"""One Adam iteration of the cage solver on a real part pair (a mug body onto the template's):
the whole solve at two iteration counts, and the per-iteration cost from their difference.

    .venv/bin/python tests/bench/bench_cage_iteration.py [--points 2000] [--out out/bench/cage_iteration.json]
"""

from __future__ import annotations

import argparse
import sys

import numpy as np
import torch

import harness
from harness import report, timeit
from proctex.correspond.cage import CageConfig
from proctex.correspond.dense import correspond_parts
from proctex.geometry.parts import part_mesh, segment
from proctex.geometry.surface import normalised_frame
from proctex.models import get_model


def run(args) -> dict:
    torch.set_num_threads(args.threads)
    src = get_model("mug").generate({"radius": 0.048, "height": 0.12})
    tpl = get_model("mug").generate()
    v, f = part_mesh(src, segment(src).parts[0])
    tv, tf = part_mesh(tpl, segment(tpl).parts[0])
    c, r = normalised_frame(tv)
    tvn = (tv - c) / r
    lo, hi = args.short, args.long
    results = {}
    for k in (lo, hi):
        cfg = CageConfig(level=args.level, iterations=k, patience=k + 1)  # no early stop: exactly k steps
        results[f"solve, {k} iterations"] = timeit(lambda: correspond_parts(v, f, tvn, tf, method="cage", n_points=args.points, seed=0, cage=cfg), repeats=args.repeats)
    a, b = results[f"solve, {lo} iterations"], results[f"solve, {hi} iterations"]
    per = {q: max(b[q] - a[q], 0.0) / (hi - lo) for q in ("median", "p10", "p90", "min", "max", "mean")}
    per["p10"], per["p90"] = sorted((per["p10"], per["p90"]))  # differences of percentiles need not stay ordered
    per["min"], per["max"] = sorted((per["min"], per["max"]))
    per.update(spread=float(np.hypot(a["spread"] * a["median"], b["spread"] * b["median"]) / (b["median"] - a["median"])) if b["median"] > a["median"] else 0.0, repeats=args.repeats)
    results["one iteration (difference / iterations)"] = per
    return report("cage_iteration", vars(args), results, args.out)


def parser() -> argparse.ArgumentParser:
    ap = harness.parser(__doc__, repeats=5)
    ap.add_argument("--points", type=int, default=2000)
    ap.add_argument("--level", type=int, default=1)
    ap.add_argument("--short", type=int, default=10)
    ap.add_argument("--long", type=int, default=60)
    ap.add_argument("--threads", type=int, default=1)
    return ap


if __name__ == "__main__":
    run(parser().parse_args())
    sys.exit(0)
