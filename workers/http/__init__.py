"""The HTTP API of the transfer service (FastAPI), shared by the Ray Serve ingress and tests: the app
(:mod:`workers.http.app`), one router per resource (:mod:`workers.http.routes`), reading bodies
within their bounds (:mod:`workers.http.bodies`), errors as JSON (:mod:`workers.http.errors`). The
service answers (:mod:`proctex.serve`): this layer reads requests and writes answers, and runs no
build step.

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
  (default: the look's), with each group's evidence and score (:func:`proctex.looks.family_parts`).
  ``PUT`` (the token, JSON ``{"groups": {"3": "legs", "5": ""}, "replace": false}``) stores the
  user's word per group in the family (an empty word clears one); every look painted afterwards
  follows it.

Errors are JSON ``{"error": message}`` on every route: unknown family (or group in a path) 404, body
over the size limit 413, bad JSON, parameters out of bounds, unknown parameters, an unreadable mesh,
too many parts, a transfer past its time budget or a bad edit (unknown group, non-finite numbers, hue
outside [-360, 360], saturation or value outside [0, 4], prompt too long) 422; edits off 403, a wrong
token 401, a non-JSON edit 415, a stale stamp 409; a damaged family 503; anything unexpected a JSON 500.
"""

from .app import STUDIO_DIST, create_app
from .bodies import MAX_SEED, TransferRequest, client_of, json_object, read_body, read_json_object, read_look_request, read_transfer_request
from .errors import Busy, Forbidden, SlowBody, TooManyFromClient, Unauthorized, UnsupportedType, error_response
from .looks import MAX_LOOK_BODY, MAX_LOOK_PHOTOS, MAX_LOOK_TEXTURE, parse_look, parse_photos
from .routes.transfer import GLB_MEDIA_TYPE

__all__ = [
    "STUDIO_DIST",
    "create_app",
    "MAX_SEED",
    "TransferRequest",
    "client_of",
    "json_object",
    "read_body",
    "read_json_object",
    "read_look_request",
    "read_transfer_request",
    "Busy",
    "Forbidden",
    "SlowBody",
    "TooManyFromClient",
    "Unauthorized",
    "UnsupportedType",
    "error_response",
    "MAX_LOOK_BODY",
    "MAX_LOOK_PHOTOS",
    "MAX_LOOK_TEXTURE",
    "parse_look",
    "parse_photos",
    "GLB_MEDIA_TYPE",
]
