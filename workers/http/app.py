"""The FastAPI application (:func:`create_app`): one router per resource (:mod:`workers.http.routes`)
over an :class:`~workers.http.context.AppContext`, with every error answered as JSON."""

from __future__ import annotations

import json
import os
from pathlib import Path
from typing import Any, Awaitable, Callable

from fastapi import FastAPI, Request
from fastapi.exceptions import RequestValidationError
from fastapi.responses import JSONResponse
from starlette.exceptions import HTTPException as StarletteHTTPException

from proctex.serve.catalog import Catalog, Watchdog
from proctex.serve.service import FamilyService

from .context import AppContext
from .errors import error, error_response
from .routes import edits, families, health, looks, parts, studio, textures, transfer

STUDIO_DIST = Path(__file__).resolve().parent.parent / "studio" / "dist"


def create_app(
    get_catalog: Callable[[], Catalog],
    run: Callable[[Callable[[], Any]], Awaitable[Any]] | None = None,
    studio_dir: str | Path | None = None,
    watchdog: Watchdog | None = None,
    edit_token: str | None = None,
    get_family: Callable[[str], Awaitable[FamilyService]] | None = None,
    replica: str | None = None,
) -> FastAPI:
    """The FastAPI application over a :class:`Catalog`.

    ``run(fn)`` executes the blocking transfer (default: a worker thread), so the event loop keeps
    serving other requests. ``studio_dir``: the built studio bundle (default: ``$PROCTEX_STUDIO_DIR``,
    else ``workers/studio/dist`` beside this file). ``watchdog``: the transfers under way (default: a
    new one whose stuck time is twice the catalog's transfer budget plus 30 s); ``/healthz`` answers
    503 while one is stuck. ``edit_token``: the secret that stored edits need (header
    ``X-ProcTex-Token`` or ``Authorization: Bearer``); without one the families are read-only.
    ``get_family(name)``: how a route gets a family's service (default: the catalog's, in a worker
    thread; the multiplexed Serve replica passes its LRU). ``replica``: this replica's name, sent
    back as ``X-ProcTex-Replica`` and in ``/healthz``.

    Transfers of one family run one at a time: a request waits for its turn in the event loop (no
    worker thread is held while waiting), has ``max_seconds`` of work (a 422 past it), and is
    cancelled when its client goes away.
    """
    dist = Path(studio_dir or os.environ.get("PROCTEX_STUDIO_DIR") or STUDIO_DIST)
    app = FastAPI(
        title="ProcTex transfer service",
        version="1",
        description="Texture any member of a procedural shape family from its family's template in real time.",
        # no redirect to the path with or without its last slash: "/v1/families/%2e%2e%2f" was a 307
        # with an empty body; every unknown path is a JSON 404
        redirect_slashes=False,
    )
    ctx = AppContext(
        get_catalog=get_catalog,
        run=run,
        watchdog=watchdog if watchdog is not None else Watchdog(2 * get_catalog().limits.max_seconds + 30),
        edit_token=edit_token,
        get_family=get_family,
        replica=replica,
    )

    @app.exception_handler(Exception)
    async def any_error(request: Request, exc: Exception):
        return error_response(exc)

    @app.exception_handler(RequestValidationError)
    async def validation_error(request: Request, exc: RequestValidationError):
        parts = ["/".join(str(x) for x in e.get("loc", ())) + ": " + str(e.get("msg", "")) for e in exc.errors()]
        return error(422, "; ".join(parts) or "bad request")

    @app.exception_handler(StarletteHTTPException)
    async def http_error(request: Request, exc: StarletteHTTPException):
        message = exc.detail if isinstance(exc.detail, str) else json.dumps(exc.detail)
        if exc.status_code == 404:
            message = f"no route {request.url.path!r}; see /docs"
        return JSONResponse({"error": message}, status_code=exc.status_code, headers=getattr(exc, "headers", None))

    app.include_router(studio.router(ctx, dist), include_in_schema=False)
    for resource in (health, families, transfer, textures, edits, looks, parts):
        app.include_router(resource.router(ctx))
    app.state.context = ctx  # for tests and wrappers: the routes' shared state
    return app
