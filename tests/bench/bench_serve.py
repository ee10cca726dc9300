"""Benchmark: the Ray Serve transfer endpoint over HTTP on 127.0.0.1.

Starts ``proctex serve`` over a store root, warms the family up, then for each
concurrency level sends requests from that many client threads: sofa meshes (multipart uploads of
the inference split) for a folder family, random parameter settings for a model family. Reports
latency p50 / p90 / p99 and requests per second per level (saturation = the best level), as JSON,
with where the time went per stage (the answers' Server-Timing: the proxy, the ingress, the hop to
the replica, the route's stages) and the same requests in process (shape, transfer, GLB): once
before Ray starts, and, at 1 client, each request in process right after its HTTP answer: that
run's paired HTTP-over-in-process ratio (:func:`paired_ratio`; a machine whose speed drifts moves
both halves of a pair alike, which a figure taken minutes before the run does not).

    .venv/bin/python tests/bench/bench_serve.py --root out/families --family sofa --out out/bench_serve.json
    .venv/bin/python tests/bench/bench_serve.py --root out/families --family chair --requests 200 --concurrency 1,2,4,8
    .venv/bin/python tests/bench/bench_serve.py --root out/families --family sofa --http front,serve --runs 2 --replicas 2 --concurrency 1,8
    .venv/bin/python tests/bench/bench_serve.py --root out/families --family sofa --in-process-only --before ../before --requests 100

The last: the in-process figures alone, of this checkout and an older one taking turns of
:data:`BLOCK` requests, each in a process of its own (:func:`alternated_in_process`).

Each run is ``proctex serve`` in a process of its own (``--http front``: its one-hop front;
``serve``: Ray Serve's proxy and the ingress deployment), started afresh and stopped after.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import signal
import socket
import statistics
import subprocess
import sys
import threading
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


def one_in_process(svc, body: bytes, ctype: str, linked: bool) -> tuple[float, float, float]:
    """One request (a JSON or multipart ``body``) in this process with no HTTP, as the route does
    it: ``(total, shape, transfer and GLB)`` in ms, the shape generated from the parameters or the
    upload parsed here."""
    from proctex.geometry.meshio import load_mesh_bytes

    t = time.perf_counter()
    if ctype == "application/json":
        shape = svc.shape_from_params(json.loads(body)["params"])
    else:
        _, _, rest = body.partition(b"\r\n\r\n")
        shape = svc.check_shape(load_mesh_bytes(rest[: rest.rindex(b"\r\n--")], "upload.obj", groups=True)[0])
    t_shape = time.perf_counter()
    _, summary = svc.transfer(shape, linked=linked)
    return 1000 * (time.perf_counter() - t), 1000 * (t_shape - t), 1000 * summary["seconds"]


def paired_ratio(http_ms: list[float], in_process_ms: list[float]) -> dict[str, float]:
    """HTTP over in process for requests timed in pairs (each request over HTTP, then the same
    request in process at once): the ratio of the two medians and the median of the per-request
    ratios. A drift of the machine's speed within the run moves both halves of a pair alike, which
    the ratio of figures taken minutes apart does not. ``ValueError`` for no pairs or lists of
    other lengths."""
    if not http_ms or len(http_ms) != len(in_process_ms):
        raise ValueError(f"paired_ratio needs pairs, got {len(http_ms)} and {len(in_process_ms)} figures")
    h, p = np.asarray(http_ms, dtype=float), np.asarray(in_process_ms, dtype=float)
    return {
        "http_p50_ms": float(np.median(h)),
        "in_process_p50_ms": float(np.median(p)),
        "ratio_of_medians": float(np.median(h) / np.median(p)),
        "median_ratio": float(np.median(h / p)),
    }


def in_process_ms(svc, payloads: list[tuple[bytes, str]], n: int, linked: bool) -> dict[str, float]:
    """The same requests in this process with no HTTP (:func:`one_in_process`); medians of ``n``."""
    times, shaping, texturing = [], [], []
    for i in range(n + 4):
        total, shape_ms, texture_ms = one_in_process(svc, *payloads[i % len(payloads)], linked)
        if i >= 4:  # the first few warm the caches
            times.append(total)
            shaping.append(shape_ms)
            texturing.append(texture_ms)
    out = {"p50_ms": float(np.median(times)), "p10_ms": float(np.percentile(times, 10)), "p90_ms": float(np.percentile(times, 90)), "n": len(times)}
    # apart: the shape (generated, or the upload parsed) and its texturing (the transfer and the GLB)
    out["shape_p50_ms"] = float(np.median(shaping))
    out.update({f"transfer_{q}_ms": float(np.percentile(texturing, int(q[1:]))) for q in ("p10", "p50", "p90")})
    return out


#: Requests per turn when two checkouts' in-process figures are alternated (:func:`alternated_in_process`).
BLOCK = 10


def payloads_of(svc, sofa: str, seed: int) -> list[tuple[bytes, str]]:
    """The requests a run sends: the sofa export's inference meshes as uploads for a folder family,
    64 random parameter settings (``seed``) for a model family."""
    if svc.model is None:
        return [_multipart(p.name, p.read_bytes()) for p in sorted(Path(sofa, "inference").glob("*.obj"))]
    return [(json.dumps({"params": p}).encode(), "application/json") for p in svc.model.space.sample(64, seed=seed)]


def in_process_worker(args) -> int:
    """``--in-process-worker``: the requests in process with the code of the checkout ``--code``
    (first on the import path), :data:`BLOCK` at a time each time a line arrives on stdin, each
    block's ``[total, shape, transfer and GLB]`` ms as a JSON line on stdout; "ready" once the
    family is loaded and warm. Ends at end of input."""
    sys.path.insert(0, str(Path(args.code).resolve()))
    from proctex.serve.catalog import Catalog

    svc = Catalog(args.root).get(args.family)
    payloads = payloads_of(svc, args.sofa, args.seed)
    linked = args.textures == "linked"
    for i in range(4):  # the first few warm the caches
        one_in_process(svc, *payloads[i % len(payloads)], linked)
    print("ready", flush=True)
    i = 0
    for _ in sys.stdin:
        block = []
        for _ in range(BLOCK):
            block.append(one_in_process(svc, *payloads[i % len(payloads)], linked))
            i += 1
        print(json.dumps(block), flush=True)
    return 0


def alternated_in_process(args, checkouts: dict[str, Path]) -> dict[str, dict]:
    """The in-process figures of each checkout (``{mode: checkout}``), each in a process of its own
    started once, taking turns of :data:`BLOCK` requests until each made ``--requests``: the
    machine's drift within the run reaches every checkout alike (a figure taken minutes apart does
    not). Per checkout its medians and spread (as :func:`in_process_ms`), and per mode after the
    first its ``paired`` ratio over the first's (:func:`paired_ratio` of the turns' medians)."""
    procs = {}
    for mode, code in checkouts.items():
        cmd = [sys.executable, str(Path(__file__).resolve()), "--in-process-worker", "--code", str(code), "--root", args.root, "--family", args.family, "--sofa", args.sofa]
        cmd += ["--seed", str(args.seed), "--textures", args.textures]
        procs[mode] = subprocess.Popen(cmd, stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True, env={**os.environ, "PYTHONPATH": str(code)})
    try:
        for mode, proc in procs.items():
            if proc.stdout.readline().strip() != "ready":
                raise SystemExit(f"the in-process worker of {mode} ({checkouts[mode]}) did not start")
        rows: dict[str, list[list[float]]] = {mode: [] for mode in procs}
        turns: dict[str, list[float]] = {mode: [] for mode in procs}
        for _ in range(-(-args.requests // BLOCK)):
            for mode, proc in procs.items():
                proc.stdin.write("go\n")
                proc.stdin.flush()
                line = proc.stdout.readline()
                if not line:
                    raise SystemExit(f"the in-process worker of {mode} ({checkouts[mode]}) stopped (exit status {proc.wait(timeout=60)})")
                block = json.loads(line)
                rows[mode] += block
                turns[mode].append(float(np.median([r[2] for r in block])))
    finally:
        for proc in procs.values():
            proc.stdin.close()
            proc.wait(timeout=60)
    return alternated_figures(rows, turns)


def alternated_figures(rows: dict[str, list[list[float]]], turns: dict[str, list[float]]) -> dict[str, dict]:
    """:func:`alternated_in_process`'s figures from each mode's requests ``[total, shape, transfer
    and GLB]`` ms and its turns' medians (the same number of turns per mode, taken in turn): per
    mode its medians and spread, and after the first mode its ``paired`` ratio over the first."""
    out = {}
    first = next(iter(rows))
    for mode, got in rows.items():
        times, shaping, texturing = (np.array([r[k] for r in got]) for k in range(3))
        fig = {"p50_ms": float(np.median(times)), "p10_ms": float(np.percentile(times, 10)), "p90_ms": float(np.percentile(times, 90)), "n": len(times), "shape_p50_ms": float(np.median(shaping))}
        fig.update({f"transfer_{q}_ms": float(np.percentile(texturing, int(q[1:]))) for q in ("p10", "p50", "p90")})
        if mode != first:  # this checkout's turns over the first's, turn by turn
            pr = paired_ratio(turns[mode], turns[first])
            fig["paired"] = {"ratio_of_medians": pr["ratio_of_medians"], "median_ratio": pr["median_ratio"], "turns": len(turns[mode])}
        out[mode] = fig
    return out


def start_server(root: str, replicas: int, http: str, code: Path = ROOT) -> tuple[subprocess.Popen, str]:
    """``proctex serve ROOT`` of the checkout ``code`` in a process of its own (its private Ray),
    ``--http`` as given (``before``: no such option, the checkout's own default), on a free port;
    returns the process and its base URL once it says it serves."""
    port = _free_port()
    cmd = [sys.executable, "-m", "workflows.cli", "serve", root, "--port", str(port), "--replicas", str(replicas)] + ([] if http == "before" else ["--http", http])
    proc = subprocess.Popen(cmd, cwd=code, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, env={**os.environ, "PYTHONPATH": str(code)})
    lines = []
    deadline = time.monotonic() + 300
    while time.monotonic() < deadline:
        line = proc.stdout.readline()
        if not line and proc.poll() is not None:
            break
        lines.append(line)
        if line.startswith("serving "):
            threading.Thread(target=lambda: [None for _ in proc.stdout], daemon=True).start()  # keep draining its output
            return proc, f"http://127.0.0.1:{port}"
    proc.kill()
    raise SystemExit("proctex serve did not start:\n" + "".join(lines[-30:]))


def stop_server(proc: subprocess.Popen) -> None:
    proc.send_signal(signal.SIGINT)
    try:
        proc.wait(60)
    except subprocess.TimeoutExpired:
        proc.kill()
        proc.wait()


def measure(base: str, family: str, payloads: list, levels_spec: str, n: int, textures: str, seed: int, svc=None) -> tuple[list[dict], int]:
    """The concurrency levels against a server at ``base``: latency percentiles, rate and the
    stage breakdown per level; and the median answer's bytes. With the family's service ``svc``,
    the level of 1 client also times each request in this process right after its HTTP answer
    (the server idle meanwhile): its ``paired`` figures (:func:`paired_ratio`)."""
    from proctex.serve.timing import parse_server_timing

    url = f"{base}/v1/families/{family}/transfer?textures={textures}"
    rng = np.random.default_rng(seed)
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
    for c in (int(x) for x in levels_spec.split(",")):
        order = rng.permutation(n)
        paired: list[float] = []
        t0 = time.perf_counter()
        if c == 1 and svc is not None:  # each request over HTTP, then the same in process at once
            res = []
            for i in order:
                res.append(call(i))
                t_here = time.perf_counter()
                paired.append(one_in_process(svc, *payloads[i % len(payloads)], textures == "linked")[0])
                t0 += time.perf_counter() - t_here  # the rate counts the HTTP requests' time alone
        else:
            with ThreadPoolExecutor(c) as pool:
                res = list(pool.map(call, order))
        wall = time.perf_counter() - t0
        lat = np.array([r[0] for r in res])
        errors = sum(r[1] != 200 for r in res)
        levels.append(
            {
                "concurrency": c,
                "requests": n,
                "errors": int(errors),
                "rps": n / wall,
                **{f"p{q}_ms": 1000 * float(np.percentile(lat, q)) for q in (10, 25, 50, 75, 90, 99)},
                "mean_ms": 1000 * statistics.fmean(lat),
                "stages_ms": stage_breakdown([(1000 * r[0], r[2]) for r in res if r[1] == 200]),
            }
        )
        if paired:
            levels[-1]["paired"] = paired_ratio([1000 * r[0] for r in res], paired)
    return levels, int(np.median(sizes)) if sizes else 0


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--root", required=True, help="store root holding family folders")
    ap.add_argument("--family", required=True)
    ap.add_argument("--requests", type=int, default=120, help="requests per concurrency level")
    ap.add_argument("--concurrency", default="1,2,4,8")
    ap.add_argument("--replicas", type=int, default=1)
    ap.add_argument("--http", default="front", help="comma-separated: front (proctex serve's default), serve (Serve's proxy and the ingress deployment)")
    ap.add_argument("--runs", type=int, default=1, help="runs of each --http mode, alternated")
    ap.add_argument("--before", default="", help="a checkout of older code (git worktree): its proctex serve runs too, as mode 'before', alternated with the others")
    ap.add_argument("--sofa", default=str(SOFA))
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--textures", choices=["embedded", "linked"], default="embedded", help="answers with the textures, or referring to them")
    ap.add_argument("--out", default="")
    ap.add_argument("--in-process-only", action="store_true", help="the in-process figures alone (--requests of them), no server; with --before, both checkouts' alternated")
    ap.add_argument("--in-process-worker", action="store_true", help=argparse.SUPPRESS)
    ap.add_argument("--code", default=str(ROOT), help=argparse.SUPPRESS)
    args = ap.parse_args(argv)
    if args.in_process_worker:
        return in_process_worker(args)
    modes = [m.strip() for m in args.http.split(",") if m.strip()]
    if not modes or any(m not in ("front", "serve") for m in modes):
        raise SystemExit(f"--http takes front and/or serve, got {args.http!r}")
    if args.before:
        if not Path(args.before, "workflows", "cli.py").is_file():
            raise SystemExit(f"--before {args.before}: not a checkout of this project")
        modes = ["before", *modes]

    if args.in_process_only and args.before:
        figures = alternated_in_process(args, {"before": Path(args.before).resolve(), "after": ROOT})
        for mode, fig in figures.items():
            print(
                f"[{mode}] in process: the transfer and GLB median {fig['transfer_p50_ms']:.1f} ms (p10 {fig['transfer_p10_ms']:.1f}, p90 {fig['transfer_p90_ms']:.1f}), with the shape {fig['p50_ms']:.1f} ms",
                flush=True,
            )
            if "paired" in fig:
                print(f"  after over before, turn by turn: ratio of medians {fig['paired']['ratio_of_medians']:.3f}x, median ratio {fig['paired']['median_ratio']:.3f}x", flush=True)
        if args.out:
            Path(args.out).parent.mkdir(parents=True, exist_ok=True)
            Path(args.out).write_text(json.dumps({"benchmark": "serve", "family": args.family, "in_process_alternated": figures}, indent=1))
        return 0

    import ray

    from proctex.serve.catalog import Catalog

    svc = Catalog(args.root).get(args.family)
    payloads = payloads_of(svc, args.sofa, args.seed)
    inproc = in_process_ms(svc, payloads, args.requests, args.textures == "linked")
    print(f"in process (shape, transfer, GLB; no HTTP): median {inproc['p50_ms']:.1f} ms (p10 {inproc['p10_ms']:.1f}, p90 {inproc['p90_ms']:.1f})", flush=True)
    print(
        f"  of which the shape {inproc['shape_p50_ms']:.1f} ms; the transfer and GLB: median {inproc['transfer_p50_ms']:.1f} ms (p10 {inproc['transfer_p10_ms']:.1f}, p90 {inproc['transfer_p90_ms']:.1f})",
        flush=True,
    )
    if args.in_process_only:
        if args.out:
            Path(args.out).parent.mkdir(parents=True, exist_ok=True)
            Path(args.out).write_text(json.dumps({"benchmark": "serve", "family": args.family, "in_process": inproc}, indent=1))
        return 0
    runs = []
    root = str(Path(args.root).resolve())
    for k in range(args.runs):
        for mode in modes:
            proc, base = start_server(root, args.replicas, mode, Path(args.before).resolve() if mode == "before" else ROOT)
            try:
                levels, size = measure(base, args.family, payloads, args.concurrency, args.requests, args.textures, args.seed + k, svc)
            finally:
                stop_server(proc)
            runs.append({"http": mode, "run": k, "levels": levels, "bytes_per_answer": size})
            for lv in levels:
                print(f"[{mode} run {k}] concurrency {lv['concurrency']}: p50 {lv['p50_ms']:.1f} ms, p99 {lv['p99_ms']:.0f} ms, {lv['rps']:.1f} req/s, {lv['errors']} errors", flush=True)
                print("  stages (median ms): " + ", ".join(f"{s} {v:.1f}" for s, v in lv["stages_ms"].items()), flush=True)
                if "paired" in lv:
                    pr = lv["paired"]
                    print(
                        f"  paired with in process: {pr['http_p50_ms']:.1f} / {pr['in_process_p50_ms']:.1f} ms, ratio of medians {pr['ratio_of_medians']:.2f}x, median ratio {pr['median_ratio']:.2f}x",
                        flush=True,
                    )
    report = {
        "benchmark": "serve",
        "family": args.family,
        "replicas": args.replicas,
        "textures": args.textures,
        "in_process": inproc,
        "runs": runs,
        "summary": {
            mode: {
                "p50_ms_at_1": [r["levels"][0]["p50_ms"] for r in runs if r["http"] == mode],
                "rps_at_max": [r["levels"][-1]["rps"] for r in runs if r["http"] == mode],
                "in_process_p50_ms": [lv["paired"]["in_process_p50_ms"] for r in runs if r["http"] == mode for lv in r["levels"] if "paired" in lv],
                "paired_ratio_at_1": [lv["paired"]["ratio_of_medians"] for r in runs if r["http"] == mode for lv in r["levels"] if "paired" in lv],
            }
            for mode in modes
        },
        "machine": {"python": platform.python_version(), "cpus": os.cpu_count(), "ray": ray.__version__},
        "time": time.strftime("%Y-%m-%d %H:%M:%S"),
    }
    print(json.dumps(report["summary"]), flush=True)
    if args.out:
        Path(args.out).parent.mkdir(parents=True, exist_ok=True)
        Path(args.out).write_text(json.dumps(report, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
