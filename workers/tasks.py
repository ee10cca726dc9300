"""Ray tasks of the preprocessing workflow: thin wrappers around the build's job functions.

A task takes a stage plan's batch function, the store URI, the build config (put in Ray's object
store once per plan, never rebuilt from a dict) and a batch of jobs, runs the same function the single-process build runs, and returns the job records. The
job functions write their outputs straight to the store (atomically, data before record) and skip
work that is already complete, so a task that Ray retries after its worker died redoes only the jobs
that had not finished. Application failures (a pair the solver cannot do) come back as "failed"
records, not exceptions; only system failures (a dead worker, a lost node) make Ray retry a task.
"""

from __future__ import annotations

from typing import Any, Callable

import ray

from proctex.store.config import BuildConfig
from proctex.store.layout import FamilyStore

#: Ray retries a task whose worker died this many times (a job's own errors are recorded instead).
MAX_RETRIES = 3


def _single_thread() -> None:
    """One torch / BLAS thread per task: Ray runs one task per CPU, more threads only contend."""
    import torch

    torch.set_num_threads(1)


@ray.remote(num_cpus=1, max_retries=MAX_RETRIES)
def run_batch(run: Callable[..., list[Any]], store_uri: str, config: BuildConfig, batch: list[Any]) -> list[Any]:
    """Run one batch of a stage plan (:class:`proctex.build.plan.Plan`): ``run`` is the plan's
    module-level batch function (e.g. :func:`proctex.build.pairs.run_pair_batch`), which loads what it
    needs itself (template assets once per worker process). Returns its results."""
    _single_thread()
    if not isinstance(config, BuildConfig):
        raise TypeError(f"run_batch takes a BuildConfig, got {type(config).__name__}")
    return run(FamilyStore(store_uri), config, batch, None)
