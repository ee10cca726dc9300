"""One hop: the ingress as the HTTP server itself, before the transfer replicas.

Served through Ray Serve's proxy (:func:`workers.serve.build_app`), a request crosses three
processes: Serve's proxy parses the HTTP and calls the :class:`workers.serve.Ingress` replica,
which pulls the body back from the proxy, forwards the request to a transfer replica and streams
the answer back through the proxy. The front here is the same ingress app
(:func:`workers.ingress.ingress_app`: bodies read within the time bounds, per-client slots, a lost
replica's idempotent request retried, JSON on every error) run by its own HTTP server (uvicorn) in
the process that started Serve, forwarding through a Serve handle to the transfer replicas: one
process and two copies of the request and answer fewer. Serve runs no proxy then; the transfer
replicas, their health checks, replacement and multiplexing are Serve's as before.

``proctex serve`` uses it by default (``--http serve`` keeps Serve's proxy and the ingress
deployment, as a Serve config or KubeRay's RayService deploy :func:`workers.serve.build_app`).
"""

from __future__ import annotations

import asyncio
import contextlib
import gc
import shutil
import signal
import tempfile
from typing import Any, Callable, NamedTuple

import uvicorn
from ray import serve

from proctex.serve.service import Limits
from workers.ingress import Answer, Forwarded, ingress_app
from workers.serve import autoscaled, lost, transfer_app
from workers.sidechannel import SideChannel, Unreachable


def front_app(handle: Any, limits: Limits, multiplexed: bool = False, sockets: str | None = None, replicas: int = 0) -> Any:
    """The ASGI app of the front: :func:`workers.ingress.ingress_app` forwarding to the transfer
    deployment's ``handle`` (a request about a family goes, multiplexed, to a replica holding it).
    ``sockets``: the directory of the replicas' side channel (:mod:`workers.sidechannel`; not
    multiplexed): a request goes there to a replica on this node while all ``replicas`` listen
    on it, else through the handle (some run on other nodes, none listens yet); the directory is
    removed when the server stops. Each answer says which way it came (``X-ProcTex-Hop:
    side-channel`` or ``serve-handle``)."""

    routed: list[Any] = []
    side: list[SideChannel] = []

    async def send(request: Forwarded, family: str | None) -> Answer:
        if sockets and not multiplexed:
            if not side:
                import ray

                side.append(SideChannel(sockets, ray.get_runtime_context().get_node_id(), replicas))
            try:
                return _via(await side[0].send(request), b"side-channel")
            except Unreachable:  # nothing was sent: Serve's router knows the replicas
                pass
        if not routed:  # the first request, on the server's event loop: a handle routing on it
            routed.append(on_this_loop(handle))
        base = routed[0]
        h = base.options(multiplexed_model_id=family) if (multiplexed and family) else base
        return _via(await h.forward.remote(request), b"serve-handle")

    async def stop() -> None:  # the server stops: the router's tasks end on its loop, before the loop closes
        if side:
            side[0].close()
        if sockets:
            shutil.rmtree(sockets, ignore_errors=True)
        if routed and routed[0] is not handle:
            await routed[0].shutdown_async()

    return ingress_app(send, limits, is_lost=lost, on_shutdown=stop)


def _via(answer: Answer, hop: bytes) -> Answer:
    """``answer`` saying (``X-ProcTex-Hop``) which way it came from the replica."""
    answer["headers"] = [*answer.get("headers", []), (b"x-proctex-hop", hop)]
    return answer


def on_this_loop(handle: Any) -> Any:
    """A handle to ``handle``'s deployment whose router runs on the running event loop (the front's
    server's), not on a loop of its own in another thread (Serve's default for a handle outside a
    replica): each call and its answer then cross no thread. It is a new handle (Serve's own cache
    keeps ``handle``, which ``serve.shutdown`` stops after this loop has closed); its owner stops it
    with ``shutdown_async`` on this loop. Where the option is missing (another Ray), ``handle``."""
    try:
        from ray.serve.handle import DeploymentHandle

        own = DeploymentHandle(handle.deployment_id.name, handle.deployment_id.app_name)
        own._init(_run_router_in_separate_loop=False)
    except (RuntimeError, TypeError, AttributeError, ImportError):  # a Ray without the option: Serve's default router
        return handle
    return own


def takes_side_channel(app_args: dict[str, Any], multiplexed: bool) -> bool:
    """Whether transfer replicas deployed from ``app_args`` can be reached by the side channel:
    not when multiplexed (Serve's router knows which replica holds a family) nor when they
    autoscale (Serve scales by the requests under way through its handles)."""
    return not multiplexed and not autoscaled(app_args)


class Deployed(NamedTuple):
    """What :func:`deploy_transfer` started: :func:`front_app`'s arguments."""

    handle: Any
    limits: Limits
    multiplexed: bool
    sockets: str | None
    replicas: int


def deploy_transfer(app_args: dict[str, Any], name: str = "proctex") -> Deployed:
    """Deploy the transfer replicas of ``app_args`` (:func:`workers.serve.build_app`'s arguments)
    as a Serve application with no HTTP route (Serve must be started without proxies:
    ``serve.start(proxy_location="Disabled")``). The replicas listen for the side channel in a new
    private directory (:mod:`workers.sidechannel`), unless the families are multiplexed or the
    replicas autoscale (:func:`takes_side_channel`) or no directory can be made (the handle then)."""
    app, limits, multiplexed = transfer_app(app_args)  # the arguments checked before a directory is made
    sockets = None
    if takes_side_channel(app_args, multiplexed):
        with contextlib.suppress(OSError):  # no writable temporary directory: the handle only
            sockets = tempfile.mkdtemp(prefix="proctex-")  # mode 0700: only this user connects
    if sockets:
        app, limits, multiplexed = transfer_app(app_args, sockets=sockets)
    try:
        handle = serve.run(app, name=name, route_prefix=None)
    except BaseException:
        if sockets:
            shutil.rmtree(sockets, ignore_errors=True)
        raise
    return Deployed(handle, Limits(**limits), multiplexed, sockets, int(app_args.get("replicas", 1)))


def server(app: Any, host: str, port: int) -> Any:
    """A uvicorn server of ``app`` on ``host:port``: HTTP/1.1 (h11), no access log, a keep-alive
    of 5 s, the client the TCP peer (forwarded headers are the app's ``trusted_proxies`` to read,
    not uvicorn's); slow bodies are the app's to bound (:func:`workers.http.read_body`). It installs
    no signal handlers: :func:`run_until_signal` stops it."""

    class Server(uvicorn.Server):
        @contextlib.contextmanager
        def capture_signals(self):  # uvicorn's re-raises the signal after a graceful stop
            yield

    config = uvicorn.Config(app, host=host, port=port, http="h11", lifespan="on", access_log=False, log_level="warning", timeout_keep_alive=5, server_header=False, proxy_headers=False)
    return Server(config)


def run_until_signal(srv: Any, on_started: Callable[[], Any] | None = None) -> None:
    """Run the server ``srv`` (:func:`server`) in this thread until SIGINT or SIGTERM: then it
    stops taking connections, finishes the requests under way and returns. ``on_started`` is
    called once it listens. ``OSError`` when it could not start (e.g. the port was taken meanwhile)."""

    def stop(*_: Any) -> None:
        srv.should_exit = True

    async def run() -> None:
        task = asyncio.ensure_future(srv.serve())
        while not srv.started and not task.done():
            await asyncio.sleep(0.02)
        if srv.started:
            gc.freeze()  # what start-up made (Ray, Serve, the app) stays out of the collector's passes
            if on_started is not None:
                on_started()
        await task

    old = {sig: signal.signal(sig, stop) for sig in (signal.SIGINT, signal.SIGTERM)}
    try:
        try:
            asyncio.run(run())
        except SystemExit as exc:  # uvicorn exits when it cannot bind
            raise OSError(f"the HTTP server could not start on {srv.config.host}:{srv.config.port}") from exc
    finally:
        for sig, handler in old.items():
            signal.signal(sig, handler)
