"""The family build on Ray: the same stages as ``proctex.pipeline.build``, fanned out over a cluster.

- ``sample``: batches of samples as Ray tasks (:func:`workers.tasks.sample_batch`);
- ``template`` and ``paint``: on the driver (one shape; seconds);
- ``pairs``: every (shape, group) cage pair as Ray tasks, one task per shape (its groups share the
  loaded mesh), at most ``max_in_flight`` tasks submitted at a time, each retried by Ray if its
  worker dies; records stream back, ``pairs.parquet`` is rewritten as they arrive, with progress;
- ``train``: one Ray Train ``TorchTrainer`` per group (:mod:`workers.train`);
- ``evaluate``: on the driver.

Every job writes straight to the store, atomically, data before record, and skips complete work,
so a rerun after a crash (of a worker or of the driver) does only what is missing or failed and ends
with the same artifacts as an uninterrupted run. Seeds depend on (family seed, sample, group) only.
"""

from __future__ import annotations

import os
import time
from typing import Any, Callable, Sequence

from proctex.family.config import BuildConfig
from proctex.family.stages import (
    STAGES,
    _mark,
    finish_pairs_stage,
    finish_sample_stage,
    load_assets,
    pair_complete,
    pair_jobs,
    pair_records,
    sample_jobs,
    stage_done,
    write_pairs_index,
)
from proctex.family.pipeline import STAGE_RUNNERS, build
from proctex.family.store import FamilyStore
from proctex.progress import Progress


def store_uri(root: str) -> str:
    """An absolute store URI (Ray workers do not share the driver's working directory)."""
    return root if "://" in root else os.path.abspath(root)


def init_ray(address: str | None = None, num_cpus: int | None = None) -> None:
    """Connect to ``address`` ("auto", "host:port", "ray://...") or start a private local Ray."""
    import ray

    if ray.is_initialized():
        return
    if address:
        ray.init(address=address, log_to_driver=False)
    else:
        ray.init(address="local", num_cpus=num_cpus, include_dashboard=False, log_to_driver=False)


def cluster_cpus() -> int:
    import ray

    return max(1, int(ray.cluster_resources().get("CPU", 1)))


def _fan_out(submit: Callable[[Any], Any], batches: Sequence[Any], max_in_flight: int, on_result: Callable[[Any, Any], None]) -> None:
    """Submit ``submit(batch)`` for every batch with at most ``max_in_flight`` pending; call
    ``on_result(batch, value)`` as each finishes (in completion order)."""
    import ray

    pending: dict[Any, Any] = {}
    queue = list(batches)
    while queue or pending:
        while queue and len(pending) < max_in_flight:
            batch = queue.pop(0)
            pending[submit(batch)] = batch
        done, _ = ray.wait(list(pending), num_returns=1)
        for ref in done:
            on_result(pending.pop(ref), ray.get(ref))


def ray_stage_sample(store: FamilyStore, config: BuildConfig, batch_size: int = 8, max_in_flight: int | None = None,
                     log: Callable[[str], None] = print, quiet: bool = False) -> None:
    from workers.tasks import job_dict, sample_batch

    if stage_done(store, "sample"):
        log("sample: done already")
        return
    jobs = sample_jobs(config)
    batches = [jobs[i : i + batch_size] for i in range(0, len(jobs), batch_size)]
    rows: dict[int, dict[str, Any]] = {}
    bar = Progress("sample", len(jobs), quiet=quiet)
    cfg = config.to_dict()

    def collect(batch, result):
        for job, row in zip(batch, result):
            rows[job.index] = row
        bar.update(len(batch))

    _fan_out(lambda b: sample_batch.remote(store.uri, cfg, [job_dict(j) for j in b]), batches, max_in_flight or 2 * cluster_cpus(), collect)
    finish_sample_stage(store, [rows[j.index] for j in jobs])
    log(f"sample: {len(jobs)} shapes")


def ray_stage_pairs(store: FamilyStore, config: BuildConfig, max_in_flight: int | None = None, log: Callable[[str], None] = print,
                    quiet: bool = False, index_every: float = 5.0) -> dict[str, Any]:
    """Cage pairs as Ray tasks (one per shape); returns ``{"solved", "pids", "seconds"}``."""
    from workers.tasks import job_dict, pair_batch

    assets = load_assets(store)
    jobs = pair_jobs(store, config, assets)
    records = pair_records(store, jobs)
    todo = [j for j in jobs if not pair_complete(records.get(j.key))]
    if not todo and stage_done(store, "pairs"):
        log("pairs: done already")
        return {"solved": 0, "pids": [], "seconds": 0.0}
    by_shape: dict[str, list] = {}
    for job in todo:
        by_shape.setdefault(job.row["id"], []).append(job)
    batches = list(by_shape.values())
    bar = Progress("pairs", len(todo), quiet=quiet)
    cfg = config.to_dict()
    pids: set[int] = set()
    last = [time.perf_counter()]
    t0 = time.perf_counter()

    def collect(batch, result):
        for rec in result["records"]:
            records[(rec["id"], rec["group"])] = rec
        pids.add(result["pid"])
        bar.update(len(batch))
        if time.perf_counter() - last[0] >= index_every:
            write_pairs_index(store, jobs, records)
            last[0] = time.perf_counter()

    _fan_out(lambda b: pair_batch.remote(store.uri, cfg, [job_dict(j) for j in b]), batches, max_in_flight or 2 * cluster_cpus(), collect)
    finish_pairs_stage(store, jobs, records, log)
    return {"solved": len(todo), "pids": sorted(pids), "seconds": time.perf_counter() - t0}


def ray_stage_train(store: FamilyStore, config: BuildConfig, num_workers: int | None = None, log: Callable[[str], None] = print,
                    quiet: bool = False) -> None:
    from workers.train import train_groups

    trained = train_groups(store.uri, config, num_workers=num_workers or min(2, cluster_cpus()), log=log, quiet=quiet)
    _mark(store, "train", groups={str(g): m for g, m in trained.items()}, ray=True)


def build_on_ray(
    root: str,
    config: BuildConfig,
    address: str | None = None,
    stages: Sequence[str] = STAGES,
    num_cpus: int | None = None,
    max_in_flight: int | None = None,
    train_workers: int | None = None,
    log: Callable[[str], None] = print,
    quiet: bool = False,
) -> dict[str, Any]:
    """Run the build stages on Ray (module docstring): :func:`proctex.pipeline.build`'s loop with the
    sample, pairs and train stages fanned out; returns the family state with per-stage wall times."""
    unknown = set(stages) - set(STAGES)
    if unknown:
        raise ValueError(f"unknown stages: {', '.join(sorted(unknown))}; known: {', '.join(STAGES)}")
    store = FamilyStore(store_uri(root))
    init_ray(address, num_cpus)
    log(f"ray: {cluster_cpus()} CPUs")
    runners = {
        **STAGE_RUNNERS,
        "sample": lambda st, cfg, log: ray_stage_sample(st, cfg, max_in_flight=max_in_flight, log=log, quiet=quiet),
        "pairs": lambda st, cfg, log: ray_stage_pairs(st, cfg, max_in_flight=max_in_flight, log=log, quiet=quiet),
        "train": lambda st, cfg, log: ray_stage_train(st, cfg, num_workers=train_workers, log=log, quiet=quiet),
    }
    return build(store, config, stages=tuple(stages), log=log, runners=runners)
