"""Benchmark: the Ray Serve transfer endpoint over HTTP on 127.0.0.1.

Starts a private local Ray with Serve over a store root, warms the family up, then for each
concurrency level sends requests from that many client threads: sofa meshes (multipart uploads of
the inference split) for a folder family, random parameter settings for a model family. Reports
latency p50 / p90 / p99 and requests per second per level (saturation = the best level), as JSON,
with where the time went per stage (the answers' Server-Timing: the proxy, the ingress, the hop to
the replica, the route's stages) and, in the same run before Ray starts, the same requests in
process (shape, transfer, GLB).

    .venv/bin/python tests/bench/bench_serve.py --root out/families --family sofa --out out/bench_serve.json
    .venv/bin/python tests/bench/bench_serve.py --root out/families --family chair --requests 200 --concurrency 1,2,4,8
"""

from __future__ import annotations

import argparse
import json
import platform
import socket
import statistics
import sys
import time
import urllib.error
import urllib.request
import uuid
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(Path(__file__).resolve().parents[2]))  # the repository root (tests.data)
from tests.data import SOFA  # noqa: E402


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _multipart(name: str, data: bytes) -> tuple[bytes, str]:
    boundary = uuid.uuid4().hex
    body = (f'--{boundary}\r\nContent-Disposition: form-data; name="mesh"; filename="{name}"\r\nContent-Type: application/octet-stream\r\n\r\n').encode() + data + f"\r\n--{boundary}--\r\n".encode()
    return body, f"multipart/form-data; boundary={boundary}"


#: The route's own stages in the order a request meets them (proctex.serve.timing; workers/http/routes/transfer.py).
ROUTE_STAGES = ("family", "body", "queue", "thread", "generate", "parse", "segment", "assign", "map", "uv", "new", "glb")


def stage_breakdown(answers: list[tuple[float, dict[str, float]]]) -> dict[str, float]:
    """Median ms per stage of the answers ``(client ms, Server-Timing stages)``, from the client in:
    ``proxy`` (the client's time less the ingress's: HTTP, Serve's proxy and its call of the
    ingress), ``ingress-body``, ``hop`` (the ingress's forwarding round trip less the replica's run:
    the handle call, the request and answer between processes), ``asgi`` (the replica's run less the
    route's: the ASGI app around the route), the route's stages, ``route-other`` (the route's time
    in none of its stages), ``client`` (the whole)."""
    if not answers:
        return {}
    rows: dict[str, list[float]] = {}

    def put(key: str, value: float) -> None:
        rows.setdefault(key, []).append(value)

    for total, st in answers:
        if "ingress" in st:
            put("proxy", total - st["ingress"])
            put("ingress-body", st.get("ingress-body", 0.0))
            put("hop", st.get("forward", 0.0) - st.get("replica", 0.0))
        if "replica" in st and "app" in st:
            put("asgi", st["replica"] - st["app"])
        for k in ROUTE_STAGES:
            if k in st:
                put(k, st[k])
        if "app" in st:
            put("route-other", st["app"] - sum(st.get(k, 0.0) for k in ROUTE_STAGES))
        put("client", total)
    return {k: float(np.median(v)) for k, v in rows.items()}


def in_process_ms(svc, payloads: list[tuple[bytes, str]], n: int, linked: bool) -> dict[str, float]:
    """The same requests in this process with no HTTP: the shape (generated from the parameters, or
    the upload parsed here), the transfer and the GLB, as the route does them; medians of ``n``."""
    from proctex.geometry.meshio import load_mesh_bytes

    def shape_of(body: bytes, ctype: str):
        if ctype == "application/json":
            return svc.shape_from_params(json.loads(body)["params"])
        head, _, rest = body.partition(b"\r\n\r\n")
        data = rest[: rest.rindex(b"\r\n--")]
        return svc.check_shape(load_mesh_bytes(data, "upload.obj", groups=True)[0])

    times = []
    for i in range(n + 4):
        body, ctype = payloads[i % len(payloads)]
        t = time.perf_counter()
        svc.transfer(shape_of(body, ctype), linked=linked)
        if i >= 4:  # the first few warm the caches
            times.append(1000 * (time.perf_counter() - t))
    return {"p50_ms": float(np.median(times)), "p10_ms": float(np.percentile(times, 10)), "p90_ms": float(np.percentile(times, 90)), "n": len(times)}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--root", required=True, help="store root holding family folders")
    ap.add_argument("--family", required=True)
    ap.add_argument("--requests", type=int, default=120, help="requests per concurrency level")
    ap.add_argument("--concurrency", default="1,2,4,8")
    ap.add_argument("--replicas", type=int, default=1)
    ap.add_argument("--sofa", default=str(SOFA))
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--textures", choices=["embedded", "linked"], default="embedded", help="answers with the textures, or referring to them")
    ap.add_argument("--out", default="")
    args = ap.parse_args(argv)

    import ray
    from ray import serve

    from proctex.serve.catalog import Catalog
    from proctex.serve.timing import parse_server_timing
    from workers.serve import build_app

    svc = Catalog(args.root).get(args.family)
    rng = np.random.default_rng(args.seed)
    if svc.model is None:
        meshes = sorted(Path(args.sofa, "inference").glob("*.obj"))
        payloads = [_multipart(p.name, p.read_bytes()) for p in meshes]
    else:
        space = svc.model.space
        payloads = [(json.dumps({"params": p}).encode(), "application/json") for p in space.sample(64, seed=args.seed)]
    inproc = in_process_ms(svc, payloads, args.requests, args.textures == "linked")
    print(f"in process (shape, transfer, GLB; no HTTP): median {inproc['p50_ms']:.1f} ms (p10 {inproc['p10_ms']:.1f}, p90 {inproc['p90_ms']:.1f})", flush=True)
    ray.init(address="local", include_dashboard=False, log_to_driver=False)
    port = _free_port()
    serve.start(http_options={"host": "127.0.0.1", "port": port})
    serve.run(build_app({"root": str(Path(args.root).resolve()), "replicas": args.replicas, "max_ongoing_requests": 16}), name="bench", route_prefix="/")
    url = f"http://127.0.0.1:{port}/v1/families/{args.family}/transfer?textures={args.textures}"
    sizes: list[int] = []

    def call(i: int) -> tuple[float, int, dict[str, float]]:
        body, ctype = payloads[i % len(payloads)]
        req = urllib.request.Request(url, data=body, headers={"content-type": ctype}, method="POST")
        t = time.perf_counter()
        stages: dict[str, float] = {}
        try:
            with urllib.request.urlopen(req, timeout=120) as r:
                sizes.append(len(r.read()))
                code = r.status
                stages = parse_server_timing(", ".join(r.headers.get_all("server-timing") or []))
        except urllib.error.HTTPError as e:
            code = e.code
        return time.perf_counter() - t, code, stages

    for i in range(8):  # warm-up
        call(i)
    levels = []
    for c in (int(x) for x in args.concurrency.split(",")):
        order = rng.permutation(args.requests)
        t0 = time.perf_counter()
        with ThreadPoolExecutor(c) as pool:
            res = list(pool.map(call, order))
        wall = time.perf_counter() - t0
        lat = np.array([r[0] for r in res])
        errors = sum(r[1] != 200 for r in res)
        breakdown = stage_breakdown([(1000 * r[0], r[2]) for r in res if r[1] == 200])
        levels.append(
            {
                "concurrency": c,
                "requests": args.requests,
                "errors": int(errors),
                "rps": args.requests / wall,
                "p10_ms": 1000 * float(np.percentile(lat, 10)),
                "p25_ms": 1000 * float(np.percentile(lat, 25)),
                "p75_ms": 1000 * float(np.percentile(lat, 75)),
                "p50_ms": 1000 * float(np.percentile(lat, 50)),
                "p90_ms": 1000 * float(np.percentile(lat, 90)),
                "p99_ms": 1000 * float(np.percentile(lat, 99)),
                "mean_ms": 1000 * statistics.fmean(lat),
                "stages_ms": breakdown,
            }
        )
        print(f"concurrency {c}: p50 {levels[-1]['p50_ms']:.0f} ms, p99 {levels[-1]['p99_ms']:.0f} ms, {levels[-1]['rps']:.1f} req/s, {errors} errors", flush=True)
        print("  stages (median ms): " + ", ".join(f"{k} {v:.1f}" for k, v in breakdown.items()), flush=True)
    serve.shutdown()
    ray.shutdown()
    print(f"bytes per answer (median): {int(np.median(sizes))}", flush=True)
    best = max(levels, key=lambda lv: lv["rps"])
    report = {
        "benchmark": "serve",
        "family": args.family,
        "replicas": args.replicas,
        "textures": args.textures,
        "bytes_per_answer": int(np.median(sizes)),
        "levels": levels,
        "saturation_rps": best["rps"],
        "p50_ms_at_1": levels[0]["p50_ms"],
        "in_process": inproc,
        "http_over_in_process_at_1": levels[0]["p50_ms"] / inproc["p50_ms"],
        "p99_ms_at_1": levels[0]["p99_ms"],
        "machine": {"python": platform.python_version(), "cpus": __import__("os").cpu_count(), "ray": ray.__version__},
        "time": time.strftime("%Y-%m-%d %H:%M:%S"),
    }
    if args.out:
        Path(args.out).parent.mkdir(parents=True, exist_ok=True)
        Path(args.out).write_text(json.dumps(report, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
