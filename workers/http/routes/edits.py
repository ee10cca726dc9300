"""Stored edits of a family's group textures and their undo (the edit token; conditional on ``If-Match``)."""

from __future__ import annotations

from typing import Any

from fastapi import APIRouter, Request

from ..bodies import read_json_object
from ..context import AppContext
from ..errors import error_response


def router(ctx: AppContext) -> APIRouter:
    """The routes of this resource over ``ctx``."""
    router = APIRouter()

    @router.post(
        "/v1/families/{name}/edits",
        responses={404: {"description": "unknown family"}, 422: {"description": "bad edit"}},
        openapi_extra={
            "requestBody": {
                "required": True,
                "content": {
                    "application/json": {
                        "schema": {
                            "type": "object",
                            "required": ["group"],
                            "properties": {
                                "group": {"type": ["integer", "string"]},
                                "hue": {"type": "number"},
                                "saturation": {"type": "number"},
                                "value": {"type": "number"},
                                "prompt": {"type": "string"},
                            },
                        }
                    }
                },
            }
        },
    )
    async def persist_edit(name: str, request: Request, look: str | None = None):
        """Store an edit of one group texture in the family (``?look=``: of that look); every later
        transfer uses it. Needs the edit token; ``If-Match: <stamp>`` makes it conditional on the
        family being unchanged (409)."""
        try:
            svc = await ctx.look_of(name, look)
            ctx.check_edit_request(request)
            body = await read_json_object(request, limits=svc.limits)
            expect = request.headers.get("if-match")
            changed = await ctx.blocking(lambda: svc.persist_edit(body, expect_stamp=expect))  # the stamp read under the edit's lock
        except Exception as exc:
            return error_response(exc)
        finally:
            ctx.get_catalog().invalidate(name)
        return {"family": name, "edit": changed.record, "stamp": changed.version}

    async def undo(name: str, request: Request, look: str | None = None, **how: Any):
        """Undo stored edits of family ``name``'s ``look`` (``how``: :meth:`FamilyService.undo_edit`'s arguments)."""
        try:
            svc = await ctx.look_of(name, look)
            ctx.check_edit_request(request)
            changed = await ctx.blocking(lambda: svc.undo_edit(**how))
        except Exception as exc:
            return error_response(exc)
        finally:
            ctx.get_catalog().invalidate(name)
        return {"family": name, "undone": changed.record, "stamp": changed.version}

    @router.delete("/v1/families/{name}/edits/last", responses={404: {"description": "unknown family"}, 409: {"description": "nothing to undo"}})
    async def undo_edit(name: str, request: Request, look: str | None = None):
        """Undo the family's (``?look=``: that look's) last stored edit (needs the edit token;
        ``If-Match: <stamp>`` makes it conditional)."""
        return await undo(name, request, look, expect_stamp=request.headers.get("if-match"))

    @router.delete("/v1/families/{name}/edits", responses={404: {"description": "unknown family"}})
    async def reset_edits(name: str, request: Request, look: str | None = None):
        """Undo every stored edit (``?look=``: of that look): the look as painted (needs the edit token)."""
        return await undo(name, request, look, all_edits=True)

    return router
