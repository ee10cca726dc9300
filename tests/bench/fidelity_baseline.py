"""No family got worse: a committed fidelity baseline and the check that compares with it (issue 52).

Every family of the baseline (:data:`FAMILIES`: the real suite of :mod:`bench_fidelity` and the
built-ins at the README's default scale) is built and evaluated at several seeds (the build's seed:
its shapes where they are sampled, the template's paint, the cage pairs' samples, the networks'
initialisation and batches). Per family and figure (:data:`FIGURES`: GT mean / p99 / max where a
truth exists, the pseudo-GT mean, the tracked-point variance and its ratios to the identity and
nearest mappers, the flipped share against the truth and against the teacher, coverage) the
baseline keeps every seed's value, their mean and their spread (largest minus smallest): the noise
is a measured number per family and figure.

``--compare`` builds and evaluates the baseline's families again at the same seeds with today's
code, prints each figure beside its baseline with the ratio of the means, and calls a figure
*worse* when today's mean exceeds the baseline's by more than its noise (the larger spread of the
two runs, at least the figure's floor: :data:`FIGURES`); every figure is better when lower. It
exits 1 when a family got worse. Run it before a change to the teacher, training, assignment,
serving choice or build shortcuts lands (``make bench-fidelity``; docs/results.md).

    .venv/bin/python tests/bench/fidelity_baseline.py --record tests/bench/fidelity_baseline.json --families sofa,mushroom
    .venv/bin/python tests/bench/fidelity_baseline.py --compare tests/bench/fidelity_baseline.json
    .venv/bin/python tests/bench/fidelity_baseline.py --compare tests/bench/fidelity_baseline.json --against out/x/today.json
    .venv/bin/python tests/bench/fidelity_baseline.py --table tests/bench/fidelity_baseline.json     # the README's table

Runs are kept under ``--root`` (one family folder per seed, built from scratch) and the measured
figures in ``ROOT/today.json``: an interrupted run resumes, reusing each seed measured with the same
config at the same commit (``--fresh`` after changing uncommitted code).
"""

from __future__ import annotations

import argparse
import json
import shutil
import subprocess
import sys
import time
from pathlib import Path
from typing import Any, Callable

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))
sys.path.insert(0, str(Path(__file__).resolve().parent))

import bench_fidelity as F  # noqa: E402

REPO = Path(__file__).resolve().parents[2]
#: The README's built-in scale: 24 train and 8 test shapes, 300 cage iterations, 3000 training steps.
BUILTIN_SCALE = {"n_train": 24, "n_test": 8, "cage_iterations": 300, "train_iterations": 3000}
BUILTINS = ("fork", "vase", "mug", "chair", "table", "mushroom", "cake", "desk")
#: Built-ins written as a real export writes them and read back as folder families (:mod:`seamsplit`:
#: GLB files split at UV seams, +y up, truth beside each file): thin parts through the files' path.
SEAMS = ("fork.seams",)
FILES = "${FILES}"  # where a SEAMS family's files are written: ROOT/files
METHODS = ["corrnet", "identity", "nearest"]
SEEDS = (0, 1, 2)


def family_config(name: str, seed: int) -> dict[str, Any]:
    """The build config of baseline family ``name`` at ``seed``: a real family's (:data:`bench_fidelity.REAL`,
    default build settings) or a built-in's at :data:`BUILTIN_SCALE`."""
    if name in F.REAL:
        return {**F.real_config(name), "seed": seed}
    if name in BUILTINS:
        return F.family_config(name, BUILTIN_SCALE["n_train"], BUILTIN_SCALE["n_test"], BUILTIN_SCALE["cage_iterations"], BUILTIN_SCALE["train_iterations"], seed)
    if name in SEAMS:  # the files of the built-in's family at this seed (24 train and 8 test shapes)
        model = name.split(".")[0]
        return {
            "source": {"folder": f"{FILES}/{name}/s{seed}", "up": "y"},
            "paint": {"prompt": F.PROMPTS.get(model, "painted wood")},
            "cage": {"iterations": BUILTIN_SCALE["cage_iterations"]},
            "train": {"iterations": BUILTIN_SCALE["train_iterations"]},
            "seed": seed,
            "truth": "canonical",
        }
    raise ValueError(f"unknown family {name!r}; the baseline's families: {', '.join([*F.REAL, *BUILTINS, *SEAMS])}")


def materialise(name: str, seed: int, config: dict[str, Any], root: Path) -> dict[str, Any]:
    """``config`` ready to build: a :data:`SEAMS` family's files written under ``root/files`` (once:
    a folder with its ``export.json`` is complete) and ``${FILES}`` resolved; other configs as they are."""
    if name not in SEAMS:
        return config
    import seamsplit

    folder = root / "files" / name / f"s{seed}"
    if not (folder / "export.json").exists():
        if folder.exists():
            shutil.rmtree(folder)
        seamsplit.export_family(name.split(".")[0], folder, BUILTIN_SCALE["n_train"], BUILTIN_SCALE["n_test"], seed)
    return json.loads(json.dumps(config).replace(FILES, str(root / "files")))


def portable_config(config: dict[str, Any]) -> dict[str, Any]:
    """``config`` with the shared data folder's path written ``${DATA}`` (the baseline is read on
    machines whose checkouts lie elsewhere)."""
    return json.loads(json.dumps(config).replace(str(F.DATA), "${DATA}"))


def _gt(key: str) -> Callable[[dict[str, Any]], float | None]:
    return lambda ms: (ms["corrnet"].get("gt_error") or {}).get(key)


def _ratio(base: str) -> Callable[[dict[str, Any]], float | None]:
    def get(ms: dict[str, Any]) -> float | None:
        if base not in ms:
            return None
        return ms["corrnet"]["tracked_point_variance"] / max(ms[base]["tracked_point_variance"], 1e-12)

    return get


#: figure -> (how it is read from an evaluation's ``methods``, its noise floor: a difference under
#: it is never "moved", whatever the seeds' spread). Lower is better for every figure.
FIGURES: dict[str, tuple[Callable[[dict[str, Any]], float | None], float]] = {
    "gt_mean": (_gt("mean"), 2e-4),
    "gt_p99": (_gt("p99"), 2e-3),
    "gt_max": (_gt("max"), 5e-3),
    "pgt_mean": (lambda ms: (ms["corrnet"].get("pgt_error") or {}).get("mean"), 2e-4),
    "variance": (lambda ms: ms["corrnet"]["tracked_point_variance"], 1e-5),
    "x_identity": (_ratio("identity"), 0.02),
    "x_nearest": (_ratio("nearest"), 0.02),
    "flipped_truth": (_gt("flipped"), 5e-4),
    "flipped_teacher": (lambda ms: (ms["corrnet"].get("pgt_error") or {}).get("flipped"), 5e-4),
    "coverage": (lambda ms: ms["corrnet"].get("coverage"), 1e-4),
    "coverage_baked": (lambda ms: ms["corrnet"].get("coverage_baked"), 1e-4),
}


def headline(methods: dict[str, Any]) -> dict[str, float | None]:
    """The headline figures (:data:`FIGURES`) of one evaluation's ``methods`` (None where the
    family has no such figure: no truth, no baseline method)."""
    out = {}
    for name, (get, _) in FIGURES.items():
        v = get(methods)
        out[name] = None if v is None else float(v)
    return out


def summarise(per_seed: dict[str, dict[str, float | None]]) -> dict[str, dict[str, Any]]:
    """``{seed: figures}`` -> per figure ``{"values": [per seed], "mean", "spread"}`` (figures
    missing at any seed are left out)."""
    seeds = sorted(per_seed, key=int)
    out = {}
    for name in FIGURES:
        vals = [per_seed[s].get(name) for s in seeds]
        if not vals or any(v is None for v in vals):
            continue
        out[name] = {"values": [round(v, 8) for v in vals], "mean": round(sum(vals) / len(vals), 8), "spread": round(max(vals) - min(vals), 8)}
    return out


def compare(baseline: dict[str, Any], today: dict[str, Any]) -> list[dict[str, Any]]:
    """One row per family and figure present in both: ``family``, ``figure``, ``base`` and ``today``
    (means), ``ratio`` (today / base), ``noise`` (the larger spread, at least the figure's floor)
    and ``verdict``: "worse" (today's mean above the baseline's by more than the noise), "better"
    (below by more), "same"; a family missing today is one row with verdict "missing"."""
    rows = []
    for fam, base in baseline["families"].items():
        now = today.get("families", {}).get(fam)
        if now is None:
            rows.append({"family": fam, "figure": "-", "verdict": "missing"})
            continue
        for name, b in base["figures"].items():
            t = now["figures"].get(name)
            if t is None:
                rows.append({"family": fam, "figure": name, "base": b["mean"], "today": None, "verdict": "missing"})
                continue
            noise = max(b["spread"], t["spread"], FIGURES[name][1])
            diff = t["mean"] - b["mean"]
            verdict = "worse" if diff > noise else "better" if diff < -noise else "same"
            rows.append({"family": fam, "figure": name, "base": b["mean"], "today": t["mean"], "ratio": (t["mean"] / b["mean"]) if b["mean"] else None, "noise": noise, "verdict": verdict})
    return rows


def worse_families(rows: list[dict[str, Any]]) -> list[str]:
    """The families with a figure worse than the baseline, or missing."""
    return list(dict.fromkeys(r["family"] for r in rows if r["verdict"] in ("worse", "missing")))


def compare_table(rows: list[dict[str, Any]]) -> str:
    """Markdown of :func:`compare`'s rows."""
    lines = ["| family | figure | baseline mean | today mean | ratio | noise | verdict |", "|---|---|---|---|---|---|---|"]
    f = lambda x: "-" if x is None else f"{x:.5g}"  # noqa: E731
    for r in rows:
        ratio = "-" if r.get("ratio") is None else f"{r['ratio']:.2f}x"
        verdict = "**worse**" if r["verdict"] == "worse" else r["verdict"]
        lines.append(f"| {r['family']} | {r['figure']} | {f(r.get('base'))} | {f(r.get('today'))} | {ratio} | {f(r.get('noise'))} | {verdict} |")
    return "\n".join(lines)


def baseline_table(data: dict[str, Any]) -> str:
    """Markdown: per family, each headline figure as mean ± half its spread over the seeds."""
    shown = ("gt_mean", "gt_p99", "gt_max", "pgt_mean", "variance", "x_identity", "x_nearest", "flipped_truth", "flipped_teacher", "coverage")
    lines = ["| family | seeds | " + " | ".join(shown) + " |", "|" + "---|" * (2 + len(shown))]
    for fam, entry in data["families"].items():
        cells = []
        for name in shown:
            s = entry["figures"].get(name)
            cells.append("-" if s is None else f"{s['mean']:.4g} ± {s['spread'] / 2:.2g}")
        lines.append(f"| {fam} | {len(entry['seeds'])} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


def readme_table(data: dict[str, Any]) -> str:
    """Markdown: the README's results table from a baseline record: per family the seeds, the
    paper's ProcCorrNet mean / max (:data:`bench_fidelity.PAPER`), and the run-time path's pseudo-GT
    mean, GT mean / p99 / max, variance with its ratios to identity and nearest, and flipped share
    against the truth / the teacher, each as the mean over the seeds ± half their spread."""

    def cell(entry: dict[str, Any], name: str, fmt: str, pct: bool = False) -> str:
        s = entry["figures"].get(name)
        if s is None:
            return "-"
        k = 100.0 if pct else 1.0
        half = f"{k * s['spread'] / 2:{fmt}}"
        return f"{k * s['mean']:{fmt}}" + (f" ± {half}" if half.strip("0.") else "") + ("%" if pct else "")

    lines = ["| family | seeds | paper mean / max | pseudo-GT mean | GT mean / p99 / max | variance (x identity, x nearest) | flipped (truth / teacher) |", "|---|---|---|---|---|---|---|"]
    for fam, e in data["families"].items():
        paper = F.PAPER.get(fam, F.PAPER.get(fam.split(".")[0]) if fam in SEAMS else None)  # a SEAMS family: its model's
        lines.append(
            f"| {fam} | {len(e['seeds'])} | {'-' if not paper else f'{paper[0]:.3f} / {paper[1]:.3f}'} "
            f"| {cell(e, 'pgt_mean', '.4f')} | {cell(e, 'gt_mean', '.4f')} / {cell(e, 'gt_p99', '.3f')} / {cell(e, 'gt_max', '.3f')} "
            f"| {cell(e, 'variance', '.4f')} ({cell(e, 'x_identity', '.2f')}x, {cell(e, 'x_nearest', '.2f')}x) "
            f"| {cell(e, 'flipped_truth', '.2f', True)} / {cell(e, 'flipped_teacher', '.2f', True)} |"
        )
    return "\n".join(lines)


def git_head() -> str:
    try:
        return subprocess.run(["git", "rev-parse", "--short", "HEAD"], cwd=REPO, capture_output=True, text=True, timeout=30).stdout.strip()
    except (OSError, subprocess.SubprocessError):
        return "unknown"


def measure(families: list[str], seeds: list[int], root: Path, fresh: bool, workers: int, log: Callable[[str], None] = print) -> dict[str, Any]:
    """Build and evaluate every family at every seed in ``root/<family>/s<seed>`` (resuming from
    ``root/today.json``: a seed measured with the same config at the same commit is reused; after
    changing uncommitted code, ``fresh``); the baseline record ``{"code", "made", "methods", "families": {family:
    {"config" (seed 0's), "seeds", "per_seed", "figures", "seconds"}}}``."""
    path = root / "today.json"
    done = json.loads(path.read_text()) if path.exists() and not fresh else {}
    per = done.get("per_seed", {})
    code = git_head()
    for fam in families:
        for seed in seeds:
            key = f"{fam}/s{seed}"
            cfg = family_config(fam, seed)
            if key in per and per[key]["config"] == cfg and per[key].get("code") == code:
                log(f"{key}: measured already")
                continue
            log(f"{key}:")
            t0 = time.perf_counter()
            res = F.run_family(root / fam / f"s{seed}", materialise(fam, seed, cfg, root), METHODS, workers, 5000, True)  # built by today's code, from scratch
            per[key] = {"config": cfg, "code": code, "figures": headline(res["metrics"]["methods"]), "build_seconds": res["build_seconds"], "seconds": round(time.perf_counter() - t0, 1)}
            root.mkdir(parents=True, exist_ok=True)
            path.write_text(json.dumps({"per_seed": per}, indent=1) + "\n")
    out: dict[str, Any] = {"code": code, "made": time.strftime("%Y-%m-%d"), "methods": METHODS, "families": {}}
    for fam in families:
        runs = {str(s): per[f"{fam}/s{s}"] for s in seeds}
        out["families"][fam] = {
            "config": portable_config(family_config(fam, 0)),
            "seeds": list(seeds),
            "per_seed": {s: r["figures"] for s, r in runs.items()},
            "figures": summarise({s: r["figures"] for s, r in runs.items()}),
            "seconds": round(sum(r["seconds"] for r in runs.values()), 1),
        }
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    what = ap.add_mutually_exclusive_group(required=True)
    what.add_argument("--record", metavar="FILE.json", help="measure the --families at the --seeds and write the baseline")
    what.add_argument("--compare", metavar="FILE.json", help="measure the baseline's families again and compare")
    what.add_argument("--table", metavar="FILE.json", help="print the README's results table of a baseline")
    ap.add_argument("--against", metavar="TODAY.json", help="--compare: a record already measured (no builds)")
    ap.add_argument("--families", default=None, help=f"--record: comma-separated (default: {','.join([*F.REAL, *BUILTINS, *SEAMS])}); --compare: a subset of the baseline's")
    ap.add_argument("--seeds", default=",".join(map(str, SEEDS)), help="--record: build seeds (at least 3 make the noise a measurement)")
    ap.add_argument("--root", default=None, help="where the families are built (default out/fidelity_record or out/fidelity_compare)")
    ap.add_argument("--workers", type=int, default=1)
    ap.add_argument("--fresh", action="store_true", help="rebuild families found in --root")
    args = ap.parse_args(argv)
    if args.table:
        print(readme_table(json.loads(Path(args.table).read_text())))
        return 0
    if args.record:
        families = [f.strip() for f in (args.families or ",".join([*F.REAL, *BUILTINS, *SEAMS])).split(",") if f.strip()]
        for f in families:
            family_config(f, 0)  # unknown names refused before any build
        try:
            seeds = [int(s) for s in args.seeds.split(",") if s.strip()]
        except ValueError:
            raise SystemExit(f"--seeds must be integers separated by commas, got {args.seeds!r}") from None
        if len(seeds) < 3:
            raise SystemExit("a baseline needs at least 3 seeds: its noise is their spread")
        data = measure(families, seeds, Path(args.root or "out/fidelity_record"), args.fresh, args.workers)
        old = json.loads(Path(args.record).read_text()) if Path(args.record).exists() else {"families": {}}
        data["families"] = {**old.get("families", {}), **data["families"]}  # families not measured now stay
        Path(args.record).write_text(json.dumps(data, indent=1) + "\n")
        print(baseline_table(data))
        print(f"wrote {args.record}")
        return 0
    baseline = json.loads(Path(args.compare).read_text())
    if args.families:
        wanted = [f.strip() for f in args.families.split(",") if f.strip()]
        unknown = sorted(set(wanted) - set(baseline["families"]))
        if unknown:
            raise SystemExit(f"not in the baseline: {', '.join(unknown)}; it has {', '.join(baseline['families'])}")
        baseline = {**baseline, "families": {f: baseline["families"][f] for f in wanted}}
    if args.against:
        today = json.loads(Path(args.against).read_text())
    else:
        fams = list(baseline["families"])
        seeds = sorted({int(s) for e in baseline["families"].values() for s in e["seeds"]})
        today = measure(fams, seeds, Path(args.root or "out/fidelity_compare"), args.fresh, args.workers)
        out = Path(args.root or "out/fidelity_compare") / "compared.json"
        out.write_text(json.dumps(today, indent=1) + "\n")
    rows = compare(baseline, today)
    print(compare_table(rows))
    bad = worse_families(rows)
    print(f"baseline {baseline.get('code', '?')} ({baseline.get('made', '?')}) against {today.get('code', '?')}: " + (f"WORSE: {', '.join(bad)}" if bad else "no family got worse"))
    return 1 if bad else 0


if __name__ == "__main__":
    raise SystemExit(main())
