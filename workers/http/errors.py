"""The HTTP answers of errors: every route answers JSON ``{"error": message}`` with the status of
its exception (:func:`error_response`), never a traceback or a plain 500."""

from __future__ import annotations

import errno

from fastapi.responses import JSONResponse

from proctex.serve.edits import EditConflict
from proctex.serve.service import NotFound, TooLarge, Unavailable
from proctex.store.layout import StoreDamaged, StoreWriteError
from proctex.transfer.budget import OverBudget


class Forbidden(ValueError):
    """Stored edits are off on this service."""


class Unauthorized(ValueError):
    """A missing or wrong edit token."""


class UnsupportedType(ValueError):
    """A body of another content type than the route takes."""


class SlowBody(ValueError):
    """A request body that did not arrive in time (408)."""


class Busy(RuntimeError):
    """Every upload slot of the replica is taken (503, retry)."""


class TooManyFromClient(Busy):
    """One client holds its share of the body slots already (429, retry)."""


def error(status: int, message: str) -> JSONResponse:
    return JSONResponse({"error": message}, status_code=status)


def error_response(exc: BaseException) -> JSONResponse:
    """The JSON answer to an exception: unknown family or group 404, too large 413, over the time
    budget 422 (cancelled: 499), a store write that did not land 507 (a full disk) or 503 (no
    permission), a damaged or unreadable family 503, any other bad input (``ValueError``, a number
    too large for its type, a body nested too deep) 422; anything else 500, with its type, never a
    traceback."""
    if isinstance(exc, NotFound):
        return error(404, str(exc))
    if isinstance(exc, TooLarge):
        return error(413, str(exc))
    if isinstance(exc, Unavailable):
        return error(503, str(exc))
    if isinstance(exc, SlowBody):
        return error(408, str(exc))
    if isinstance(exc, TooManyFromClient):
        return JSONResponse({"error": str(exc)}, status_code=429, headers={"Retry-After": "1"})
    if isinstance(exc, Busy):
        return JSONResponse({"error": str(exc)}, status_code=503, headers={"Retry-After": "1"})
    if isinstance(exc, StoreWriteError):  # nothing of the change landed: the message says so and names the file
        return error(507 if exc.errno in (errno.ENOSPC, errno.EDQUOT) else 503, str(exc))
    if isinstance(exc, StoreDamaged):
        return error(503, f"the family is damaged: {exc}"[:1000])
    if isinstance(exc, PermissionError):
        return error(503, f"the family's files cannot be read: permission denied ({exc.filename or exc})"[:1000])
    if isinstance(exc, OverBudget):
        return error(499 if exc.cancelled else 422, str(exc))
    for kind, status in ((Forbidden, 403), (Unauthorized, 401), (UnsupportedType, 415), (EditConflict, 409)):
        if isinstance(exc, kind):
            return error(status, str(exc))
    if isinstance(exc, (ValueError, OverflowError, RecursionError, UnicodeError)):
        return error(422, (str(exc) or type(exc).__name__)[:1000])
    return error(500, f"internal error ({type(exc).__name__}); the request was not served")
