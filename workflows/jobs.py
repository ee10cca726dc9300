"""Submitting to a Ray cluster that may still be starting (issue 49).

A head node answers its Jobs API before its job agent is up: a submission then gets
``500 No available agent to submit job`` (Ray's head waits 10 s for the agent, a busy machine takes
longer), and a driver that connects right after ``ray start`` may see a head whose worker nodes have
not registered their CPUs yet (a KubeRay head has none of its own). Everything here waits for that,
for a bounded time (``PROCTEX_CLUSTER_WAIT`` seconds, default 180), saying on stderr what it waits
for, and then fails with an error that says what did not come:

- :func:`submit_job`: a Jobs API submission, retried while the dashboard does not answer or the head
  has no job agent yet; other refusals (a bad runtime environment, a taken submission id) at once;
- :func:`wait_for_jobs`: a cluster that runs a job: a no-op job (``true``, submission id
  ``proctex-ready-...``, metadata ``{"proctex": "readiness check"}``) submitted and run to its end
  (``cluster/local_cluster.sh start`` returns only after it; ``python -m workflows.jobs wait URL``).
  It stays in the cluster's job list: deleting a job right after it ends races with its supervisor,
  which then records it again as failed;
- :func:`wait_for_cpus`: a connected driver waits until the cluster has CPUs (``build --ray ADDRESS``,
  ``generate --address``).
"""

from __future__ import annotations

import os
import sys
import time
import uuid
from typing import Any, Callable

#: Default bound on every wait here, in seconds (``PROCTEX_CLUSTER_WAIT`` overrides it).
DEFAULT_WAIT_S = 180.0


def cluster_wait_s(value: float | None = None) -> float:
    """The bound on a wait: ``value``, else ``PROCTEX_CLUSTER_WAIT``, else :data:`DEFAULT_WAIT_S`.
    Raises ``ValueError`` on a value that is not a finite number >= 0."""
    raw: Any = value if value is not None else os.environ.get("PROCTEX_CLUSTER_WAIT", DEFAULT_WAIT_S)
    try:
        s = float(raw)
    except (TypeError, ValueError):
        raise ValueError(f"PROCTEX_CLUSTER_WAIT must be a number of seconds, got {raw!r}") from None
    if not (s >= 0 and s < float("inf")):
        raise ValueError(f"the cluster wait must be a finite number of seconds >= 0, got {raw!r}")
    return s


def _say(msg: str) -> None:
    print(msg, file=sys.stderr, flush=True)


def transient_reason(exc: BaseException) -> str | None:
    """What a failed Jobs API call waits for, when it is worth retrying: the head's job agent (``No
    available agent``), or the dashboard itself (refused or reset connections while it starts);
    None for every other error."""
    text = str(exc)
    if "No available agent" in text:
        return "the head's job agent"
    try:
        import requests

        if isinstance(exc, (requests.exceptions.ConnectionError, requests.exceptions.Timeout)):
            return "the Jobs API"
    except ImportError:  # pragma: no cover - requests comes with ray[default]
        pass
    if isinstance(exc, (ConnectionError, TimeoutError)) or "Failed to connect to Ray" in text or "Connection refused" in text:
        return "the Jobs API"
    return None


def retry(
    call: Callable[[], Any], what: str, wait_s: float | None = None, say: Callable[[str], None] = _say, sleep: Callable[[float], None] = time.sleep, clock: Callable[[], float] = time.monotonic
) -> Any:
    """``call()``, again while it fails for a :func:`transient_reason`, until ``wait_s`` seconds
    have passed (back-off 0.5 s doubling to 5 s). Says once what it waits for. Raises
    ``TimeoutError`` naming ``what`` and the last error when the time is up; any other error at once."""
    limit = cluster_wait_s(wait_s)
    start = clock()
    delay, told = 0.5, None
    while True:
        try:
            return call()
        except Exception as exc:  # noqa: BLE001 - sorted by transient_reason
            reason = transient_reason(exc)
            if reason is None:
                raise
            waited = clock() - start
            if waited + delay > limit:
                raise TimeoutError(f"{what}: {reason} did not answer within {limit:g} s (PROCTEX_CLUSTER_WAIT); last error: {str(exc).strip()[:300]}") from exc
            if told != reason:
                say(f"{what}: waiting for {reason} (up to {limit:g} s): {str(exc).strip().splitlines()[0][:160]}")
                told = reason
            sleep(delay)
            delay = min(5.0, delay * 2)


def cluster_env(ray_tmp: str = "/tmp/ray") -> dict[str, str]:
    """What a client of ``cluster/local_cluster.sh``'s cluster (its ``RAY_TMP``) needs in its
    environment: the cluster's token (``RAY_TMP/auth_token``), and the node address Ray resolves
    for a multi-node cluster (not the loopback one a private Ray keeps: :data:`workflows.build.LOOPBACK`)."""
    return {"RAY_ENABLE_WINDOWS_OR_OSX_CLUSTER": "1", "RAY_AUTH_MODE": "token", "RAY_AUTH_TOKEN_PATH": f"{ray_tmp}/auth_token"}


def job_client(address: str, wait_s: float | None = None, say: Callable[[str], None] = _say, token_path: str | None = None):
    """A ``JobSubmissionClient`` for ``address`` (``http://host:8265``), waiting while the dashboard
    does not answer yet. ``token_path``: a file holding the cluster's token, sent as a bearer token
    (Ray reads ``RAY_AUTH_MODE`` once a process: set later, it is not seen; default: what Ray reads)."""
    from ray.job_submission import JobSubmissionClient

    headers = None
    if token_path is not None:
        with open(token_path) as fh:
            headers = {"Authorization": f"Bearer {fh.readline().strip()}"}
    return retry(lambda: JobSubmissionClient(address, headers=headers), f"connecting to {address}", wait_s, say)


def submit_job(client_or_address: Any, entrypoint: str, wait_s: float | None = None, say: Callable[[str], None] = _say, **kwargs: Any) -> str:
    """Submit ``entrypoint`` (with ``runtime_env``, ``submission_id``, ... as
    ``JobSubmissionClient.submit_job`` takes them) and return the job's id, retrying while the head
    has no job agent yet. A refused submission creates nothing (Ray answers before it asks the
    agent), so a retry with the same submission id is safe; a try whose answer was lost and that
    landed is found by its id on the next (without ``submission_id``, one is made: ``proctex-...``)."""
    client = job_client(client_or_address, wait_s, say) if isinstance(client_or_address, str) else client_or_address
    # An id of our own when none is given: a submission whose answer was lost (the connection
    # dropped after the head took it) is then found on the retry instead of submitted twice.
    sid = kwargs.get("submission_id") or f"proctex-{uuid.uuid4().hex[:16]}"
    kwargs["submission_id"] = sid
    tries = []

    def submit() -> str:
        tries.append(1)
        try:
            return client.submit_job(entrypoint=entrypoint, **kwargs)
        except RuntimeError as exc:
            if len(tries) > 1 and f"submission_id {sid} already exists" in str(exc):
                return sid  # an earlier try of ours landed
            raise

    return retry(submit, "submitting a job", wait_s, say)


def wait_for_jobs(address: str, wait_s: float | None = None, say: Callable[[str], None] = _say) -> float:
    """Wait until the cluster at ``address`` runs a job: a no-op job submitted (retried as
    :func:`submit_job` does) and run to its end. Returns the seconds it took; raises
    ``TimeoutError`` when that does not happen within ``wait_s`` (the job is stopped),
    ``RuntimeError`` when the job fails."""
    from ray.job_submission import JobStatus

    limit = cluster_wait_s(wait_s)
    t0 = time.monotonic()
    client = job_client(address, limit, say)
    job = submit_job(client, "true", max(0.0, limit - (time.monotonic() - t0)), say, submission_id=f"proctex-ready-{os.getpid()}-{time.time_ns()}", metadata={"proctex": "readiness check"})
    while True:
        status = client.get_job_status(job)
        if status.is_terminal():
            break
        if time.monotonic() - t0 > limit:
            client.stop_job(job)
            raise TimeoutError(f"the cluster at {address} accepted a no-op job but did not run it within {limit:g} s (PROCTEX_CLUSTER_WAIT; last status {status})")
        time.sleep(0.2)
    if status != JobStatus.SUCCEEDED:
        raise RuntimeError(f"the cluster at {address} could not run a no-op job ({status}): {client.get_job_logs(job)[-500:]}")
    return time.monotonic() - t0


def wait_for_cpus(
    minimum: float = 1.0,
    wait_s: float | None = None,
    say: Callable[[str], None] = _say,
    resources: Callable[[], dict] | None = None,
    sleep: Callable[[float], None] = time.sleep,
    clock: Callable[[], float] = time.monotonic,
) -> float:
    """In a driver connected to a cluster (``ray.init(address=...)``): wait until it has at least
    ``minimum`` CPUs (a head without CPUs of its own, worker nodes still joining). Returns the
    cluster's CPUs; raises ``TimeoutError`` after ``wait_s`` seconds (:func:`cluster_wait_s`)
    naming what it saw."""
    if resources is None:
        import ray

        resources = ray.cluster_resources
    limit = cluster_wait_s(wait_s)
    start, told = clock(), False
    while True:
        cpus = float(resources().get("CPU", 0.0))
        if cpus >= minimum:
            return cpus
        if clock() - start >= limit:
            raise TimeoutError(f"the Ray cluster has {cpus:g} CPUs, and none more joined within {limit:g} s (PROCTEX_CLUSTER_WAIT); start worker nodes, or give the head CPUs")
        if not told:
            say(f"waiting for the Ray cluster's CPUs (it has {cpus:g}; up to {limit:g} s): its nodes are still joining")
            told = True
        sleep(0.5)


def main(argv: list[str] | None = None) -> int:
    import argparse

    ap = argparse.ArgumentParser(prog="python -m workflows.jobs", description="Wait for a Ray cluster's Jobs API to run jobs.")
    sub = ap.add_subparsers(dest="cmd", required=True)
    w = sub.add_parser("wait", help="return when the cluster at ADDRESS runs a no-op job")
    w.add_argument("address", help="the Jobs API, e.g. http://127.0.0.1:8265")
    w.add_argument("--timeout", type=float, help=f"seconds (default PROCTEX_CLUSTER_WAIT or {DEFAULT_WAIT_S:g})")
    a = ap.parse_args(argv)
    try:
        took = wait_for_jobs(a.address, a.timeout)
    except (TimeoutError, RuntimeError, ValueError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 1
    print(f"jobs API ready: {a.address} ran a job in {took:.1f} s")
    return 0


if __name__ == "__main__":
    sys.exit(main())
