"""The front of the service: a thin ASGI layer before the transfer replicas.

Ray Serve's proxy answers a request whose ingress replica died with a plain-text ``500 Internal
Server Error`` and never retries it. So the ingress here does no heavy work that could kill it: it
reads the request body within the time bounds of :class:`proctex.serve.service.Limits` (a stalled
client holds a cheap coroutine here, never a transfer replica's slot), forwards the whole request
to a transfer replica (:func:`call_app` runs it there against the FastAPI app of
:mod:`workers.http`) and sends its answer back. When the replica is lost mid-request (killed, out
of memory, its node gone), the ingress answers in JSON: an idempotent request (every ``GET`` and
a transfer, whose answer depends only on its input) is sent once more, to another replica; an edit
is not (it may have landed: its answer says how to tell).

Nothing here imports Ray: :func:`ingress_app` takes the forwarding call and the test that says
"the replica was lost" as functions (:mod:`workers.serve` passes Serve's handle and Ray's errors),
so tests drive it in process with replicas that fail on purpose.
"""

from __future__ import annotations

import asyncio
import json
import re
import time
from typing import Any, Awaitable, Callable

from starlette.requests import Request

from proctex.serve.service import Limits
from proctex.serve.timing import server_timing

#: A request as it travels from the ingress to a replica: ``method``, ``path``, ``query_string``
#: (bytes), ``headers`` (list of (bytes, bytes)), ``body`` (bytes), ``client`` ((host, port) or None).
Forwarded = dict
#: An answer as it travels back: ``status`` (int), ``headers`` (list of (bytes, bytes)), ``body`` (bytes).
Answer = dict

_FAMILY = re.compile(r"^/v1/families/([^/]+)(/|$)")
_TRANSFER = re.compile(r"^/v1/families/[^/]+/transfer$")
#: Background app runs of :func:`call_app` whose caller was cancelled: kept until they finish.
_ORPHANS: set[asyncio.Task] = set()


def idempotent(method: str, path: str) -> bool:
    """Whether a request may be sent twice with the same effect as once: reads (``GET``, ``HEAD``,
    ``OPTIONS``) and transfers (``POST .../transfer``: the answer is a function of the request; the
    family is not changed). Stored edits and undos are not."""
    return method in ("GET", "HEAD", "OPTIONS") or (method == "POST" and bool(_TRANSFER.match(path)))


def family_of(path: str) -> str | None:
    """The family a request is about (``/v1/families/{name}/...``), or None (health, the family
    list, the studio). Used to route to a replica that holds the family (multiplexing)."""
    m = _FAMILY.match(path)
    return m.group(1) if m else None


def is_lost_default(exc: BaseException) -> bool:
    """Without Ray: nothing is a lost replica (tests pass their own test)."""
    return False


def _json(status: int, payload: dict[str, Any], headers: list[tuple[bytes, bytes]] | None = None) -> Answer:
    body = json.dumps(payload).encode()
    return {"status": status, "headers": [(b"content-type", b"application/json"), (b"content-length", str(len(body)).encode()), *(headers or [])], "body": body}


async def call_app(app: Callable, request: Forwarded) -> Answer:
    """Run one forwarded request against the ASGI ``app`` in this process and return its whole
    answer. The app reads the body from memory; when the caller is cancelled (its client went
    away) the app is told ``http.disconnect``, so a transfer under way stops at its next budget
    check, and the app's run finishes in the background."""
    disconnected = asyncio.Event()
    sent_body = False
    status, headers, chunks = 500, [], []

    async def receive() -> dict:
        nonlocal sent_body
        if not sent_body:
            sent_body = True
            return {"type": "http.request", "body": request.get("body", b""), "more_body": False}
        await disconnected.wait()
        return {"type": "http.disconnect"}

    async def send(message: dict) -> None:
        nonlocal status, headers
        if message["type"] == "http.response.start":
            status, headers = int(message["status"]), list(message.get("headers", []))
        elif message["type"] == "http.response.body":
            chunks.append(bytes(message.get("body", b"")))

    path = request["path"]
    scope = {
        "type": "http",
        "asgi": {"version": "3.0"},
        "http_version": "1.1",
        "method": request["method"],
        "scheme": "http",
        "path": path,
        "raw_path": path.encode(),
        "root_path": "",
        "query_string": request.get("query_string", b""),
        "headers": [(bytes(k), bytes(v)) for k, v in request.get("headers", [])],
        "client": request.get("client"),
        "server": ("proctex", 80),
    }
    task = asyncio.ensure_future(app(scope, receive, send))
    try:
        await asyncio.shield(task)
    except asyncio.CancelledError:
        disconnected.set()
        _ORPHANS.add(task)
        task.add_done_callback(_ORPHANS.discard)
        raise
    return {"status": status, "headers": headers, "body": b"".join(chunks)}


def ingress_app(
    forward: Callable[[Forwarded, str | None], Awaitable[Answer]],
    limits: Limits | None = None,
    is_lost: Callable[[BaseException], bool] = is_lost_default,
    retry_seconds: float = 60.0,
    on_shutdown: Callable[[], Awaitable[None]] | None = None,
) -> Callable:
    """The ASGI app of the ingress.

    ``forward(request, family)`` sends a :data:`Forwarded` request to a replica (``family``: the
    family it is about, or None) and returns its :data:`Answer`. Bodies are read here within
    ``limits`` (:func:`workers.http.read_body`: size, time, rate and upload slots), so their errors
    (413, 408, 503) are answered here in JSON. ``is_lost(exc)`` tells a lost replica from any other
    failure: an idempotent request is then forwarded once more (within ``retry_seconds``: a
    replacement replica may be starting) and its answer carries ``X-ProcTex-Retried: 1``; anything
    else that goes wrong is a JSON error (503 with ``Retry-After`` for a lost replica, 500 with the
    error's type otherwise), never plain text. A forwarded answer's ``Server-Timing`` gains
    ``ingress-body`` (reading the body here), ``forward`` (the replica's round trip, retry
    included) and ``ingress`` (both). ``on_shutdown``: awaited when the server running the app
    stops (ASGI lifespan), before its event loop closes.
    """
    from workers.http import error_response, read_body

    limits = limits or Limits()

    async def answer(send: Callable, ans: Answer) -> None:
        await send({"type": "http.response.start", "status": ans["status"], "headers": ans["headers"]})
        await send({"type": "http.response.body", "body": ans["body"]})

    async def lifespan(receive: Callable, send: Callable) -> None:
        while True:
            message = await receive()
            if message["type"] == "lifespan.startup":
                await send({"type": "lifespan.startup.complete"})
            elif message["type"] == "lifespan.shutdown":
                if on_shutdown is not None:
                    await on_shutdown()
                await send({"type": "lifespan.shutdown.complete"})
                return

    async def app(scope: dict, receive: Callable, send: Callable) -> None:
        if scope["type"] == "lifespan":
            return await lifespan(receive, send)
        if scope["type"] != "http":  # websockets: not served
            await send({"type": "websocket.close", "code": 1003})
            return
        request = Request(scope, receive)
        t0 = time.perf_counter()
        try:
            body = await read_body(request, limits.max_bytes, limits)
        except Exception as exc:  # too large, too slow, every upload slot taken: JSON as the replicas would answer
            response = error_response(exc)
            return await response(scope, receive, send)
        method, path = scope["method"], scope["path"]
        forwarded: Forwarded = {
            "method": method,
            "path": path,
            "query_string": scope.get("query_string", b""),
            "headers": [(bytes(k), bytes(v)) for k, v in scope.get("headers", [])],
            "body": body,
            "client": scope.get("client"),
        }
        family = family_of(path)
        t_forward = time.perf_counter()
        try:
            ans = await forward(forwarded, family)
        except Exception as exc:
            if not is_lost(exc):
                return await answer(send, _json(500, {"error": f"internal error ({type(exc).__name__}); the request was not served"}))
            if not idempotent(method, path):
                where = f" (GET /v1/families/{family} shows its stamp and edits)" if family else ""
                return await answer(
                    send,
                    _json(
                        503, {"error": f"the replica serving this request was lost before it answered; an edit is atomic: it landed whole or not at all{where}; not retried"}, [(b"retry-after", b"5")]
                    ),
                )
            try:
                ans = await asyncio.wait_for(forward(forwarded, family), timeout=retry_seconds)
            except Exception as again:  # a second loss, no replica within the time, or another failure
                lost = is_lost(again) or isinstance(again, asyncio.TimeoutError)
                return await answer(
                    send,
                    _json(
                        503 if lost else 500,
                        {"error": ("the replica serving this request was lost and the retry failed too" if lost else f"internal error ({type(again).__name__}) on retry") + "; try again shortly"},
                        [(b"retry-after", b"5")] if lost else None,
                    ),
                )
            ans = {**ans, "headers": [*ans["headers"], (b"x-proctex-retried", b"1")]}
        t_end = time.perf_counter()
        timing = server_timing({"ingress-body": t_forward - t0, "forward": t_end - t_forward, "ingress": t_end - t0})
        await answer(send, {**ans, "headers": [*ans["headers"], (b"server-timing", timing.encode())]})

    return app
