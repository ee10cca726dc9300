"""Grouping many parts (issue 31): ``analyse`` on shapes of boxes, 100 / 1,000 / 10,000 parts, either
five kinds of box repeated or every box a little different (the worst case for rigid matching: every
pair passes the size prefilter).

    .venv/bin/python tests/bench/bench_grouping.py [--parts 100,1000,10000] [--repeats 1] [--out out/bench/grouping.json]
"""

from __future__ import annotations

import sys
from pathlib import Path


import harness
from harness import report, timeit

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))
from proctex.geometry.parts import analyse  # noqa: E402
from tests.meshes import boxes  # noqa: E402


def shapes(n: int) -> dict[str, object]:
    grid = [(i % 100 * 0.5, i // 100 * 0.5, 0.0) for i in range(n)]
    return {
        "5 kinds": boxes([((0.1 + 0.05 * (i % 5), 0.1, 0.1 + 0.02 * (i % 5)), c) for i, c in enumerate(grid)]),
        "every size different": boxes([((0.1 + 0.3 * i / n, 0.1, 0.05), c) for i, c in enumerate(grid)]),
    }


def run(args) -> dict:
    results, notes = {}, {}
    for n in (int(x) for x in args.parts.split(",")):
        for kind, shape in shapes(n).items():
            key = f"{n} parts, {kind}"
            results[key] = timeit(lambda: analyse(shape), repeats=args.repeats, warmup=0)
            notes[key] = {"groups": len(analyse(shape).groups), "faces": int(shape.n_faces)}
    return report("grouping", vars(args), results, args.out, notes)


def parser():
    ap = harness.parser(__doc__, repeats=1)
    ap.add_argument("--parts", default="100,1000,10000")
    return ap


if __name__ == "__main__":
    run(parser().parse_args())
    sys.exit(0)
