"""Benchmark: ``.blend`` families. The fixtures of ``tests/fixtures/blend`` are built, then:

- the Blender process's start (process, ``bpy`` import, file open);
- one evaluated shape, round trip through the pipe and Blender's own evaluation, for the small vase
  and the heavier pumpkin at three resolutions (random parameters, median over repeats);
- a whole family build from ``pumpkin.blend`` (every stage, seconds per stage), in one process and,
  with ``--ray``, on a private local Ray with 2 CPUs.

    .venv/bin/python tests/bench/bench_blender.py --out out/bench/blender.json [--ray] [--n-train 12]
"""

from __future__ import annotations

import argparse
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))

from harness import report, timeit  # noqa: E402

FIXTURES = HERE.parent / "fixtures" / "blend" / "make_fixtures.py"


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", default="out/bench/blender.json")
    ap.add_argument("--repeats", type=int, default=20)
    ap.add_argument("--n-train", type=int, default=12)
    ap.add_argument("--n-test", type=int, default=4)
    ap.add_argument("--ray", action="store_true", help="also build on a local Ray with 2 CPUs")
    args = ap.parse_args(argv)

    from proctex.sources.blender import BlenderModel, BlenderSession, blender_python

    python = blender_python()
    if python is None:
        raise SystemExit("no Python with bpy: make blender")
    work = Path(tempfile.mkdtemp(prefix="bench-blender-"))
    subprocess.run([python, str(FIXTURES), str(work)], check=True, capture_output=True, timeout=300)
    results, notes = {}, {}

    results["process start and file open (pumpkin.blend)"] = timeit(lambda: BlenderSession(work / "pumpkin.blend", "Pumpkin").close(), repeats=5, warmup=1)
    cases = [("vase.blend", "Vase", {}), ("pumpkin.blend", "Pumpkin", {"Resolution": 24}), ("pumpkin.blend", "Pumpkin", {"Resolution": 48}), ("pumpkin.blend", "Pumpkin", {"Resolution": 96})]
    for file, obj, pins in cases:
        model = BlenderModel(work / file, obj, pins=pins)
        draws = iter(model.space.sample(10 * args.repeats, seed=0))
        own: list[float] = []
        faces: list[int] = []

        def one() -> None:
            shape = model.generate(next(draws))
            own.append(model.last_seconds)
            faces.append(shape.n_faces)

        label = f"{obj.lower()}{' ' + str(pins) if pins else ''}"
        results[f"one shape, round trip: {label}"] = timeit(one, repeats=args.repeats, warmup=2)
        own = own[2:]  # the warm-up calls' times out
        q1, q3 = np.percentile(own, [25, 75])
        results[f"one shape, Blender's evaluation: {label}"] = {
            "median": float(np.median(own)),
            "p10": float(np.percentile(own, 10)),
            "p90": float(np.percentile(own, 90)),
            "min": float(min(own)),
            "max": float(max(own)),
            "mean": float(np.mean(own)),
            "repeats": len(own),
            "spread": float((q3 - q1) / np.median(own)),
        }
        notes[f"triangles: {label}"] = int(np.median(faces))
        model.close()

    from proctex.build.pipeline import build
    from proctex.store.config import BuildConfig
    from proctex.store.layout import FamilyStore

    data = {
        "source": {"blender": {"file": str(work / "pumpkin.blend"), "object": "Pumpkin", "uv": "UVMap", "pins": {"Resolution": 48}}, "n_train": args.n_train, "n_test": args.n_test},
        "paint": {"prompt": "an orange pumpkin with a green stem", "texture_size": 256},
        "corr_points": 1000,
        "cage": {"iterations": 100},
        "train": {"iterations": 300},
    }
    cfg = BuildConfig.from_dict(data)
    stages = ("sample", "template", "paint", "pairs", "train", "evaluate")
    t0 = time.perf_counter()
    state = build(FamilyStore(work / "local"), cfg, stages=stages, log=lambda *_: None)
    notes["build, one process: total seconds"] = round(time.perf_counter() - t0, 2)
    notes["build, one process: wall seconds per stage"] = state["wall_seconds"]
    notes["build: template groups, test metrics"] = [state["stages"]["paint"].get("groups"), state["stages"]["evaluate"]]
    if args.ray:
        import ray

        from workflows.build import build_on_ray

        ray.init(address="local", num_cpus=2, include_dashboard=False, log_to_driver=False)
        t0 = time.perf_counter()
        ray_state = build_on_ray(str(work / "ray"), cfg, stages=stages, train_workers=2, quiet=True, log=lambda *_: None)
        notes["build, Ray 2 CPUs: total seconds"] = round(time.perf_counter() - t0, 2)
        notes["build, Ray 2 CPUs: wall seconds per stage"] = ray_state["wall_seconds"]
        ray.shutdown()
    print(notes, flush=True)
    report("blender", {"repeats": args.repeats, "n_train": args.n_train, "n_test": args.n_test, "build": data}, results, args.out, notes)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
