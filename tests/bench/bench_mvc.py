"""Mean value coordinates of surface samples w.r.t. the cage (the cage solver's setup and its
negative-MVC penalty): points x cage levels.

    .venv/bin/python tests/bench/bench_mvc.py [--points 2000] [--levels 0,1,2] [--out out/bench/mvc.json]
"""

from __future__ import annotations

import argparse
import sys

import numpy as np
import torch

import harness
from harness import report, timeit
from proctex.correspond.cage import init_cage
from proctex.correspond.mvc import mean_value_coordinates


def run(args) -> dict:
    torch.set_num_threads(args.threads)
    rng = np.random.default_rng(0)
    pts = rng.uniform(-1, 1, (args.points, 3))
    results, notes = {}, {}
    for level in (int(x) for x in args.levels.split(",")):
        cage_v, cage_f = init_cage(pts, level=level)
        results[f"level {level} ({len(cage_v)} cage vertices), {args.points} points"] = timeit(lambda: mean_value_coordinates(pts, cage_v, cage_f), repeats=args.repeats)
        notes[f"level {level}"] = {"cage_vertices": int(len(cage_v)), "cage_faces": int(len(cage_f))}
    return report("mvc", vars(args), results, args.out, notes)


def parser() -> argparse.ArgumentParser:
    ap = harness.parser(__doc__, repeats=7)
    ap.add_argument("--points", type=int, default=2000)
    ap.add_argument("--levels", default="0,1,2")
    ap.add_argument("--threads", type=int, default=1)
    return ap


if __name__ == "__main__":
    run(parser().parse_args())
    sys.exit(0)
