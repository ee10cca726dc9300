"""The processes a test started: found by their command line among this process's descendants, so a
test never touches anything it did not start (another Ray on the machine included)."""

import os
import subprocess
from contextlib import contextmanager
from pathlib import Path
from typing import Iterator


def _parent(pid: int) -> int:
    try:
        for line in Path(f"/proc/{pid}/status").read_text().splitlines():
            if line.startswith("PPid:"):
                return int(line.split()[1])
    except OSError:
        pass
    return 0


def _ours(pid: int) -> bool:
    """Whether ``pid`` descends from this test process (a worker of the Ray it started), so a test
    never touches another Ray on the machine."""
    me = os.getpid()
    for _ in range(64):
        pid = _parent(pid)
        if pid == me:
            return True
        if pid <= 1:
            return False
    return False


def pids_running(title: bytes) -> list[int]:
    """This test process's own processes whose command line holds ``title``."""
    out = []
    for p in Path("/proc").iterdir():
        if p.name.isdigit():
            try:
                if title in (p / "cmdline").read_bytes() and _ours(int(p.name)):
                    out.append(int(p.name))
            except OSError:
                pass
    return out


def free_port() -> int:
    """A port free on 127.0.0.1 now."""
    import socket

    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


@contextmanager
def serving(root: str, log: Path, replicas: int = 1, env: dict | None = None, wait: float = 240.0) -> Iterator[tuple[str, subprocess.Popen]]:
    """A real ``proctex serve ROOT`` (a private Ray, Serve, ``replicas`` transfer replicas) on a free
    port of 127.0.0.1, in a process group of its own, its output in ``log``: yields ``(URL, process)``
    once ``/healthz`` answers, then stops it with Ctrl-C (SIGINT; SIGKILL to its group after 60 s)."""
    import signal
    import sys
    import time
    import urllib.request

    url = f"http://127.0.0.1:{free_port()}"
    with open(log, "w") as out:
        proc = subprocess.Popen(
            [sys.executable, "-m", "workflows.cli", "serve", root, "--port", url.rsplit(":", 1)[1], "--replicas", str(replicas)],
            stdout=out,
            stderr=subprocess.STDOUT,
            start_new_session=True,
            cwd=Path(__file__).resolve().parents[1],
            env=env,
        )
        try:
            deadline = time.monotonic() + wait
            while True:
                assert proc.poll() is None, Path(log).read_text()[-3000:]
                assert time.monotonic() < deadline, f"proctex serve did not answer in {wait:g} s"
                try:
                    with urllib.request.urlopen(url + "/healthz", timeout=5) as answer:
                        if answer.status == 200:
                            break
                except OSError:
                    time.sleep(1.0)
            yield url, proc
        finally:
            proc.send_signal(signal.SIGINT)  # Ctrl-C stops it: Serve shut down, Ray stopped, exit 0
            try:
                proc.wait(timeout=60)
            except subprocess.TimeoutExpired:
                os.killpg(proc.pid, signal.SIGKILL)
                proc.wait()
