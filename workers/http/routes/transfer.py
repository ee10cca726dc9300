"""A textured GLB of new parameters or an uploaded mesh, one transfer of a family at a time, within its budget."""

from __future__ import annotations

import json
import time

from fastapi import APIRouter, Request
from fastapi.responses import Response

from proctex.serve.service import BadInput
from proctex.serve.timing import StageClock
from proctex.transfer.budget import Budget

from ..bodies import TransferRequest, read_transfer_request
from ..context import AppContext
from ..errors import error, error_response

GLB_MEDIA_TYPE = "model/gltf-binary"


def router(ctx: AppContext) -> APIRouter:
    """The routes of this resource over ``ctx``."""
    router = APIRouter()

    @router.post(
        "/v1/families/{name}/transfer",
        response_class=Response,
        responses={
            200: {"content": {GLB_MEDIA_TYPE: {}}, "description": "the textured shape (binary glTF)"},
            404: {"description": "unknown family"},
            413: {"description": "body too large"},
            422: {"description": "bad parameters or mesh"},
        },
        openapi_extra={
            "requestBody": {
                "required": True,
                "content": {
                    "application/json": {"schema": TransferRequest.model_json_schema()},
                    "multipart/form-data": {"schema": {"type": "object", "required": ["mesh"], "properties": {"mesh": {"type": "string", "format": "binary"}, "seed": {"type": "integer"}}}},
                },
            }
        },
    )
    async def transfer(name: str, request: Request, textures: str = "embedded", look: str | None = None):
        """``?textures=linked``: the GLB refers to the family's textures (``textures/<g>.png?v=...``,
        relative to this URL) instead of carrying them; a client caches those once. ``?look=NAME``:
        textured as that look of the family (``GET .../looks``; default: the build's). The answer's
        ``Server-Timing`` header says where the time went, in ms: ``family`` (finding it), ``body``
        (reading the request), ``queue`` (waiting for the family's turn), ``thread`` (the hop into
        the worker thread), ``generate`` or ``parse``, ``segment``, ``assign``, ``map``, ``uv``,
        ``glb``, and ``app`` (the whole route)."""
        token = None
        clock, t_app = StageClock(), time.perf_counter()
        try:
            if textures not in ("embedded", "linked"):
                raise BadInput(f"textures must be 'embedded' or 'linked', got {textures[:40]!r}")
            with clock.stage("family"):
                svc = await ctx.look_of(name, look)
            with clock.stage("body"):
                kind, payload, seed, raw_edits = await read_transfer_request(request, svc.limits.max_bytes, svc.limits)
            edits = svc.parse_edits(raw_edits)

            def work():
                clock.add("thread", time.perf_counter() - t_turn)  # the hop into the worker thread
                shape = svc.shape_from_params(payload, clock) if kind == "params" else svc.shape_from_mesh(*payload, budget=budget, clock=clock)
                budget.check("reading the shape")
                out = svc.transfer(shape, seed=seed, edits=edits, budget=budget, linked=textures == "linked")
                for stage, seconds in out[1]["timings"].items():
                    clock.add(stage, seconds)
                return out

            gate = ctx.gate(svc)
            t_queue = time.perf_counter()
            async with gate:  # one transfer of this family at a time; the others wait here, not in a thread
                clock.add("queue", time.perf_counter() - t_queue)
                if await request.is_disconnected():
                    return error(499, "the client went away before its transfer started")
                budget = Budget(svc.limits.max_seconds)  # the budget counts from the turn, not the queue
                token = ctx.watchdog.begin()
                t_turn = time.perf_counter()
                data, summary = await ctx.watched(work, request, budget)
        except Exception as exc:
            return error_response(exc)
        finally:
            if token is not None:
                ctx.watchdog.end(token)
        clock.add("app", time.perf_counter() - t_app)
        headers = {
            "X-ProcTex-Seconds": str(summary["seconds"]),
            "X-ProcTex-Notes": json.dumps(summary["notes"])[:2000],
            "Content-Disposition": f'inline; filename="{name}.glb"',
            "Server-Timing": clock.header(),
            **ctx.served_by,
        }
        return Response(content=data, media_type=GLB_MEDIA_TYPE, headers=headers)

    return router
