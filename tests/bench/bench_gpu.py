"""Benchmark: the torch steps on CUDA against the CPU, in one run on one machine (for a session that is
lent a GPU): a sofa cage pair, one ProcCorrNet training, and a transfer through a family's service.

    .venv/bin/python tests/bench/bench_gpu.py --family out/bench/gen_families/sofa --out out/bench/gpu.json

Without ``--family`` a small sofa family is built first. Each row is the median of ``--repeats`` runs
after a warm-up. The CUDA column is skipped (and says so) where no CUDA device exists.
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))
sys.path.insert(0, str(HERE.parents[1]))

from harness import machine, timeit, versions, write_json  # noqa: E402


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--family", help="a built family (default: build a small sofa family first)")
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--train-iterations", type=int, default=300)
    ap.add_argument("--pairs", type=int, default=16, help="cage pairs of the family's group with the most, solved one at a time and batched (0: no such rows)")
    ap.add_argument("--out", default="out/bench/gpu.json")
    args = ap.parse_args(argv)

    import torch

    from proctex.build.pipeline import build
    from proctex.build.groupdata import group_training_data
    from proctex.correspond.cage import CageConfig
    from proctex.correspond.corrnet import CorrNetConfig
    from proctex.correspond.dense import correspond_parts
    from proctex.correspond.training import train
    from proctex.geometry.parts import analyse
    from proctex.models import get_model
    from proctex.serve.service import FamilyService
    from proctex.store.config import BuildConfig
    from proctex.store.layout import FamilyStore
    from proctex.store.state import stored_config

    family = args.family
    if family is None:
        family = str(Path(tempfile.mkdtemp(prefix="bench-gpu-")) / "sofa")
        cfg = BuildConfig.from_dict(
            {"model": "sofa", "n_train": 6, "n_test": 0, "prompt": "a patchwork bohemian sofa", "texture_size": 512, "corr_points": 1000, "cage": {"iterations": 100}, "train": {"iterations": 100}}
        )
        build(FamilyStore(family), cfg, stages=("sample", "template", "paint", "pairs", "train"), log=lambda *_: None)
    store = FamilyStore(family)
    config = stored_config(store)
    devices = ["cpu"] + (["cuda"] if torch.cuda.is_available() else [])

    model = get_model("sofa")
    a, b = model.generate(model.space.sample(2, seed=1)[0]), model.generate(model.space.sample(2, seed=1)[1])
    pa, pb = analyse(a).parts, analyse(b).parts
    big_a, big_b = max(pa, key=lambda p: p.area), max(pb, key=lambda p: p.area)

    def part(shape, p):
        lookup = np.full(shape.n_vertices, -1)
        lookup[p.vertices] = np.arange(len(p.vertices))
        return shape.vertices[p.vertices], lookup[shape.faces[p.faces]]

    sv, sf = part(a, big_a)
    tv, tf = part(b, big_b)
    data = group_training_data(store, config, min(int(k) for k in store.read_json("family.json")["stages"]["train"]["groups"]))
    try:
        shape = FamilyService(store).shape_from_params(model.space.sample(1, seed=7)[0])
    except ValueError:  # a family of exported meshes (the sofa export): one of its own test shapes
        from proctex.store.samples import load_sample, samples

        shape = load_sample(store, samples(store)[-1], config)
    results = {}
    for device in devices:
        cage = CageConfig(iterations=100, device=device)
        results[f"cage pair (sofa's largest part, 2,000 points, 100 iterations), {device}"] = timeit(lambda: correspond_parts(sv, sf, tv, tf, n_points=2000, cage=cage), repeats=args.repeats, warmup=1)
        net = CorrNetConfig(**{**config.train.to_dict(), "device": device, "iterations": args.train_iterations, "plain_below": 0.0})  # trained even where the box map fits
        results[f"ProcCorrNet training, {args.train_iterations} iterations, {device}"] = timeit(lambda: train(data["train"], data["val"] or None, net), repeats=max(1, args.repeats // 2), warmup=0)
        svc = FamilyService(store, device=device)
        results[f"transfer (sofa, {shape.n_faces} faces), {device}"] = timeit(lambda: svc.textured(shape), repeats=args.repeats * 4, warmup=2)
    if args.pairs:
        results.update(batched_pairs(store, config, args.pairs, devices, args.repeats))
    for key, r in results.items():
        print(f"{key}: {1000 * r['median']:.1f} ms (p10 {1000 * r['p10']:.1f}, p90 {1000 * r['p90']:.1f})", flush=True)
    if "cuda" not in devices:
        print("no CUDA device here: CPU rows only", flush=True)
    write_json(
        args.out,
        {
            "benchmark": "gpu",
            "family": family,
            "devices": devices,
            "results": results,
            "machine": machine(),
            "versions": versions(),
            "gpu": torch.cuda.get_device_name(0) if "cuda" in devices else None,
            "time": time.strftime("%Y-%m-%d %H:%M:%S"),
        },
    )
    return 0


def batched_pairs(store, config, n: int, devices: list[str], repeats: int) -> dict:
    """Rows for ``n`` cage pairs of the family's own shapes onto its group with the most pairs:
    one at a time on a CPU core (the CPU build's way), batched on the CPU (host searches) and, where
    CUDA is, batched on it (device searches); each row's ``pair_ms``: its median per pair."""
    import dataclasses

    import torch

    from harness import timeit
    from proctex.build.pairs import pair_input
    from proctex.correspond.dense import correspond_parts, correspond_parts_batch
    from proctex.store.samples import load_sample, pair_seed, samples
    from proctex.transfer.assets import load_assets

    assets = load_assets(store)
    rows = samples(store)
    shapes = [load_sample(store, r, config) for r in rows[: 2 * n]]
    best: list = []
    for ga in assets.groups:
        if ga.degenerate:
            continue
        src = [(inp[1], inp[2], pair_seed(config, i, ga.group)) for i, s in enumerate(shapes) if (inp := pair_input(s, assets, ga.group)) is not None][:n]
        if len(src) > len(best):
            best, group = src, ga
    out = {}
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    try:
        cpu = dataclasses.replace(config.cage, device="cpu")
        runs = {
            f"cage pairs one at a time ({len(best)} pairs onto group {group.group}), cpu": lambda: [
                correspond_parts(v, f, group.vertices, group.faces, "cage", n_points=config.corr_points, seed=s, cage=cpu) for v, f, s in best
            ],
            f"cage pairs batched ({len(best)} pairs, host searches), cpu": lambda: correspond_parts_batch(best, group.vertices, group.faces, n_points=config.corr_points, cage=cpu, search="host"),
        }
        if "cuda" in devices:
            gpu = dataclasses.replace(config.cage, device="cuda")
            runs[f"cage pairs batched ({len(best)} pairs, device searches), cuda"] = lambda: correspond_parts_batch(best, group.vertices, group.faces, n_points=config.corr_points, cage=gpu)
        for key, fn in runs.items():
            out[key] = timeit(fn, repeats=max(1, repeats), warmup=1)
            out[key]["pair_ms"] = round(1000 * out[key]["median"] / max(len(best), 1), 2)
    finally:
        torch.set_num_threads(threads)
    return out


if __name__ == "__main__":
    raise SystemExit(main())
