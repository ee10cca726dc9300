"""The family build: the table of stage planners and the one loop that runs their plans.

Each stage is planned when its turn comes (a plan reads what the stages before it stored; a stage in
steps plans the next on what the last stored, :func:`proctex.build.plan.run_steps`) and handed
to an *executor*: :func:`proctex.build.plan.run_in_process` here, or the Ray executor of
``workflows/build.py``, which fans the same plans out over a cluster. The planners are the stage
modules of :mod:`proctex.build` (one per stage); the table is assembled here, at the top, so no stage
imports another's back.
"""

from __future__ import annotations

import time
from typing import Any, Callable, Mapping

from proctex.build.evaluate import stage_evaluate
from proctex.build.paint import stage_paint
from proctex.build.pairs import plan_pairs
from proctex.build.plan import Plan, run_in_process, run_steps, single_step
from proctex.build.sample import plan_sample
from proctex.build.template import stage_template
from proctex.build.train import plan_train
from proctex.pools import shared_pool
from proctex.store.config import BuildConfig
from proctex.store.layout import FamilyStore
from proctex.store.locks import build_lock
from proctex.store.state import STAGES, FamilyState, write_config

Planner = Callable[[FamilyStore, BuildConfig, Callable[[str], None]], Plan]
Executor = Callable[[Plan, FamilyStore, BuildConfig, Callable[[str], None]], Plan]

#: Stage name -> ``planner(store, config, log) -> Plan``, in :data:`proctex.store.state.STAGES` order.
PLANNERS: Mapping[str, Planner] = {
    "sample": plan_sample,
    "template": lambda store, config, log: single_step("template", stage_template, store, config, log),
    "paint": lambda store, config, log: single_step("paint", stage_paint, store, config, log),
    "pairs": plan_pairs,
    "train": plan_train,
    "evaluate": lambda store, config, log: single_step("evaluate", stage_evaluate, store, config, log),
}


def build(store: FamilyStore, config: BuildConfig, stages: tuple[str, ...] | list[str] = STAGES, log: Callable[[str], None] = print,
          executor: Executor = run_in_process) -> dict[str, Any]:
    """Run the build ``stages`` in :data:`proctex.store.state.STAGES` order: plan each (skipping what
    is complete) and run the plan with ``executor``. Returns the family state with ``wall_seconds``
    per stage run. ``ValueError`` for a stage name the table does not know, before any work; the
    store's build lock is held throughout (:func:`proctex.store.locks.build_lock`: a second build
    or an edit of the same store is refused with who holds it)."""
    unknown = set(stages) - set(PLANNERS)
    if unknown:
        raise ValueError(f"unknown stages: {', '.join(sorted(unknown))}; known: {', '.join(PLANNERS)}")
    fresh = _fresh_folder(store)
    walls: dict[str, float] = {}
    try:
        # one build (and no edit) of a store at a time, the config checked under the lock; the stages'
        # worker processes started once a build (shared_pool: a worker's start is 3-4 s on 2 cores)
        with build_lock(store), shared_pool():
            write_config(store, config)
            for stage in STAGES:
                if stage in stages:
                    t = time.perf_counter()
                    run_steps(PLANNERS[stage](store, config, log), executor, store, config, log)  # a stage may run in steps
                    walls[stage] = round(time.perf_counter() - t, 2)
            return {**FamilyState.load(store).to_dict(), "wall_seconds": walls}
    except ValueError:
        if fresh is not None and not walls:  # refused before its first stage ended: --out as it was
            _remove_fresh(fresh)
        raise


def _fresh_folder(store: FamilyStore) -> tuple[str, bool] | None:
    """For a local store whose folder is missing or empty: ``(its path, whether it exists)``, so a
    build refused before its first stage ends leaves it as it was (:func:`_remove_fresh`); else None."""
    import os

    if not store.local:
        return None
    path = store.base
    if not os.path.exists(path):
        return path, False
    return (path, True) if os.path.isdir(path) and not os.listdir(path) else None


def _remove_fresh(fresh: tuple[str, bool]) -> None:
    """Put a folder :func:`_fresh_folder` saw back as it was: removed, or emptied."""
    import os
    import shutil

    path, existed = fresh
    if not existed:
        shutil.rmtree(path, ignore_errors=True)
        return
    for name in os.listdir(path):
        full = os.path.join(path, name)
        shutil.rmtree(full, ignore_errors=True) if os.path.isdir(full) and not os.path.islink(full) else os.remove(full)
