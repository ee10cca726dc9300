"""The web studio: its page and bundled assets (503 with a note while its bundle is not built)."""

from __future__ import annotations

import mimetypes
import re
from pathlib import Path

from fastapi import APIRouter
from fastapi.responses import FileResponse, HTMLResponse

from ..context import AppContext
from ..errors import error


_ASSET_NAME = re.compile(r"^[A-Za-z0-9_-][A-Za-z0-9._-]*(/[A-Za-z0-9_-][A-Za-z0-9._-]*)*$")
NOT_BUILT = """<!doctype html><html><head><meta charset="utf-8"><title>ProcTex studio not built</title></head>
<body style="font-family: sans-serif; max-width: 40em; margin: 3em auto">
<h1>ProcTex studio: not built</h1>
<p>The web studio's bundle is missing (<code>{dist}</code>). Build it with <code>make setup</code>
(it runs <code>npm ci --prefix workers/studio</code> and <code>npm run --prefix workers/studio build</code>;
needs Node.js and npm), then reload this page.</p>
<p>The JSON API works without it: <a href="/docs">/docs</a>, <a href="/v1/families">/v1/families</a>.</p>
</body></html>"""


def router(ctx: AppContext, dist: Path) -> APIRouter:
    """The routes of this resource over ``ctx``."""
    router = APIRouter()

    @router.get("/", response_class=HTMLResponse, include_in_schema=False)
    def studio_index():
        index = dist / "index.html"
        if not index.is_file():
            return HTMLResponse(NOT_BUILT.format(dist=dist), status_code=503)
        return FileResponse(index, media_type="text/html", headers={"Cache-Control": "no-cache"})

    @router.get("/studio/{path:path}", include_in_schema=False)
    def studio_asset(path: str):
        if _ASSET_NAME.match(path) and ".." not in path.split("/"):
            root = dist.resolve()
            target = (root / path).resolve()
            if target.is_relative_to(root) and target.is_file():
                media = mimetypes.guess_type(target.name)[0] or "application/octet-stream"
                return FileResponse(target, media_type=media, headers={"Cache-Control": "no-cache"})
        return error(404, f"no studio asset {path!r}")

    return router
