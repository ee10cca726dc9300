"""A pytest plugin that ``python -m tests.suite`` loads into both passes (``-p tests.tracing``): which
test each process runs and since when, and every thread's stack on demand, for the suite's watchdog.

With ``PROCTEX_TEST_TRACE`` naming a folder, each test process (an xdist worker, or pytest itself)
keeps ``<pass>-<worker>-<pid>.now`` there: ``{"test": nodeid, "since": epoch seconds, "pid": pid}``
while a test runs, empty between tests; SIGUSR1 appends every thread's stack to ``<name>.stacks``
(:mod:`faulthandler`: written from C, so also while the main thread is stuck in a C call); a test
whose process died while running it (a timeout) is skipped when handed out again. Without the
variable the plugin does nothing.
"""

from __future__ import annotations

import faulthandler
import json
import os
import signal
import time
from pathlib import Path

import pytest

_STACKS = pytest.StashKey()


def _folder() -> Path | None:
    trace = os.environ.get("PROCTEX_TEST_TRACE")
    return Path(trace) if trace and Path(trace).is_dir() else None


def trace_name() -> str:
    """This process's name in the trace folder: its pass, its xdist worker and its pid."""
    kind = "second" if os.environ.get("PROCTEX_KERNELS", "native") != "native" else "first"
    return f"{kind}-{_WORKER[0] if _WORKER else 'main'}-{os.getpid()}"


_ROOT: list[Path] = []  # the session's rootdir: test ids are relative to it
_WORKER: list[str] = []  # this process's xdist worker id, where it is one


def pytest_configure(config: pytest.Config) -> None:
    _ROOT[:] = [Path(config.rootpath)]
    # from the config, not the environment: a suite run inside a test inherits its worker's variables
    _WORKER[:] = [config.workerinput["workerid"]] if hasattr(config, "workerinput") else []
    folder = _folder()
    if folder is not None:
        stacks = open(folder / f"{trace_name()}.stacks", "w")  # noqa: SIM115 (open while the process lives)
        faulthandler.register(signal.SIGUSR1, file=stacks, all_threads=True, chain=False)
        config.stash[_STACKS] = stacks


def pytest_unconfigure(config: pytest.Config) -> None:
    stacks = config.stash.get(_STACKS, None)
    if stacks is not None:
        faulthandler.unregister(signal.SIGUSR1)
        stacks.close()


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return Path(f"/proc/{pid}/stat").exists() and Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0] not in "ZX"


def running(folder: Path, kind: str = "*") -> list[dict]:
    """What the ``.now`` files of pass ``kind`` (``*``: both) in ``folder`` name, in file order:
    ``[{"name", "test", "pid", "since"}]``; empty files (between tests) and damaged ones (read while
    written) are skipped. A dead process's entry is the test it died running."""
    found = []
    for path in sorted(folder.glob(f"{kind}-*.now")):
        try:
            entry = json.loads(path.read_text() or "null")
            found.append({"name": path.stem, "test": str(entry["test"]), "pid": int(entry["pid"]), "since": float(entry["since"])})
        except (OSError, ValueError, TypeError, KeyError):
            continue
    return found


def crashed(folder: Path, kind: str) -> list[str]:
    """The tests of pass ``kind`` whose process died while running them (their ``.now`` still names them)."""
    return list(dict.fromkeys(e["test"] for e in running(folder, kind) if not _alive(e["pid"])))


def crashed_before(folder: Path, nodeid: str, kind: str) -> int | None:
    """The pid of another process of pass ``kind`` that died while running ``nodeid``, or None."""
    return next((e["pid"] for e in running(folder, kind) if e["test"] == nodeid and e["pid"] != os.getpid() and not _alive(e["pid"])), None)


@pytest.hookimpl(tryfirst=True)
def pytest_runtest_setup(item: pytest.Item) -> None:
    """A test that stopped its worker before (pytest-timeout's thread method ends a stuck worker) is
    not run again: pytest-xdist's ``--dist loadfile`` hands a crashed worker's test to the next
    worker, and a hang would then cost its timeout once per replaced worker."""
    folder = _folder()
    if folder is not None:
        pid = crashed_before(folder, item.nodeid, trace_name().split("-")[0])
        if pid is not None:
            pytest.skip(f"not run again: it stopped worker process {pid} before (its failure is reported above)")


def pytest_runtest_logreport(report: pytest.TestReport) -> None:
    """In the process that reports (pytest, or xdist's controller): each failed test appended to
    ``<pass>-failures.jsonl`` (``{"test", "when"}``), so tests.suite knows whether a pass failed only
    by tests whose worker died (a hang its timeout ended)."""
    folder = _folder()
    if folder is None or not report.failed or _WORKER:
        return
    with open(folder / f"{trace_name().split('-')[0]}-failures.jsonl", "a") as fh:
        fh.write(json.dumps({"test": report.nodeid, "when": report.when, "root": str(_ROOT[0]) if _ROOT else ""}) + "\n")


def failures(folder: Path, kind: str) -> list[tuple[str, str]]:
    """The tests of pass ``kind`` reported failed, ``(test id, its session's rootdir)``, in order, each once."""
    path = folder / f"{kind}-failures.jsonl"
    if not path.exists():
        return []
    out = []
    for line in path.read_text().splitlines():
        try:
            entry = json.loads(line)
            out.append((str(entry["test"]), str(entry.get("root", ""))))
        except (ValueError, KeyError, TypeError):
            continue
    return list(dict.fromkeys(out))


@pytest.hookimpl(hookwrapper=True)
def pytest_runtest_protocol(item: pytest.Item, nextitem: pytest.Item | None):
    folder = _folder()
    now = folder / f"{trace_name()}.now" if folder is not None else None
    if now is not None:
        now.write_text(json.dumps({"test": item.nodeid, "since": time.time(), "pid": os.getpid()}))
    try:
        yield
    finally:
        if now is not None:
            now.write_text("")
