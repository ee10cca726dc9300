"""Benchmark: a family's group networks trained one by one or together in one batched loop.

Reads a built family's train pairs (:func:`proctex.build.groupdata.group_training_data`) and trains
every group for ``--iterations`` steps (no early stopping; the best evaluation kept) with the
family's network settings (``--seeds``: several network seeds, to see the spread):
``alone`` (:func:`proctex.correspond.training.train`, one group after another) and ``together``
(:func:`proctex.correspond.grouped.train_together`), each on ``--threads`` torch threads; prints
the wall time of each, the milliseconds per group step and each group's held-out error.

    .venv/bin/python tests/bench/bench_train_together.py out/bench/looks/family --iterations 100 --threads 1,2
"""

from __future__ import annotations

import argparse
import sys
import time


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("family", help="a built family (read only)")
    ap.add_argument("--iterations", type=int, default=100)
    ap.add_argument("--threads", default="1,2")
    ap.add_argument("--modes", default="alone,together")
    ap.add_argument("--autocast", choices=("none", "bfloat16", "auto"), help="default: the family's")
    ap.add_argument("--groups", help="comma-separated groups (default: every trainable group)")
    ap.add_argument("--seeds", default="", help="comma-separated network seeds (default: the family's)")
    args = ap.parse_args(argv)

    import dataclasses

    import torch

    from proctex.build.groupdata import VAL_SHARE, group_training_data, trainable_groups
    from proctex.correspond.grouped import train_together
    from proctex.correspond.training import train
    from proctex.store.layout import FamilyStore
    from proctex.store.state import FamilyState

    store = FamilyStore(args.family)
    config = FamilyState.load(store).build_config()
    base = dataclasses.replace(config.train, iterations=args.iterations, eval_every=min(config.train.eval_every, args.iterations), patience=0)
    if args.autocast:
        base.autocast = args.autocast
    groups = [int(g) for g in args.groups.split(",")] if args.groups else trainable_groups(store)
    data = [group_training_data(store, config, g, VAL_SHARE) for g in groups]
    seeds = [int(s) for s in args.seeds.split(",")] if args.seeds else [base.seed]
    for threads, seed, mode in ((int(t), s, m) for t in args.threads.split(",") for s in seeds for m in args.modes.split(",")):
        torch.set_num_threads(threads)
        cfg = dataclasses.replace(base, seed=seed)
        t = time.perf_counter()
        if mode == "alone":
            results = [train(d["train"], d["val"], cfg) for d in data]
        else:
            results = train_together([(d["train"], d["val"]) for d in data], cfg)
        wall = time.perf_counter() - t
        errors = [round(r.best_val.get("mean", float("nan")), 5) for r in results]
        print(
            f"{mode:8s} {threads} thread(s), seed {seed}, {cfg.autocast}: {len(groups)} groups x {args.iterations} steps in {wall:.1f} s "
            f"({wall / len(groups) / args.iterations * 1e3:.1f} ms per group step); held-out {errors}",
            flush=True,
        )
    return 0


if __name__ == "__main__":
    sys.exit(main())
