"""Benchmark: a whole family build, stage by stage, in process or on a local Ray, with its figures.

Builds a fresh store for each ``--runs`` entry (``process``: :func:`proctex.build.pipeline.build`
with ``--workers`` worker processes; ``ray``: :func:`workflows.build.build_on_ray` on a private local
Ray of ``--cpus`` CPUs, as many Ray Train workers) and prints the wall seconds of every stage, the
total and what the evaluate stage measured on the test shapes (ground-truth and pseudo-ground-truth
mean error, tracked-point variance), so a faster build shows it is no worse. ``--repeats`` builds
each run that many times and reports the median total.

    .venv/bin/python tests/bench/bench_build.py --preset demo --runs process,ray --out out/bench/build_demo.json
    .venv/bin/python tests/bench/bench_build.py --folder $PROCTEX_DATA/procedural_sofa --runs process,ray --out out/bench/build_sofa.json
    .venv/bin/python tests/bench/bench_build.py --preset demo --runs process --store s3 --out out/bench/build_demo_s3.json   # the S3 overhead
    .venv/bin/python tests/bench/bench_build.py --preset demo --runs head,cluster --store s3 --out out/bench/build_demo_nodes.json  # one node vs two
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import shutil
import statistics
import sys
import time
from pathlib import Path
from typing import Any


def figures(state: dict[str, Any]) -> dict[str, Any]:
    """The evaluate stage's measurements from a build's state (empty without the stage)."""
    ev = state.get("stages", {}).get("evaluate", {})
    if not ev:
        return {}
    return {"gt_mean": (ev.get("gt_error") or {}).get("mean"), "pgt_mean": (ev.get("pgt_error") or {}).get("mean"), "tracked_point_variance": ev.get("tracked_point_variance")}


def fresh(root: str) -> None:
    """An empty store root (a folder removed, or an object store prefix emptied)."""
    if "://" not in root:
        shutil.rmtree(root, ignore_errors=True)
        return
    from proctex.store.layout import FamilyStore

    st = FamilyStore(root)
    st.fs.delete_dir_contents(st.base, missing_dir_ok=True)


CLUSTER_PORT, CLUSTER_DASHBOARD = "6397", "8283"


def cluster(action: str, cpus: int, tmp: str, nodes: int = 2) -> None:
    """Start or stop a cluster on this machine (``cluster/local_cluster.sh``): a head and a worker node
    of ``cpus // 2`` CPUs each (``nodes`` 2), or a head alone with ``cpus`` (``nodes`` 1)."""
    import subprocess

    here = Path(__file__).resolve().parents[2]
    env = {**os.environ, "RAY_PORT": CLUSTER_PORT, "DASHBOARD_PORT": CLUSTER_DASHBOARD, "RAY_TMP": tmp, "RAY": str(here / ".venv" / "bin" / "ray")}
    args = (["start", "1", str(max(1, cpus // 2))] if nodes == 2 else ["start", "0", str(cpus)]) if action == "start" else ["stop"]
    subprocess.run(["bash", str(here / "cluster" / "local_cluster.sh"), *args], env=env, check=True, capture_output=True, timeout=300)


def build_once(kind: str, root: str, config: Any, workers: int, cpus: int, stages: tuple[str, ...] | None = None) -> dict[str, Any]:
    fresh(root)
    t0 = time.perf_counter()
    if kind == "process":
        from proctex.build.pipeline import build
        from proctex.build.plan import local_executor
        from proctex.store.layout import FamilyStore

        from proctex.store.state import STAGES

        state = build(FamilyStore(root), config, stages or STAGES, log=lambda *_: None, executor=local_executor(workers))
    elif kind in ("ray", "cluster", "head"):
        import ray

        from workflows.build import build_on_ray

        if kind == "ray":
            ray.init(address="local", num_cpus=cpus, include_dashboard=False, log_to_driver=False)
        else:  # a started cluster: a head alone, or a head and a worker node (the same cores: the multi-node overhead)
            ray.init(address=f"127.0.0.1:{CLUSTER_PORT}", log_to_driver=False)
        try:
            state = build_on_ray(str(root), config, train_workers=cpus, quiet=True, log=lambda *_: None)
        finally:
            ray.shutdown()
    else:
        raise ValueError(f"unknown run {kind!r}: process or ray")
    return {"wall_seconds": state["wall_seconds"], "total_seconds": round(time.perf_counter() - t0, 2), **figures(state)}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    src = ap.add_mutually_exclusive_group(required=True)
    src.add_argument("--preset", help="a named build preset (demo)")
    src.add_argument("--folder", help="a folder of exports (the real sofa)")
    ap.add_argument(
        "--runs",
        default="process",
        help="comma-separated: process, ray (a private local Ray, its start timed), head (a started one-node cluster), cluster (a started head and worker node on this machine, half the CPUs each)",
    )
    ap.add_argument("--store", choices=("folder", "s3"), default="folder", help="where the families go: folders under --work, or a local S3 server (SeaweedFS, started and stopped here)")
    ap.add_argument("--workers", type=int, default=2, help="in-process worker processes")
    ap.add_argument("--cpus", type=int, default=2, help="CPUs of the local Ray")
    ap.add_argument("--repeats", type=int, default=1)
    ap.add_argument("--stages", default="", help="comma-separated stages to run (in process only; default: all), e.g. sample,template,paint,pairs,train")
    ap.add_argument("--set", action="append", default=[], help='a config override as JSON, e.g. \'{"train": {"autocast": "none"}}\'')
    ap.add_argument("--work", default="out/bench/build")
    ap.add_argument("--out", default="")
    args = ap.parse_args(argv)

    from proctex.store.config import BuildConfig, merge, sections

    data: dict[str, Any] = {} if args.preset else {"source": {"folder": os.path.abspath(args.folder)}}
    for extra in args.set:
        data = merge(data, sections(json.loads(extra)))
    config = BuildConfig.from_dict(data, preset=args.preset)
    report: dict[str, Any] = {
        "benchmark": "build",
        "preset": args.preset,
        "config": data,
        "runs": {},
        "machine": {"python": platform.python_version(), "cpus": os.cpu_count()},
        "time": time.strftime("%Y-%m-%d %H:%M:%S"),
    }
    server = None
    if args.store == "s3":
        from workflows.objectstore import start_server

        server = start_server(Path(args.work) / "s3")
        os.environ.update(server.env())
        report["store"] = "s3 (SeaweedFS weed mini, loopback)"
    try:
        for kind in args.runs.split(","):
            builds = run_kind(kind, args, config, server)
            report["runs"][kind] = {"builds": builds, "median_total_seconds": statistics.median(b["total_seconds"] for b in builds)}
    finally:
        if server is not None:
            from workflows.objectstore import stop_server

            stop_server(server)
    for a, b in (("ray", "process"), ("cluster", "head")):
        if a in report["runs"] and b in report["runs"]:
            ratio = report["runs"][a]["median_total_seconds"] / report["runs"][b]["median_total_seconds"]
            report[f"{a}_over_{b}"] = round(ratio, 3)
            print(f"{a} / {b}: {ratio:.2f}")
    if args.out:
        from harness import write_json

        write_json(args.out, report)
    return 0


def run_kind(kind: str, args: Any, config: Any, server: Any) -> list[dict[str, Any]]:
    """``--repeats`` builds of one kind; the cluster started around them for ``cluster``."""
    import tempfile

    started = kind in ("cluster", "head")
    tmp = tempfile.mkdtemp(prefix="rayb", dir="/tmp") if started else ""
    if started:
        cluster("start", args.cpus, tmp, nodes=2 if kind == "cluster" else 1)
    builds = []
    try:
        for r in range(args.repeats):
            root = server.uri(f"bench/{kind}{r}") if server is not None else str(Path(args.work) / f"{kind}{r}")
            out = build_once(kind, root, config, args.workers, args.cpus, tuple(args.stages.split(",")) if args.stages else None)
            builds.append(out)
            stages = ", ".join(f"{k} {v:.1f}s" for k, v in out["wall_seconds"].items())
            figs = ", ".join(f"{k} {v:.5g}" for k, v in out.items() if k not in ("wall_seconds", "total_seconds") and v is not None)
            print(f"{kind} #{r + 1}: {stages}; total {out['total_seconds']:.1f}s; {figs}", flush=True)
    finally:
        if started:
            cluster("stop", args.cpus, tmp)
            shutil.rmtree(tmp, ignore_errors=True)
            shutil.rmtree(tmp + "-w0", ignore_errors=True)
    return builds


if __name__ == "__main__":
    sys.exit(main())
