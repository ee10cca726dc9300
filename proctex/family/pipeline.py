"""The family build: the table of stage planners and the one loop that runs their plans.

Each stage is planned when its turn comes (a plan reads what the stages before it stored) and handed
to an *executor*: :func:`proctex.family.plan.run_in_process` here, or the Ray executor of
``workflows/build.py``, which fans the same plans out over a cluster. The planners live below this
module (:mod:`proctex.family.stages` for sample, template, paint, pairs and train;
:mod:`proctex.family.evaluate` for evaluate): the table is assembled here, at the top, so neither
imports the other's stages back.
"""

from __future__ import annotations

import time
from typing import Any, Callable, Mapping

from .config import BuildConfig
from .evaluate import stage_evaluate
from .plan import Plan, run_in_process, single_step
from .stages import STAGES, _state, plan_pairs, plan_sample, plan_train, stage_paint, stage_template, write_config
from .store import FamilyStore

Planner = Callable[[FamilyStore, BuildConfig, Callable[[str], None]], Plan]
Executor = Callable[[Plan, FamilyStore, BuildConfig, Callable[[str], None]], Plan]

#: Stage name -> ``planner(store, config, log) -> Plan``, in :data:`proctex.family.stages.STAGES` order.
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
    """Run the build ``stages`` in :data:`proctex.family.stages.STAGES` order: plan each (skipping what
    is complete) and run the plan with ``executor``. Returns the family state with ``wall_seconds``
    per stage run. ``ValueError`` for a stage name the table does not know, before any work."""
    unknown = set(stages) - set(PLANNERS)
    if unknown:
        raise ValueError(f"unknown stages: {', '.join(sorted(unknown))}; known: {', '.join(PLANNERS)}")
    write_config(store, config)
    walls: dict[str, float] = {}
    for stage in STAGES:
        if stage in stages:
            t = time.perf_counter()
            executor(PLANNERS[stage](store, config, log), store, config, log)
            walls[stage] = round(time.perf_counter() - t, 2)
    return {**_state(store), "wall_seconds": walls}
