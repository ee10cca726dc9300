"""Ray Train: one ProcCorrNet per part group, fitted data-parallel by Ray Train workers on CPUs (a
``TorchTrainer`` where a team of several workers averages gradients, else a plain data-parallel
trainer).

Every worker runs the same pure training loop as the single-process build
(:func:`proctex.correspond.training.train`) on the group's pairs from the store, drawing its own share of each
batch; a gradient hook averages the gradients across workers (gloo ``all_reduce``), so the workers
keep identical weights and stop together. A team's first rank writes its networks to the store
(``models/group_<g>.pt``) and puts them, with their records, in the run's checkpoint (under
``train_runs/`` in the store), where the driver reads the records. The workers form teams
(:func:`teams`); a team trains its groups with :func:`proctex.build.train.fit_groups` (in one
batched loop on a GPU, one after another on CPUs), so fewer workers than groups run side by side
and more workers than groups shorten every group's run instead of idling.
"""

from __future__ import annotations

import json
import os
import tempfile
import time
from typing import Any, Callable

from proctex.build.groupdata import trainable_groups
from proctex.build.train import fit_groups, serving_line
from proctex.store.config import BuildConfig
from proctex.store.layout import FamilyStore, StoreLayout


#: Ray Train's controller polling interval (its environment variable) and the value a fit uses unless set.
HEALTH_CHECK_ENV, HEALTH_CHECK_SECONDS = "RAY_TRAIN_HEALTH_CHECK_INTERVAL_S", "0.25"


def teams(world: int, groups: list[int]) -> list[tuple[list[int], list[int]]]:
    """Split ``world`` workers into ``min(world, len(groups))`` teams: ``[(ranks, groups)]``. Team
    ``t`` holds ranks ``r % T == t`` and groups ``i % T == t``; each team fits its groups
    (:func:`proctex.build.train.fit_groups`), data-parallel across its ranks. So with fewer workers than groups the groups run in
    parallel, and extra workers join a team instead of idling."""
    if world < 1:
        raise ValueError(f"need at least one worker, got {world}")
    T = max(1, min(world, len(groups)))
    return [([r for r in range(world) if r % T == t], [g for i, g in enumerate(groups) if i % T == t]) for t in range(T)]


def train_group_loop(loop_config: dict[str, Any]) -> dict[str, Any]:
    """``train_loop_per_worker`` of the trainer (runs inside each Ray Train worker): this worker's
    team (:func:`teams`) fits its groups, averaging gradients within the team."""
    import ray.train
    import torch
    from ray.train import Checkpoint

    torch.set_num_threads(int(loop_config.get("threads", 1)))
    ctx = ray.train.get_context()
    rank, world = ctx.get_world_rank(), ctx.get_world_size()
    store = FamilyStore(loop_config["store"])
    config = BuildConfig.from_dict(loop_config["config"])
    plan = teams(world, [int(g) for g in loop_config["groups"]])
    handles: list[Any] = [None] * len(plan)
    if shared_teams(plan):  # a TorchTrainer's process group: every rank creates every team's, in the same order
        import torch.distributed as dist

        handles = [dist.new_group(ranks) if len(ranks) > 1 else None for ranks, _ in plan]
    t = next(i for i, (ranks, _) in enumerate(plan) if rank in ranks)
    ranks, my_groups = plan[t]
    team_rank, team_size, pg = ranks.index(rank), len(ranks), handles[t]

    def average(model: torch.nn.Module) -> None:
        if team_size > 1:
            import torch.distributed as dist

            for p in model.parameters():
                if p.grad is not None:
                    dist.all_reduce(p.grad, group=pg)
                    p.grad /= team_size

    step = loop_config.get("step") or fit_groups  # the plan's team step: the in-process train body and records
    out = {}
    with tempfile.TemporaryDirectory() as tmp:
        if my_groups:  # the team's groups trained together in one loop; each record names the team size
            out = {str(g): r for g, r in zip(my_groups, step(store, config, my_groups, rank=team_rank, world=team_size, grad_hook=average))}
        has = team_rank == 0 and bool(my_groups)
        if has:  # the team leader's networks and their records form its share of the run's checkpoint
            for group in my_groups:
                with open(os.path.join(tmp, f"group_{group}.pt"), "wb") as fh:
                    fh.write(store.read_bytes(StoreLayout.model(group)))
            with open(os.path.join(tmp, f"records_rank{rank}.json"), "w") as fh:
                json.dump(out, fh, default=lambda x: x.item() if hasattr(x, "item") else str(x))  # NumPy scalars
        # One report per worker (a barrier); every worker's files land in one checkpoint.
        ray.train.report({"groups": sorted(out)}, checkpoint=Checkpoint.from_directory(tmp) if has else None)
    return out


def shared_teams(plan: list[tuple[list[int], list[int]]]) -> bool:
    """Whether a team of :func:`teams` has several ranks (which average gradients over
    ``torch.distributed``: a ``TorchTrainer``); teams of one need no process group."""
    return any(len(ranks) > 1 for ranks, _ in plan)


def checkpoint_records(checkpoint: Any) -> dict[str, Any]:
    """The group records the team leaders put in a fit's checkpoint (``records_rank<r>.json``):
    ``{group: record}``."""
    out: dict[str, Any] = {}
    if checkpoint is None:
        return out
    with checkpoint.as_directory() as folder:
        for name in sorted(os.listdir(folder)):
            if name.startswith("records_rank") and name.endswith(".json"):
                with open(os.path.join(folder, name)) as fh:
                    out.update(json.load(fh))
    return out


def _fit_with_progress(trainer: Any, store: FamilyStore, groups: list[int], quiet: bool = False, every: float = 2.0) -> Any:
    """``trainer.fit()`` with a progress line per finished network (the driver watches the store for
    ``models/group_<g>.pt``, which team leaders write as each group finishes)."""
    import threading

    from proctex.progress import Progress

    bar = Progress("train", len(groups), quiet=quiet, interval=0.0)
    stop = threading.Event()

    def watch() -> None:
        seen: set[int] = set()
        while not stop.wait(every):
            done = {g for g in groups if g not in seen and store.exists(StoreLayout.model(g))}
            if done:
                seen |= done
                bar.update(len(done))

    thread = threading.Thread(target=watch, name="train-progress", daemon=True)
    thread.start()
    try:
        return trainer.fit()
    finally:
        stop.set()
        thread.join()


def train_groups(
    store_uri: str,
    config: BuildConfig,
    num_workers: int = 2,
    cpus_per_worker: float = 1.0,
    groups: list[int] | None = None,
    log: Callable[[str], None] = print,
    quiet: bool = False,
    step: Callable[..., dict[str, Any]] | None = None,
) -> dict[int, dict[str, Any]]:
    """Fit the networks of every trainable group that has none yet with one ``TorchTrainer`` of
    ``num_workers`` CPU workers (Ray must be initialised); ``step``: what fits one group on a team
    (``Plan.team``; default :func:`proctex.build.train.fit_groups`). Returns ``{group: metrics}``."""
    from ray.train import RunConfig, ScalingConfig
    from ray.train.torch import TorchTrainer
    from ray.train.v2.api.data_parallel_trainer import DataParallelTrainer

    if num_workers < 1:
        raise ValueError(f"num_workers must be >= 1, got {num_workers}")
    store = FamilyStore(store_uri)
    todo = [g for g in (groups if groups is not None else trainable_groups(store)) if not store.exists(StoreLayout.model(g))]
    if not todo:
        return {}
    log(f"train: {len(todo)} group networks on {num_workers} Ray Train workers")
    storage = store.path("train_runs")
    store.fs.create_dir(storage, recursive=True)
    t0 = time.perf_counter()
    # Teams of one rank (no more workers than groups) share no gradients: no torch process group to
    # set up (a fit that trains nothing: 8.1 -> 5.4 s on 2 cores).
    trainer_class = TorchTrainer if shared_teams(teams(num_workers, todo)) else DataParallelTrainer
    trainer = trainer_class(
        train_group_loop,
        train_loop_config={"store": store_uri, "config": config.to_dict(), "groups": todo, "step": step or fit_groups},
        scaling_config=ScalingConfig(num_workers=num_workers, use_gpu=False, resources_per_worker={"CPU": cpus_per_worker}),
        # A fresh run name: Ray Train resumes silently from an existing run of the same name.
        run_config=RunConfig(name=f"corrnet_{time.strftime('%Y%m%d-%H%M%S')}_{os.getpid()}", storage_path=storage, storage_filesystem=store.fs),
    )
    # Ray Train's controller looks at its workers every 2 s by default, so a fit ended up to 2 s
    # after its last worker returned (4.5 s from the last loop to fit() returning on 2 cores; 0.6 s
    # at this interval). The driver's value travels to the controller (Ray propagates it).
    before = os.environ.get(HEALTH_CHECK_ENV)
    os.environ[HEALTH_CHECK_ENV] = before or HEALTH_CHECK_SECONDS
    try:
        result = _fit_with_progress(trainer, store, todo, quiet=quiet)
    finally:
        if before is None:
            os.environ.pop(HEALTH_CHECK_ENV, None)
    out = {int(g): m for g, m in checkpoint_records(result.checkpoint).items()}
    for g, m in out.items():
        log(
            f"train: group {g} on {m['workers']} of {num_workers} Ray Train workers: val {(m['best_val'] or {}).get('mean', float('nan')):.4f}, "
            f"{m['iterations']} iterations, "
            f"{m['seconds']:.1f}s; {serving_line(m.get('serving'))}"
        )
    log(f"train: {len(todo)} groups in {time.perf_counter() - t0:.1f}s")
    return out
