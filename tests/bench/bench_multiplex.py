"""Benchmark: a cold against a warm family request on a multiplexed Serve replica.

One replica with room for one family serves two families. A request for the family it holds is
warm; alternating between the two makes every request cold (the family loads: template textures,
networks, model). Both are timed over HTTP, parameters chosen at random, medians over repeats.

    .venv/bin/python tests/bench/bench_multiplex.py --root out/bench/gen_families --families sofa,chair --repeats 10
"""

from __future__ import annotations

import argparse
import json
import socket
import sys
import time
import urllib.request
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))
sys.path.insert(0, str(HERE.parents[1]))

from harness import machine, versions, write_json  # noqa: E402


def _port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--root", required=True)
    ap.add_argument("--families", required=True, help="two family names under --root, comma-separated")
    ap.add_argument("--repeats", type=int, default=10)
    ap.add_argument("--out", default="out/bench/multiplex.json")
    args = ap.parse_args(argv)
    a, b = args.families.split(",")

    import ray
    from ray import serve

    from proctex.serve.catalog import Catalog
    from workers.serve import build_app

    specs = {n: Catalog(args.root).get(n).model.space for n in (a, b)}
    rng = np.random.default_rng(0)
    ray.init(address="local", num_cpus=2, include_dashboard=False, log_to_driver=False)
    port = _port()
    serve.start(http_options={"host": "127.0.0.1", "port": port})
    serve.run(build_app({"root": args.root, "replicas": "1", "max_families": "1"}), name="bench-mux", route_prefix="/")
    base = f"http://127.0.0.1:{port}"

    def request(family: str) -> float:
        params = specs[family].sample(1, seed=rng)[0]
        body = json.dumps({"params": {k: (v.item() if hasattr(v, "item") else v) for k, v in params.items()}}).encode()
        req = urllib.request.Request(f"{base}/v1/families/{family}/transfer", data=body, method="POST", headers={"content-type": "application/json", "serve_multiplexed_model_id": family})
        t0 = time.perf_counter()
        with urllib.request.urlopen(req, timeout=300) as r:
            r.read()
        return time.perf_counter() - t0

    try:
        results = {}
        for family in (a, b):
            request(family)  # load it
            results[f"warm {family}"] = [request(family) for _ in range(args.repeats)]
        cold = {a: [], b: []}
        for k in range(2 * args.repeats):
            family = (a, b)[k % 2]
            cold[family].append(request(family))
        for family in (a, b):
            results[f"cold {family}"] = cold[family]
        with urllib.request.urlopen(base + "/healthz", timeout=60) as r:
            health = json.loads(r.read())
    finally:
        serve.shutdown()
        ray.shutdown()
    summary = {k: {"median_ms": round(1000 * float(np.median(v)), 1), "p90_ms": round(1000 * float(np.percentile(v, 90)), 1), "n": len(v)} for k, v in results.items()}
    summary["loads"] = health["loads"]
    for k, v in summary.items():
        print(k, v, flush=True)
    write_json(args.out, {"benchmark": "multiplex", "root": args.root, "results": summary, "machine": machine(), "versions": versions(), "time": time.strftime("%Y-%m-%d %H:%M:%S")})
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
