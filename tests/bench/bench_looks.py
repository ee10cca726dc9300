"""Benchmark: a family's build against a new look of it (issue 35), in one run on one machine.

Builds a family in process (the demo preset by default: the sofa model, 10 training shapes, every
stage but the evaluation), timing each stage, then adds looks with other prompts and times each
(``proctex.looks.add_look``: the stored template painted again, nothing else). With
``--family``, a family built before is copied and given looks (its build is not rerun: its stage
records give no wall times, so only the look times are reported). Prints a table and writes JSON.

    .venv/bin/python tests/bench/bench_looks.py --out out/bench/looks_demo.json
    .venv/bin/python tests/bench/bench_looks.py --family out/fidelity_real2/sofa --out out/bench/looks_sofa.json
"""

from __future__ import annotations

import argparse
import shutil
import statistics
import sys
import time
from dataclasses import replace
from pathlib import Path

from harness import machine, write_json

PROMPTS = ("dark walnut wood", "white oak", "red velvet")


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--family", help="a built family to add looks to (copied first)")
    ap.add_argument("--preset", default="demo")
    ap.add_argument("--work", default="out/bench/looks")
    ap.add_argument("--out", default="")
    args = ap.parse_args(argv)

    from proctex.looks import add_look
    from proctex.build.pipeline import build
    from proctex.store.config import BuildConfig
    from proctex.store.layout import FamilyStore
    from proctex.store.state import FamilyState

    work = Path(args.work)
    shutil.rmtree(work, ignore_errors=True)
    walls: dict[str, float] = {}
    if args.family:
        shutil.copytree(args.family, work / "family")
        store = FamilyStore(work / "family")
        name = str(args.family)
    else:
        store = FamilyStore(work / "family")
        config = BuildConfig.from_dict({}, preset=args.preset)
        walls = build(store, config, stages=("sample", "template", "paint", "pairs", "train"), log=lambda *_: None)["wall_seconds"]
        name = f"preset {args.preset}"
    paint = FamilyState.load(store).build_config().paint
    looks = []
    for k, prompt in enumerate(PROMPTS):
        t = time.perf_counter()
        add_look(store, f"look{k}", replace(paint, prompt=prompt), log=lambda *_: None)
        looks.append(time.perf_counter() - t)
    build_total = sum(walls.values())
    report = {
        "family": name,
        "build_stage_seconds": walls,
        "build_seconds": round(build_total, 2),
        "look_seconds": [round(x, 2) for x in looks],
        "look_median_seconds": round(statistics.median(looks), 2),
        "look_share_of_build": round(statistics.median(looks) / build_total, 4) if build_total else None,
        "machine": machine(),
        "time": time.strftime("%Y-%m-%d %H:%M:%S"),
    }
    print(
        f"{name}: build {build_total:.1f} s ({', '.join(f'{k} {v:.1f}' for k, v in walls.items())}); "
        f"look add {', '.join(f'{x:.2f}' for x in looks)} s (median {statistics.median(looks):.2f} s" + (f", {100 * report['look_share_of_build']:.1f}% of the build)" if build_total else ")")
    )
    if args.out:
        write_json(args.out, report)
    return 0


if __name__ == "__main__":
    sys.exit(main())
