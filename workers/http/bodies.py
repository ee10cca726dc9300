"""Reading a request's body within its bounds (size, time, rate, upload slots, the client's share)
and parsing it: a transfer by parameters or by an uploaded mesh, a JSON object, a look with photos;
who sent a request (:func:`client_of`)."""

from __future__ import annotations

import asyncio
import json
import time
from typing import Any

from fastapi import Request
from pydantic import BaseModel, Field

from proctex.serve.service import BadInput, Limits, TooLarge

from .errors import Busy, SlowBody, TooManyFromClient
from .looks import MAX_LOOK_BODY, MAX_LOOK_PHOTOS

MAX_SEED = 2**31 - 1

#: Bodies being read now, per (event loop, pool): what ``Limits.max_uploads`` (pool "upload") and
#: ``Limits.max_small_bodies`` (pool "small") bound; and per (event loop, pool, client), what
#: ``Limits.client_uploads`` and ``Limits.client_small_bodies`` bound.
_READING: dict[tuple[int, str], int] = {}
_CLIENT_READING: dict[tuple[int, str, str], int] = {}


class TransferRequest(BaseModel):
    """JSON body of a transfer by parameters."""

    params: dict[str, Any] = Field(default_factory=dict, description="parameter values (missing ones take their defaults)")
    seed: int = Field(0, ge=0, le=2**31 - 1, strict=True, description="seed (a whole number, not true or 1.0) of the network's context samples and of painting new parts")
    edits: dict[str, Any] | None = Field(None, description='non-destructive edits: {"<group index or label>": {"hue": degrees, "saturation": scale, "value": scale, "prompt": text}}')


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
                raise SlowBody(
                    f"request body too slow: {size} bytes in {time.monotonic() - t0:.1f} s, then "
                    + (f"nothing for {limits.body_idle_seconds:g} s" if idle else f"past the limit of {limits.body_seconds:g} s")
                ) from None
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
        raise BadInput(f'bad JSON body: {str(exc).splitlines()[0] if str(exc) else exc.__class__.__name__}; expected {{"params": {{"name": value, ...}}, "seed": 0}}') from exc
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
            part = key[len("image.") :]
            if not part or len(part) > 200 or part in photos:
                raise BadInput(f"photo fields are image.<part> (a group number, part name or word, or *), each once; got {key[:60]!r}")
            photos[part] = (await value.read(MAX_LOOK_BODY + 1), str(value.filename or part)[:120])
        else:
            raise BadInput(f"unknown multipart field {key[:60]!r}; a photo look sends 'look' (JSON) and image.<part> files, a repainted template 'look' and a 'glb' file")
    if text is None:
        raise BadInput('a multipart look needs a \'look\' field: the look\'s JSON ({"name": ..., "prompt": ...})')
    return json_object(text, "the 'look' field must be JSON", "the 'look' field"), photos
