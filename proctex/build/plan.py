"""A build stage as a plan of work, and the in-process executor.

Every stage of the build (one module each in :mod:`proctex.build`) is a
:class:`Plan`: its jobs in batches (a batch shares its loading: one shape's pairs, eight samples,
one group's network), the module-level function that runs one batch anywhere (this process or a Ray
worker), what to do with each batch's results as they arrive, and how to finish the stage. An
*executor* decides where batches run: :func:`run_in_process` here, runs them one after the other;
``workflows/build.py`` fans them out as Ray tasks (and the train stage's as Ray Train jobs). Both run
the same plans, so both builds write the same artifacts.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from enum import Enum
from typing import Any, Callable

from proctex.pools import process_pool


class Placement(str, Enum):
    """Where a stage's batches may run (each stage declares its own, :mod:`proctex.build.pipeline`).

    - ``HERE``: one step where the build runs (the template, the paint, the evaluation);
    - ``TASKS``: independent batches anywhere: one after another here, worker processes of one
      thread, or Ray tasks on a cluster (samples, cage pairs);
    - ``TEAM``: jobs a data-parallel team may fit together: worker processes here, a Ray Train job
      on a cluster (the groups' networks, :attr:`Plan.team`).
    """

    HERE = "here"
    TASKS = "tasks"
    TEAM = "team"


@dataclass
class Plan:
    """One stage's work.

    Attributes:
        stage: the stage name.
        batches: the jobs to run, in batches; empty when nothing is left to do (``skip`` says why
            when the stage is complete).
        run_batch: ``run_batch(store, config, batch, context) -> list`` of one result per job; a
            module-level function, so a Ray worker can run it (with ``context`` None: it loads what
            it needs itself).
        collect: ``collect(batch, results)`` as each batch finishes (progress, partial indexes).
        finish: ``finish(results)`` once, with every batch's results in batch order; returns the
            stage's record when the stage is complete (the pipeline writes it into ``family.json``:
            no stage marks itself done), else None. Every executor keeps it in :attr:`record`.
        context: what the in-process executor hands every batch (e.g. the loaded template assets).
        skip: "done already" when the stage is complete and nothing is to be run.
        placement: where its batches may run (:class:`Placement`): what an executor decides by.
        record: what ``finish`` returned (None: the stage is not complete, or nothing ran).
        team: for plans whose jobs can be run by a data-parallel team of workers (groups'
            networks): ``team(store, config, jobs, rank, world, grad_hook) -> [result per job]`` (a
            module-level function; ``grad_hook(model)`` averages the gradients across the team). An
            executor with teams (Ray Train, ``workflows/build.py``) gives each team a share of the
            jobs and hands ``finish`` the same results ``run_batch`` would give; the in-process
            executor runs ``run_batch``.
        parallel: its batches are independent and run better side by side than one after the other
            on more threads (a cage solve gains nothing from a second thread; a small network's
            training little): :func:`run_in_process` with ``workers`` > 1 runs them in worker
            processes of one thread each, once the plan has ``pool_min_jobs`` jobs (a pool costs
            a few seconds to start: worth it for a few trainings, not for a few short pairs).
        info: what the stage reports (e.g. pairs solved); ``info["then"]``, where set by the planner,
            plans the stage's next step once this plan has run (:func:`run_steps`).
        merge: its batches run better merged than one by one (the groups' networks, trained together
            in one batched loop): :func:`run_in_process` hands ``run_batch`` every batch at once, or
            with ``workers`` a share of them per worker (round robin), and splits the results back
            per batch for ``collect`` and ``finish``.
        threads: torch threads for the batches :func:`run_in_process` runs here rather than in its
            pool (None: as they are). One for the cage pairs: what a pool's worker and a Ray task use,
            so a pair's figures are the same bits wherever it was solved (a residual's mean moved by
            one ULP between 2 threads here and 1 on Ray).
    """

    stage: str
    batches: list[list[Any]]
    run_batch: Callable[..., list[Any]]
    finish: Callable[[list[list[Any]]], None]
    collect: Callable[[list[Any], list[Any]], None] | None = None
    context: Any = None
    skip: str | None = None
    placement: Placement = Placement.TASKS
    record: dict[str, Any] | None = None
    info: dict[str, Any] = field(default_factory=dict)
    team: Callable[..., Any] | None = None
    parallel: bool = False
    pool_min_jobs: int = 2
    merge: bool = False
    threads: int | None = None

    @property
    def n_jobs(self) -> int:
        return sum(len(b) for b in self.batches)


def run_in_process(plan: Plan, store: Any, config: Any, log: Callable[[str], None] = print, workers: int = 1, min_jobs: int | None = None) -> Plan:
    """Run ``plan`` here, batch after batch; returns it (``info`` filled by its ``finish``). With
    ``workers`` > 1, a ``parallel`` plan of at least ``min_jobs`` jobs (None: its own
    ``pool_min_jobs``) runs its batches side by side in that many worker processes (one torch
    thread each; each loads what it needs, as a Ray worker does), collected as they finish and
    handed to ``finish`` in batch order: the same artifacts as one after the other."""
    if plan.skip:
        log(f"{plan.stage}: {plan.skip}")
        return plan
    enough = plan.n_jobs >= (plan.pool_min_jobs if min_jobs is None else min_jobs)
    pooled = workers > 1 and plan.parallel and len(plan.batches) > 1 and enough
    units = merged_units(len(plan.batches), min(workers, len(plan.batches)) if pooled else 1) if plan.merge else [[k] for k in range(len(plan.batches))]
    if pooled:
        results = _run_pooled(plan, store, config, units, min(workers, len(units)))
    else:
        from proctex.pools import torch_threads

        results = [None] * len(plan.batches)
        with torch_threads(plan.threads):
            for unit in units:
                _collect_unit(plan, unit, plan.run_batch(store, config, [j for k in unit for j in plan.batches[k]], plan.context), results)
    plan.record = plan.finish(results)
    return plan


def run_steps(plan: Plan, executor: Callable[..., Plan], store: Any, config: Any, log: Callable[[str], None] = print) -> Plan:
    """Run ``plan`` with ``executor`` and then each next step it plans (``info["then"]``: a stage in
    steps, the next one planned on what the last stored); returns the last plan run."""
    plan = executor(plan, store, config, log)
    while plan.info.get("then"):
        plan = executor(plan.info.pop("then")(), store, config, log)
    return plan


def merged_units(n_batches: int, n_units: int) -> list[list[int]]:
    """Batch indices ``0..n_batches-1`` dealt round robin into ``n_units`` units (``Plan.merge``)."""
    n_units = max(1, min(n_units, n_batches))
    return [list(range(u, n_batches, n_units)) for u in range(n_units) if u < n_batches]


def _collect_unit(plan: Plan, unit: list[int], out: list[Any], results: list[Any]) -> None:
    """Split one unit's results (its batches' jobs, in order) back per batch, collecting each."""
    i = 0
    for k in unit:
        n = len(plan.batches[k])
        results[k] = list(out[i : i + n])
        i += n
        if plan.collect is not None:
            plan.collect(plan.batches[k], results[k])


#: The most worker processes a default (0) ``--workers`` gives: one per CPU up to this.
MAX_DEFAULT_WORKERS = 4


def default_workers() -> int:
    """Worker processes when none are asked for: one per CPU, at most :data:`MAX_DEFAULT_WORKERS`."""
    import os

    return max(1, min(MAX_DEFAULT_WORKERS, os.cpu_count() or 1))


def local_executor(workers: int, min_jobs: int | None = None) -> Callable[..., Plan]:
    """The in-process executor with ``workers`` processes for parallel plans of at least
    ``min_jobs`` jobs (None: each plan's ``pool_min_jobs``; :func:`run_in_process`)."""
    if isinstance(workers, bool) or not isinstance(workers, int) or not 1 <= workers <= 256:
        raise ValueError(f"workers must be an integer in 1..256, got {workers!r}")

    def run(plan: Plan, store: Any, config: Any, log: Callable[[str], None] = print) -> Plan:
        return run_in_process(plan, store, config, log, workers=workers, min_jobs=min_jobs)

    return run


def _pooled_batch(uri: str, config: Any, run_batch: Callable[..., list[Any]], batch: list[Any]) -> list[Any]:
    from proctex.store.layout import FamilyStore

    return run_batch(FamilyStore(uri), config, batch, None)


def _run_pooled(plan: Plan, store: Any, config: Any, units: list[list[int]], workers: int) -> list[list[Any]]:
    from concurrent.futures import as_completed

    results: list[Any] = [None] * len(plan.batches)
    with process_pool(workers) as pool:
        futures = {pool.submit(_pooled_batch, store.uri, config, plan.run_batch, [j for k in unit for j in plan.batches[k]]): unit for unit in units}
        for future in as_completed(futures):
            _collect_unit(plan, futures[future], future.result(), results)
    return results


def single_step(stage: str, step: Callable[[Any, Any, Callable[[str], None]], dict[str, Any] | None], store: Any, config: Any, log: Callable[[str], None]) -> Plan:
    """A one-step stage as a plan placed :attr:`Placement.HERE`: ``step(store, config, log)`` runs
    where the build runs and returns the stage's record (None: done already, nothing to record)."""
    return Plan(stage, [[None]], lambda st, cfg, batch, context: [step(st, cfg, log)], finish=lambda results: results[0][0], placement=Placement.HERE)
