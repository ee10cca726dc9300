"""The faults probe of issue 34 (``tests/bench/probe_faults.py``) in ``make test``: every hostile
client, disk and neighbour case gets the answer it must, in JSON where it is an HTTP answer."""

from __future__ import annotations

import sys
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).resolve().parent / "bench"))

pytest.importorskip("httpx")


def test_every_fault_case_gets_the_answer_it_must(tmp_path):
    import probe_faults

    rows = probe_faults.run(tmp_path)
    assert len(rows) >= 35 and {r["class"] for r in rows} >= {
        "slow bodies",
        "bounded work",
        "lost replica",
        "writes",
        "damage",
        "builds",
        "nonsense numbers",
        "fairness",
        "odd input",
        "looks",
        "bounds",
        "units",
        "files",
    }
    failed = [r for r in rows if not r["ok"]]
    assert not failed, probe_faults.table(failed)
    assert all(r["json"] for r in rows if str(r["got"]).isdigit() and r["got"] != 200)  # every HTTP refusal is JSON
