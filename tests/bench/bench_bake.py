"""Baking a transferred shape into its own atlas (xatlas + texel maps + template lookups +
dis-occlusion check), and the whole in-process transfer (segment, assign, map, UVs, GLB) of the
same shapes, per shape.

    .venv/bin/python tests/bench/bench_bake.py [--size 512] [--out out/bench/bake.json]
"""

from __future__ import annotations

import argparse
import sys

import harness
import torch
from fixtures import shapes, template
from harness import report, timeit

from proctex.correspond.corrnet import CorrNetConfig, build_model
from proctex.transfer.apply import bake, glb, transfer
from proctex.transfer.mappers import NetworkMapper


def run(args) -> dict:
    torch.set_num_threads(1)
    torch.manual_seed(0)
    _, _, _, assets = template(args.model, args.texture)
    nets = {g.group: build_model(CorrNetConfig()).eval() for g in assets.groups}  # untrained: same cost
    mapper = NetworkMapper(nets)
    items = shapes(args.model, args.shapes, seed=1)
    results_of = [transfer(s, assets, mapper, shortcut=False) for s in items]
    k = [0]

    def one_transfer():
        s = items[k[0] % len(items)]
        k[0] += 1
        glb(s, transfer(s, assets, mapper, shortcut=args.shortcut), assets)

    def one_bake():
        i = k[0] % len(items)
        k[0] += 1
        bake(items[i], results_of[i], assets, size=args.size)

    results = {
        f"transfer + GLB, {args.model}, network on every part": timeit(one_transfer, repeats=args.repeats * len(items)),
        f"bake into own {args.size}² atlas": timeit(one_bake, repeats=args.repeats * len(items)),
    }
    return report("bake_and_transfer", vars(args), results, args.out)


def parser() -> argparse.ArgumentParser:
    ap = harness.parser(__doc__, repeats=2)
    ap.add_argument("--model", default="chair")
    ap.add_argument("--shapes", type=int, default=4)
    ap.add_argument("--texture", type=int, default=512)
    ap.add_argument("--size", type=int, default=512)
    ap.add_argument("--shortcut", action="store_true", help="let same-connectivity parts take the template UVs (the run-time path)")
    return ap


if __name__ == "__main__":
    run(parser().parse_args())
    sys.exit(0)
