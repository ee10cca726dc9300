"""The float-check recorder and its margin report (tests/floatrecord.py, tests/float_margins.py)."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

from .float_margins import margins
from .floatrecord import parse_explanation

ROOT = Path(__file__).resolve().parents[1]

SAMPLE = """
import numpy as np
import pytest


def test_sample():
    x = 0.0513
    assert x < 0.08
    assert 0.01 < x <= 0.06
    assert len([1, 2]) < 3  # integers: exact, not recorded
    assert np.float64(0.25) == pytest.approx(0.2501, abs=1e-3)
    for i in range(3):
        assert abs(i * 0.1 - i * 0.1) < 1e-9
    np.testing.assert_allclose([1.0, 2.0], [1.0, 2.0 + 1e-8], rtol=1e-7)
    assert np.allclose([1.0], [1.0 + 5e-6], rtol=1e-5, atol=0)
"""


def test_explanations_give_each_numeric_comparison():
    assert parse_explanation("0.0513 < 0.08\n +  where 0.0513 = f()") == [("compare", 0.0513, 0.08, "<")]
    assert parse_explanation("(0.01 < 0.0513 <= 0.06)") == [("compare", 0.01, 0.0513, "<"), ("compare", 0.0513, 0.06, "<=")]
    assert parse_explanation("(np.float64(0.2) >= 0.1 and 3 < 4)") == [("compare", 0.2, 0.1, ">=")]
    assert parse_explanation("np.float64(0.25) == 0.2501 ± 1.0e-03") == [("approx", abs(0.25 - 0.2501), 1e-3, "<=")]
    assert parse_explanation("2 == 2") == [] and parse_explanation("True") == []
    # "(time() - t) < 5": the left side is an expression, not the number before the bracket
    assert parse_explanation("(4045.6 - 4045.5) < 5") == [] and parse_explanation("f(0.3) < 0.5") == []
    assert parse_explanation("tensor(0.25) < 0.5") == [("compare", 0.25, 0.5, "<")]
    assert parse_explanation("-1.5e-07 >= -inf") == [("compare", -1.5e-07, float("-inf"), ">=")]


def test_a_run_records_every_float_check_with_its_value_and_threshold(tmp_path):
    (tmp_path / "test_sample.py").write_text(SAMPLE)
    out = tmp_path / "rec.jsonl"
    run = subprocess.run(
        [
            sys.executable,
            "-m",
            "pytest",
            "-q",
            "-p",
            "no:cacheprovider",
            "-p",
            "tests.floatrecord",
            "-o",
            "enable_assertion_pass_hook=true",
            "--rootdir",
            str(tmp_path),
            str(tmp_path / "test_sample.py"),
        ],
        env={**__import__("os").environ, "PROCTEX_FLOAT_RECORD": str(out), "PYTHONPATH": str(ROOT)},
        cwd=tmp_path,
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert run.returncode == 0, run.stdout[-3000:] + run.stderr[-2000:]
    lines = [json.loads(x) for x in out.read_text().splitlines()]
    checks = [r for r in lines if "value" in r]
    by_line = {}
    for r in checks:
        by_line.setdefault(int(r["where"].rsplit(":", 1)[1]), []).append(r)
    assert [(r["value"], r["threshold"], r["op"]) for r in by_line[8]] == [(0.0513, 0.08, "<")]
    assert [(r["k"], r["op"], r["threshold"]) for r in by_line[9]] == [(0, "<=", 0.06)]  # pytest explains a chain by its last link
    assert 10 not in by_line  # two integers
    assert by_line[11][0]["kind"] == "approx" and abs(by_line[11][0]["threshold"] - 1e-3) < 1e-12
    assert [r["n"] for r in by_line[13]] == [0, 1, 2]  # a loop: one record per pass
    assert by_line[14][0]["kind"] == "allclose" and abs(by_line[14][0]["value"] - 1e-8 / (1e-7 * (2.0 + 1e-8))) < 1e-6
    assert abs(by_line[15][0]["value"] - 5e-6 / (1e-5 * (1.0 + 5e-6))) < 1e-6
    outcome = [r for r in lines if "outcome" in r]
    assert outcome and outcome[0]["outcome"] == "passed"


def _rec(test, where, value, threshold, n=0, k=0, op="<"):
    return {(test, where, n, k): dict(test=test, where=where, n=n, k=k, kind="compare", value=value, threshold=threshold, op=op)}


def test_the_report_flags_margins_thinner_than_the_spread_and_nothing_else():
    """A check like the chart's of issue 49 (0.0323 on one BLAS kernel, 0.0495 on another, threshold
    0.05) is thin; a check far from its threshold is not, however much it moves; a check a run did not make
    is missing there, and a test that failed in a run is listed as failed."""
    t = "tests/test_x.py::test_a"
    native = {**_rec(t, "tests/test_x.py:1", 0.0323, 0.05), **_rec(t, "tests/test_x.py:2", 0.1, 10.0), **_rec(t, "tests/test_x.py:3", 1.0, 2.0)}
    other = {**_rec(t, "tests/test_x.py:1", 0.0495, 0.05), **_rec(t, "tests/test_x.py:2", 0.9, 10.0)}
    res = margins({"native": native, "other": other}, {"native": {t: "passed"}, "other": {t: "passed"}})
    assert [r["where"] for r in res["thin"]] == ["tests/test_x.py:1"]
    thin = res["thin"][0]
    assert abs(thin["margin"] - 0.0005 / 0.05) < 1e-12 and abs(thin["spread"] - 0.0172 / 0.05) < 1e-12  # in units of the threshold
    # a tolerance relative to a value that moves (pytest.approx's) moves with it: not thin
    rel = margins({"a": _rec(t, "tests/test_x.py:5", 1e-18, 0.05 * 0.0074), "b": _rec(t, "tests/test_x.py:5", 7e-18, 0.05 * 0.0032)}, {"a": {t: "passed"}, "b": {t: "passed"}})
    assert rel["thin"] == [] and rel["checks"] == 1
    assert [m["where"] for m in res["missing"]] == ["tests/test_x.py:3"] and res["missing"][0]["missing_in"] == ["other"]
    failed = margins({"native": native, "other": other}, {"native": {t: "passed"}, "other": {t: "failed"}})
    assert failed["failed"] == [dict(test=t, outcomes={"native": "passed", "other": "failed"})] and failed["missing"] == []
    same = margins({"native": native, "again": native}, {"native": {t: "passed"}, "again": {t: "passed"}})
    assert same["thin"] == [] and same["checks"] == 3
    misread = {**native, **_rec(t, "tests/test_x.py:4", 4045.6, 5.0)}  # "(t1 - t0) < 5" read by an older recorder
    assert margins({"a": misread, "b": misread}, {"a": {t: "passed"}, "b": {t: "passed"}})["checks"] == 3
