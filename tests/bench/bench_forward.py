"""ProcCorrNet forward pass (``predict``): the global feature from the context samples, then the
decoder at the query points (a part's vertices at run time). Untrained weights cost the same.

    .venv/bin/python tests/bench/bench_forward.py [--queries 2000,20000] [--out out/bench/forward.json]
"""

from __future__ import annotations

import argparse
import sys

import numpy as np
import torch

import harness
from harness import report, timeit
from proctex.correspond.corrnet import CorrNetConfig, build_model, predict


def run(args) -> dict:
    torch.set_num_threads(args.threads)
    torch.manual_seed(0)
    cfg = CorrNetConfig(context_points=args.context)
    model = build_model(cfg).eval()
    rng = np.random.default_rng(0)
    ctx = rng.uniform(-1, 1, (args.context, 3))
    results = {}
    for q in (int(x) for x in args.queries.split(",")):
        query = rng.uniform(-1, 1, (q, 3))
        results[f"context {args.context}, {q} queries, {args.threads} thread(s)"] = timeit(lambda: predict(model, ctx, query), repeats=args.repeats)
    params = sum(p.numel() for p in model.parameters())
    return report("forward", vars(args), results, args.out, {"parameters": int(params)})


def parser() -> argparse.ArgumentParser:
    ap = harness.parser(__doc__, repeats=9)
    ap.add_argument("--context", type=int, default=512)
    ap.add_argument("--queries", default="2000,20000")
    ap.add_argument("--threads", type=int, default=1)
    return ap


if __name__ == "__main__":
    run(parser().parse_args())
    sys.exit(0)
