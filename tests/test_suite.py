"""``python -m tests.suite`` (what ``make test`` runs): the second pass runs beside the first on idle
cores, is run again at the normal priority when it could not finish beside it, and either pass
failing fails the whole; on a tiny project of its own (a few tests, its own pytest.ini)."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import tomllib
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]

INI = """[pytest]
markers =
    numeric: compares floats
    slow: slow
"""
#: The second pass (PROCTEX_KERNELS set by tests.portable.other_env) says when its session ended and
#: which process it is (tests.portable execs pytest: the process tests.suite started).
CONFTEST = """import os
from pathlib import Path

def pytest_sessionfinish(session):
    if os.environ.get("PROCTEX_KERNELS", "native") != "native":
        Path(os.environ["SUITE_FLAG"]).write_text(str(os.getpid()))
"""
TESTS = """import os, time
from pathlib import Path
import pytest

pytestmark = pytest.mark.numeric
OTHER = os.environ.get("PROCTEX_KERNELS", "native") != "native"

def exited(pid):
    try:  # a child tests.suite has not reaped yet is a zombie: it has exited
        return Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0] in "ZX"
    except (FileNotFoundError, ProcessLookupError):
        return True

def test_waits_as_told():
    how = os.environ["SUITE_CASE"]
    if how == "beside" and not OTHER:  # the first pass ends only after the second's process has exited
        deadline = time.monotonic() + 480  # a nice-10 process on a busy machine gets little
        flag = Path(os.environ["SUITE_FLAG"])
        while not (flag.exists() and flag.read_text() and exited(int(flag.read_text()))) and time.monotonic() < deadline:
            time.sleep(0.2)
    deadline = time.monotonic() + 600
    while how == "starved" and OTHER and os.nice(0) >= int(os.environ["SUITE_NICE"]) + 10 and time.monotonic() < deadline:
        time.sleep(0.2)  # beside the first: as if it had no idle core, until its priority is raised

def test_kernels():
    assert not (OTHER and os.environ["SUITE_CASE"] == "fails_on_other")
    Path(os.environ["SUITE_FLAG"] + (".other" if OTHER else ".first")).write_text(str(os.getsid(0)))
"""


def run_suite(tmp_path: Path, case: str, *extra: str) -> subprocess.CompletedProcess:
    proj = tmp_path / case
    proj.mkdir()
    (proj / "pytest.ini").write_text(INI)
    (proj / "conftest.py").write_text(CONFTEST)
    (proj / "test_tiny.py").write_text(TESTS)

    env = {**os.environ, "SUITE_CASE": case, "SUITE_FLAG": str(proj / "second.done"), "SUITE_NICE": str(os.nice(0))}
    return subprocess.run([sys.executable, "-m", "tests.suite", "--workers", "0", *extra, str(proj)], cwd=ROOT, env=env, capture_output=True, text=True, timeout=900)


def test_the_second_pass_runs_beside_the_first(tmp_path):
    run = run_suite(tmp_path, "beside")
    assert run.returncode == 0, run.stdout[-3000:] + run.stderr[-2000:]
    assert "run beside the first" in run.stdout and "runs now" not in run.stdout, run.stdout[-3000:]
    assert run.stdout.count("2 passed") == 2 and "first pass: exit 0; second pass: exit 0" in run.stdout
    # both passes in one session: Linux's autogroup shares the CPU between sessions before nice
    # counts, so a second pass in a session of its own took half of a busy machine at nice 10
    flag = tmp_path / "beside" / "second.done"
    assert Path(f"{flag}.first").read_text() == Path(f"{flag}.other").read_text()


def test_a_second_pass_starved_beside_the_first_goes_on_at_the_normal_priority_or_is_run_again(tmp_path):
    run = run_suite(tmp_path, "starved")
    assert run.returncode == 0, run.stdout[-3000:] + run.stderr[-2000:]
    # root may raise the pass's priority where it is; another user stops it and runs it again
    told = "it goes on at the normal priority" if os.geteuid() == 0 else "it runs now"
    assert f"had no idle core beside the first: {told}" in run.stdout, run.stdout[-3000:]
    assert run.stdout.count("2 passed") == 2
    assert not subprocess.run(["pgrep", "-f", str(tmp_path / "starved")], capture_output=True).stdout  # the starved one is gone


def test_a_failure_in_either_pass_fails_the_whole(tmp_path):
    run = run_suite(tmp_path, "fails_on_other")
    assert run.returncode == 1, run.stdout[-3000:]
    assert "1 failed, 1 passed" in run.stdout and "first pass: exit 0; second pass: exit 1" in run.stdout


def test_bad_worker_counts_are_refused():

    run = subprocess.run([sys.executable, "-m", "tests.suite", "--workers", "-1"], cwd=ROOT, capture_output=True, text=True, timeout=60)
    assert run.returncode == 2 and "workers must be >= 0" in run.stderr
    run = subprocess.run([sys.executable, "-m", "tests.suite"], cwd=ROOT, capture_output=True, text=True, timeout=60, env={**os.environ, "TEST_WORKERS": "two"})
    assert run.returncode == 2 and "TEST_WORKERS" in run.stderr and "Traceback" not in run.stderr


def test_a_terminated_suite_stops_both_passes(tmp_path):
    """SIGTERM to ``tests.suite`` (a CI's cancel) while both passes run: both are stopped."""
    import signal
    import time

    proj = tmp_path / "stopped"
    proj.mkdir()
    (proj / "pytest.ini").write_text(INI)
    (proj / "test_sleeps.py").write_text("import time, pytest\npytestmark = pytest.mark.numeric\n\ndef test_sleeps():\n    time.sleep(300)\n")
    suite = subprocess.Popen([sys.executable, "-m", "tests.suite", "--workers", "0", str(proj)], cwd=ROOT, stdout=subprocess.PIPE, text=True)
    try:
        deadline = time.monotonic() + 240
        while time.monotonic() < deadline and len(subprocess.run(["pgrep", "-f", str(proj)], capture_output=True).stdout.split()) < 3:
            time.sleep(0.5)  # the suite, the first pass and the second pass all name the project
        assert len(subprocess.run(["pgrep", "-f", str(proj)], capture_output=True).stdout.split()) >= 3
        os.kill(suite.pid, signal.SIGTERM)
        assert suite.wait(timeout=120) != 0
    finally:
        if suite.poll() is None:
            suite.kill()
    deadline = time.monotonic() + 60
    while time.monotonic() < deadline and subprocess.run(["pgrep", "-f", str(proj)], capture_output=True).stdout:
        time.sleep(0.5)
    assert not subprocess.run(["pgrep", "-f", str(proj)], capture_output=True).stdout, "a pass outlived the suite"


def test_options_before_the_path_reach_both_passes(tmp_path):
    run = run_suite(tmp_path, "options", "-k", "kernels", "--durations=1")
    assert run.returncode == 0, run.stdout[-3000:] + run.stderr[-2000:]
    assert run.stdout.count("1 passed, 1 deselected") == 2 and run.stdout.count("slowest 1 durations") == 2, run.stdout[-3000:]


def test_in_flight_reads_the_trace_files_longest_first_and_skips_damaged_ones(tmp_path):
    from tests.suite import in_flight

    (tmp_path / "first-gw0-11.now").write_text(json.dumps({"test": "t.py::a", "since": 100.0, "pid": 11}))
    (tmp_path / "first-gw1-12.now").write_text(json.dumps({"test": "t.py::b", "since": 40.0, "pid": 12}))
    (tmp_path / "second-gw0-13.now").write_text("")  # between two tests
    (tmp_path / "second-gw1-14.now").write_text('{"test": "t.py::c", "si')  # read while written
    (tmp_path / "first-gw2-15.now").write_text(json.dumps({"test": "t.py::d", "pid": "x", "since": 1.0}))
    assert [(e["test"], e["pid"], e["running_s"]) for e in in_flight(tmp_path, 160.0)] == [("t.py::b", 12, 120.0), ("t.py::a", 11, 60.0)]
    assert in_flight(tmp_path / "missing", 0.0) == []


def tiny_project(tmp_path: Path, name: str, body: str, ini_extra: str = "") -> Path:
    proj = tmp_path / name
    proj.mkdir()
    (proj / "pytest.ini").write_text(INI + ini_extra)
    (proj / "test_hang.py").write_text(body)
    return proj


HANGS_IN_C = """import signal, time

def test_stuck_where_no_signal_reaches():
    # SIGALRM blocked in this thread: as a main thread stuck in a C call, which never runs
    # a signal's Python handler (pytest-timeout's "signal" method)
    signal.pthread_sigmask(signal.SIG_BLOCK, {signal.SIGALRM})
    time.sleep(240)

def test_after_it():
    pass
"""


def test_a_test_stuck_in_c_is_named_with_its_threads_and_stopped_and_the_rest_runs(tmp_path):
    """The watchdog names a stalled test with its stack; pytest-timeout's method (the project's own,
    read from pyproject.toml) stops it although no signal reaches its thread, and the module's next
    test still runs: a hang costs one test, not the suite."""
    method = tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["pytest"]["ini_options"]["timeout_method"]
    proj = tiny_project(tmp_path, "stuck", HANGS_IN_C, f"timeout = 20\ntimeout_method = {method}\n")
    run = subprocess.run(
        [sys.executable, "-m", "tests.suite", "--workers", "1", "-rs", str(proj)], cwd=ROOT, capture_output=True, text=True, timeout=600, env={**os.environ, "PROCTEX_TEST_STALL_S": "8"}
    )
    out = run.stdout
    assert run.returncode == 1, out[-4000:] + run.stderr[-2000:]
    assert "test_hang.py::test_stuck_where_no_signal_reaches has run" in out and "over 8 s (PROCTEX_TEST_STALL_S)" in out, out[-4000:]
    threads = out.split("its process's threads:")[1].split("==== end of")[0]
    assert "line 7 in test_stuck_where_no_signal_reaches" in threads, threads  # its stack, down to the stuck line
    assert "crashed while running 'test_hang.py::test_stuck_where_no_signal_reaches'" in out, out[-4000:]
    assert "1 failed, 1 passed, 1 skipped" in out and "not run again: it stopped worker process" in out, out[-4000:]
    assert out.count("crashed while running") == 1  # run once: the new worker skips it and runs the next
    # every failure a hang: it runs once more, alone, hangs again and fails the suite
    assert "1 test(s) stopped their worker" in out and "they failed again" in out, out[-4000:]


HOLDS_THE_GIL = """import ctypes, time

class Timespec(ctypes.Structure):
    _fields_ = [("tv_sec", ctypes.c_long), ("tv_nsec", ctypes.c_long)]

def test_stuck_in_c_holding_the_gil():
    # a mutex locked twice, the second time through PyDLL (which keeps the GIL): no thread of this
    # process runs Python for 90 s, pytest-timeout's timer among them, and no signal ends the wait
    libc = ctypes.PyDLL(None)
    mutex = ctypes.create_string_buffer(64)  # zeroed: a default mutex (PTHREAD_MUTEX_INITIALIZER)
    libc.pthread_mutex_lock(mutex)
    libc.pthread_mutex_timedlock(mutex, ctypes.byref(Timespec(int(time.time()) + 90, 0)))

def test_after_it():
    pass
"""


def test_a_test_holding_the_gil_past_the_kill_limit_is_killed_named_last_and_the_rest_runs(tmp_path):
    """A hang that pytest-timeout cannot end (its timer thread needs the GIL) is named at the stall
    limit, its process killed at the kill limit (the next test still runs, the hung one runs once
    more alone and is killed again), and the suite's last lines name it with its innermost frames.
    Without the kill the pass would wait the lock's 90 s out, twice."""
    proj = tiny_project(tmp_path, "gil", HOLDS_THE_GIL, "timeout = 5\ntimeout_method = thread\n")
    run = subprocess.run(
        [sys.executable, "-m", "tests.suite", "--workers", "1", str(proj)],
        cwd=ROOT,
        capture_output=True,
        text=True,
        timeout=600,
        env={**os.environ, "PROCTEX_TEST_STALL_S": "4", "PROCTEX_TEST_KILL_S": "12"},
    )
    out = run.stdout
    assert run.returncode == 1, out[-4000:] + run.stderr[-2000:]
    assert "over 4 s (PROCTEX_TEST_STALL_S)" in out and "over 12 s (PROCTEX_TEST_KILL_S)" in out, out[-4000:]
    assert "crashed while running 'test_hang.py::test_stuck_in_c_holding_the_gil'" in out, out[-4000:]
    assert "1 failed, 1 passed" in out and "they failed again" in out, out[-4000:]
    tail = out[out.rindex("they failed again") :]
    assert tail.count("test_hang.py::test_stuck_in_c_holding_the_gil: killed (a hang the timeout could not end)") == 2, tail
    assert "test_hang.py:12 in test_stuck_in_c_holding_the_gil" in tail, tail  # the innermost frame, in the last lines


HANGS_ONCE = """import os, signal, time
from pathlib import Path

def test_hangs_the_first_time():
    flag = Path(os.environ["SUITE_FLAG"])
    if not flag.exists():
        flag.write_text("hung")
        signal.pthread_sigmask(signal.SIG_BLOCK, {signal.SIGALRM})
        time.sleep(240)

def test_fine():
    pass
"""


@pytest.mark.parametrize("also_fails", [False, True])
def test_a_test_that_hung_once_runs_again_and_a_real_failure_is_never_retried(tmp_path, also_fails):
    """A pass whose only failure is a hung test (its worker ended by the timeout) runs it once more:
    passing then, the suite passes, naming the hang. With a real failure beside it nothing is run
    again and the suite fails."""
    body = HANGS_ONCE + ("\ndef test_fails():\n    assert False\n" if also_fails else "")
    proj = tiny_project(tmp_path, "once", body, "timeout = 15\ntimeout_method = thread\n")
    run = subprocess.run(
        [sys.executable, "-m", "tests.suite", "--workers", "1", str(proj)], cwd=ROOT, capture_output=True, text=True, timeout=600, env={**os.environ, "SUITE_FLAG": str(proj / "hung.flag")}
    )
    out = run.stdout
    assert (proj / "hung.flag").exists() and "crashed while running 'test_hang.py::test_hangs_the_first_time'" in out, out[-4000:]
    if also_fails:
        assert run.returncode == 1 and "runs once more" not in out, out[-4000:]
    else:
        assert run.returncode == 0, out[-4000:] + run.stderr[-2000:]
        assert "1 test(s) stopped their worker (a hang that the timeout ended): test_hang.py::test_hangs_the_first_time" in out
        assert "they passed (hung once: test_hang.py::test_hangs_the_first_time" in out


def test_a_suite_past_its_budget_names_every_running_test_and_stops(tmp_path):
    proj = tiny_project(tmp_path, "budget", "import time\n\ndef test_sleeps_long():\n    time.sleep(300)\n")
    run = subprocess.run([sys.executable, "-m", "tests.suite", "--workers", "0", str(proj)], cwd=ROOT, capture_output=True, text=True, timeout=600, env={**os.environ, "PROCTEX_SUITE_BUDGET_S": "15"})
    out = run.stdout
    assert run.returncode == 1, out[-4000:] + run.stderr[-2000:]
    assert "past its budget of 15 s (PROCTEX_SUITE_BUDGET_S): 1 test(s) running, then stopped" in out, out[-4000:]
    assert "test_hang.py::test_sleeps_long has run" in out and "line 4 in test_sleeps_long" in out, out[-4000:]
    assert "(stopped: past the suite's budget of 15 s)" in out
    assert not subprocess.run(["pgrep", "-f", str(proj)], capture_output=True).stdout, "a pass outlived the suite"
    bad = subprocess.run([sys.executable, "-m", "tests.suite", str(proj)], cwd=ROOT, capture_output=True, text=True, timeout=60, env={**os.environ, "PROCTEX_SUITE_BUDGET_S": "nan"})
    assert bad.returncode == 2 and "PROCTEX_SUITE_BUDGET_S" in bad.stderr and "Traceback" not in bad.stderr
