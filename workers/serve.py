"""Ray Serve deployment of the transfer service: a thin ingress before the transfer replicas.

The application has two deployments. :class:`Ingress` (``ProcTexIngress``) takes every HTTP
request from Serve's proxy, reads its body within the time bounds (a stalled client holds a cheap
coroutine there) and forwards it whole to a :class:`TransferService` replica (``ProcTexTransfer``)
through a Serve handle; a replica lost mid-request is answered in JSON and an idempotent request is
retried once on another replica (:mod:`workers.ingress`). Each transfer replica keeps a
:class:`proctex.serve.catalog.Catalog` of the families under the store root (reloaded when a
family's build stamp changes): all of them, or, multiplexed, the few it serves; it answers a
forwarded request with the FastAPI app of :mod:`workers.http`. Transfers run in a worker thread of
the replica, so one replica overlaps request parsing, encoding and I/O with the CPU-bound transfer.
"""

from __future__ import annotations

import asyncio
import gc
import logging
import os
import time
from typing import Any

from ray import serve
from ray.exceptions import RayActorError

from proctex.serve.catalog import Catalog, Watchdog
from proctex.serve.parse_worker import READER
from proctex.serve.service import Limits
from proctex.serve.timing import server_timing
from proctex.transfer.apply import warm_kernels
from workers.http import create_app
from workers.ingress import Answer, Forwarded, call_app, ingress_app
from workers.sidechannel import ReplicaLost, listen


#: Ray's system settings for the private Ray ``proctex serve`` starts (a cluster started elsewhere
#: keeps its own: ``ray start --system-config``). A request and its answer travel between the front
#: and a replica inside Ray's calls up to this size instead of through its object store: a sofa
#: upload (220 KB in, 590 KB out) crossed a Serve handle in 11 ms, inline in 6 ms
#: (``tests/bench/bench_serve.py`` measures the hop).
RAY_SYSTEM_CONFIG = {"max_direct_call_object_size": 8 * 2**20}

#: The transfer replicas' environment: Serve runs their methods on the replica's own event loop, not
#: on a second loop in a thread of its own, so a forwarded request and its answer cross no thread
#: inside the replica (the transfer itself runs in a worker thread either way). With the front's
#: handle routing on its own loop too (:func:`workers.front.on_this_loop`), a bare handle round trip
#: on 2 cores took 3.0 / 3.9 ms for answers of 1 KB / 850 KB, against 4.6 / 4.9 ms with Serve's threads.
REPLICA_ENV = {"RAY_SERVE_RUN_USER_CODE_IN_SEPARATE_THREAD": "0"}


class TransferService:
    """One transfer replica: the catalog of families under ``root`` behind the FastAPI app, which
    answers the requests the ingress forwards (:meth:`forward`).

    Without ``max_families`` every family is preloaded and kept. With it the replica is multiplexed
    (:func:`deployment`): families load on their first request and at most ``max_families`` stay,
    least recently used first out."""

    max_families = 0

    def __init__(
        self, root: str, check_every: float = 2.0, limits: dict[str, Any] | None = None, preload: bool = True, edit_token: str | None = None, device: str = "cpu", sockets: str | None = None
    ) -> None:
        self.edit_token, self.app, self.side = edit_token or None, None, None
        self.catalog = Catalog(root, Limits(**(limits or {})), check_every, lazy=self.max_families > 0, device=device)
        self.watchdog = Watchdog(2 * self.catalog.limits.max_seconds + 30)
        READER.warm()  # the mesh reader process, started before the first upload needs it
        warm_kernels()  # the transfer's compiled kernels, loaded before the first request needs them
        if preload and not self.max_families:
            for name in self.catalog.names():
                try:
                    self.catalog.get(name)
                except Exception:  # not built yet, or damaged: reported per request (503) and in /v1/families
                    pass
        gc.freeze()  # the families and modules loaded so far stay out of the collector's passes
        if sockets:  # the front's side channel (workers.sidechannel), on this replica's event loop
            try:
                loop = asyncio.get_running_loop()
            except RuntimeError:  # built outside a replica (tests): no loop to listen on
                loop = None
            if loop is not None:
                import ray

                self.side = loop.create_task(_listen(sockets, ray.get_runtime_context().get_node_id(), self.forward))

    async def forward(self, request: Forwarded) -> Answer:
        """One HTTP request forwarded by the ingress, answered by the FastAPI app of
        :mod:`workers.http` in this replica (built on the first request, in the replica); the
        answer's ``Server-Timing`` gains ``replica``, the app's whole run here."""
        if self.app is None:
            self.app = create_app(lambda: self.catalog, watchdog=self.watchdog, edit_token=self.edit_token, get_family=self.family if self.max_families else None, replica=_replica_name())
        t0 = time.perf_counter()
        answer = await call_app(self.app, request)
        answer["headers"].append((b"server-timing", server_timing({"replica": time.perf_counter() - t0}).encode()))
        return answer

    def check_health(self) -> None:
        """Serve's health check: a transfer stuck far past its budget fails it, so Serve replaces
        this replica (``/healthz`` answers 503 meanwhile)."""
        if self.watchdog.stuck():
            raise RuntimeError(f"a transfer has run {self.watchdog.oldest():.0f} s (stuck after {self.watchdog.stuck_after:.0f} s)")


class _Held:
    """What Serve's multiplexing LRU keeps per family: unloading it (``__del__``, which Serve calls
    when the family leaves the LRU) makes the catalog let the family go too, whichever build of it
    the catalog holds by then (a rebuild reloads it there, not here). Only the first call counts:
    the garbage collector calls ``__del__`` again later, maybe after the family was loaded anew."""

    def __init__(self, catalog: Catalog, name: str) -> None:
        self.catalog, self.name, self.released = catalog, name, False

    def __del__(self) -> None:
        if not self.released:
            self.released = True
            self.catalog.forget(self.name)


def _replica_name() -> str:
    try:
        return serve.get_replica_context().replica_tag
    except Exception:  # outside a replica (tests building the class directly)
        return f"pid-{os.getpid()}"


def deployment(max_families: int = 0, name: str = "ProcTexTransfer"):
    """The Serve deployment class: :class:`TransferService`, multiplexed when ``max_families`` > 0.

    Multiplexed, the family is Serve's model id (:func:`ray.serve.multiplexed`): a family loads on
    its first request, a replica keeps at most ``max_families`` (LRU), and requests about a family
    are routed by :class:`Ingress` to a replica that already holds it. The catalog behind it still checks the
    family's build stamp, so a rebuilt or edited family is reloaded in place."""
    if max_families < 0:
        raise ValueError(f"max_families must be >= 0 (0: every family, preloaded), got {max_families}")
    cls = TransferService
    if max_families:

        class MultiplexedTransferService(TransferService):
            @serve.multiplexed(max_num_models_per_replica=max_families)
            async def held(self, name: str) -> _Held:
                await asyncio.to_thread(self.catalog.get, name)  # loads it (or says why not)
                return _Held(self.catalog, name)

            async def family(self, name: str) -> Any:
                await self.held(name)  # the LRU (a miss loads it) and the routing table
                return await asyncio.to_thread(self.catalog.get, name)  # a rebuilt family reloads here

        MultiplexedTransferService.max_families = max_families
        cls = MultiplexedTransferService
    return serve.deployment(name=name, ray_actor_options={"num_cpus": 0}, max_ongoing_requests=16, health_check_period_s=10)(cls)


async def _listen(sockets: str, node: str, forward: Any) -> Any:
    """:func:`workers.sidechannel.listen`, or None with a warning where the socket cannot be made
    (the front then sends this replica's requests through the handle: it waits for every replica)."""
    try:
        return await listen(sockets, node, forward)
    except OSError as exc:
        logging.getLogger("ray.serve").warning("the side channel is off for this replica: %s", exc)
        return None


def lost(exc: BaseException) -> bool:
    """Whether a failed handle call means the replica was lost (its actor died or cannot be
    reached), looking through the errors that wrap it (``RayTaskError``, Serve's own); also a
    side channel's replica lost mid-request (:class:`workers.sidechannel.ReplicaLost`)."""
    seen = 0
    while exc is not None and seen < 8:
        if isinstance(exc, (RayActorError, ReplicaLost)):
            return True
        exc, seen = (getattr(exc, "cause", None) or exc.__cause__), seen + 1
    return False


@serve.deployment(name="ProcTexIngress", ray_actor_options={"num_cpus": 0}, max_ongoing_requests=1024)
@serve.ingress()
class Ingress:
    """The HTTP ingress (:func:`workers.ingress.ingress_app`) over a handle to the transfer
    replicas; multiplexed (``max_families``), a request about a family is routed to a replica
    that holds it (the family is Serve's model id)."""

    def __init__(self, transfer: Any, limits: dict[str, Any] | None = None, multiplexed: bool = False) -> None:
        self.transfer, self.limits, self.multiplexed = transfer, Limits(**(limits or {})), multiplexed

    async def send(self, request: Forwarded, family: str | None) -> Answer:
        handle = self.transfer.options(multiplexed_model_id=family) if (self.multiplexed and family) else self.transfer
        return await handle.forward.remote(request)

    def __serve_build_asgi_app__(self):
        return ingress_app(self.send, self.limits, is_lost=lost)


def limits_from(args: dict[str, Any]) -> dict[str, Any]:
    """The :class:`proctex.serve.service.Limits` fields in ``args`` (strings accepted), each read as
    its field's type and checked (``ValueError`` naming a bad one)."""
    import dataclasses

    out: dict[str, Any] = {}
    for f in dataclasses.fields(Limits):
        if f.name in args:
            kind = str if isinstance(f.default, str) else int if isinstance(f.default, int) and not isinstance(f.default, bool) else float
            try:
                out[f.name] = kind(args[f.name])
            except (TypeError, ValueError) as exc:
                raise ValueError(f"limit {f.name} must be a number, got {str(args[f.name])[:40]!r}") from exc
    Limits(**out)  # checked here, before any replica starts
    return out


def build_app(args: dict[str, Any]) -> Any:
    """Serve application builder (``serve run workers.serve:build_app root=...``, Serve config files,
    KubeRay ``RayService``).

    Args (all strings accepted, as from the command line): ``root`` (store root folder or URI,
    required); ``replicas`` (fixed count) or ``min_replicas``/``max_replicas``/``target_ongoing_requests``
    (autoscaling); ``max_ongoing_requests``; ``num_cpus`` per replica; ``check_every`` seconds;
    every field of :class:`proctex.serve.service.Limits` (``max_bytes``, ``max_vertices``, ...,
    ``body_seconds``, ``body_idle_seconds``, ``body_min_rate``, ``max_uploads``); ``preload``;
    ``edit_token`` (default ``$PROCTEX_EDIT_TOKEN``): the secret stored edits need (none: read-only);
    ``max_families`` (default 0: every family, preloaded): multiplex the families, at most this many
    per replica (:func:`deployment`); ``device`` (default "cpu"): where the networks run, with
    ``num_gpus`` per replica (default for "cuda": the GPU shared by the replicas);
    ``ingress_replicas`` (default 1) and ``ingress_max_ongoing_requests`` (default 1024): the
    :class:`Ingress` in front (bodies are read there, ``max_uploads`` at a time per ingress replica).
    """
    transfer, limits, multiplexed = transfer_app(args)
    front = {"num_replicas": int(args.get("ingress_replicas", 1)), "max_ongoing_requests": int(args.get("ingress_max_ongoing_requests", 1024))}
    if front["num_replicas"] < 1 or front["max_ongoing_requests"] < 1:
        raise ValueError(f"ingress_replicas and ingress_max_ongoing_requests must be >= 1, got {front}")
    grace = float(args.get("graceful_shutdown_timeout_s", 5.0))
    return Ingress.options(**front, graceful_shutdown_timeout_s=grace, graceful_shutdown_wait_loop_s=1.0).bind(transfer, limits, multiplexed)


def autoscaled(args: dict[str, Any]) -> bool:
    """Whether :func:`build_app`'s ``args`` ask for autoscaled transfer replicas (``min_replicas`` or
    ``max_replicas``) rather than a fixed count."""
    return "min_replicas" in args or "max_replicas" in args


def transfer_app(args: dict[str, Any], sockets: str | None = None) -> tuple[Any, dict[str, Any], bool]:
    """The transfer replicas of :func:`build_app`'s ``args`` as a bound Serve application (no
    ingress: :func:`build_app` puts :class:`Ingress` before it, :mod:`workers.front` its own HTTP
    server), with the checked :class:`~proctex.serve.service.Limits` fields given
    (:func:`limits_from`) and whether the families are multiplexed. ``sockets``: a directory where
    each replica listens for the front's side channel (:mod:`workers.sidechannel`)."""
    if not args.get("root"):
        raise ValueError("build_app needs args['root'], the family store root")
    options: dict[str, Any] = {
        "max_ongoing_requests": int(args.get("max_ongoing_requests", 16)),
        "ray_actor_options": {"num_cpus": float(args.get("num_cpus", 0)), "runtime_env": {"env_vars": dict(REPLICA_ENV)}},
        # a replica being stopped (Ctrl-C, a scale-down) waits this long for its requests, not 20 s
        "graceful_shutdown_timeout_s": float(args.get("graceful_shutdown_timeout_s", 5.0)),
        "graceful_shutdown_wait_loop_s": 1.0,
    }
    if autoscaled(args):
        options["autoscaling_config"] = {
            "min_replicas": int(args.get("min_replicas", 1)),
            "max_replicas": int(args.get("max_replicas", 2)),
            "target_ongoing_requests": float(args.get("target_ongoing_requests", 4)),
        }
    else:
        options["num_replicas"] = int(args.get("replicas", 1))
    limits = limits_from(args)
    preload = str(args.get("preload", "true")).lower() not in ("0", "false", "no")
    token = args.get("edit_token") or os.environ.get("PROCTEX_EDIT_TOKEN") or None
    device = str(args.get("device", "cpu"))
    if device.startswith("cuda"):
        replicas = int(args.get("replicas", args.get("max_replicas", 1)))
        options["ray_actor_options"]["num_gpus"] = float(args.get("num_gpus", 1.0 / max(1, replicas)))
    max_families = int(args.get("max_families", 0))
    transfer = deployment(max_families).options(**options).bind(str(args["root"]), float(args.get("check_every", 2.0)), limits, preload, token, device, sockets)
    return transfer, limits, max_families > 0
