"""A family's looks, and a new look painted from a prompt or photos (the edit token)."""

from __future__ import annotations

from fastapi import APIRouter, Request

from proctex.transfer.budget import Budget

from ..bodies import read_look_request
from ..context import AppContext
from ..errors import error, error_response
from ..looks import parse_look


def router(ctx: AppContext) -> APIRouter:
    """The routes of this resource over ``ctx``."""
    router = APIRouter()

    @router.get("/v1/families/{name}/looks", responses={404: {"description": "unknown family"}})
    async def family_looks(name: str):
        """The family's looks: name, prompt, painter, texture size, edits; the build's first."""
        try:
            svc = await ctx.family_of(name)
            return {"family": name, "looks": await ctx.blocking(svc.looks)}
        except Exception as exc:
            return error_response(exc)

    @router.post(
        "/v1/families/{name}/looks",
        responses={404: {"description": "unknown family"}, 409: {"description": "a build or edit of the family is running"}, 422: {"description": "bad look"}},
        openapi_extra={
            "requestBody": {
                "required": True,
                "content": {
                    "application/json": {
                        "schema": {
                            "type": "object",
                            "required": ["name", "prompt"],
                            "properties": {
                                "name": {"type": "string"},
                                "prompt": {"type": "string"},
                                "group_prompts": {"type": "object"},
                                "part_words": {"type": "object"},
                                "painter": {"type": "string"},
                                "texture_size": {"type": "integer"},
                                "force": {"type": "boolean"},
                            },
                        }
                    },
                    "multipart/form-data": {
                        "schema": {
                            "type": "object",
                            "required": ["look"],
                            "properties": {
                                "look": {"type": "string", "description": "the look's JSON (prompt optional), with images: {part: {scale, rotate, normal, roughness}}"},
                                "image.*": {"type": "string", "format": "binary", "description": "a photo per part: fields image.<part>"},
                            },
                        }
                    },
                },
            }
        },
    )
    async def add_family_look(name: str, request: Request):
        """Paint a new look of the family (the stored template with another prompt, or photos sent
        as multipart ``image.<part>`` files: seconds, no rebuild) and store it; served at once
        (``?look=NAME``). Needs the edit token."""
        try:
            svc = await ctx.family_of(name)
            ctx.check_edit_request(request, multipart=True)
            body, files = await read_look_request(request, limits=svc.limits)
            look, paint, force, photos = await ctx.blocking(lambda: parse_look(body, svc, files))  # photos decode off the loop
            gate = ctx.look_gate(svc)
            async with gate:  # at most look_paints paints of this family at a time; the others wait here, not in a thread
                if await request.is_disconnected():
                    return error(499, "the client went away before its look was painted")
                budget = Budget(svc.limits.look_seconds)
                changed = await ctx.watched(lambda: svc.add_look(look, paint, force, photos, budget), request, budget)
        except Exception as exc:
            return error_response(exc)
        finally:
            ctx.get_catalog().invalidate(name)
        return {"family": name, "look": changed.record, "stamp": changed.version}

    return router
