"""The family build: the registry of stages and the one loop that runs their plans.

Each stage is registered once (:data:`STAGES_TABLE`, a :class:`Stage`): its planner, where its
batches may run (:class:`~proctex.build.plan.Placement`: here, as tasks, or by a team) and the store
files it reads and writes. A stage is planned when its turn comes (a plan reads what the stages
before it stored; a stage in steps plans the next on what the last stored,
:func:`proctex.build.plan.run_steps`) and handed to an *executor*: :func:`proctex.build.plan.run_in_process`
here, or the Ray executor of ``workflows/build.py``, which fans the same plans out over a cluster by
their placement. A stage's plan returns its record when the stage is complete; this module alone
writes stage records into ``family.json`` (:func:`run_stage`). The planners are the stage modules of
:mod:`proctex.build` (one per stage, sharing helpers through lower modules: ``plan``,
``groupdata``); the table is assembled here, at the top, so no stage imports another.
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from typing import Any, Callable, Mapping

from proctex.build.evaluate import evaluate_step
from proctex.build.paint import paint_step
from proctex.build.pairs import plan_pairs
from proctex.build.plan import Placement, Plan, run_in_process, run_steps, single_step
from proctex.build.sample import plan_sample
from proctex.build.template import template_step
from proctex.build.train import plan_train
from proctex.pools import shared_pool
from proctex.store.config import BuildConfig
from proctex.store.layout import FamilyStore, StoreLayout
from proctex.store.locks import build_lock
from proctex.store.state import STAGES, FamilyState, held_state, mark_stage, write_config

Planner = Callable[..., Plan]
Executor = Callable[[Plan, FamilyStore, BuildConfig, Callable[[str], None]], Plan]


@dataclass(frozen=True)
class Stage:
    """One build stage as registered.

    Attributes:
        name: its name (:data:`proctex.store.state.STAGES`, in build order).
        plan: ``plan(store, config, log, **args) -> Plan``.
        placement: where its batches may run; the pipeline gives its plans this placement, and an
            executor decides by it alone.
        reads: the store files it reads (paths of :class:`~proctex.store.layout.StoreLayout`, ``*``
            for any name), besides ``family.json``.
        writes: the store files it writes (the same patterns); ``family.json``'s stage record is
            the pipeline's.
    """

    name: str
    plan: Planner
    placement: Placement
    reads: tuple[str, ...]
    writes: tuple[str, ...]


_L = StoreLayout
_SAMPLES = (_L.SAMPLES, _L.mesh("*"), _L.sample_record("*"))
_TEMPLATE = (_L.TEMPLATE_MESH, _L.TEMPLATE_SHAPE)
_PAINTED = (f"{_L.TEMPLATE}/*",)
_PAIRS = (_L.PAIRS, _L.pair("*", "*"), _L.pair_vertices("*", "*"), _L.pair_record("*", "*"))

#: The stages, in :data:`proctex.store.state.STAGES` order.
STAGES_TABLE: Mapping[str, Stage] = {
    s.name: s
    for s in (
        Stage("sample", plan_sample, Placement.TASKS, reads=(), writes=_SAMPLES),
        Stage("template", lambda store, config, log: single_step("template", template_step, store, config, log), Placement.HERE, reads=_SAMPLES, writes=_TEMPLATE),
        Stage("paint", lambda store, config, log: single_step("paint", paint_step, store, config, log), Placement.HERE, reads=_TEMPLATE, writes=_PAINTED),
        Stage("pairs", plan_pairs, Placement.TASKS, reads=_SAMPLES + _PAINTED, writes=_PAIRS),
        Stage("train", plan_train, Placement.TEAM, reads=_SAMPLES + _PAIRS, writes=(_L.model("*"),)),
        Stage(
            "evaluate",
            lambda store, config, log: single_step("evaluate", evaluate_step, store, config, log),
            Placement.HERE,
            reads=_SAMPLES + _PAINTED + _PAIRS + (_L.model("*"),),
            writes=(_L.METRICS,),
        ),
    )
}


def run_stage(store: FamilyStore, config: BuildConfig, stage: str, log: Callable[[str], None] = print, executor: Executor = run_in_process, **args: Any) -> Plan:
    """Plan stage ``stage`` (``args``: its planner's own, e.g. the pairs' ``splits``), run its plans
    with ``executor`` at the stage's placement, and record the stage in ``family.json`` when its last
    plan returned a record (the one writer of stage records). Returns the last plan run."""
    entry = STAGES_TABLE[stage]

    def placed(plan: Plan, *rest: Any) -> Plan:
        plan.placement = entry.placement
        return executor(plan, *rest)

    plan = run_steps(entry.plan(store, config, log, **args), placed, store, config, log)  # a stage may run in steps
    if plan.record is not None:
        mark_stage(store, stage, **plan.record)
    return plan


def stage_sample(store: FamilyStore, config: BuildConfig, log: Callable[[str], None] = print) -> Plan:
    """The sample stage here (:func:`run_stage`): shapes into ``meshes/`` and ``samples.parquet``."""
    return run_stage(store, config, "sample", log)


def stage_template(store: FamilyStore, config: BuildConfig, log: Callable[[str], None] = print) -> Plan:
    """The template stage here (:func:`run_stage`)."""
    return run_stage(store, config, "template", log)


def stage_paint(store: FamilyStore, config: BuildConfig, log: Callable[[str], None] = print) -> Plan:
    """The paint stage here (:func:`run_stage`): parts, groups, UVs and textures into ``template/``."""
    return run_stage(store, config, "paint", log)


def stage_pairs(store: FamilyStore, config: BuildConfig, log: Callable[[str], None] = print, splits: tuple[str, ...] = ("train", "test")) -> Plan:
    """The pairs stage here, in its steps (:func:`run_stage`); ``splits``: the samples it pairs."""
    return run_stage(store, config, "pairs", log, splits=splits)


def stage_train(store: FamilyStore, config: BuildConfig, log: Callable[[str], None] = print) -> Plan:
    """The train stage here (:func:`run_stage`): one ProcCorrNet per group that needs one."""
    return run_stage(store, config, "train", log)


def stage_evaluate(store: FamilyStore, config: BuildConfig, log: Callable[[str], None] = print) -> Plan:
    """The evaluate stage here (:func:`run_stage`): ``metrics.json``."""
    return run_stage(store, config, "evaluate", log)


def build(store: FamilyStore, config: BuildConfig, stages: tuple[str, ...] | list[str] = STAGES, log: Callable[[str], None] = print, executor: Executor = run_in_process) -> dict[str, Any]:
    """Run the build ``stages`` in :data:`proctex.store.state.STAGES` order: plan each (skipping what
    is complete) and run the plan with ``executor``. Returns the family state with ``wall_seconds``
    per stage run. ``ValueError`` for a stage name the table does not know, before any work; the
    store's build lock is held throughout (:func:`proctex.store.locks.build_lock`: a second build
    or an edit of the same store is refused with who holds it)."""
    unknown = set(stages) - set(STAGES_TABLE)
    if unknown:
        raise ValueError(f"unknown stages: {', '.join(sorted(unknown))}; known: {', '.join(STAGES_TABLE)}")
    fresh = _fresh_folder(store)
    walls: dict[str, float] = {}
    try:
        # one build (and no edit) of a store at a time, the config checked under the lock; the stages'
        # worker processes started once a build (shared_pool: a worker's start is 3-4 s on 2 cores)
        # family.json read once (held_state): under the exclusive lock this build is its only writer
        with build_lock(store), shared_pool(), held_state(store):
            write_config(store, config)
            return _run_stages(store, config, stages, log, executor, walls)
    except ValueError:
        if fresh is not None and not walls:  # refused before its first stage ended: --out as it was
            _remove_fresh(fresh)
        raise


def _run_stages(store: FamilyStore, config: BuildConfig, stages, log: Callable[[str], None], executor: Executor, walls: dict[str, float]) -> dict[str, Any]:
    for stage in STAGES:
        if stage in stages:
            t = time.perf_counter()
            run_stage(store, config, stage, log, executor)
            walls[stage] = round(time.perf_counter() - t, 2)
    return {**FamilyState.load(store).to_dict(), "wall_seconds": walls}


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
