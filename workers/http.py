"""The HTTP API of the transfer service (FastAPI), shared by the Ray Serve ingress and tests.

Routes:

- ``GET /healthz``: liveness and the loaded families.
- ``GET /v1/families``: the families under the store root.
- ``GET /v1/families/{name}``: parameter specs, groups, prompts, build state, metrics.
- ``POST /v1/families/{name}/transfer``: a textured GLB (``model/gltf-binary``) for either a JSON
  body ``{"params": {...}, "seed": 0}`` (families of a procedural model) or a multipart upload with
  a ``mesh`` file field (``.obj .ply .stl .glb .gltf``). Timing and notes come back in the headers
  ``X-ProcTex-Seconds`` and ``X-ProcTex-Notes``.

Errors are JSON ``{"error": message}``: unknown family 404, body over the size limit 413, bad JSON,
parameters out of bounds, unknown parameters or an unreadable mesh 422.
"""

from __future__ import annotations

import asyncio
import json
from typing import Any, Callable

from fastapi import FastAPI, Request
from fastapi.responses import JSONResponse, Response
from pydantic import BaseModel, Field

from proctex.service import BadInput, Catalog, NotFound, TooLarge

GLB_MEDIA_TYPE = "model/gltf-binary"


class TransferRequest(BaseModel):
    """JSON body of a transfer by parameters."""

    params: dict[str, Any] = Field(default_factory=dict, description="parameter values (missing ones take their defaults)")
    seed: int = Field(0, description="seed of the network's context samples and of painting new parts")


def _error(status: int, message: str) -> JSONResponse:
    return JSONResponse({"error": message}, status_code=status)


def error_response(exc: Exception) -> JSONResponse:
    if isinstance(exc, NotFound):
        return _error(404, str(exc))
    if isinstance(exc, TooLarge):
        return _error(413, str(exc))
    return _error(422, str(exc))


async def read_transfer_request(request: Request, max_bytes: int) -> tuple[str, Any, int]:
    """``("params", dict, seed)`` or ``("mesh", (bytes, filename), seed)`` from a request."""
    length = request.headers.get("content-length")
    if length is not None and length.isdigit() and int(length) > max_bytes:
        raise TooLarge(f"request body of {length} bytes is over the limit of {max_bytes}")
    ctype = request.headers.get("content-type", "").split(";")[0].strip().lower()
    if ctype == "multipart/form-data":
        try:
            form = await request.form(max_files=1, max_fields=4)
        except Exception as exc:  # malformed multipart
            raise BadInput(f"cannot read the multipart body: {exc}") from exc
        upload = form.get("mesh")
        if upload is None or isinstance(upload, str):
            raise BadInput("multipart uploads need a file field named 'mesh'")
        data = await upload.read(max_bytes + 1)
        if len(data) > max_bytes:
            raise TooLarge(f"mesh upload over the limit of {max_bytes} bytes")
        seed = form.get("seed", "0")
        try:
            seed_value = int(seed) if isinstance(seed, str) else 0
        except ValueError as exc:
            raise BadInput(f"seed must be an integer, got {seed!r}") from exc
        return "mesh", (data, upload.filename or "mesh.obj"), seed_value
    body = await request.body()
    if len(body) > max_bytes:
        raise TooLarge(f"request body over the limit of {max_bytes} bytes")
    if ctype not in ("application/json", ""):
        raise BadInput(f"send application/json ({{\"params\": {{...}}}}) or multipart/form-data with a 'mesh' file, not {ctype!r}")
    try:
        req = TransferRequest.model_validate_json(body)
    except Exception as exc:  # pydantic ValidationError or JSON errors
        raise BadInput(f"bad JSON body: {str(exc).splitlines()[0] if str(exc) else exc.__class__.__name__}; "
                       'expected {"params": {"name": value, ...}, "seed": 0}') from exc
    return "params", req.params, req.seed


def create_app(get_catalog: Callable[[], Catalog], run: Callable[[Callable[[], Any]], Any] | None = None) -> FastAPI:
    """The FastAPI application over a :class:`Catalog`.

    ``run(fn)`` executes the blocking transfer (default: a worker thread), so the event loop keeps
    serving other requests.
    """
    app = FastAPI(
        title="ProcTex transfer service",
        version="1",
        description="Texture any member of a procedural shape family from its family's template in real time.",
    )

    async def blocking(fn: Callable[[], Any]) -> Any:
        if run is not None:
            return await run(fn)
        return await asyncio.to_thread(fn)

    @app.get("/healthz")
    def healthz() -> dict[str, Any]:
        cat = get_catalog()
        return {"status": "ok", "families": len(cat.names()), "loads": cat.loads}

    @app.get("/v1/families")
    def families() -> dict[str, Any]:
        return {"families": get_catalog().names()}

    @app.get("/v1/families/{name}", responses={404: {"description": "unknown family"}})
    async def family(name: str):
        try:
            svc = await blocking(lambda: get_catalog().get(name))
            return svc.describe()
        except (NotFound, BadInput, TooLarge) as exc:
            return error_response(exc)

    @app.post(
        "/v1/families/{name}/transfer",
        response_class=Response,
        responses={
            200: {"content": {GLB_MEDIA_TYPE: {}}, "description": "the textured shape (binary glTF)"},
            404: {"description": "unknown family"}, 413: {"description": "body too large"}, 422: {"description": "bad parameters or mesh"},
        },
        openapi_extra={"requestBody": {"required": True, "content": {
            "application/json": {"schema": TransferRequest.model_json_schema()},
            "multipart/form-data": {"schema": {"type": "object", "required": ["mesh"], "properties": {
                "mesh": {"type": "string", "format": "binary"}, "seed": {"type": "integer"}}}},
        }}},
    )
    async def transfer(name: str, request: Request):
        try:
            cat = get_catalog()
            svc = await blocking(lambda: cat.get(name))
            kind, payload, seed = await read_transfer_request(request, svc.limits.max_bytes)

            def work():
                shape = svc.shape_from_params(payload) if kind == "params" else svc.shape_from_mesh(*payload)
                return svc.transfer(shape, seed=seed)

            data, summary = await blocking(work)
        except (NotFound, BadInput, TooLarge) as exc:
            return error_response(exc)
        headers = {"X-ProcTex-Seconds": str(summary["seconds"]), "X-ProcTex-Notes": json.dumps(summary["notes"])[:2000],
                   "Content-Disposition": f'inline; filename="{name}.glb"'}
        return Response(content=data, media_type=GLB_MEDIA_TYPE, headers=headers)

    return app
