"""How far each float check of the suite sits from its threshold, natively, under other CPU kernels
and under load (issue 49).

    python -m tests.float_margins run --env native --out out/margins/native.jsonl [-- PYTEST ARGS]
    python -m tests.float_margins run --env other  --out out/margins/other.jsonl  [-- PYTEST ARGS]
    python -m tests.float_margins run --env native --load --out out/margins/load.jsonl [-- PYTEST ARGS]
    python -m tests.float_margins report out/margins/*.jsonl [--json out/margins/report.json]

``run`` runs pytest (default: the fast tests, ``-m "not slow"``) with :mod:`tests.floatrecord`, which
writes one JSON line per float check (value, threshold); ``--env other`` takes
:func:`tests.portable.other_env` (kernels one tier below this CPU's), ``--load`` keeps every core busy
with as many spinning processes for the whole run. ``report`` joins the runs check by check and
lists every check whose margin (the smallest distance between value and threshold over the runs) is
under ``--factor`` (3) times its spread (how far value - threshold moved between the runs), the
tests that failed in some run, the checks of passing tests that some run did not make (another
path through the test) and the fast tests that made float checks without the ``numeric`` marker.
"""

from __future__ import annotations

import argparse
import json
import multiprocessing
import os
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def _spin() -> None:  # pragma: no cover - a load process
    while True:
        pass


def run(env_name: str, out: Path, load: bool, pytest_args: list[str]) -> int:
    from .portable import other_env

    env = other_env() if env_name == "other" else dict(os.environ)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.unlink(missing_ok=True)
    env["PROCTEX_FLOAT_RECORD"] = str(out.resolve())  # tests.floatrecord keeps its rewritten modules apart
    args = [sys.executable, "-m", "pytest", "-q", "-p", "no:cacheprovider", "-p", "tests.floatrecord", "-o", "enable_assertion_pass_hook=true", *(pytest_args or ["-m", "not slow"])]
    spinners = []
    if load:
        ctx = multiprocessing.get_context("spawn")
        spinners = [ctx.Process(target=_spin, daemon=True) for _ in range(os.cpu_count() or 1)]
        for p in spinners:
            p.start()
    try:
        return subprocess.run(args, env=env, cwd=ROOT).returncode
    finally:
        for p in spinners:
            p.kill()
            p.join()


def load_runs(paths: list[Path]) -> tuple[dict[str, dict[tuple, dict]], dict[str, dict[str, str]], set[str]]:
    """``({run name: {(test, where, n, k): record}}, {run name: {test: outcome}}, fast tests without
    the numeric marker)``; a run's name is its file's stem, and ``STEM-other`` for the records of a
    file made on other kernels (``make test``'s second pass). A test's outcome is "passed" only
    when no phase of it failed."""
    runs, outcomes, unmarked = {}, {}, set()
    for path in paths:
        for line in path.read_text(encoding="utf-8").splitlines():
            r = json.loads(line)
            kernels = r.get("kernels", "native")  # one file may hold both passes of a make test
            name = path.stem if kernels == "native" else f"{path.stem}-other"
            recs, outs = runs.setdefault(name, {}), outcomes.setdefault(name, {})
            if "outcome" in r:
                if outs.get(r["test"]) in (None, "passed"):
                    outs[r["test"]] = r["outcome"]
                if r.get("numeric") is False and not r.get("slow"):
                    unmarked.add(r["test"])
                continue
            recs[(r["test"], r["where"], r["n"], r["k"])] = r
    return runs, outcomes, unmarked


def _holds(rec: dict) -> bool:
    """Whether a recorded passing check agrees with its own operator."""
    v, t, op = rec["value"], rec["threshold"], rec["op"]
    return {"<": v < t, "<=": v <= t, ">": v > t, ">=": v >= t}.get(op, True)


def margins(runs: dict[str, dict[tuple, dict]], outcomes: dict[str, dict[str, str]] | None = None, unmarked: set[str] = frozenset(), factor: float = 3.0) -> dict:
    """Per check (a test's line, its occurrence and its place in the assertion) made in every run
    where its test ran: the values in each run, the margin (smallest distance of value to threshold
    over the runs, in units of the threshold) and the spread (how far that moved between runs: both
    sides may move, a threshold computed from another measured value). ``thin``: checks
    whose margin is under ``factor`` x spread (per test and line, the thinnest); ``failed``: tests
    that ran in every run and failed in some; ``missing``: checks of tests that passed everywhere,
    made in some runs only (another path through the test); ``unmarked``: fast tests that made float
    checks without carrying the ``numeric`` marker."""
    names = list(runs)
    outcomes = outcomes or {n: {} for n in names}
    ran_everywhere = set.intersection(*(set(outcomes[n]) for n in names)) if names else set()
    failed = sorted(t for t in ran_everywhere if any(outcomes[n][t] == "failed" for n in names))
    keys = {k for r in runs.values() for k in r if k[0] in ran_everywhere or not any(outcomes.values())}
    thin, missing_sites = {}, {}
    checked = 0
    for key in keys:
        got = [runs[n].get(key) for n in names]
        present = [g for g in got if g is not None]
        site = (key[0], key[1])
        if len(present) < len(names):
            if key[0] not in failed:
                missing_sites.setdefault(site, [n for n, g in zip(names, got) if g is None])
            continue
        if not all(_holds(g) for g in present):  # a comparison misread from its explanation (older records)
            continue
        checked += 1
        if all(g["value"] == 0 and g["op"] in ("<", "<=") for g in present):
            continue  # a distance exactly zero in every run (two paths agreeing to the bit): as far from failing as it gets
        values = [g["value"] for g in present]
        thresholds = [g["threshold"] for g in present]
        # A check fails when value crosses threshold. In units of the threshold where it is not 0
        # (a tolerance relative to a value that itself moves, pytest.approx's, moves with it):
        # the margin is the least |value / threshold - 1| over the runs, the spread how far that
        # ratio moved; against a threshold of 0, the same on value - threshold.
        if all(t != 0 for t in thresholds):
            slack = [v / t - 1.0 for v, t in zip(values, thresholds)]
        else:
            slack = [v - t for v, t in zip(values, thresholds)]
        spread = max(slack) - min(slack)
        margin = min(abs(x) for x in slack)
        if margin < factor * spread:
            old = thin.get(site)
            if old is None or margin / spread < old["margin"] / old["spread"]:
                thin[site] = dict(
                    test=key[0], where=key[1], occurrence=key[2], kind=present[0]["kind"], op=present[0]["op"], threshold=thresholds[0], values=dict(zip(names, values)), margin=margin, spread=spread
                )
    from .conftest import NOT_NUMERIC

    unmarked = {t for t in unmarked if t.split("::")[0].rsplit("/", 1)[-1] not in NOT_NUMERIC}  # those by choice
    return dict(
        runs=names,
        tests=len(ran_everywhere),
        unmarked=sorted({k[0] for r in runs.values() for k in r} & unmarked),
        checks=checked,
        sites=len({(k[0], k[1]) for k in keys}),
        thin=sorted(thin.values(), key=lambda r: r["where"]),
        failed=[dict(test=t, outcomes={n: outcomes[n][t] for n in names}) for t in failed],
        missing=[dict(test=t, where=w, missing_in=m) for (t, w), m in sorted(missing_sites.items())],
    )


def report(paths: list[Path], factor: float, json_out: Path | None) -> int:
    res = margins(*load_runs(paths), factor=factor)
    print(f"{res['tests']} tests ran in every run; {res['checks']} checks at {res['sites']} sites in runs {', '.join(res['runs'])}")
    print(f"fast tests with float checks (in a fixture or another module's helper) but without the numeric marker, outside the modules tests/conftest.py keeps off it: {len(res['unmarked'])}")
    for t in res["unmarked"]:
        print(f"  {t}")
    print(f"failed in some run: {len(res['failed'])} tests")
    for r in res["failed"]:
        print(f"  {r['test']}: {', '.join(f'{k} {v}' for k, v in r['outcomes'].items())}")
    print(f"margin under {factor:g} x spread: {len(res['thin'])} sites")
    for r in res["thin"]:
        vals = ", ".join(f"{k} {v:.6g}" for k, v in r["values"].items())
        print(f"  {r['where']}  {r['kind']} {r['op']} {r['threshold']:.6g}: {vals}  margin {r['margin']:.3g} spread {r['spread']:.3g} (x{r['margin'] / r['spread']:.2f})  ({r['test']})")
    print(f"recorded in some runs only: {len(res['missing'])} sites")
    for r in res["missing"]:
        print(f"  {r['where']}  missing in {', '.join(r['missing_in'])}  ({r['test']})")
    if json_out:
        json_out.parent.mkdir(parents=True, exist_ok=True)
        json_out.write_text(json.dumps(res, indent=1))
    return 0


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m tests.float_margins", description=__doc__.split("\n\n")[0])
    sub = ap.add_subparsers(dest="cmd", required=True)
    r = sub.add_parser("run", help="run pytest recording every float check")
    r.add_argument("--env", choices=("native", "other"), default="native")
    r.add_argument("--load", action="store_true", help="keep every core busy meanwhile")
    r.add_argument("--out", type=Path, required=True)
    r.add_argument("pytest_args", nargs="*")
    p = sub.add_parser("report", help="checks whose margin is thinner than their spread over the runs")
    p.add_argument("files", nargs="+", type=Path)
    p.add_argument("--factor", type=float, default=3.0)
    p.add_argument("--json", type=Path)
    a = ap.parse_args(argv)
    if a.cmd == "run":
        return run(a.env, a.out, a.load, a.pytest_args)
    return report(a.files, a.factor, a.json)


if __name__ == "__main__":
    sys.exit(main())
