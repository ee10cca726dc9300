"""Benchmark: a family's networks trained again in process, one after the other or side by side.

Copies a built family without its networks, plans the train stage and runs it with WORKERS
processes (:func:`proctex.build.plan.run_in_process`; 1: one after the other on every thread),
printing the groups, the wall time and each group's held-out error (the same either way).

    .venv/bin/python tests/bench/bench_train_pool.py out/bench/looks/family out/bench/train_w2 2
"""
import sys, time, shutil
from pathlib import Path
from dataclasses import replace

def main():
    from proctex.store.layout import FamilyStore
    from proctex.store.state import FamilyState
    from proctex.build.train import plan_train
    from proctex.build.plan import run_in_process
    src, work, workers = sys.argv[1], Path(sys.argv[2]), int(sys.argv[3])
    shutil.rmtree(work, ignore_errors=True)
    shutil.copytree(src, work, ignore=shutil.ignore_patterns("models", "looks", "metrics.json", "train_runs"))
    st = FamilyStore(work)
    state = FamilyState.load(st)
    for s in ("train", "evaluate"):
        state.stages.pop(s, None)
    state.save(st)
    cfg = state.build_config()
    plan = plan_train(st, cfg, log=lambda *_: None)
    t = time.perf_counter()
    run_in_process(plan, st, cfg, log=lambda *_: None, workers=workers)
    rec = FamilyState.load(st).stage("train")["groups"]
    print(f"workers {workers}: {plan.n_jobs} groups in {time.perf_counter() - t:.1f} s;", {g: round(r['best_val'].get('mean', 0), 5) for g, r in rec.items()})

if __name__ == "__main__":
    main()
