"""The benchmark suite keeps running: its harness, and each script's quickest setting."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

BENCH = Path(__file__).resolve().parent / "bench"
sys.path.insert(0, str(BENCH))

from harness import summary_table, timeit  # noqa: E402


def test_timeit_reports_order_statistics():
    calls = []
    r = timeit(lambda: calls.append(1), repeats=5, warmup=2)
    assert len(calls) == 7 and r["repeats"] == 5
    assert r["min"] <= r["p10"] <= r["median"] <= r["p90"] <= r["max"] and r["spread"] >= 0
    with pytest.raises(ValueError):
        timeit(lambda: None, repeats=0)
    table = summary_table([{"benchmark": "b", "results": {"x": r}}])
    assert "| b | x |" in table


@pytest.mark.parametrize("script, argv", [
    ("bench_mvc.py", ["--points", "200", "--levels", "0", "--repeats", "1"]),
    ("bench_forward.py", ["--context", "256", "--queries", "100", "--repeats", "1"]),
    ("bench_projection.py", ["--model", "mug", "--points", "200", "--repeats", "1"]),
    ("bench_texel_map.py", ["--model", "mug", "--sizes", "64", "--repeats", "1"]),
    ("bench_cage_iteration.py", ["--points", "200", "--short", "2", "--long", "4", "--repeats", "1"]),
    ("bench_bake.py", ["--model", "mug", "--shapes", "1", "--texture", "64", "--size", "64", "--repeats", "1"]),
])
def test_each_benchmark_writes_its_report(tmp_path, script, argv):
    out = tmp_path / "r.json"
    done = subprocess.run([sys.executable, str(BENCH / script), *argv, "--out", str(out)], capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr
    rep = json.loads(out.read_text())
    assert rep["results"] and rep["machine"]["cpus"] >= 1 and "torch" in rep["versions"]
    for r in rep["results"].values():
        assert r["median"] >= 0 and r["repeats"] >= 1
