"""``python -m tests.suite [--workers N] [PYTEST ARGS]``: what ``make test`` runs (issue 49).

Two passes: the whole suite, then the fast tests marked ``numeric`` again on other kernels than
this CPU's own (:mod:`tests.portable`). The first pass spends much of its time waiting on the
processes it started (a private Ray, a cluster, Serve, an S3 server, a browser), so the second
(compute only) starts beside it at a lower priority (nice 10) and runs on the cores the first
leaves idle. It stays in this process's session: Linux's autogroup scheduler shares the CPU
between sessions first and applies nice only within one, so a pass in a session of its own took
half of a busy machine from the first whatever its nice value. A machine with no idle core
(another job keeps it busy) gives a nice-10 process almost nothing: if the second pass is still
running when the first ends, it goes on at the normal priority where this user may raise a
priority (root), else it is stopped and run again at the normal priority. A watchdog names a test
running over ``PROCTEX_TEST_STALL_S`` (600) with its process's threads, kills the process of a test
still running past ``PROCTEX_TEST_KILL_S`` (960: pytest-timeout's 900 s could not end it, a hang
in C that holds the GIL, so its timer thread never runs), and past ``PROCTEX_SUITE_BUDGET_S``
(4500) in all names every running test with its threads and stops both passes (:mod:`tests.tracing`,
loaded into both, keeps what each test process runs). The last lines name every test the watchdog
named, with the innermost frames of the thread it stalled in (a CI log's tail shows them). A first pass
that failed only by tests whose worker died running them (a hang the timeout ended) runs those once
more, alone, and takes their verdict (:func:`rerun_hung`). Its output follows the first's; the exit status is 0 only when both
passed (a second pass that selects no test passes: a selection without ``numeric`` tests). PYTEST
ARGS (paths, ``-k``, ...) go to both passes. Ctrl-C or SIGTERM stops both.
"""

from __future__ import annotations

import argparse
import os
import re
import shutil
import signal
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
SECOND = ["-q", "-p", "no:cacheprovider", "-m", "numeric and not slow"]
NO_TESTS = 5  # pytest's exit status when nothing was selected
#: A test running this long is named and its process's threads printed (before pytest-timeout's 900 s
#: stops it); both passes together running this long are stopped, every test then running named with
#: its threads: a hang is reported inside CI's 90 minutes (setup takes up to about 10 of them).
STALL_S = 600.0
#: pytest-timeout's 900 s (pyproject.toml) and a minute: a test still running then is one the timeout
#: could not end, and its process is killed (pytest-xdist starts another worker and reports the test).
KILL_S = 960.0
BUDGET_S = 4500.0
TRACING = ["-p", "tests.tracing"]  # what each test process runs, and its threads on SIGUSR1


def in_flight(folder: Path, now: float) -> list[dict]:
    """The tests running now per the trace files in ``folder`` (:func:`tests.tracing.running`), each
    with ``running_s``, longest first."""
    from tests.tracing import running

    return sorted(({**e, "running_s": now - e["since"]} for e in running(folder)), key=lambda e: -e["running_s"])


def innermost(threads: str, frames: int = 8) -> str:
    """The first ``frames`` frames (most recent call first) of the thread that runs pytest in a dump
    as :meth:`Watchdog.threads_of` returns it (faulthandler's format; the block whose frames pass
    through ``_pytest``, else the "Current thread"), one ``path:line in function`` each, joined by
    " <- "; "" when the dump has none."""
    blocks = [b for b in re.split(r"\n(?=(?:Current thread|Thread) 0x)", "\n" + threads) if re.match(r"(Current thread|Thread) 0x", b)]
    chosen = next((b for b in blocks if "_pytest" in b), next((b for b in blocks if b.startswith("Current")), None))
    if chosen is None:
        return ""
    found = re.findall(r'^\s*File "(.*)", line (\d+) in (.*)$', chosen, flags=re.M)
    return " <- ".join(f"{path}:{line} in {func}" for path, line, func in found[:frames])


class Watchdog(threading.Thread):
    """Every ``every`` s: a test running over ``stall`` s is named once with its process's threads
    (SIGUSR1: :mod:`tests.tracing`'s faulthandler writes them to ``<name>.stacks``); one running over
    ``kill`` s has its process killed (SIGKILL: a hang nothing else ends); past ``budget`` s since the
    start, every running test is named with its threads and ``on_budget`` is called. :attr:`stalls`
    keeps ``(test, seconds, what happened, innermost frames)`` of each one named, for :meth:`summary`."""

    def __init__(self, folder: Path, stall: float, budget: float, on_budget, every: float = 10.0, out=None, kill: float = float("inf")):
        super().__init__(daemon=True, name="suite-watchdog")
        if stall <= 0 or budget <= 0 or every <= 0 or not kill > stall:
            raise ValueError(f"stall, budget and every must be > 0 and kill > stall, got {stall}, {budget}, {every}, {kill}")
        self.folder, self.stall, self.budget, self.on_budget, self.every = folder, stall, budget, on_budget, every
        self.kill = kill
        self.out = out if out is not None else sys.stdout
        self.start_time = time.time()
        self.named: set[tuple[str, str]] = set()
        self.killed: set[tuple[str, str]] = set()
        self.stalls: list[tuple[str, float, str, str]] = []
        self.over_budget = False
        self._halt = threading.Event()

    def halt(self) -> None:
        self._halt.set()

    def threads_of(self, entry: dict) -> str:
        """The threads of the process running ``entry``'s test, as its faulthandler wrote them."""
        path = self.folder / f"{entry['name']}.stacks"
        try:
            before = path.stat().st_size
            os.kill(entry["pid"], signal.SIGUSR1)
        except (OSError, ProcessLookupError) as exc:
            return f"(its threads could not be read: {exc})\n"
        deadline = time.monotonic() + 5.0
        while time.monotonic() < deadline and path.stat().st_size == before:
            time.sleep(0.1)
        time.sleep(0.3)  # the rest of the dump
        with open(path, "rb") as f:
            f.seek(before)
            return f.read(200_000).decode(errors="replace")

    def report(self, entry: dict, why: str, what: str) -> None:
        threads = self.threads_of(entry)
        self.out.write(f"\n==== tests.suite: {entry['test']} has run {entry['running_s']:.0f} s ({entry['name']}){why}; its process's threads:\n{threads}==== end of {entry['name']}'s threads\n")
        self.out.flush()
        self.stalls.append((entry["test"], entry["running_s"], what, innermost(threads)))

    def summary(self) -> str:
        """A line per test the watchdog named (what happened, where it was), "" when none: printed
        last, where a CI log's tail shows it."""
        return "".join(f"==== tests.suite: {test}: {what} at {seconds:.0f} s; innermost frames: {frames or '(none read)'}\n" for test, seconds, what, frames in self.stalls)

    def check(self, now: float) -> None:
        """One look: name stalled tests once; past the budget name every running test and stop."""
        running = in_flight(self.folder, now)
        if now - self.start_time > self.budget:
            self.over_budget = True
            self.out.write(
                f"\n==== tests.suite: the suite has run {now - self.start_time:.0f} s, past its budget of {self.budget:.0f} s (PROCTEX_SUITE_BUDGET_S): {len(running)} test(s) running, then stopped\n"
            )
            for entry in running:
                self.report(entry, "", "running past the suite's budget")
            self.on_budget()
            self.halt()
            return
        for entry in running:
            key = (entry["name"], entry["test"])
            if entry["running_s"] > self.kill and key not in self.killed:
                self.killed.add(key)
                self.report(entry, f", over {self.kill:.0f} s (PROCTEX_TEST_KILL_S): a hang its timeout could not end", "killed (a hang the timeout could not end)")
                try:
                    os.kill(entry["pid"], signal.SIGKILL)
                except (ProcessLookupError, PermissionError):
                    pass
                self.out.write(f"==== tests.suite: its process {entry['pid']} killed; the pass goes on without it\n")
                self.out.flush()
            elif entry["running_s"] > self.stall and key not in self.named:
                self.named.add(key)
                self.report(entry, f", over {self.stall:.0f} s (PROCTEX_TEST_STALL_S)", "stalled")

    def run(self) -> None:
        while not self._halt.wait(self.every):
            self.check(time.time())


def xdist(workers: int) -> list[str]:
    """pytest-xdist's arguments for ``workers`` processes (0: in this process), each test module
    whole in one worker (``--dist loadfile``: its fixtures are built once)."""
    if workers < 0:
        raise ValueError(f"workers must be >= 0, got {workers}")
    return ["-n", str(workers), "--dist", "loadfile"]


def stop(proc: subprocess.Popen, grace: float = 30.0) -> None:
    """SIGTERM to ``proc``'s process group (pytest and its xdist workers), SIGKILL after ``grace`` s."""
    if proc.poll() is not None:
        return
    try:
        os.killpg(proc.pid, signal.SIGTERM)
        proc.wait(timeout=grace)
    except subprocess.TimeoutExpired:
        os.killpg(proc.pid, signal.SIGKILL)
        proc.wait()
    except ProcessLookupError:
        pass


def renice(pgid: int, niceness: int) -> bool:
    """Every process of group ``pgid`` to ``niceness``; False where this user may not raise a
    priority (only root, or CAP_SYS_NICE, may lower a nice value)."""
    try:
        os.setpriority(os.PRIO_PGRP, pgid, niceness)
        return True
    except PermissionError:
        return False
    except ProcessLookupError:  # the group ended meanwhile
        return True


def rerun_hung(scratch: Path, env: dict[str, str], passes: list[subprocess.Popen], watchdog: "Watchdog") -> int:
    """After a first pass that failed (exit 1): where every failed test is one whose worker died
    running it (pytest-timeout's thread method ends a hung worker; :mod:`tests.tracing` kept which),
    those tests run once more in a new pytest and the pass's status is theirs, the hang named loudly
    either way; else 1 (a real failure is never run again)."""
    from tests.tracing import crashed, failures

    reported, hung = failures(scratch / "trace", "first"), crashed(scratch / "trace", "first")
    failed = [test for test, _ in reported]
    if not failed or not set(failed) <= set(hung):
        return 1
    where = [str(Path(root) / test) if root else test for test, root in reported]  # ids are relative to the rootdir
    print(f"\n==== tests.suite: {len(failed)} test(s) stopped their worker (a hang that the timeout ended): {', '.join(failed)}; each runs once more, alone", flush=True)
    again_trace = scratch / "trace-again"
    again_trace.mkdir(exist_ok=True)
    watchdog.folder = again_trace
    again = subprocess.Popen([sys.executable, "-m", "pytest", "-q", *TRACING, "-p", "no:cacheprovider", *where], cwd=ROOT, env={**env, "PROCTEX_TEST_TRACE": str(again_trace)}, process_group=0)
    passes.append(again)
    status = again.wait()
    print(f"==== tests.suite: run again, {'they passed' if status == 0 else 'they failed again'} (hung once: {', '.join(failed)}; the threads above show where)", flush=True)
    return 0 if status == 0 else 1


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        prog="python -m tests.suite",
        description=__doc__.split("\n\n")[0],
        allow_abbrev=False,
        epilog="Every other argument (paths, -k EXPR, --durations=N, ...) is given to both passes' pytest, in its order.",
    )
    parser.add_argument("--workers", type=int, default=None, help="pytest-xdist workers per pass (0: in one process; default TEST_WORKERS or 2)")
    args, pytest_args = parser.parse_known_args(argv)
    try:
        par = xdist(int(os.environ.get("TEST_WORKERS", "2")) if args.workers is None else args.workers)
    except ValueError as exc:
        parser.error(f"{exc} (--workers or TEST_WORKERS: a whole number >= 0)")
    try:
        stall = float(os.environ.get("PROCTEX_TEST_STALL_S", STALL_S))
        kill = float(os.environ.get("PROCTEX_TEST_KILL_S", KILL_S))
        budget = float(os.environ.get("PROCTEX_SUITE_BUDGET_S", BUDGET_S))
        if not (0 < stall < kill < float("inf") and 0 < budget < float("inf")):
            raise ValueError("not positive numbers, or the kill not after the stall")
    except ValueError as exc:
        parser.error(f"PROCTEX_TEST_STALL_S, PROCTEX_TEST_KILL_S and PROCTEX_SUITE_BUDGET_S: seconds > 0, the kill after the stall ({exc})")
    scratch = Path(tempfile.mkdtemp(prefix="proctex-second-"))
    (scratch / "trace").mkdir()
    # workers reuse compiled modules; a suite run by a test of another does not pass as its xdist worker
    env = {k: v for k, v in os.environ.items() if k != "PYTHONDONTWRITEBYTECODE" and not k.startswith("PYTEST_XDIST")}
    env["PROCTEX_TEST_TRACE"] = str(scratch / "trace")
    second_cmd = [sys.executable, "-m", "tests.portable", *SECOND, *TRACING, *par, *pytest_args]
    log = open(scratch / "log", "w+b")
    second = subprocess.Popen([*second_cmd, "--basetemp", str(scratch / "tmp")], cwd=ROOT, env=env, stdout=log, stderr=subprocess.STDOUT, preexec_fn=lambda: os.nice(10), process_group=0)
    first = other = None
    main_pass = None
    passes: list[subprocess.Popen] = [second]

    def stop_all() -> None:
        for proc in passes:
            stop(proc)

    watchdog = Watchdog(scratch / "trace", stall, budget, stop_all, kill=kill)
    watchdog.start()
    # SIGTERM (a CI's cancel) ends this process through the finally below, which stops both passes
    signal.signal(signal.SIGTERM, lambda *_: sys.exit(143))
    try:
        print("the second pass (numeric tests on other kernels) runs beside the first at nice 10; its output follows", flush=True)
        main_pass = subprocess.Popen([sys.executable, "-m", "pytest", "-q", *TRACING, *par, *pytest_args], cwd=ROOT, env=env, process_group=0)
        passes.append(main_pass)
        first = main_pass.wait()
        if first == 1 and par[1] != "0" and not watchdog.over_budget:
            first = rerun_hung(scratch, env, passes, watchdog)
        if watchdog.over_budget:
            other = second.wait()
        elif second.poll() is None and not renice(second.pid, os.getpriority(os.PRIO_PROCESS, 0)):
            stop(second)
            print("\n---- the second pass had no idle core beside the first: it runs now (numeric tests on other kernels)", flush=True)
            again = subprocess.Popen([*second_cmd, "--basetemp", str(scratch / "again")], cwd=ROOT, env=env, process_group=0)
            passes.append(again)
            other = again.wait()
        else:
            if second.poll() is None:
                print("\n---- the second pass had no idle core beside the first: it goes on at the normal priority", flush=True)
                second.wait()
            print("\n---- the second pass (numeric tests on other kernels), run beside the first:", flush=True)
            log.seek(0)
            sys.stdout.write(log.read().decode(errors="replace"))
            other = second.returncode
    except KeyboardInterrupt:
        return 130
    finally:
        watchdog.halt()
        stop_all()
        log.close()
        shutil.rmtree(scratch, ignore_errors=True)
    sys.stdout.write(watchdog.summary())
    print(f"first pass: exit {first}; second pass: exit {other}" + (f" (stopped: past the suite's budget of {budget:.0f} s)" if watchdog.over_budget else ""), flush=True)
    if watchdog.over_budget:
        return 1
    return 0 if first == 0 and other in (0, NO_TESTS) else 1


if __name__ == "__main__":
    raise SystemExit(main())
