"""A family's stored textures (what linked GLBs point to) and a group's texture, edited as the query says."""

from __future__ import annotations

from fastapi import APIRouter, Request
from fastapi.responses import Response

from proctex.serve.service import NotFound, parse_edit

from ..context import AppContext
from ..errors import error_response


def router(ctx: AppContext) -> APIRouter:
    """The routes of this resource over ``ctx``."""
    router = APIRouter()

    @router.get(
        "/v1/families/{name}/textures/{file}",
        response_class=Response,
        responses={
            200: {"content": {"image/png": {}}, "description": "a template group's texture as stored"},
            304: {"description": "not modified (If-None-Match)"},
            404: {"description": "unknown family or group"},
        },
    )
    async def group_texture_file(name: str, file: str, request: Request, v: str | None = None, look: str | None = None):
        """The texture a linked GLB refers to (``<group>.png``; ``?look=``: of that look), with its
        digest as ETag. With ``v`` equal to the digest's start (as the GLB writes it) it is cached
        as immutable."""
        try:
            if not file.endswith(".png"):
                raise NotFound(f"no texture {file[:80]!r}; textures are <group>.png")
            svc = await ctx.look_of(name, look)
            png, digest = svc.texture_png(file[:-4])
        except Exception as exc:
            return error_response(exc)
        etag = f'"{digest}"'
        cache = "public, max-age=31536000, immutable" if v and digest.startswith(v) and len(v) >= 8 else "no-cache"
        headers = {"ETag": etag, "Cache-Control": cache, **ctx.served_by}
        if etag in [t.strip() for t in request.headers.get("if-none-match", "").split(",")]:
            return Response(status_code=304, headers=headers)
        return Response(content=png, media_type="image/png", headers=headers)

    @router.get(
        "/v1/families/{name}/groups/{group}/texture.png",
        response_class=Response,
        responses={200: {"content": {"image/png": {}}, "description": "the (edited) group texture"}, 404: {"description": "unknown family or group"}, 422: {"description": "bad edit or size"}},
    )
    async def group_texture(
        name: str, group: str, size: str = "128", hue: str | None = None, saturation: str | None = None, value: str | None = None, prompt: str | None = None, look: str | None = None
    ):
        """The group's template texture (``?look=``: of that look), edited as the query says (no
        edit: the stored one)."""
        try:
            svc = await ctx.look_of(name, look)
            g = svc.group_index(group, missing=NotFound)
            edit = parse_edit({"hue": hue, "saturation": saturation, "value": value, "prompt": prompt}, svc.limits.max_prompt)
            data = await ctx.blocking(lambda: svc.thumbnail(g, edit, size))
        except Exception as exc:
            return error_response(exc)
        return Response(content=data, media_type="image/png", headers={"Cache-Control": "no-cache", "X-ProcTex-Stamp": svc.stamp})

    return router
