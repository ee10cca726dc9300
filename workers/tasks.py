"""Ray tasks of the preprocessing workflow: thin wrappers around the build's job functions.

Each task takes the store URI, the build config (a dict) and a batch of jobs, runs the same
``proctex.family`` job function the single-process build runs, and returns the job records. The
job functions write their outputs straight to the store (atomically, data before record) and skip
work that is already complete, so a task that Ray retries after its worker died redoes only the jobs
that had not finished. Application failures (a pair the solver cannot do) come back as "failed"
records, not exceptions; only system failures (a dead worker, a lost node) make Ray retry a task.
"""

from __future__ import annotations

import os
from dataclasses import asdict
from typing import Any

import ray

from proctex.family.config import BuildConfig
from proctex.family.stages import PairJob, SampleJob, load_assets, run_pair_job, run_sample_job
from proctex.family.store import FamilyStore, StoreLayout

#: Ray retries a task whose worker died this many times (a job's own errors are recorded instead).
MAX_RETRIES = 3

# Template assets per (store, template stamp), kept by the worker process between tasks.
_ASSETS: dict[tuple[str, str], Any] = {}


def _single_thread() -> None:
    """One torch / BLAS thread per task: Ray runs one task per CPU, more threads only contend."""
    import torch

    torch.set_num_threads(1)


def _assets(store: FamilyStore) -> Any:
    stamp = str(store.read_json(StoreLayout.STATE).get("stages", {}).get("paint", {}).get("finished", ""))
    key = (store.uri, stamp)
    if key not in _ASSETS:
        _ASSETS.clear()
        _ASSETS[key] = load_assets(store)
    return _ASSETS[key]


@ray.remote(num_cpus=1, max_retries=MAX_RETRIES)
def sample_batch(store_uri: str, config: dict[str, Any], jobs: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """Make and store a batch of samples; returns their ``samples.parquet`` rows."""
    _single_thread()
    store, cfg = FamilyStore(store_uri), BuildConfig.from_dict(config)
    return [run_sample_job(store, cfg, SampleJob(**job)) for job in jobs]


@ray.remote(num_cpus=1, max_retries=MAX_RETRIES)
def pair_batch(store_uri: str, config: dict[str, Any], jobs: list[dict[str, Any]]) -> dict[str, Any]:
    """Solve and store a batch of cage pairs (all of one shape, which is loaded once).

    Returns ``{"records": [...], "pid": worker process id}``.
    """
    from proctex.family.stages import load_sample

    _single_thread()
    store, cfg = FamilyStore(store_uri), BuildConfig.from_dict(config)
    assets = _assets(store)
    records, shape, shape_id = [], None, None
    for job in (PairJob(**j) for j in jobs):
        if shape_id != job.row["id"]:
            shape, shape_id = None, job.row["id"]
            try:
                shape = load_sample(store, job.row, cfg)
            except (ValueError, RuntimeError):
                shape = None  # run_pair_job loads it again and records the failure
        records.append(run_pair_job(store, cfg, assets, job, shape))
    return {"records": records, "pid": os.getpid()}


def job_dict(job: SampleJob | PairJob) -> dict[str, Any]:
    """A job as plain data for a task argument."""
    return asdict(job)
