"""Benchmark: a family's networks trained again in process, one after the other or side by side.

Copies a built family without its networks, plans the train stage and runs it with ``--workers``
processes (:func:`proctex.build.plan.run_in_process`; 1: one after the other on every thread),
printing the groups, the wall time and each group's held-out error (the same either way).

    .venv/bin/python tests/bench/bench_train_pool.py out/bench/looks/family --workers 2 --work out/bench/train_w2
"""

from __future__ import annotations

import argparse
import sys
import time


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("family", help="a built family (copied, not changed)")
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--work", default="out/bench/train_pool")
    ap.add_argument("--autocast", choices=("none", "bfloat16", "auto"), help="the networks' training autocast (default: the family's)")
    args = ap.parse_args(argv)

    from harness import copy_family
    from proctex.build.plan import run_in_process
    from proctex.build.train import plan_train
    from proctex.store.state import FamilyState

    st, config = copy_family(args.family, args.work, ("models", "looks", "metrics.json", "train_runs"), ("train", "evaluate"))
    if args.autocast:
        config.train.autocast = args.autocast
    plan = plan_train(st, config, log=lambda *_: None)
    t = time.perf_counter()
    run_in_process(plan, st, config, log=lambda *_: None, workers=args.workers)
    groups = FamilyState.load(st).stage("train")["groups"]
    errors = {g: round(r["best_val"].get("mean", 0.0), 5) for g, r in groups.items()}
    print(f"{args.family}: {plan.n_jobs} groups with {args.workers} worker(s) in {time.perf_counter() - t:.1f} s; held-out mean error {errors}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
