"""Benchmark: the family build on a local Ray with 1 and with 2 CPUs (wall time per stage, speed-up).

For each CPU count a fresh store is built on a fresh private Ray instance (``num_cpus=N``; the
Ray Train job uses N workers). Reports the wall seconds of every stage and the speed-up of the
largest CPU count over the smallest, as JSON.

    .venv/bin/python tests/bench/bench_ray_build.py --model sofa --n-train 16 --n-test 0 --stages sample,template,paint,pairs,train --out out/bench_ray_build.json
    .venv/bin/python tests/bench/bench_ray_build.py --folder $PROCTEX_DATA/procedural_sofa --cpus 2 --out out/bench_ray_sofa.json
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import shutil
import time
from pathlib import Path


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    src = ap.add_mutually_exclusive_group(required=True)
    src.add_argument("--model")
    src.add_argument("--folder")
    ap.add_argument("--n-train", type=int, default=24)
    ap.add_argument("--n-test", type=int, default=8)
    ap.add_argument("--prompt", default="a patchwork bohemian sofa")
    ap.add_argument("--train-iterations", type=int, default=None)
    ap.add_argument("--stages", default="sample,template,paint,pairs,train,evaluate")
    ap.add_argument("--cpus", default="1,2")
    ap.add_argument("--work", default="out/bench_ray_build")
    ap.add_argument("--out", default="")
    args = ap.parse_args(argv)

    import ray

    from proctex.store.config import BuildConfig
    from workflows.build import build_on_ray

    data = {"prompt": args.prompt}
    if args.model:
        data.update(model=args.model, n_train=args.n_train, n_test=args.n_test)
    else:
        data.update(folder=os.path.abspath(args.folder))
    if args.train_iterations:
        data["train"] = {"iterations": args.train_iterations}
    config = BuildConfig.from_dict(data)
    stages = tuple(args.stages.split(","))
    runs = []
    for n in (int(c) for c in args.cpus.split(",")):
        root = Path(args.work) / f"cpus{n}"
        shutil.rmtree(root, ignore_errors=True)
        ray.init(address="local", num_cpus=n, include_dashboard=False, log_to_driver=False)
        t0 = time.perf_counter()
        state = build_on_ray(str(root), config, stages=stages, train_workers=n, quiet=True, log=lambda *_: None)
        total = time.perf_counter() - t0
        ray.shutdown()
        runs.append({"cpus": n, "wall_seconds": state["wall_seconds"], "total_seconds": total})
        print(f"{n} CPU(s): " + ", ".join(f"{k} {v:.1f}s" for k, v in state["wall_seconds"].items()) + f"; total {total:.1f}s", flush=True)
    report = {
        "benchmark": "ray_build",
        "config": data,
        "stages": list(stages),
        "runs": runs,
        "machine": {"python": platform.python_version(), "cpus": os.cpu_count(), "ray": ray.__version__},
        "time": time.strftime("%Y-%m-%d %H:%M:%S"),
    }
    if len(runs) > 1:
        lo, hi = runs[0], runs[-1]
        report["speedup"] = {k: lo["wall_seconds"][k] / hi["wall_seconds"][k] for k in lo["wall_seconds"] if hi["wall_seconds"].get(k)}
        report["speedup"]["total"] = lo["total_seconds"] / hi["total_seconds"]
        print("speed-up " + ", ".join(f"{k} {v:.2f}x" for k, v in report["speedup"].items()))
    if args.out:
        Path(args.out).parent.mkdir(parents=True, exist_ok=True)
        Path(args.out).write_text(json.dumps(report, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
