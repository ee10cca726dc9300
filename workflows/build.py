"""The family build on Ray: the same stage plans as ``proctex.build.pipeline.build`` runs in process,
run by a Ray executor (:func:`ray_executor`) that fans them out over a cluster.

- ``sample``: batches of samples as Ray tasks (:func:`workers.tasks.run_batch`);
- ``template`` and ``paint``: on the driver (one shape; seconds);
- ``pairs``: every (shape, group) cage pair as Ray tasks, one task per shape (its groups share the
  loaded mesh), at most ``max_in_flight`` tasks submitted at a time, each retried by Ray if its
  worker dies; records stream back, ``pairs.parquet`` is rewritten as they arrive, with progress;
- ``train``: groups whose box map or identity already fits settled on the driver, the others in
  one Ray Train job (:mod:`workers.train`);
- ``evaluate``: on the driver (its shapes in worker processes).

Every job writes straight to the store, atomically, data before record, and skips complete work,
so a rerun after a crash (of a worker or of the driver) does only what is missing or failed and ends
with the same artifacts as an uninterrupted run. Seeds depend on (family seed, sample, group) only.
"""

from __future__ import annotations

import os
from typing import Any, Callable, Sequence

from proctex.build.pipeline import build
from proctex.build.plan import Placement, Plan, run_in_process
from proctex.progress import Progress
from proctex.store.config import BuildConfig
from proctex.store.layout import FamilyStore
from proctex.store.state import STAGES


def store_uri(root: str) -> str:
    """An absolute store URI (Ray workers do not share the driver's working directory)."""
    return root if "://" in root else os.path.abspath(root)


def init_ray(address: str | None = None, num_cpus: int | None = None) -> None:
    """Connect to ``address`` ("auto", "host:port", "ray://...") and wait (bounded) until the cluster
    has CPUs (:func:`workflows.jobs.wait_for_cpus`), or start a private local Ray
    (:func:`start_private_ray`)."""
    import ray

    if ray.is_initialized():
        return
    if address:
        ray.init(address=address, log_to_driver=False)
        from .jobs import wait_for_cpus

        wait_for_cpus()  # a head without CPUs whose worker nodes are still joining (bounded: PROCTEX_CLUSTER_WAIT)
    else:
        start_private_ray(num_cpus=num_cpus)


#: Ray's own message when a starting node's raylet did not register within its fixed 30 s
#: (``ray/_private/node.py``; not configurable).
NODE_START_TIMEOUT = "timed out during startup"


def _descendants(pid: int) -> set[int]:
    """The PIDs of ``pid``'s descendant processes (Linux ``/proc``; empty elsewhere)."""
    children: dict[int, list[int]] = {}
    try:
        entries = os.listdir("/proc")
    except OSError:
        return set()
    for name in entries:
        if name.isdigit():
            try:
                with open(f"/proc/{name}/stat", "rb") as fh:
                    ppid = int(fh.read().rsplit(b")", 1)[1].split()[1])
            except (OSError, ValueError, IndexError):
                continue
            children.setdefault(ppid, []).append(int(name))
    out, todo = set(), [pid]
    while todo:
        for child in children.get(todo.pop(), []):
            if child not in out:
                out.add(child)
                todo.append(child)
    return out


#: What makes a private Ray private (:func:`private_ray_env`): its node address stays loopback
#: (Ray 2.60 rewrites 127.0.0.1 to the machine's routable address unless this is "0"; every
#: listener that follows the node address then binds loopback), and token authentication is on.
LOOPBACK = {"RAY_ENABLE_WINDOWS_OR_OSX_CLUSTER": "0"}


def private_ray_env() -> dict[str, str]:
    """Set (in this process's environment, which Ray's processes inherit) what a private local Ray
    needs to be reachable from no other host and usable by no other user: the loopback node address
    (:data:`LOOPBACK`) and, unless the user chose a token mode, Ray's token authentication with a
    token of its own (64 hex characters in a file of mode 0600 in a private folder, not the shared
    ``~/.ray/auth_token``, which Ray writes 0644). Returns the variables set. The listener Ray
    binds to every interface whatever its options (a Serve replica's gRPC server, ``[::]:0``)
    refuses connections without the token."""
    import secrets
    import tempfile

    out = dict(LOOPBACK)
    if "RAY_AUTH_MODE" not in os.environ and "RAY_AUTH_TOKEN" not in os.environ and "RAY_AUTH_TOKEN_PATH" not in os.environ:
        import atexit
        import shutil

        folder = tempfile.mkdtemp(prefix="proctex-ray-auth-")  # 0700
        atexit.register(shutil.rmtree, folder, True)  # this process's private Ray ends with it
        path = os.path.join(folder, "auth_token")
        fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o600)
        with os.fdopen(fd, "w") as fh:
            fh.write(secrets.token_hex(32) + "\n")
        out.update(RAY_AUTH_MODE="token", RAY_AUTH_TOKEN_PATH=path)
    for key, value in out.items():
        os.environ.setdefault(key, value)
    # Ray reads the mode and the token once per process (when it is imported): as ray.init does when
    # it turns token authentication on itself, refresh them (Ray's own internals; no public call)
    try:
        from ray._private import ray_constants
        from ray._raylet import AuthenticationTokenLoader, Config

        Config.initialize("")
        AuthenticationTokenLoader.instance().reset_cache()
        ray_constants.ENABLE_RAY_CLUSTER = os.environ["RAY_ENABLE_WINDOWS_OR_OSX_CLUSTER"] not in ("0", "false", "False")
    except (ImportError, AttributeError):  # another Ray: what it reads at ray.init is what is set
        pass
    return out


def start_private_ray(num_cpus: int | None = None, tries: int | None = None, log: Callable[[str], None] | None = None, system_config: dict[str, Any] | None = None) -> None:
    """``ray.init`` of a private local Ray (no dashboard, workers' output not copied here; loopback
    only, behind a token of its own: :func:`private_ray_env`), started
    again when its node did not come up within Ray's fixed 30 s (:data:`NODE_START_TIMEOUT`: a
    machine whose cores are busy with other work), at most ``tries`` times (default
    ``PROCTEX_RAY_START_TRIES`` or 3), saying so through ``log`` (default: stderr). The processes a
    failed start left (its GCS server, raylet, agents: this process's new descendants) are
    stopped first. Any other failure, or the last try's, is raised as Ray raised it.
    ``system_config``: Ray's system settings for this Ray (``ray.init``'s ``_system_config``)."""
    import signal
    import sys

    import ray

    if tries is None:
        raw = os.environ.get("PROCTEX_RAY_START_TRIES", "3")
        try:
            tries = int(raw)
        except ValueError:
            raise ValueError(f"PROCTEX_RAY_START_TRIES must be a whole number of tries, got {raw!r}") from None
    if not 1 <= tries <= 20:
        raise ValueError(f"the private Ray's start tries must be 1-20, got {tries}")
    say = log or (lambda line: print(line, file=sys.stderr, flush=True))
    private_ray_env()
    for attempt in range(1, tries + 1):
        before = _descendants(os.getpid())
        try:
            ray.init(address="local", num_cpus=num_cpus, include_dashboard=False, log_to_driver=False, _system_config=dict(system_config) if system_config else None)
            return
        except Exception as exc:  # Ray raises a bare Exception for this one
            if NODE_START_TIMEOUT not in str(exc) or attempt == tries:
                raise
            for pid in _descendants(os.getpid()) - before:
                try:
                    os.kill(pid, signal.SIGKILL)
                except OSError:
                    pass
            try:
                ray.shutdown()
            except Exception:  # nothing was connected: there is nothing to shut down
                pass
            say(f"Ray's node did not start within Ray's fixed 30 s (a busy machine); starting it again (try {attempt + 1} of {tries})")


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


def ray_executor(max_in_flight: int | None = None, train_workers: int | None = None, quiet: bool = False):
    """An executor for :func:`proctex.build.pipeline.build` that runs a plan by its placement
    (:class:`proctex.build.plan.Placement`, the stage table's): ``TASKS`` batches as Ray tasks
    (:func:`workers.tasks.run_batch`; at most ``max_in_flight`` submitted at a time, default 2 x
    CPUs), a ``TEAM`` plan's jobs (the train plan's groups, each by ``Plan.team``) as Ray Train
    jobs through :func:`run_teams` (``train_workers`` workers, default min(2, CPUs)), and ``HERE``
    plans here on the driver."""

    def execute(plan: Plan, store: FamilyStore, config: BuildConfig, log: Callable[[str], None]) -> Plan:
        if plan.skip or plan.placement is Placement.HERE or not plan.batches:
            return run_in_process(plan, store, config, log)
        if plan.placement is Placement.TEAM:
            return run_teams(plan, store, config, log, train_workers or min(2, cluster_cpus()), quiet)
        import ray

        from workers.tasks import run_batch

        bar = Progress(plan.stage, plan.n_jobs, quiet=quiet)
        cfg = ray.put(config)  # the config once in the object store: every task gets it as it is, never rebuilt
        results: dict[int, list[Any]] = {}

        def collect(i: int, out: list[Any]) -> None:
            if plan.collect is not None:
                plan.collect(plan.batches[i], out)
            bar.update(len(plan.batches[i]))
            results[i] = out

        _fan_out(lambda i: run_batch.remote(plan.run_batch, store.uri, cfg, plan.batches[i]), list(range(len(plan.batches))), max_in_flight or 2 * cluster_cpus(), collect)
        plan.record = plan.finish([results[i] for i in range(len(plan.batches))])
        return plan

    return execute


def run_teams(plan: Plan, store: FamilyStore, config: BuildConfig, log: Callable[[str], None], workers: int, quiet: bool = False) -> Plan:
    """The executor's hook for a plan with a team step: its jobs (each a group) fitted by one Ray Train
    ``TorchTrainer`` of ``workers`` workers (:func:`workers.train.train_groups`, each job by
    ``plan.team``), the results handed to ``plan.finish`` in batch order, as the in-process executor
    would; the stage's record notes Ray."""
    from workers.train import train_groups

    jobs = [job for batch in plan.batches for job in batch]
    out = train_groups(store.uri, config, num_workers=workers, groups=jobs, log=log, quiet=quiet, step=plan.team)
    plan.info["mark"] = {"ray": True}
    plan.record = plan.finish([[out.get(job) for job in batch] for batch in plan.batches])
    return plan


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
    """Run the build stages on Ray (module docstring): :func:`proctex.build.pipeline.build`'s loop with the
    sample, pairs and train stages fanned out; returns the family state with per-stage wall times."""
    unknown = set(stages) - set(STAGES)
    if unknown:
        raise ValueError(f"unknown stages: {', '.join(sorted(unknown))}; known: {', '.join(STAGES)}")
    store = FamilyStore(store_uri(root))
    init_ray(address, num_cpus)
    log(f"ray: {cluster_cpus()} CPUs")
    executor = ray_executor(max_in_flight=max_in_flight, train_workers=train_workers, quiet=quiet)
    return build(store, config, stages=tuple(stages), log=log, executor=executor)
