"""Shared benchmark harness: timing with warm-up and repeats (median and spread), machine and
versions, one JSON report per benchmark and a Markdown summary row.

Every ``bench_*.py`` built on it takes ``--repeats`` and ``--out`` and returns its report from
``run(args)``, so ``run_all.py`` (``make bench``) can call them in one process.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import statistics
import time
from pathlib import Path
from typing import Any, Callable

import numpy as np


def timeit(fn: Callable[[], Any], repeats: int = 7, warmup: int = 1) -> dict[str, float]:
    """Run ``fn`` ``warmup`` times untimed, then ``repeats`` times: seconds as median, p10, p90,
    min, max, mean and the relative spread (inter-quartile range over the median)."""
    if repeats < 1 or warmup < 0:
        raise ValueError(f"need repeats >= 1 and warmup >= 0, got {repeats}, {warmup}")
    for _ in range(warmup):
        fn()
    t = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        t.append(time.perf_counter() - t0)
    a = np.asarray(t)
    med = float(np.median(a))
    q1, q3 = np.percentile(a, [25, 75])
    return {
        "median": med,
        "p10": float(np.percentile(a, 10)),
        "p90": float(np.percentile(a, 90)),
        "min": float(a.min()),
        "max": float(a.max()),
        "mean": float(a.mean()),
        "spread": float((q3 - q1) / med) if med > 0 else 0.0,
        "repeats": repeats,
    }


def machine() -> dict[str, Any]:
    cpu = platform.processor()
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                cpu = line.split(":", 1)[1].strip()
                break
    except OSError:
        pass
    import torch

    return {"platform": platform.platform(), "cpu": cpu, "cpus": os.cpu_count(), "torch_threads": torch.get_num_threads(), "cuda": torch.cuda.is_available()}


def versions() -> dict[str, str]:
    import importlib.metadata as md

    out = {"python": platform.python_version()}
    for pkg in ("numpy", "scipy", "torch", "trimesh", "pyarrow", "embreex", "ray", "scikit-image", "proctex"):
        try:
            out[pkg] = md.version(pkg)
        except md.PackageNotFoundError:
            pass
    return out


def report(name: str, params: dict[str, Any], results: dict[str, dict[str, float]], out: str | None = None, notes: dict[str, Any] | None = None) -> dict[str, Any]:
    """The benchmark's JSON report (written to ``out`` when given) and a line per result on stdout."""
    rep = {"benchmark": name, "params": params, "results": results, "notes": notes or {}, "machine": machine(), "versions": versions(), "time": time.strftime("%Y-%m-%d %H:%M:%S")}
    for key, r in results.items():
        print(f"{name} {key}: median {fmt(r['median'])} (p10 {fmt(r['p10'])}, p90 {fmt(r['p90'])}, spread {100 * r['spread']:.0f}%, {r['repeats']} runs)", flush=True)
    if out:
        write_json(out, rep)
    return rep


def write_json(out: str | os.PathLike, data: Any) -> None:
    """Write ``data`` as indented JSON to ``out`` atomically (folders created)."""
    Path(out).parent.mkdir(parents=True, exist_ok=True)
    tmp = Path(f"{out}.tmp{os.getpid()}")
    tmp.write_text(json.dumps(data, indent=1, default=str))
    os.replace(tmp, out)


def copy_family(family: str | os.PathLike, work: str | os.PathLike, drop: tuple[str, ...], stages: tuple[str, ...]):
    """A fresh copy of a built family at ``work`` without the files ``drop`` (glob patterns) and the
    records of ``stages``, so those stages run again there; returns ``(store, its build config)``."""
    import shutil

    from proctex.store.layout import FamilyStore
    from proctex.store.state import FamilyState

    shutil.rmtree(work, ignore_errors=True)
    shutil.copytree(family, work, ignore=shutil.ignore_patterns(*drop))
    store = FamilyStore(work)
    state = FamilyState.load(store)
    for stage in stages:
        state.stages.pop(stage, None)
    state.save(store)
    return store, state.build_config()


def fmt(seconds: float) -> str:
    if seconds < 1e-3:
        return f"{seconds * 1e6:.0f} µs"
    if seconds < 1:
        return f"{seconds * 1e3:.1f} ms"
    return f"{seconds:.2f} s"


def summary_table(reports: list[dict[str, Any]]) -> str:
    """Markdown: one row per (benchmark, result)."""
    lines = ["| benchmark | what | median | p10 - p90 | spread | runs |", "|---|---|---|---|---|---|"]
    for rep in reports:
        for key, r in rep["results"].items():
            lines.append(f"| {rep['benchmark']} | {key} | {fmt(r['median'])} | {fmt(r['p10'])} - {fmt(r['p90'])} | {100 * r['spread']:.0f}% | {r['repeats']} |")
    return "\n".join(lines)


def median_of(values: list[float]) -> float:
    return float(statistics.median(values))


def parser(doc: str, repeats: int) -> argparse.ArgumentParser:
    """An argument parser titled by the script's docstring, with the suite's ``--repeats`` and ``--out``."""
    ap = argparse.ArgumentParser(description=doc.splitlines()[0])
    ap.add_argument("--repeats", type=int, default=repeats)
    ap.add_argument("--out", help="JSON report")
    return ap
