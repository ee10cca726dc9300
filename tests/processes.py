"""The processes a test started: found by their command line among this process's descendants, so a
test never touches anything it did not start (another Ray on the machine included)."""

import os
from pathlib import Path


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
