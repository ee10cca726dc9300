"""Liveness: the families and those unavailable, the transfers under way (503 while one is stuck)."""

from __future__ import annotations

from fastapi import APIRouter
from fastapi.responses import JSONResponse

from ..context import AppContext


def router(ctx: AppContext) -> APIRouter:
    """The routes of this resource over ``ctx``."""
    router = APIRouter()

    @router.get("/healthz")
    def healthz():
        cat = ctx.get_catalog()
        health = cat.health()
        info = {
            "families": len(health),
            "unavailable": sorted(n for n, h in health.items() if h not in ("ok", "not built")),
            "loaded": cat.loaded(),
            "loads": cat.loads,
            "replica": ctx.replica,
            "transfers_running": ctx.watchdog.running(),
            "oldest_transfer_seconds": round(ctx.watchdog.oldest(), 3),
        }
        if ctx.watchdog.stuck():
            return JSONResponse({"status": "stuck", **info}, status_code=503)
        return {"status": "ok", **info}

    return router
