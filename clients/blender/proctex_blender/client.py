"""The ProcTex HTTP API as the add-on speaks it: the standard library only (no ``bpy``, no
``proctex``), so it runs in any Blender's Python and can be tested outside Blender.

Every call is bounded by a timeout and raises :class:`ServiceError` with the service's own message
(its JSON ``error`` field) or the network's.
"""

from __future__ import annotations

import json
import urllib.error
import urllib.parse
import urllib.request
import uuid
from typing import Any

DEFAULT_URL = "http://127.0.0.1:8000"
MAX_ANSWER = 256 * 2**20  # a GLB larger than this is refused rather than read into memory


class ServiceError(Exception):
    """A failed call: ``status`` is the HTTP status (0 when the service could not be reached)."""

    def __init__(self, message: str, status: int = 0) -> None:
        super().__init__(message)
        self.status = status


def _base(url: str) -> str:
    url = (url or "").strip().rstrip("/")
    parts = urllib.parse.urlsplit(url)
    if parts.scheme not in ("http", "https") or not parts.netloc:
        raise ServiceError(f"the service URL must look like {DEFAULT_URL}, got {url!r}")
    return url


def _family_path(name: str) -> str:
    if not name:
        raise ServiceError("pick a family first")
    return "/v1/families/" + urllib.parse.quote(name, safe="")


def _call(url: str, path: str, data: bytes | None = None, headers: dict[str, str] | None = None, timeout: float = 30.0) -> tuple[bytes, dict[str, str]]:
    req = urllib.request.Request(_base(url) + path, data=data, headers=dict(headers or {}), method="POST" if data is not None else "GET")
    try:
        with urllib.request.urlopen(req, timeout=timeout) as answer:
            body = answer.read(MAX_ANSWER + 1)
            if len(body) > MAX_ANSWER:
                raise ServiceError(f"the answer is over {MAX_ANSWER} bytes")
            return body, {k.lower(): v for k, v in answer.headers.items()}
    except urllib.error.HTTPError as exc:
        text = exc.read(65536).decode("utf-8", "replace")
        try:
            message = json.loads(text).get("error") or text
        except (ValueError, AttributeError):
            message = text
        raise ServiceError(f"{exc.code}: {str(message)[:500]}", exc.code) from None
    except (urllib.error.URLError, OSError) as exc:  # refused, timed out, DNS...
        raise ServiceError(f"cannot reach {url}: {getattr(exc, 'reason', exc)}") from None


def _json(body: bytes) -> Any:
    try:
        return json.loads(body)
    except ValueError as exc:
        raise ServiceError(f"the service answered something that is not JSON: {exc}") from None


def families(url: str, timeout: float = 10.0) -> list[dict[str, str]]:
    """``[{"name", "health"}]`` of the families the service holds (``GET /v1/families``)."""
    data = _json(_call(url, "/v1/families", timeout=timeout)[0])
    health = data.get("health") or {}
    return [{"name": str(n), "health": str(health.get(n, "ok"))} for n in data.get("families", [])]


def describe(url: str, name: str, timeout: float = 30.0) -> dict[str, Any]:
    """The family's description: ``parameters`` (specs), ``groups``, ``inputs`` ("params", "mesh")."""
    return _json(_call(url, _family_path(name), timeout=timeout)[0])


def looks(url: str, name: str, timeout: float = 30.0) -> list[dict[str, Any]]:
    """The family's looks (``GET /v1/families/{name}/looks``): ``[{"name", "prompt", ...}]``, the
    build's first."""
    data = _json(_call(url, _family_path(name) + "/looks", timeout=timeout)[0])
    return [dict(lk) for lk in data.get("looks", []) if isinstance(lk, dict) and isinstance(lk.get("name"), str)]


def _transfer_path(name: str, look: str | None) -> str:
    return _family_path(name) + "/transfer" + (f"?look={urllib.parse.quote(look, safe='')}" if look else "")


def multipart(fields: dict[str, str], file_field: str, filename: str, content: bytes) -> tuple[bytes, str]:
    """A ``multipart/form-data`` body and its content type."""
    boundary = "proctex-" + uuid.uuid4().hex
    out = []
    for key, value in fields.items():
        out.append(f'--{boundary}\r\nContent-Disposition: form-data; name="{key}"\r\n\r\n{value}\r\n'.encode())
    out.append(f'--{boundary}\r\nContent-Disposition: form-data; name="{file_field}"; filename="{filename}"\r\nContent-Type: application/octet-stream\r\n\r\n'.encode())
    out.append(content)
    out.append(f"\r\n--{boundary}--\r\n".encode())
    return b"".join(out), f"multipart/form-data; boundary={boundary}"


def multipart_files(fields: dict[str, str], files: list[tuple[str, str, bytes]]) -> tuple[bytes, str]:
    """A ``multipart/form-data`` body of text ``fields`` and ``files`` (field, file name, bytes), and its content type."""
    boundary = "proctex-" + uuid.uuid4().hex
    out = []
    for key, value in fields.items():
        out.append(f'--{boundary}\r\nContent-Disposition: form-data; name="{key}"\r\n\r\n{value}\r\n'.encode())
    for field, filename, content in files:
        safe = "".join(c for c in filename if c.isprintable() and c not in '"\\\r\n')[:120] or "photo"
        out.append(f'--{boundary}\r\nContent-Disposition: form-data; name="{field}"; filename="{safe}"\r\nContent-Type: application/octet-stream\r\n\r\n'.encode())
        out.append(content)
        out.append(b"\r\n")
    out.append(f"--{boundary}--\r\n".encode())
    return b"".join(out), f"multipart/form-data; boundary={boundary}"


def add_photo_look(
    url: str, name: str, token: str, look: str, photos: dict[str, tuple[str, bytes]], prompt: str | None = None, settings: dict[str, dict[str, Any]] | None = None, timeout: float = 120.0
) -> dict[str, Any]:
    """Paint a new look of the family from photos (``POST /v1/families/{name}/looks``, multipart):
    ``photos`` part -> (file name, bytes), a part being a group number, part name or word, or ``*``
    for the rest; ``settings`` part -> ``{"scale", "rotate", "normal", "roughness"}``; ``token``
    the service's edit token. Returns the look's record."""
    if not token:
        raise ServiceError("a new look needs the service's edit token")
    if not look or not photos:
        raise ServiceError("a photo look needs a name and at least one photo")
    body_json: dict[str, Any] = {"name": look}
    if prompt:
        body_json["prompt"] = prompt
    if settings:
        body_json["images"] = settings
    files = [(f"image.{part}", fname, data) for part, (fname, data) in photos.items()]
    body, ctype = multipart_files({"look": json.dumps(body_json)}, files)
    data, _ = _call(url, _family_path(name) + "/looks", body, {"Content-Type": ctype, "X-ProcTex-Token": token}, timeout=timeout)
    return _json(data).get("look") or {}


def transfer_mesh(url: str, name: str, obj_text: bytes, seed: int = 0, timeout: float = 120.0, look: str | None = None) -> tuple[bytes, dict[str, Any]]:
    """Texture a mesh (OBJ text) in the family's ``look`` (None: the build's): ``(GLB bytes, {"seconds", "notes"})``."""
    body, ctype = multipart({"seed": str(int(seed))}, "mesh", "mesh.obj", obj_text)
    data, headers = _call(url, _transfer_path(name, look), body, {"Content-Type": ctype}, timeout=timeout)
    return data, _summary(headers)


def transfer_params(url: str, name: str, params: dict[str, Any], seed: int = 0, timeout: float = 120.0, look: str | None = None) -> tuple[bytes, dict[str, Any]]:
    """Texture the family's own shape for ``params`` in its ``look`` (None: the build's):
    ``(GLB bytes, {"seconds", "notes"})``."""
    body = json.dumps({"params": params, "seed": int(seed)}).encode()
    data, headers = _call(url, _transfer_path(name, look), body, {"Content-Type": "application/json"}, timeout=timeout)
    return data, _summary(headers)


def _summary(headers: dict[str, str]) -> dict[str, Any]:
    try:
        notes = json.loads(headers.get("x-proctex-notes", "[]"))
    except ValueError:
        notes = []
    try:
        seconds = float(headers.get("x-proctex-seconds", "nan"))
    except ValueError:
        seconds = float("nan")
    return {"seconds": seconds, "notes": notes if isinstance(notes, list) else []}


def obj_text(vertices: Any, triangles: Any, parts: Any = None) -> bytes:
    """OBJ text of a triangle mesh: ``vertices`` a flat sequence of x, y, z; ``triangles`` a flat
    sequence of 0-based vertex indices, three per face; ``parts`` (optional): a part value per
    triangle, written as OBJ groups (``g part_<value>`` before each run of a part's faces)."""
    n, m = len(vertices) // 3, len(triangles) // 3
    if parts is not None and len(parts) != m:
        raise ValueError(f"parts needs one value per triangle, got {len(parts)} for {m}")
    lines = [f"v {vertices[3 * i]:.7g} {vertices[3 * i + 1]:.7g} {vertices[3 * i + 2]:.7g}" for i in range(n)]
    current = None
    for k in range(m):
        if parts is not None and parts[k] != current:
            current = parts[k]
            lines.append(f"g part_{current:g}" if isinstance(current, float) else f"g part_{current}")
        lines.append(f"f {triangles[3 * k] + 1} {triangles[3 * k + 1] + 1} {triangles[3 * k + 2] + 1}")
    return ("\n".join(lines) + "\n").encode()
