"""Benchmark: a family's cage pairs solved again in process, one after the other or side by side.

Copies a built family without its pairs (and the stages after them), plans the pairs stage and runs
it (both steps where groups can settle) with ``--workers`` processes (:func:`proctex.build.plan.run_in_process`; 1: one after the other),
printing the pairs and the wall time; with ``--compare`` another copy's pairs are checked against
this run's (sources exactly, targets' largest difference printed).

    .venv/bin/python tests/bench/bench_pairs.py out/bench/looks/family --workers 2 --work out/bench/pairs_w2
    .venv/bin/python tests/bench/bench_pairs.py out/fidelity_real2/sofa --workers 1 --work out/bench/sofa_w1 --compare out/bench/sofa_w2
"""

from __future__ import annotations

import argparse
import sys
import time

import numpy as np


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("family", help="a built family (copied, not changed)")
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--work", default="out/bench/pairs")
    ap.add_argument("--compare", help="another run's copy to compare the pairs with")
    args = ap.parse_args(argv)

    from harness import copy_family
    from proctex.build.pairs import plan_pairs
    from proctex.build.plan import local_executor, run_steps
    from proctex.store.layout import FamilyStore
    from proctex.store.samples import read_pair

    st, config = copy_family(args.family, args.work, ("correspondences", "pairs.parquet", "looks", "models", "metrics.json"), ("pairs", "train", "evaluate"))
    t = time.perf_counter()
    plans = []

    def execute(plan, *rest):
        plans.append(plan)
        return local_executor(args.workers)(plan, *rest)

    run_steps(plan_pairs(st, config, log=lambda *_: None), execute, st, config, log=lambda *_: None)  # both steps
    solved = sum(p.n_jobs for p in plans)
    print(f"{args.family}: {solved} pairs with {args.workers} worker(s) in {time.perf_counter() - t:.1f} s", flush=True)
    if args.compare:
        other = FamilyStore(args.compare)
        rows = {(r["id"], r["group"]): r for r in st.read_table("pairs.parquet").to_pylist()}
        theirs = {(r["id"], r["group"]): r for r in other.read_table("pairs.parquet").to_pylist()}
        if set(rows) != set(theirs):
            print("the two runs solved different pairs")
            return 1
        worst, same = 0.0, True
        for key, row in rows.items():
            if row["status"] == "done" and theirs[key]["status"] == "done":
                (sa, da), (sb, db) = read_pair(st, *key), read_pair(other, *key)
                same &= bool(np.array_equal(sa, sb))
                worst = max(worst, float(np.abs(da - db).max()))
        print(f"sources {'identical' if same else 'DIFFER'}; targets differ by at most {worst:.3g}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
