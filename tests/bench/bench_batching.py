"""Benchmark: does batching ProcCorrNet forwards across requests pay on CPU?

Times one network's encode + decode for B parts (512 context points, 900 queries each) as one
batched call and as B single calls (one torch thread, median of repeats).

    .venv/bin/python tests/bench/bench_batching.py --family out/families/sofa
"""

from __future__ import annotations

import argparse
import json
import statistics
import time

import torch


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--family", help="a built family (its first network); default: an untrained one")
    ap.add_argument("--batches", default="1,2,4,8")
    ap.add_argument("--repeats", type=int, default=20)
    args = ap.parse_args(argv)
    torch.set_num_threads(1)
    if args.family:
        from proctex.store.layout import FamilyStore
        from proctex.store.networks import load_models

        model = next(iter(load_models(FamilyStore(args.family)).values()))
    else:
        from proctex.correspond.corrnet import CorrNetConfig, build_model

        model = build_model(CorrNetConfig()).eval()
    rows = []
    for B in (int(b) for b in args.batches.split(",")):
        ctx, q = torch.rand(B, 512, 3), torch.rand(B, 900, 3)
        batched, single = [], []
        with torch.inference_mode():
            for _ in range(3):
                model.decode(q, model.encode(ctx))
            for _ in range(args.repeats):
                t = time.perf_counter()
                model.decode(q, model.encode(ctx))
                batched.append(time.perf_counter() - t)
                t = time.perf_counter()
                for b in range(B):
                    model.decode(q[b : b + 1], model.encode(ctx[b : b + 1]))
                single.append(time.perf_counter() - t)
        rows.append({"B": B, "batched_ms": 1000 * statistics.median(batched), "single_ms": 1000 * statistics.median(single)})
        print(f"B={B}: batched {rows[-1]['batched_ms']:.1f} ms, one by one {rows[-1]['single_ms']:.1f} ms")
    print(json.dumps(rows))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
