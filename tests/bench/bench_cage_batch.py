"""Benchmark: a family's cage pairs of one group solved one by one or batched (``solve_cages``).

Loads ``--shapes`` train shapes of a built family, takes each one's part of template group
``--group`` and solves the pairs with :func:`proctex.correspond.dense.correspond_parts` one after the
other, then with :func:`proctex.correspond.dense.correspond_parts_batch` in batches of ``--batch``
(on one torch thread); prints the wall time per pair of each, the iterations, and how far the
batched maps are from the single ones (mean distance over the pair's mean displacement).

    .venv/bin/python tests/bench/bench_cage_batch.py out/bench/looks/family --group 1 --shapes 8 --batch 1,4,8
"""

from __future__ import annotations

import argparse
import sys
import time

import numpy as np


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("family", help="a built family (read only)")
    ap.add_argument("--group", type=int, default=0)
    ap.add_argument("--shapes", type=int, default=8)
    ap.add_argument("--batch", default="4,8")
    args = ap.parse_args(argv)

    import torch

    from proctex.build.pairs import pair_input
    from proctex.correspond.dense import correspond_parts, correspond_parts_batch
    from proctex.store.layout import FamilyStore
    from proctex.store.samples import load_sample, pair_seed, samples
    from proctex.store.state import FamilyState
    from proctex.transfer.assets import load_assets

    torch.set_num_threads(1)
    store = FamilyStore(args.family)
    config = FamilyState.load(store).build_config()
    assets = load_assets(store)
    ga = assets.groups[args.group]
    sources = []
    for i, row in enumerate(samples(store)):
        inp = pair_input(load_sample(store, row, config), assets, args.group)
        if inp is not None:
            sources.append((inp[1], inp[2], pair_seed(config, i, args.group)))
        if len(sources) == args.shapes:
            break
    correspond_parts(*sources[0][:2], ga.vertices, ga.faces, "cage", n_points=config.corr_points, seed=0, cage=config.cage)  # warm-up
    t = time.perf_counter()
    single = [correspond_parts(v, f, ga.vertices, ga.faces, "cage", n_points=config.corr_points, seed=s, cage=config.cage) for v, f, s in sources]
    one = (time.perf_counter() - t) / len(sources)
    print(f"group {args.group}: {len(sources)} pairs, {config.corr_points} points; one by one {one:.3f} s a pair, iterations {[r.iterations for r in single]}", flush=True)
    for b in (int(x) for x in args.batch.split(",")):
        t = time.perf_counter()
        out = []
        for k in range(0, len(sources), b):
            out += correspond_parts_batch(sources[k : k + b], ga.vertices, ga.faces, n_points=config.corr_points, cage=config.cage)
        per = (time.perf_counter() - t) / len(sources)
        gap = [float(np.linalg.norm(o.points - s.points, axis=1).mean() / max(np.linalg.norm(s.points - s.source_points, axis=1).mean(), 1e-12)) for o, s in zip(out, single)]
        print(f"  batches of {b}: {per:.3f} s a pair ({one / per:.2f}x); iterations {[r.iterations for r in out]}; map gap / displacement: median {np.median(gap):.3%}, max {max(gap):.3%}", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
