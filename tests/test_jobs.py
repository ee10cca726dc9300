"""Submissions wait for a cluster that is still starting (workflows/jobs.py, issue 49).

Ray's own JobSubmissionClient against a stand-in for a head's dashboard (a local HTTP server that
answers ``/api/version`` and refuses the first submissions with Ray's "No available agent" 500), and
the waits' bounds with fake clocks; the real cluster start is tests/test_cluster.py's job test."""

from __future__ import annotations

import json
import threading
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer

import pytest

from workflows.jobs import cluster_wait_s, retry, submit_job, transient_reason, wait_for_cpus

NO_AGENT = "No available agent to submit job, please try again later."


class FakeHead:
    """A dashboard that has no job agent for its first ``refusals`` submissions."""

    def __init__(self, refusals: int, status: int = 500, text: str = NO_AGENT, drop_first: bool = False):
        import ray

        head = self
        self.refusals, self.submissions, self.bodies, self.drop_first, self.jobs = refusals, 0, [], drop_first, set()

        class Handler(BaseHTTPRequestHandler):
            def log_message(self, *args):
                pass

            def _answer(self, code: int, body: str, kind: str = "application/json"):
                data = body.encode()
                self.send_response(code)
                self.send_header("Content-Type", kind)
                self.send_header("Content-Length", str(len(data)))
                self.end_headers()
                self.wfile.write(data)

            def do_GET(self):
                if self.path.startswith("/api/version"):
                    self._answer(200, json.dumps({"version": "4", "ray_version": ray.__version__, "ray_commit": "x", "session_name": "s"}))
                else:
                    self._answer(404, "not found", "text/plain")

            def do_POST(self):
                body = self.rfile.read(int(self.headers.get("Content-Length") or 0))
                if self.path.rstrip("/") == "/api/jobs":
                    head.submissions += 1
                    head.bodies.append(json.loads(body or b"{}"))
                    if head.submissions <= head.refusals:
                        return self._answer(status, text, "text/plain")
                    sid = head.bodies[-1].get("submission_id") or "raysubmit_fake"
                    if sid in head.jobs:  # Ray's words (job_manager.py)
                        return self._answer(500, f"Job with submission_id {sid} already exists. Please use a different submission_id.", "text/plain")
                    head.jobs.add(sid)
                    if head.drop_first and head.submissions == 1:  # took it, and the answer is lost
                        self.close_connection = True
                        self.connection.shutdown(2)
                        return
                    return self._answer(200, json.dumps({"job_id": sid, "submission_id": sid}))
                self._answer(404, "not found", "text/plain")

        self.server = ThreadingHTTPServer(("127.0.0.1", 0), Handler)
        self.address = f"http://127.0.0.1:{self.server.server_address[1]}"
        threading.Thread(target=self.server.serve_forever, daemon=True).start()

    def close(self):
        self.server.shutdown()
        self.server.server_close()


@pytest.fixture()
def head():
    heads = []

    def make(*args, **kwargs):
        heads.append(FakeHead(*args, **kwargs))
        return heads[-1]

    yield make
    for h in heads:
        h.close()


def test_a_submission_waits_while_the_head_has_no_job_agent(head, monkeypatch):
    """Ray's client against a head without a job agent for its first three submissions: the
    submission is retried and goes through with the same request, and what it waited for is said once."""
    import workflows.jobs as jobs

    monkeypatch.setattr(jobs.time, "sleep", lambda s: None)
    h = head(3)
    said = []
    sid = submit_job(h.address, "echo hi", wait_s=30, say=said.append, submission_id="mine", runtime_env={"env_vars": {"A": "1"}})
    assert sid == "mine" and h.submissions == 4
    assert all(b["entrypoint"] == "echo hi" and b["submission_id"] == "mine" for b in h.bodies)
    assert len(said) == 1 and "job agent" in said[0] and "No available agent" in said[0]


def test_a_submission_gives_up_after_its_bound_and_other_refusals_are_not_retried(head):
    h = head(10_000)
    with pytest.raises(TimeoutError, match="job agent did not answer within 2.5 s.*PROCTEX_CLUSTER_WAIT.*No available agent"):
        submit_job(h.address, "true", wait_s=2.5, say=lambda m: None)
    assert h.submissions == 3  # at 0, 0.5 and 1.5 s; the next would come after the bound
    bad = head(1, status=400, text="runtime_env: bad pip spec")
    with pytest.raises(RuntimeError, match="400"):
        submit_job(bad.address, "true", wait_s=20, say=lambda m: None)
    assert bad.submissions == 1


def test_a_submission_whose_answer_was_lost_is_found_not_submitted_twice(head, monkeypatch):
    """The head takes the job and the connection drops before its answer: the retry finds the job
    by the id the submission made for itself; a job id taken beforehand is still refused."""
    import workflows.jobs as jobs

    monkeypatch.setattr(jobs.time, "sleep", lambda s: None)
    h = head(0, drop_first=True)
    sid = submit_job(h.address, "true", wait_s=30, say=lambda m: None)
    assert sid.startswith("proctex-") and h.jobs == {sid} and h.submissions == 2
    taken = head(0)
    taken.jobs.add("mine")
    with pytest.raises(RuntimeError, match="already exists"):
        submit_job(taken.address, "true", wait_s=30, say=lambda m: None, submission_id="mine")


def test_a_dashboard_not_up_yet_is_waited_for_then_reported(monkeypatch):
    """Nothing listens at the address: the client's ConnectionError is transient, and the wait
    ends with an error naming the Jobs API."""
    import socket

    import workflows.jobs as jobs

    s = socket.socket()
    s.bind(("127.0.0.1", 0))
    port = s.getsockname()[1]
    s.close()  # a port nothing listens on
    monkeypatch.setattr(jobs.time, "sleep", lambda s: None)
    said = []
    with pytest.raises(TimeoutError, match="the Jobs API did not answer within 1 s"):
        jobs.job_client(f"http://127.0.0.1:{port}", wait_s=1, say=said.append)
    assert said and "waiting for the Jobs API" in said[0]


def test_retry_backs_off_within_its_bound_and_classifies_errors():
    slept, now = [], [0.0]

    def sleep(s):
        slept.append(s)
        now[0] += s

    calls = []

    def flaky():
        calls.append(1)
        if len(calls) < 5:
            raise RuntimeError(f"Request failed with status code 500: {NO_AGENT}.")
        return "ok"

    assert retry(flaky, "x", wait_s=60, say=lambda m: None, sleep=sleep, clock=lambda: now[0]) == "ok"
    assert slept == [0.5, 1.0, 2.0, 4.0]
    assert transient_reason(ConnectionError("Failed to connect to Ray at address: http://x.")) == "the Jobs API"
    assert transient_reason(RuntimeError("Request failed with status code 500: Job with submission_id x already exists.")) is None
    assert transient_reason(ValueError("bad")) is None


def test_waiting_for_cpus_returns_when_nodes_join_and_fails_when_none_do():
    seen = iter([{}, {"CPU": 0.0}, {"CPU": 0.0}, {"CPU": 2.0}])
    now = [0.0]

    def sleep(s):
        now[0] += s

    said = []
    assert wait_for_cpus(1, wait_s=10, say=said.append, resources=lambda: next(seen), sleep=sleep, clock=lambda: now[0]) == 2.0
    assert len(said) == 1 and "CPUs" in said[0]
    now[0] = 0.0
    with pytest.raises(TimeoutError, match="has 0 CPUs.*within 3 s"):
        wait_for_cpus(1, wait_s=3, say=lambda m: None, resources=lambda: {"CPU": 0.0}, sleep=sleep, clock=lambda: now[0])


@pytest.mark.parametrize("bad", ["soon", "-1", "inf", "nan"])
def test_the_wait_bound_must_be_a_finite_number(bad, monkeypatch):
    monkeypatch.setenv("PROCTEX_CLUSTER_WAIT", bad)
    with pytest.raises(ValueError, match="PROCTEX_CLUSTER_WAIT|finite"):
        cluster_wait_s()
    monkeypatch.setenv("PROCTEX_CLUSTER_WAIT", "12.5")
    assert cluster_wait_s() == 12.5 and cluster_wait_s(3) == 3.0


def test_a_private_ray_whose_node_timed_out_is_started_again_and_its_processes_stopped(monkeypatch):
    """Ray's fixed 30 s node start fails on a busy machine: the start is tried again (at most
    ``tries`` times), saying so, after the processes the failed start left are stopped; any other
    failure, and the last try's, is Ray's own; a bad number of tries is refused."""
    import os
    import subprocess

    import ray

    from workflows.build import _descendants, start_private_ray

    left: list[subprocess.Popen] = []
    calls: list[dict] = []

    def fake_init(fails: int, error: str):
        def init(**kwargs):
            calls.append(kwargs)
            if len(calls) <= fails:
                left.append(subprocess.Popen(["sleep", "60"]))  # stands for the failed start's GCS server
                raise Exception(f"The current node {error}. This could happen because ...")

        return init

    monkeypatch.setattr(ray, "shutdown", lambda: None)
    said: list[str] = []
    mine = subprocess.Popen(["sleep", "60"])  # started before: not the failed start's
    try:
        monkeypatch.setattr(ray, "init", fake_init(2, "timed out during startup"))
        start_private_ray(num_cpus=2, tries=3, log=said.append)
        assert len(calls) == 3 and all(c["address"] == "local" and c["num_cpus"] == 2 and c["_system_config"] is None for c in calls)
        calls.clear()
        from workers.serve import RAY_SYSTEM_CONFIG

        monkeypatch.setattr(ray, "init", fake_init(0, ""))
        start_private_ray(system_config=RAY_SYSTEM_CONFIG)  # proctex serve's: answers inside Ray's calls
        assert calls[-1]["_system_config"] == {"max_direct_call_object_size": 8 * 2**20}
        assert len(said) == 2 and "try 3 of 3" in said[-1] and "fixed 30 s" in said[0]
        assert all(p.wait(timeout=10) == -9 for p in left)  # killed, and only those: this process's own live on
        assert mine.poll() is None and mine.pid in _descendants(os.getpid()) and os.getpid() not in _descendants(os.getpid())
        calls.clear()
        monkeypatch.setattr(ray, "init", fake_init(5, "timed out during startup"))
        with pytest.raises(Exception, match="timed out during startup"):
            start_private_ray(tries=2, log=said.append)
        assert len(calls) == 2
        calls.clear()
        monkeypatch.setattr(ray, "init", fake_init(1, "could not reach the GCS"))
        with pytest.raises(Exception, match="could not reach the GCS"):
            start_private_ray(tries=3, log=said.append)
        assert len(calls) == 1
    finally:
        for p in (*left, mine):
            p.kill()
            p.wait()
    for bad in (0, 21):
        with pytest.raises(ValueError, match="1-20"):
            start_private_ray(tries=bad)
    monkeypatch.setenv("PROCTEX_RAY_START_TRIES", "many")
    with pytest.raises(ValueError, match="PROCTEX_RAY_START_TRIES"):
        start_private_ray()
