"""Which group takes which part word, and the user's stored word per group (the edit token)."""

from __future__ import annotations

from fastapi import APIRouter, Request

from ..bodies import read_json_object
from ..context import AppContext
from ..errors import error_response


def router(ctx: AppContext) -> APIRouter:
    """The routes of this resource over ``ctx``."""
    router = APIRouter()

    @router.get("/v1/families/{name}/parts", responses={404: {"description": "unknown family or look"}})
    async def family_parts(name: str, prompt: str | None = None, look: str | None = None):
        """Which group takes which part word of ``prompt`` (default: the look's prompt; ``look``
        default: the build's): per group its word, how it got it, its score, its evidence and the
        text it is painted with; the family's stored words (``stored``) count."""
        try:
            svc = await ctx.family_of(name)
            return await ctx.blocking(lambda: svc.parts(prompt, look))
        except Exception as exc:
            return error_response(exc)

    @router.put(
        "/v1/families/{name}/parts",
        responses={404: {"description": "unknown family"}, 409: {"description": "an edit of the family is running"}, 422: {"description": "bad words"}},
        openapi_extra={
            "requestBody": {
                "required": True,
                "content": {
                    "application/json": {
                        "schema": {"type": "object", "required": ["groups"], "properties": {"groups": {"type": "object", "additionalProperties": {"type": "string"}}, "replace": {"type": "boolean"}}}
                    }
                },
            }
        },
    )
    async def store_parts(name: str, request: Request):
        """Store the user's word per group in the family (``{"groups": {"3": "legs"}}``; an empty word
        clears a group's, ``replace`` drops the others): every look painted afterwards follows it.
        Needs the edit token. Returns the stored words."""
        try:
            svc = await ctx.family_of(name)
            ctx.check_edit_request(request)
            body = await read_json_object(request, limits=svc.limits)
            stored = await ctx.blocking(lambda: svc.store_parts(body))
        except Exception as exc:
            return error_response(exc)
        return {"family": name, "stored": stored}

    return router
