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
priority (root), else it is stopped and run again at the normal priority. Its output follows the first's; the exit status is 0 only when both
passed (a second pass that selects no test passes: a selection without ``numeric`` tests). PYTEST
ARGS (paths, ``-k``, ...) go to both passes. Ctrl-C or SIGTERM stops both.
"""

from __future__ import annotations

import argparse
import os
import shutil
import signal
import subprocess
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
SECOND = ["-q", "-p", "no:cacheprovider", "-m", "numeric and not slow"]
NO_TESTS = 5  # pytest's exit status when nothing was selected


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


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m tests.suite", description=__doc__.split("\n\n")[0], allow_abbrev=False,
                                     epilog="Every other argument (paths, -k EXPR, --durations=N, ...) is given to both passes' pytest, in its order.")
    parser.add_argument("--workers", type=int, default=None,
                        help="pytest-xdist workers per pass (0: in one process; default TEST_WORKERS or 2)")
    args, pytest_args = parser.parse_known_args(argv)
    try:
        par = xdist(int(os.environ.get("TEST_WORKERS", "2")) if args.workers is None else args.workers)
    except ValueError as exc:
        parser.error(f"{exc} (--workers or TEST_WORKERS: a whole number >= 0)")
    env = {k: v for k, v in os.environ.items() if k != "PYTHONDONTWRITEBYTECODE"}  # workers reuse compiled modules
    second_cmd = [sys.executable, "-m", "tests.portable", *SECOND, *par, *pytest_args]
    scratch = Path(tempfile.mkdtemp(prefix="proctex-second-"))
    log = open(scratch / "log", "w+b")
    second = subprocess.Popen([*second_cmd, "--basetemp", str(scratch / "tmp")], cwd=ROOT, env=env, stdout=log, stderr=subprocess.STDOUT,
                              preexec_fn=lambda: os.nice(10), process_group=0)
    first = other = None
    main_pass = None
    # SIGTERM (a CI's cancel) ends this process through the finally below, which stops both passes
    signal.signal(signal.SIGTERM, lambda *_: sys.exit(143))
    try:
        print("the second pass (numeric tests on other kernels) runs beside the first at nice 10; its output follows", flush=True)
        main_pass = subprocess.Popen([sys.executable, "-m", "pytest", "-q", *par, *pytest_args], cwd=ROOT, env=env)
        first = main_pass.wait()
        if second.poll() is None and not renice(second.pid, os.getpriority(os.PRIO_PROCESS, 0)):
            stop(second)
            print("\n---- the second pass had no idle core beside the first: it runs now (numeric tests on other kernels)", flush=True)
            other = subprocess.run([*second_cmd, "--basetemp", str(scratch / "again")], cwd=ROOT, env=env).returncode
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
        if main_pass is not None and main_pass.poll() is None:
            main_pass.terminate()
            try:
                main_pass.wait(timeout=30)
            except subprocess.TimeoutExpired:
                main_pass.kill()
                main_pass.wait()
        stop(second)
        log.close()
        shutil.rmtree(scratch, ignore_errors=True)
    print(f"first pass: exit {first}; second pass: exit {other}", flush=True)
    return 0 if first == 0 and other in (0, NO_TESTS) else 1


if __name__ == "__main__":
    raise SystemExit(main())
