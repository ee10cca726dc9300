"""The families under the root with their health, and one family's description."""

from __future__ import annotations

from typing import Any

from fastapi import APIRouter

from ..context import AppContext
from ..errors import error_response


def router(ctx: AppContext) -> APIRouter:
    """The routes of this resource over ``ctx``."""
    router = APIRouter()

    @router.get("/v1/families")
    def families() -> dict[str, Any]:
        """The families under the root and the health of each ("ok", "not built", or why a damaged
        one is unavailable)."""
        cat = ctx.get_catalog()
        return {"families": cat.names(), "health": cat.health()}

    @router.get("/v1/families/{name}", responses={404: {"description": "unknown family"}})
    async def family(name: str, look: str | None = None):
        try:
            svc = await ctx.look_of(name, look)
            return {**svc.describe(), "edits_enabled": bool(ctx.edit_token)}
        except Exception as exc:
            return error_response(exc)

    return router
