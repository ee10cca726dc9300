"""The ``proctex`` command with the Ray layer: every ``proctex.cli`` command, plus ``build --ray``
(the workflow of :mod:`workflows.build`) and ``serve`` (the Ray Serve application of
:mod:`workers.serve`). ``proctex.cli`` itself never imports Ray."""

from __future__ import annotations

import argparse
import dataclasses
import json
import os
import signal
import sys
import threading
from typing import Any, Callable

from proctex.cli import app as core
from proctex.cli import families


def cmd_build(args: argparse.Namespace) -> int:
    if args.ray is None:
        return families.cmd_build(args)
    from proctex.store.state import STAGES

    from .build import build_on_ray

    config = families.build_config_of(args)
    families.check_build_look(args)
    stages = tuple(args.stages.split(",")) if args.stages else STAGES
    address = None if args.ray == "local" else args.ray
    log = (lambda *_: None) if args.quiet else (lambda m: print(m, flush=True))
    state = build_on_ray(args.out, config, address=address, stages=stages, max_in_flight=args.max_in_flight, train_workers=args.train_workers, log=log, quiet=args.quiet)
    done = [k for k, v in state.get("stages", {}).items() if v.get("state") == "done"]
    walls = ", ".join(f"{k} {v:.1f}s" for k, v in state["wall_seconds"].items())
    print(f"family {args.out}: stages done: {', '.join(done)} (on Ray: {walls}){families.named_look(args)}")
    return 0


#: Seconds ``proctex serve`` gives Serve and Ray to stop after Ctrl-C before it exits anyway.
STOP_SECONDS = 10.0


def shutdown_within(stop: Callable[[], Any], seconds: float) -> bool:
    """Run ``stop`` in a thread and wait at most ``seconds``; True when it finished (a shutdown
    that hangs must not keep the command from exiting)."""
    t = threading.Thread(target=stop, name="shutdown", daemon=True)
    t.start()
    t.join(seconds)
    return not t.is_alive()


def cmd_serve(args: argparse.Namespace) -> int:
    import ray
    from ray import serve

    from proctex.serve.catalog import Catalog
    from proctex.serve.service import Limits
    from workers.serve import build_app

    if args.port < 1 or args.port > 65535:
        raise ValueError(f"--port must be in 1..65535, got {args.port}")
    if args.replicas < 0:
        raise ValueError(f"--replicas must be >= 0 (0: one per CPU), got {args.replicas}")
    names = Catalog(args.store).names()
    if not names:
        raise ValueError(f"{args.store}: no families found (sub-folders with a family.json)")
    app_args = {"root": os.path.abspath(args.store) if "://" not in args.store else args.store}
    token = args.edit_token or os.environ.get("PROCTEX_EDIT_TOKEN")
    if token is not None and len(token) < 8:
        raise ValueError("--edit-token must be at least 8 characters")
    if token:
        app_args["edit_token"] = token
    from workers.serve import limits_from

    for item in args.limit or []:
        key, sep, value = item.partition("=")
        if not sep or key not in {f.name for f in dataclasses.fields(Limits)}:
            raise ValueError(f"--limit takes NAME=VALUE with NAME one of {', '.join(f.name for f in dataclasses.fields(Limits))}, got {item!r}")
        app_args[key] = value
    limits_from(app_args)  # bad limits are said before Ray starts
    if args.max_families < 0:
        raise ValueError(f"--max-families must be >= 0 (0: every family, preloaded), got {args.max_families}")
    if args.max_families:
        app_args["max_families"] = args.max_families
    if args.device != "cpu":
        from proctex.correspond.corrnet import resolve_device

        resolve_device(args.device)  # CUDA asked for and absent: said before Ray starts
        app_args["device"] = args.device
    if args.autoscale:
        lo, hi = (int(x) for x in args.autoscale.split(","))
        app_args.update(min_replicas=lo, max_replicas=hi)
    else:
        # Transfers are CPU-bound and serialised per replica: one replica per core pays (sofa on
        # 2 cores: 9.9 req/s with one replica, 16.4 with two); batching requests does not (bench_batching.py).
        app_args["replicas"] = args.replicas or max(1, min(4, os.cpu_count() or 1))
    if args.http == "front":
        port_free(args.host, args.port)  # said before Ray starts
    if args.address:
        ray.init(address=args.address, log_to_driver=False)
    else:
        from workers.serve import RAY_SYSTEM_CONFIG

        from .build import start_private_ray

        start_private_ray(system_config=RAY_SYSTEM_CONFIG)
    banner = f"serving {', '.join(names)} on http://{args.host}:{args.port} (OpenAPI: /docs); Ctrl-C stops"
    try:
        if args.http == "front":
            from workers.front import deploy_transfer, front_app, run_until_signal, server

            serve.start(proxy_location="Disabled")
            srv = server(front_app(*deploy_transfer(app_args)), args.host, args.port)
            run_until_signal(srv, on_started=lambda: print(banner, flush=True))  # until SIGINT or SIGTERM, finishing the requests under way
        else:
            serve.start(http_options={"host": args.host, "port": args.port})
            serve.run(build_app(app_args), name="proctex", route_prefix="/")
            print(banner, flush=True)
            stop = threading.Event()
            for sig in (signal.SIGINT, signal.SIGTERM):
                signal.signal(sig, lambda *_: stop.set())
            while not stop.wait(1.0):
                pass
    finally:  # stopped, or failed to start: Serve and the private Ray go either way
        print("stopping: Serve shuts down, then Ray", flush=True)
        shutdown_within(lambda: (serve.shutdown(), ray.shutdown()), STOP_SECONDS)
    return 0


def port_free(host: str, port: int) -> None:
    """``ValueError`` when ``host:port`` cannot be listened on (taken, or no such address)."""
    import socket

    try:
        infos = socket.getaddrinfo(host, port, type=socket.SOCK_STREAM)
    except OSError as exc:
        raise ValueError(f"--host {host!r}: {exc}") from exc
    family, kind, proto, _, addr = infos[0]
    with socket.socket(family, kind, proto) as s:
        s.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        try:
            s.bind(addr)
        except OSError as exc:
            raise ValueError(f"cannot listen on {host}:{port}: {exc.strerror or exc}") from exc


def cmd_generate(args: argparse.Namespace) -> int:
    """``proctex generate`` on Ray Data (a private local Ray unless --address), or in this process
    with --no-ray."""
    if args.no_ray:
        return families.cmd_generate(args)
    from .generate import generate_on_ray, parse_concurrency

    settings = families.generate_settings(args)  # bad flags fail before Ray starts
    if args.cpus is not None and not 1 <= args.cpus <= 4096:
        raise ValueError(f"--cpus must be in 1..4096, got {args.cpus}")
    concurrency = parse_concurrency(args.concurrency, args.cpus or os.cpu_count() or 1) if args.concurrency else None
    log = (lambda *_: None) if args.quiet or args.json else (lambda m: print(m, flush=True))
    summary = generate_on_ray(settings, concurrency=concurrency, address=args.address, num_cpus=args.cpus, log=log, quiet=args.quiet or args.json)
    families.print_generate_summary(args, summary)
    return 0


def cmd_demo(args: argparse.Namespace) -> int:
    """The main job with the build on Ray (a private local instance unless --address), or in this
    process with --no-ray."""
    if args.no_ray:
        return families.cmd_demo(args)
    from .demo import run_demo_on_ray

    kwargs = families.demo_arguments(args)  # bad flags fail before Ray starts
    log = (lambda *_: None) if args.quiet else (lambda m: print(m, flush=True))
    families.print_demo_outputs(run_demo_on_ray(args.out, address=args.address, log=log, **kwargs))
    return 0


def cmd_screenshot(args: argparse.Namespace) -> int:
    from .screenshot import studio_screenshot

    try:
        w, h = (int(x) for x in args.size.lower().split("x"))
    except ValueError as exc:
        raise ValueError(f"--size must be WIDTHxHEIGHT, e.g. 1280x800, got {args.size!r}") from exc
    params = None
    if args.params:
        try:
            params = json.loads(args.params)
        except json.JSONDecodeError as exc:
            raise ValueError(f"--params is not valid JSON ({exc})") from exc
        if not isinstance(params, dict):
            raise ValueError('--params must be a JSON object, e.g. {"seats": 2}')
    info = studio_screenshot(args.url, args.out, params=params, width=w, height=h, timeout=args.timeout)
    print(f"wrote {args.out} ({w}x{h}): family {info['family']}, {info['requests']} transfers, last {info['client_ms']:.0f} ms round trip ({1000 * info['server_seconds']:.0f} ms in the service)")
    return 0


def cmd_eval_folder(args: argparse.Namespace) -> int:
    """``eval-folder`` with the build on Ray when ``--ray`` is given."""
    if args.ray is not None:
        from .build import build_on_ray

        address = None if args.ray == "local" else args.ray

        def builder(out, config, stages, log):
            build_on_ray(out, config, address=address, stages=stages, log=log, quiet=args.quiet or args.json)

        args.builder = builder
    return families.cmd_eval_folder(args)


def build_parser() -> argparse.ArgumentParser:
    parser = core.build_parser()
    sub = parser.subparsers  # type: ignore[attr-defined]
    build = sub.choices["build"]  # the library's commands, with what Ray adds to them
    build.add_argument("--ray", nargs="?", const="local", metavar="ADDRESS", help="run on Ray: a private local instance, or the cluster at ADDRESS ('auto', 'host:port')")
    build.add_argument("--train-workers", type=int, help="Ray Train workers per group network (--ray; default min(2, CPUs))")
    build.add_argument("--max-in-flight", type=int, help="Ray tasks submitted at a time (--ray; default 2 x CPUs)")
    build.set_defaults(func=cmd_build)
    generate = sub.choices["generate"]
    generate.description = "on Ray Data (a private local Ray unless --address), or in this process with --no-ray"
    generate.add_argument("--no-ray", action="store_true", help="run in this process (the files are the same)")
    generate.add_argument("--concurrency", metavar="SHAPES,TEXTURES", help="Ray Data actors per stage (default 1,<CPUs>; the texture actors share a GPU)")
    generate.add_argument("--cpus", type=int, help="CPUs of the private local Ray (default: all)")
    generate.add_argument("--address", help="an existing Ray cluster (default: a private local one)")
    generate.set_defaults(func=cmd_generate)
    demo = sub.choices["demo"]
    demo.add_argument("--no-ray", action="store_true", help="build in this process instead of on Ray")
    demo.add_argument("--address", help="build on an existing Ray cluster (default: a private local one)")
    demo.set_defaults(func=cmd_demo)
    ev = sub.choices["eval-folder"]
    ev.add_argument("--ray", nargs="?", const="local", metavar="ADDRESS", help="build on Ray (a private local instance, or ADDRESS)")
    ev.set_defaults(func=cmd_eval_folder)
    p = sub.add_parser("serve", help="serve the families under STORE over HTTP (Ray Serve)")
    p.add_argument("store", help="folder or URI holding family folders")
    p.add_argument("--host", default="127.0.0.1")
    p.add_argument("--port", type=int, default=8000)
    p.add_argument("--replicas", type=int, default=0, help="fixed replica count (default: one per CPU, at most 4)")
    p.add_argument("--autoscale", help="MIN,MAX replicas (autoscaling instead of a fixed count)")
    p.add_argument("--address", help="an existing Ray cluster (default: a private local one)")
    p.add_argument("--device", default="cpu", help="where the networks run: cpu, cuda or cuda:<i>")
    p.add_argument("--max-families", type=int, default=0, help="multiplex: load families on demand, at most this many per replica (LRU); 0: every family, preloaded")
    p.add_argument(
        "--http",
        choices=("front", "serve"),
        default="front",
        help="front (default): the ingress is the HTTP server and forwards to the transfer replicas, one hop; serve: Ray Serve's proxy before an ingress deployment (as a Serve config deploys it)",
    )
    p.add_argument("--edit-token", help="allow stored edits to requests carrying this secret (header X-ProcTex-Token); default $PROCTEX_EDIT_TOKEN; none: the families are read-only")
    p.add_argument(
        "--limit",
        action="append",
        metavar="NAME=VALUE",
        help="a request limit (repeatable): max_bytes, max_vertices, max_faces, max_parts, max_prompt, max_seconds, "
        "body_seconds, body_idle_seconds, body_min_rate, max_uploads, max_small_bodies, small_body (docs/http-api.md)",
    )
    p.set_defaults(func=cmd_serve)
    p = sub.add_parser("screenshot", help="a PNG of the web studio at URL (headless Chromium), e.g. http://127.0.0.1:8000/?family=sofa")
    p.add_argument("url", help="the studio's URL; ?family=NAME picks a family")
    p.add_argument("--out", default="studio.png", help="PNG file")
    p.add_argument("--params", help='slider values to set first (JSON), e.g. {"seats": 2}')
    p.add_argument("--size", default="1280x800", help="window size WIDTHxHEIGHT")
    p.add_argument("--timeout", type=float, default=60.0, help="seconds to wait for each shape")
    p.set_defaults(func=cmd_screenshot)
    return parser


def main(argv: list[str] | None = None) -> int:
    return core.run(build_parser(), argv)


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
