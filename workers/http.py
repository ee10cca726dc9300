"""The HTTP API of the transfer service (FastAPI), shared by the Ray Serve ingress and tests.

Routes:

- ``GET /``: the web studio (``workers/studio/dist/index.html``; 503 with a note naming
  ``make setup`` when the bundle has not been built). ``GET /studio/<file>``: its bundled assets.
- ``GET /healthz``: liveness, the families and those unavailable, the transfers under way (503
  while one is stuck far past its budget).
- ``GET /v1/families``: the families under the store root and each one's health.
- ``GET /v1/families/{name}``: parameter specs, groups, prompts, build state, metrics.
- ``POST /v1/families/{name}/transfer``: a textured GLB (``model/gltf-binary``) for either a JSON
  body ``{"params": {...}, "seed": 0, "edits": {...}}`` (families of a procedural model) or a
  multipart upload with a ``mesh`` file field (``.obj .ply .stl .glb .gltf``) and optional ``seed``
  and ``edits`` (JSON text) fields. ``edits`` = ``{"<group index or label>": {"hue": degrees,
  "saturation": scale, "value": scale, "prompt": text}}`` textures this GLB with edited copies of
  the template's group textures (re-paint first, then the HSV shift; the family is unchanged).
  Timing and notes come back in the headers ``X-ProcTex-Seconds`` and ``X-ProcTex-Notes``.
- ``GET /v1/families/{name}/groups/{group}/texture.png?size=128&hue=&saturation=&value=&prompt=``:
  the group's texture (edited as given) as a PNG at most ``size`` pixels a side.
- ``POST /v1/families/{name}/edits``: ``{"group": index or label, "hue", "saturation", "value",
  "prompt"}`` stored into the family (:func:`proctex.serve.edits.edit_group`); returns
  ``{"family", "edit": record, "stamp": new build stamp}``. Later transfers use it. Needs the service's
  edit token (``X-ProcTex-Token``; without a token configured the service is read-only) and a JSON
  body; ``If-Match: <stamp>`` makes it conditional (409 when the family changed).
- ``DELETE /v1/families/{name}/edits/last``: undo the last stored edit; ``DELETE
  /v1/families/{name}/edits``: undo them all (the template as painted). Both need the token.
- ``GET /v1/families/{name}/looks``: the family's looks (the build's first); ``POST`` (the token, JSON
  ``{"name", "prompt", "group_prompts", "painter", "texture_size", "force"}``) paints a new look of the
  stored template in seconds, served at once. ``?look=NAME`` on the family, transfer, texture and
  edit routes: that look (default: the build's); linked answers name it in their texture URIs.
- ``GET /v1/families/{name}/parts?prompt=&look=``: which group takes which part word of the prompt
  (default: the look's), with each group's evidence and score (:func:`proctex.build.looks.family_parts`).
  ``PUT`` (the token, JSON ``{"groups": {"3": "legs", "5": ""}, "replace": false}``) stores the
  user's word per group in the family (an empty word clears one); every look painted afterwards
  follows it.

Errors are JSON ``{"error": message}`` on every route: unknown family (or group in a path) 404, body
over the size limit 413, bad JSON, parameters out of bounds, unknown parameters, an unreadable mesh,
too many parts, a transfer past its time budget or a bad edit (unknown group, non-finite numbers, hue
outside [-360, 360], saturation or value outside [0, 4], prompt too long) 422; edits off 403, a wrong
token 401, a non-JSON edit 415, a stale stamp 409; a damaged family 503; anything unexpected a JSON 500.
"""

from __future__ import annotations

import asyncio
import errno
import hmac
import json
import mimetypes
import os
import re
import time
import weakref
from pathlib import Path
from typing import Any, Awaitable, Callable

from fastapi import FastAPI, Request
from fastapi.exceptions import RequestValidationError
from fastapi.responses import FileResponse, HTMLResponse, JSONResponse, Response
from pydantic import BaseModel, Field
from starlette.exceptions import HTTPException as StarletteHTTPException

from proctex.serve.catalog import Catalog, Watchdog
from proctex.serve.edits import EditConflict
from proctex.serve.service import (
    BadInput,
    Limits,
    NotFound,
    TooLarge,
    Unavailable,
    parse_edit,
)
from proctex.store.layout import StoreDamaged, StoreWriteError
from proctex.transfer.budget import Budget, OverBudget

from .looks import MAX_LOOK_BODY, MAX_LOOK_PHOTOS, add_look_to, parse_look, parts_of, save_parts

GLB_MEDIA_TYPE = "model/gltf-binary"
MAX_SEED = 2**31 - 1
STUDIO_DIST = Path(__file__).resolve().parent / "studio" / "dist"
_ASSET_NAME = re.compile(r"^[A-Za-z0-9_-][A-Za-z0-9._-]*(/[A-Za-z0-9_-][A-Za-z0-9._-]*)*$")
NOT_BUILT = """<!doctype html><html><head><meta charset="utf-8"><title>ProcTex studio not built</title></head>
<body style="font-family: sans-serif; max-width: 40em; margin: 3em auto">
<h1>ProcTex studio: not built</h1>
<p>The web studio's bundle is missing (<code>{dist}</code>). Build it with <code>make setup</code>
(it runs <code>npm ci --prefix workers/studio</code> and <code>npm run --prefix workers/studio build</code>;
needs Node.js and npm), then reload this page.</p>
<p>The JSON API works without it: <a href="/docs">/docs</a>, <a href="/v1/families">/v1/families</a>.</p>
</body></html>"""


class TransferRequest(BaseModel):
    """JSON body of a transfer by parameters."""

    params: dict[str, Any] = Field(default_factory=dict, description="parameter values (missing ones take their defaults)")
    seed: int = Field(0, ge=0, le=2**31 - 1, strict=True, description="seed (a whole number, not true or 1.0) of the network's context samples and of painting new parts")
    edits: dict[str, Any] | None = Field(None, description='non-destructive edits: {"<group index or label>": '
                                         '{"hue": degrees, "saturation": scale, "value": scale, "prompt": text}}')


class Forbidden(ValueError):
    """Stored edits are off on this service."""


class Unauthorized(ValueError):
    """A missing or wrong edit token."""


class UnsupportedType(ValueError):
    """A body of another content type than the route takes."""


def _error(status: int, message: str) -> JSONResponse:
    return JSONResponse({"error": message}, status_code=status)


def error_response(exc: BaseException) -> JSONResponse:
    """The JSON answer to an exception: unknown family or group 404, too large 413, over the time
    budget 422 (cancelled: 499), a store write that did not land 507 (a full disk) or 503 (no
    permission), a damaged or unreadable family 503, any other bad input (``ValueError``, a number
    too large for its type, a body nested too deep) 422; anything else 500, with its type, never a
    traceback."""
    if isinstance(exc, NotFound):
        return _error(404, str(exc))
    if isinstance(exc, TooLarge):
        return _error(413, str(exc))
    if isinstance(exc, Unavailable):
        return _error(503, str(exc))
    if isinstance(exc, SlowBody):
        return _error(408, str(exc))
    if isinstance(exc, TooManyFromClient):
        return JSONResponse({"error": str(exc)}, status_code=429, headers={"Retry-After": "1"})
    if isinstance(exc, Busy):
        return JSONResponse({"error": str(exc)}, status_code=503, headers={"Retry-After": "1"})
    if isinstance(exc, StoreWriteError):  # nothing of the change landed: the message says so and names the file
        return _error(507 if exc.errno in (errno.ENOSPC, errno.EDQUOT) else 503, str(exc))
    if isinstance(exc, StoreDamaged):
        return _error(503, f"the family is damaged: {exc}"[:1000])
    if isinstance(exc, PermissionError):
        return _error(503, f"the family's files cannot be read: permission denied ({exc.filename or exc})"[:1000])
    if isinstance(exc, OverBudget):
        return _error(499 if exc.cancelled else 422, str(exc))
    for kind, status in ((Forbidden, 403), (Unauthorized, 401), (UnsupportedType, 415), (EditConflict, 409)):
        if isinstance(exc, kind):
            return _error(status, str(exc))
    if isinstance(exc, (ValueError, OverflowError, RecursionError, UnicodeError)):
        return _error(422, (str(exc) or type(exc).__name__)[:1000])
    return _error(500, f"internal error ({type(exc).__name__}); the request was not served")


class SlowBody(ValueError):
    """A request body that did not arrive in time (408)."""


class Busy(RuntimeError):
    """Every upload slot of the replica is taken (503, retry)."""


#: Bodies being read now, per (event loop, pool): what ``Limits.max_uploads`` (pool "upload") and
#: ``Limits.max_small_bodies`` (pool "small") bound; and per (event loop, pool, client), what
#: ``Limits.client_uploads`` and ``Limits.client_small_bodies`` bound.
_READING: dict[tuple[int, str], int] = {}
_CLIENT_READING: dict[tuple[int, str, str], int] = {}


class TooManyFromClient(Busy):
    """One client holds its share of the body slots already (429, retry)."""


def client_of(request: Request, proxies: tuple = ()) -> str:
    """Who sent ``request``, for fairness: its TCP peer; when the peer is one of ``proxies``
    (:meth:`Limits.proxies`), the last address of ``X-Forwarded-For`` that is not itself a trusted
    proxy (a client cannot pose as another by writing the header: only what the trusted proxies
    appended counts). An IPv6 client is its /64 (one host holds a whole /64); "" when unknown."""
    import ipaddress

    peer = request.client.host if request.client else ""

    def parse(text: str):
        try:
            return ipaddress.ip_address(text.strip().strip("[]"))
        except ValueError:
            return None

    addr = parse(peer)
    if addr is not None and proxies and any(addr in net for net in proxies):
        chain = [parse(x) for x in request.headers.get("x-forwarded-for", "").split(",")[-32:]]
        for hop in reversed([a for a in chain if a is not None]):
            if not any(hop in net for net in proxies):
                addr = hop
                break
    if addr is None:
        return peer[:64]
    if addr.version == 6:
        if addr.ipv4_mapped is not None:
            return str(addr.ipv4_mapped)
        return str(ipaddress.ip_network(f"{addr}/64", strict=False))
    return str(addr)


async def read_body(request: Request, max_bytes: int, limits: Limits | None = None) -> bytes:
    """The request body, read in chunks and refused (:class:`TooLarge`) as soon as it passes
    ``max_bytes``, whether or not it declared a Content-Length, chunked or not; within ``limits``'
    time bounds (:class:`SlowBody` past ``body_seconds``, after a gap over ``body_idle_seconds``,
    or below ``body_min_rate`` on average) and slots (:class:`Busy` when ``max_uploads`` bodies
    are still being read after a short wait; bodies declaring at most ``small_body`` bytes take
    one of ``max_small_bodies`` slots instead). A request without a body takes no slot. Later
    ``request.form()`` / ``request.body()`` calls read these bytes again, not the socket."""
    limits = limits or Limits()
    length = request.headers.get("content-length")
    if (length is None and "transfer-encoding" not in request.headers) or length == "0":
        request._body = b""  # no body (RFC 9112 6.3): nothing to wait for, no upload slot taken
        return b""
    if length is not None and length.isdigit() and int(length) > max_bytes:
        raise TooLarge(f"request body of {length} bytes is over the limit of {max_bytes}")
    small = length is not None and length.isdigit() and int(length) <= limits.small_body  # framing holds it to that length
    pool = (id(asyncio.get_running_loop()), "small" if small else "upload")
    cap = limits.max_small_bodies if small else limits.max_uploads
    mine = (*pool, client_of(request, limits.proxies()))
    share = min(cap, limits.client_small_bodies if small else limits.client_uploads)
    kind = "small bodies" if small else "uploads"
    grace = time.monotonic() + min(1.0, limits.body_idle_seconds / 2)  # a sound body reads in milliseconds: wait that long for a slot
    while _CLIENT_READING.get(mine, 0) >= share or _READING.get(pool, 0) >= cap:
        if time.monotonic() > grace:  # every slot taken (503), or this client's share while others are free (429)
            if _READING.get(pool, 0) >= cap:
                raise Busy(f"{cap} {kind} are being read already; retry in a moment")
            raise TooManyFromClient(f"this client has {share} {kind} being read already (its share); retry in a moment")
        await asyncio.sleep(0.005)
    _READING[pool] = _READING.get(pool, 0) + 1
    _CLIENT_READING[mine] = _CLIENT_READING.get(mine, 0) + 1
    chunks, size = [], 0
    t0 = time.monotonic()
    stream = request.stream().__aiter__()
    try:
        while True:
            elapsed = time.monotonic() - t0
            wait = min(limits.body_idle_seconds, limits.body_seconds - elapsed)
            try:
                chunk = await asyncio.wait_for(stream.__anext__(), timeout=max(wait, 0.0))
            except StopAsyncIteration:
                break
            except asyncio.TimeoutError:
                idle = wait >= limits.body_idle_seconds
                raise SlowBody(f"request body too slow: {size} bytes in {time.monotonic() - t0:.1f} s, then "
                               + (f"nothing for {limits.body_idle_seconds:g} s" if idle else f"past the limit of {limits.body_seconds:g} s")) from None
            size += len(chunk)
            if size > max_bytes:
                raise TooLarge(f"request body over the limit of {max_bytes} bytes")
            chunks.append(chunk)
            elapsed = time.monotonic() - t0
            if elapsed > limits.body_idle_seconds and size / elapsed < limits.body_min_rate:
                raise SlowBody(f"request body too slow: {size} bytes in {elapsed:.1f} s (at least {limits.body_min_rate} bytes/s)")
    finally:
        _READING[pool] -= 1
        _CLIENT_READING[mine] -= 1
        if not _CLIENT_READING[mine]:
            del _CLIENT_READING[mine]
    body = b"".join(chunks)
    request._body = body  # starlette reads a consumed body from here
    return body


def _seed(raw: Any) -> int:
    try:
        value = int(raw)
    except (TypeError, ValueError, OverflowError):
        raise BadInput(f"seed must be an integer, got {str(raw)[:40]!r}") from None
    if not 0 <= value <= MAX_SEED:
        raise BadInput(f"seed must be in [0, {MAX_SEED}], got {str(raw)[:40]}")
    return value


async def read_transfer_request(request: Request, max_bytes: int, limits: Limits | None = None) -> tuple[str, Any, int, Any]:
    """``("params", dict, seed, edits)`` or ``("mesh", (bytes, filename), seed, edits)`` from a
    request (``edits``: the raw JSON value or None; see :meth:`FamilyService.parse_edits`); the body
    read within ``limits`` (:func:`read_body`)."""
    body = await read_body(request, max_bytes, limits)
    ctype = request.headers.get("content-type", "").split(";")[0].strip().lower()
    if ctype == "multipart/form-data":
        try:
            form = await request.form(max_files=1, max_fields=5)
        except Exception as exc:  # malformed multipart
            raise BadInput(f"cannot read the multipart body: {exc}") from exc
        upload = form.get("mesh")
        if upload is None or isinstance(upload, str):
            raise BadInput("multipart uploads need a file field named 'mesh'")
        data = await upload.read(max_bytes + 1)
        if len(data) > max_bytes:
            raise TooLarge(f"mesh upload over the limit of {max_bytes} bytes")
        seed = form.get("seed", "0")
        seed_value = _seed(seed if isinstance(seed, str) else 0)
        edits_text = form.get("edits")
        edits = None
        if isinstance(edits_text, str) and edits_text.strip():
            try:
                edits = json.loads(edits_text)
            except (ValueError, RecursionError) as exc:
                raise BadInput(f"the 'edits' field must be JSON text: {str(exc)[:200] or type(exc).__name__}") from exc
        return "mesh", (data, upload.filename or "mesh.obj"), seed_value, edits
    if ctype not in ("application/json", ""):
        raise BadInput(f"send application/json ({{\"params\": {{...}}}}) or multipart/form-data with a 'mesh' file, not {ctype!r}")
    try:
        req = TransferRequest.model_validate_json(body)
    except (ValueError, RecursionError) as exc:  # pydantic ValidationError or JSON errors
        raise BadInput(f"bad JSON body: {str(exc).splitlines()[0] if str(exc) else exc.__class__.__name__}; "
                       'expected {"params": {"name": value, ...}, "seed": 0}') from exc
    return "params", req.params, req.seed, req.edits


def json_object(text: str | bytes, not_json: str = "bad JSON body", what: str = "the body") -> dict[str, Any]:
    """``text`` read as a JSON object; :class:`BadInput` otherwise (``not_json``: the message's start
    for text that is no JSON, ``what``: what must be an object)."""
    try:
        data = json.loads(text or b"null")
    except (ValueError, RecursionError) as exc:
        raise BadInput(f"{not_json}: {str(exc)[:200] or type(exc).__name__}") from exc
    if not isinstance(data, dict):
        raise BadInput(f"{what} must be a JSON object")
    return data


async def read_json_object(request: Request, max_bytes: int = 65536, limits: Limits | None = None) -> dict[str, Any]:
    return json_object(await read_body(request, max_bytes, limits))


async def read_look_request(request: Request, limits: Limits | None = None) -> tuple[dict[str, Any], dict[str, tuple[bytes, str]]]:
    """``(body, photos)`` of a ``POST .../looks``: a JSON object, or ``multipart/form-data`` with a
    ``look`` field holding that JSON and a file field ``image.<part>`` per photo (``image.*``: the
    photo of the rest); ``photos``: part -> (bytes, file name). Sizes bounded before anything is
    decoded: the body (:data:`MAX_LOOK_BODY`), the photo count (:data:`MAX_LOOK_PHOTOS`). A file field
    ``glb`` instead: the family's template GLB painted elsewhere (a look read from it), under the key
    ``"glb"``."""
    ctype = request.headers.get("content-type", "").split(";")[0].strip().lower()
    if ctype != "multipart/form-data":
        return await read_json_object(request, limits=limits), {}
    await read_body(request, MAX_LOOK_BODY, limits)
    try:
        form = await request.form(max_files=MAX_LOOK_PHOTOS, max_fields=MAX_LOOK_PHOTOS + 2)
    except Exception as exc:  # malformed multipart, too many parts
        raise BadInput(f"cannot read the multipart body (at most {MAX_LOOK_PHOTOS} photos): {str(exc)[:200]}") from exc
    text, photos = None, {}
    for key, value in form.multi_items():
        if key == "look" and isinstance(value, str):
            if text is not None:
                raise BadInput("the 'look' field is given twice")
            text = value
        elif key == "glb" and not isinstance(value, str):
            if "glb" in photos:
                raise BadInput("the 'glb' file is given twice")
            photos["glb"] = (await value.read(MAX_LOOK_BODY + 1), str(value.filename or "template.glb")[:120])
        elif key.startswith("image.") and not isinstance(value, str):
            part = key[len("image."):]
            if not part or len(part) > 200 or part in photos:
                raise BadInput(f"photo fields are image.<part> (a group number, part name or word, or *), each once; got {key[:60]!r}")
            photos[part] = (await value.read(MAX_LOOK_BODY + 1), str(value.filename or part)[:120])
        else:
            raise BadInput(f"unknown multipart field {key[:60]!r}; a photo look sends 'look' (JSON) and image.<part> files, "
                           "a repainted template 'look' and a 'glb' file")
    if text is None:
        raise BadInput("a multipart look needs a 'look' field: the look's JSON ({\"name\": ..., \"prompt\": ...})")
    return json_object(text, "the 'look' field must be JSON", "the 'look' field"), photos


def create_app(get_catalog: Callable[[], Catalog], run: Callable[[Callable[[], Any]], Any] | None = None,
               studio_dir: str | Path | None = None, watchdog: Watchdog | None = None, edit_token: str | None = None,
               get_family: Callable[[str], Awaitable[Any]] | None = None, replica: str | None = None) -> FastAPI:
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

    async def blocking(fn: Callable[[], Any]) -> Any:
        if run is not None:
            return await run(fn)
        return await asyncio.to_thread(fn)

    dog = watchdog if watchdog is not None else Watchdog(2 * get_catalog().limits.max_seconds + 30)
    served_by = {"X-ProcTex-Replica": replica} if replica else {}

    async def family_of(name: str) -> Any:
        if get_family is not None:
            return await get_family(name)
        return await blocking(lambda: get_catalog().get(name))

    async def look_of(name: str, look: str | None) -> Any:
        """The family's service textured as its ``look`` (None: the build's look)."""
        svc = await family_of(name)
        if look is None:
            return svc
        if not isinstance(look, str) or len(look) > 200:
            raise BadInput("look must be a look's name")
        return await blocking(lambda: svc.look_view(look))

    gates: weakref.WeakKeyDictionary[Any, asyncio.Semaphore] = weakref.WeakKeyDictionary()
    look_gates: dict[str, asyncio.Semaphore] = {}  # per family store: the looks being painted

    async def watched(fn: Callable[[], Any], request: Request, budget: Budget) -> Any:
        """Run ``fn`` off the event loop; cancel its budget if the client disconnects meanwhile."""
        task = asyncio.ensure_future(blocking(fn))
        while True:
            done, _ = await asyncio.wait({task}, timeout=0.25)
            if done:
                return task.result()
            if not budget.cancelled and await request.is_disconnected():
                budget.cancel()

    def check_edit_request(request: Request, multipart: bool = False) -> None:
        """Stored edits need the service's token and a JSON body (a cross-site form cannot send
        either; ``multipart``: a look's photos may come as multipart/form-data, still behind the
        token header a form cannot set): 403 when edits are off, 401 for a missing or wrong token,
        415 for another body type."""
        if not edit_token:
            raise Forbidden("this service is read-only: stored edits are off (start it with an edit token)")
        given = request.headers.get("x-proctex-token") or ""
        auth = request.headers.get("authorization") or ""
        if not given and auth.lower().startswith("bearer "):
            given = auth[7:].strip()
        if not hmac.compare_digest(given.encode(), edit_token.encode()):
            raise Unauthorized("stored edits need the service's edit token (header X-ProcTex-Token)")
        if request.method == "POST":
            ctype = request.headers.get("content-type", "").split(";")[0].strip().lower()
            if ctype != "application/json" and not (multipart and ctype == "multipart/form-data"):
                also = " or multipart/form-data (photos)" if multipart else ""
                raise UnsupportedType(f"send the edit as application/json{also}, not {ctype or 'no content type'!r}")

    @app.exception_handler(Exception)
    async def any_error(request: Request, exc: Exception):
        return error_response(exc)

    @app.exception_handler(RequestValidationError)
    async def validation_error(request: Request, exc: RequestValidationError):
        parts = ["/".join(str(x) for x in e.get("loc", ())) + ": " + str(e.get("msg", "")) for e in exc.errors()]
        return _error(422, "; ".join(parts) or "bad request")

    @app.exception_handler(StarletteHTTPException)
    async def http_error(request: Request, exc: StarletteHTTPException):
        message = exc.detail if isinstance(exc.detail, str) else json.dumps(exc.detail)
        if exc.status_code == 404:
            message = f"no route {request.url.path!r}; see /docs"
        return JSONResponse({"error": message}, status_code=exc.status_code, headers=getattr(exc, "headers", None))

    # ------------------------------------------------------------------------------ the studio
    @app.get("/", response_class=HTMLResponse, include_in_schema=False)
    def studio_index():
        index = dist / "index.html"
        if not index.is_file():
            return HTMLResponse(NOT_BUILT.format(dist=dist), status_code=503)
        return FileResponse(index, media_type="text/html", headers={"Cache-Control": "no-cache"})

    @app.get("/studio/{path:path}", include_in_schema=False)
    def studio_asset(path: str):
        if _ASSET_NAME.match(path) and ".." not in path.split("/"):
            root = dist.resolve()
            target = (root / path).resolve()
            if target.is_relative_to(root) and target.is_file():
                media = mimetypes.guess_type(target.name)[0] or "application/octet-stream"
                return FileResponse(target, media_type=media, headers={"Cache-Control": "no-cache"})
        return _error(404, f"no studio asset {path!r}")

    # ------------------------------------------------------------------------------------ API
    @app.get("/healthz")
    def healthz():
        cat = get_catalog()
        health = cat.health()
        info = {"families": len(health), "unavailable": sorted(n for n, h in health.items() if h not in ("ok", "not built")),
                "loaded": cat.loaded(), "loads": cat.loads, "replica": replica, "transfers_running": dog.running(),
                "oldest_transfer_seconds": round(dog.oldest(), 3)}
        if dog.stuck():
            return JSONResponse({"status": "stuck", **info}, status_code=503)
        return {"status": "ok", **info}

    @app.get("/v1/families")
    def families() -> dict[str, Any]:
        """The families under the root and the health of each ("ok", "not built", or why a damaged
        one is unavailable)."""
        cat = get_catalog()
        return {"families": cat.names(), "health": cat.health()}

    @app.get("/v1/families/{name}", responses={404: {"description": "unknown family"}})
    async def family(name: str, look: str | None = None):
        try:
            svc = await look_of(name, look)
            return {**svc.describe(), "edits_enabled": bool(edit_token)}
        except Exception as exc:
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
    async def transfer(name: str, request: Request, textures: str = "embedded", look: str | None = None):
        """``?textures=linked``: the GLB refers to the family's textures (``textures/<g>.png?v=...``,
        relative to this URL) instead of carrying them; a client caches those once. ``?look=NAME``:
        textured as that look of the family (``GET .../looks``; default: the build's)."""
        token = None
        try:
            if textures not in ("embedded", "linked"):
                raise BadInput(f"textures must be 'embedded' or 'linked', got {textures[:40]!r}")
            svc = await look_of(name, look)
            kind, payload, seed, raw_edits = await read_transfer_request(request, svc.limits.max_bytes, svc.limits)
            edits = svc.parse_edits(raw_edits)

            def work():
                shape = svc.shape_from_params(payload) if kind == "params" else svc.shape_from_mesh(*payload, budget=budget)
                budget.check("reading the shape")
                return svc.transfer(shape, seed=seed, edits=edits, budget=budget, linked=textures == "linked")

            gate = gates.setdefault(svc, asyncio.Semaphore(1))
            async with gate:  # one transfer of this family at a time; the others wait here, not in a thread
                if await request.is_disconnected():
                    return _error(499, "the client went away before its transfer started")
                budget = Budget(svc.limits.max_seconds)  # the budget counts from the turn, not the queue
                token = dog.begin()
                data, summary = await watched(work, request, budget)
        except Exception as exc:
            return error_response(exc)
        finally:
            if token is not None:
                dog.end(token)
        headers = {"X-ProcTex-Seconds": str(summary["seconds"]), "X-ProcTex-Notes": json.dumps(summary["notes"])[:2000],
                   "Content-Disposition": f'inline; filename="{name}.glb"', **served_by}
        return Response(content=data, media_type=GLB_MEDIA_TYPE, headers=headers)

    @app.get(
        "/v1/families/{name}/textures/{file}",
        response_class=Response,
        responses={200: {"content": {"image/png": {}}, "description": "a template group's texture as stored"},
                   304: {"description": "not modified (If-None-Match)"}, 404: {"description": "unknown family or group"}},
    )
    async def group_texture_file(name: str, file: str, request: Request, v: str | None = None, look: str | None = None):
        """The texture a linked GLB refers to (``<group>.png``; ``?look=``: of that look), with its
        digest as ETag. With ``v`` equal to the digest's start (as the GLB writes it) it is cached
        as immutable."""
        try:
            if not file.endswith(".png"):
                raise NotFound(f"no texture {file[:80]!r}; textures are <group>.png")
            svc = await look_of(name, look)
            png, digest = svc.texture_png(file[:-4])
        except Exception as exc:
            return error_response(exc)
        etag = f'"{digest}"'
        cache = "public, max-age=31536000, immutable" if v and digest.startswith(v) and len(v) >= 8 else "no-cache"
        headers = {"ETag": etag, "Cache-Control": cache, **served_by}
        if etag in [t.strip() for t in request.headers.get("if-none-match", "").split(",")]:
            return Response(status_code=304, headers=headers)
        return Response(content=png, media_type="image/png", headers=headers)

    @app.get(
        "/v1/families/{name}/groups/{group}/texture.png",
        response_class=Response,
        responses={200: {"content": {"image/png": {}}, "description": "the (edited) group texture"},
                   404: {"description": "unknown family or group"}, 422: {"description": "bad edit or size"}},
    )
    async def group_texture(name: str, group: str, size: str = "128", hue: str | None = None, saturation: str | None = None,
                            value: str | None = None, prompt: str | None = None, look: str | None = None):
        """The group's template texture (``?look=``: of that look), edited as the query says (no
        edit: the stored one)."""
        try:
            svc = await look_of(name, look)
            g = svc.group_index(group, missing=NotFound)
            edit = parse_edit({"hue": hue, "saturation": saturation, "value": value, "prompt": prompt}, svc.limits.max_prompt)
            data = await blocking(lambda: svc.thumbnail(g, edit, size))
        except Exception as exc:
            return error_response(exc)
        return Response(content=data, media_type="image/png", headers={"Cache-Control": "no-cache", "X-ProcTex-Stamp": svc.stamp})

    @app.post(
        "/v1/families/{name}/edits",
        responses={404: {"description": "unknown family"}, 422: {"description": "bad edit"}},
        openapi_extra={"requestBody": {"required": True, "content": {"application/json": {"schema": {
            "type": "object", "required": ["group"], "properties": {
                "group": {"type": ["integer", "string"]}, "hue": {"type": "number"}, "saturation": {"type": "number"},
                "value": {"type": "number"}, "prompt": {"type": "string"}}}}}}},
    )
    async def persist_edit(name: str, request: Request, look: str | None = None):
        """Store an edit of one group texture in the family (``?look=``: of that look); every later
        transfer uses it. Needs the edit token; ``If-Match: <stamp>`` makes it conditional on the
        family being unchanged (409)."""
        try:
            svc = await look_of(name, look)
            check_edit_request(request)
            body = await read_json_object(request, limits=svc.limits)
            expect = request.headers.get("if-match")
            changed = await blocking(lambda: svc.persist_edit(body, expect_stamp=expect))  # the stamp read under the edit's lock
        except Exception as exc:
            return error_response(exc)
        finally:
            get_catalog().invalidate(name)
        return {"family": name, "edit": changed.record, "stamp": changed.version}

    async def undo(name: str, request: Request, look: str | None = None, **how: Any):
        """Undo stored edits of family ``name``'s ``look`` (``how``: :meth:`FamilyService.undo_edit`'s arguments)."""
        try:
            svc = await look_of(name, look)
            check_edit_request(request)
            changed = await blocking(lambda: svc.undo_edit(**how))
        except Exception as exc:
            return error_response(exc)
        finally:
            get_catalog().invalidate(name)
        return {"family": name, "undone": changed.record, "stamp": changed.version}

    @app.delete("/v1/families/{name}/edits/last", responses={404: {"description": "unknown family"}, 409: {"description": "nothing to undo"}})
    async def undo_edit(name: str, request: Request, look: str | None = None):
        """Undo the family's (``?look=``: that look's) last stored edit (needs the edit token;
        ``If-Match: <stamp>`` makes it conditional)."""
        return await undo(name, request, look, expect_stamp=request.headers.get("if-match"))

    @app.delete("/v1/families/{name}/edits", responses={404: {"description": "unknown family"}})
    async def reset_edits(name: str, request: Request, look: str | None = None):
        """Undo every stored edit (``?look=``: of that look): the look as painted (needs the edit token)."""
        return await undo(name, request, look, all_edits=True)

    @app.get("/v1/families/{name}/looks", responses={404: {"description": "unknown family"}})
    async def family_looks(name: str):
        """The family's looks: name, prompt, painter, texture size, edits; the build's first."""
        try:
            svc = await family_of(name)
            return {"family": name, "looks": await blocking(svc.looks)}
        except Exception as exc:
            return error_response(exc)

    @app.post(
        "/v1/families/{name}/looks",
        responses={404: {"description": "unknown family"}, 409: {"description": "a build or edit of the family is running"},
                   422: {"description": "bad look"}},
        openapi_extra={"requestBody": {"required": True, "content": {"application/json": {"schema": {
            "type": "object", "required": ["name", "prompt"], "properties": {
                "name": {"type": "string"}, "prompt": {"type": "string"}, "group_prompts": {"type": "object"},
                "part_words": {"type": "object"}, "painter": {"type": "string"}, "texture_size": {"type": "integer"}, "force": {"type": "boolean"}}}},
            "multipart/form-data": {"schema": {"type": "object", "required": ["look"], "properties": {
                "look": {"type": "string", "description": "the look's JSON (prompt optional), with images: {part: {scale, rotate, normal, roughness}}"},
                "image.*": {"type": "string", "format": "binary", "description": "a photo per part: fields image.<part>"}}}}}}},
    )
    async def add_family_look(name: str, request: Request):
        """Paint a new look of the family (the stored template with another prompt, or photos sent
        as multipart ``image.<part>`` files: seconds, no rebuild) and store it; served at once
        (``?look=NAME``). Needs the edit token."""
        try:
            svc = await family_of(name)
            check_edit_request(request, multipart=True)
            body, files = await read_look_request(request, limits=svc.limits)
            look, paint, force, photos = await blocking(lambda: parse_look(body, svc, files))  # photos decode off the loop
            gate = look_gates.setdefault(svc.store.uri, asyncio.Semaphore(svc.limits.look_paints))
            async with gate:  # at most look_paints paints of this family at a time; the others wait here, not in a thread
                if await request.is_disconnected():
                    return _error(499, "the client went away before its look was painted")
                budget = Budget(svc.limits.look_seconds)
                changed = await watched(lambda: add_look_to(svc, look, paint, force, photos, budget), request, budget)
        except Exception as exc:
            return error_response(exc)
        finally:
            get_catalog().invalidate(name)
        return {"family": name, "look": changed.record, "stamp": changed.version}

    @app.get("/v1/families/{name}/parts", responses={404: {"description": "unknown family or look"}})
    async def family_parts(name: str, prompt: str | None = None, look: str | None = None):
        """Which group takes which part word of ``prompt`` (default: the look's prompt; ``look``
        default: the build's): per group its word, how it got it, its score, its evidence and the
        text it is painted with; the family's stored words (``stored``) count."""
        try:
            svc = await family_of(name)
            return await blocking(lambda: parts_of(svc, prompt, look))
        except Exception as exc:
            return error_response(exc)

    @app.put(
        "/v1/families/{name}/parts",
        responses={404: {"description": "unknown family"}, 409: {"description": "an edit of the family is running"},
                   422: {"description": "bad words"}},
        openapi_extra={"requestBody": {"required": True, "content": {"application/json": {"schema": {
            "type": "object", "required": ["groups"], "properties": {
                "groups": {"type": "object", "additionalProperties": {"type": "string"}}, "replace": {"type": "boolean"}}}}}}},
    )
    async def store_parts(name: str, request: Request):
        """Store the user's word per group in the family (``{"groups": {"3": "legs"}}``; an empty word
        clears a group's, ``replace`` drops the others): every look painted afterwards follows it.
        Needs the edit token. Returns the stored words."""
        try:
            svc = await family_of(name)
            check_edit_request(request)
            body = await read_json_object(request, limits=svc.limits)
            stored = await blocking(lambda: save_parts(svc, body))
        except Exception as exc:
            return error_response(exc)
        return {"family": name, "stored": stored}

    return app
