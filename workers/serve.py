"""Ray Serve deployment of the transfer service: the FastAPI app of :mod:`workers.http` as ingress.

Each replica keeps a :class:`proctex.family.service.Catalog` of the families under the store root (loaded
on first use, reloaded when a family's build stamp changes). Transfers run in a worker thread of the
replica, so one replica overlaps request parsing, encoding and I/O with the CPU-bound transfer.
"""

from __future__ import annotations

import os
from typing import Any

from ray import serve

from proctex.family.catalog import Catalog, Watchdog
from proctex.family.service import Limits
from workers.http import create_app


@serve.deployment(name="ProcTexTransfer", ray_actor_options={"num_cpus": 0}, max_ongoing_requests=16, health_check_period_s=10)
@serve.ingress()
class TransferService:
    """One replica: the catalog of families under ``root`` (preloaded) behind the FastAPI app, which
    is built in the replica after the constructor (``__serve_build_asgi_app__``), bound to it."""

    def __init__(self, root: str, check_every: float = 2.0, limits: dict[str, Any] | None = None, preload: bool = True,
                 edit_token: str | None = None) -> None:
        self.edit_token = edit_token or None
        self.catalog = Catalog(root, Limits(**(limits or {})), check_every)
        self.watchdog = Watchdog(2 * self.catalog.limits.max_seconds + 30)
        if preload:
            for name in self.catalog.names():
                try:
                    self.catalog.get(name)
                except Exception:  # not built yet, or damaged: reported per request (503) and in /v1/families
                    pass

    def __serve_build_asgi_app__(self):
        return create_app(lambda: self.catalog, watchdog=self.watchdog, edit_token=self.edit_token)

    def check_health(self) -> None:
        """Serve's health check: a transfer stuck far past its budget fails it, so Serve replaces
        this replica (``/healthz`` answers 503 meanwhile)."""
        if self.watchdog.stuck():
            raise RuntimeError(f"a transfer has run {self.watchdog.oldest():.0f} s (stuck after {self.watchdog.stuck_after:.0f} s)")


def build_app(args: dict[str, Any]) -> Any:
    """Serve application builder (``serve run workers.serve:build_app root=...``, Serve config files,
    KubeRay ``RayService``).

    Args (all strings accepted, as from the command line): ``root`` (store root folder or URI,
    required); ``replicas`` (fixed count) or ``min_replicas``/``max_replicas``/``target_ongoing_requests``
    (autoscaling); ``max_ongoing_requests``; ``num_cpus`` per replica; ``check_every`` seconds;
    ``max_bytes``/``max_vertices``/``max_faces``/``max_parts``/``max_seconds`` request limits; ``preload``;
    ``edit_token`` (default ``$PROCTEX_EDIT_TOKEN``): the secret stored edits need (none: read-only).
    """
    if not args.get("root"):
        raise ValueError("build_app needs args['root'], the family store root")
    options: dict[str, Any] = {"max_ongoing_requests": int(args.get("max_ongoing_requests", 16)),
                               "ray_actor_options": {"num_cpus": float(args.get("num_cpus", 0))}}
    if "min_replicas" in args or "max_replicas" in args:
        options["autoscaling_config"] = {
            "min_replicas": int(args.get("min_replicas", 1)), "max_replicas": int(args.get("max_replicas", 2)),
            "target_ongoing_requests": float(args.get("target_ongoing_requests", 4)),
        }
    else:
        options["num_replicas"] = int(args.get("replicas", 1))
    limits: dict[str, Any] = {k: int(args[k]) for k in ("max_bytes", "max_vertices", "max_faces", "max_parts") if k in args}
    if "max_seconds" in args:
        limits["max_seconds"] = float(args["max_seconds"])
    preload = str(args.get("preload", "true")).lower() not in ("0", "false", "no")
    token = args.get("edit_token") or os.environ.get("PROCTEX_EDIT_TOKEN") or None
    return TransferService.options(**options).bind(str(args["root"]), float(args.get("check_every", 2.0)), limits, preload, token)
