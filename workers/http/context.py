"""What every route of one app shares (:class:`AppContext`): the catalog, how blocking work runs,
the watchdog of transfers under way, the edit token, the per-family gates; and the steps routes
have in common (a family's service, a look of it, work watched for a client that leaves, the
check of a stored edit's request)."""

from __future__ import annotations

import asyncio
import hmac
import weakref
from dataclasses import dataclass, field
from typing import Any, Awaitable, Callable

from fastapi import Request

from proctex.serve.catalog import Catalog, Watchdog
from proctex.serve.service import BadInput, FamilyService
from proctex.transfer.budget import Budget

from .errors import Forbidden, Unauthorized, UnsupportedType


@dataclass
class AppContext:
    """The state one app's routes share.

    Attributes:
        get_catalog: the catalog of families (called per request: a replica builds it lazily).
        run: ``run(fn)`` awaits the blocking ``fn`` (None: a worker thread).
        watchdog: the transfers under way (``/healthz`` answers 503 while one is stuck).
        edit_token: the secret stored edits need (None: the service is read-only).
        get_family: ``await get_family(name)`` gives a family's service (None: the catalog's, in a
            worker thread; the multiplexed Serve replica passes its LRU).
        replica: this replica's name (``X-ProcTex-Replica``, ``/healthz``).
    """

    get_catalog: Callable[[], Catalog]
    run: Callable[[Callable[[], Any]], Awaitable[Any]] | None
    watchdog: Watchdog
    edit_token: str | None
    get_family: Callable[[str], Awaitable[FamilyService]] | None
    replica: str | None
    #: per family service: one transfer at a time (waiting requests hold no thread)
    gates: weakref.WeakKeyDictionary = field(default_factory=weakref.WeakKeyDictionary)
    #: per family store: the looks being painted
    look_gates: dict[str, asyncio.Semaphore] = field(default_factory=dict)

    @property
    def served_by(self) -> dict[str, str]:
        """The header naming this replica ({} without a name)."""
        return {"X-ProcTex-Replica": self.replica} if self.replica else {}

    async def blocking(self, fn: Callable[[], Any]) -> Any:
        """``fn()`` off the event loop."""
        if self.run is not None:
            return await self.run(fn)
        return await asyncio.to_thread(fn)

    async def family_of(self, name: str) -> FamilyService:
        """Family ``name``'s service (loaded or reloaded as needed)."""
        if self.get_family is not None:
            return await self.get_family(name)
        catalog = self.get_catalog()
        held = catalog.fresh(name)  # the common case answered here: no hop into a thread
        return held if held is not None else await self.blocking(lambda: catalog.get(name))

    async def look_of(self, name: str, look: str | None) -> FamilyService:
        """The family's service textured as its ``look`` (None: the build's look)."""
        svc = await self.family_of(name)
        if look is None:
            return svc
        if not isinstance(look, str) or len(look) > 200:
            raise BadInput("look must be a look's name")
        return await self.blocking(lambda: svc.look_view(look))

    def gate(self, svc: FamilyService) -> asyncio.Semaphore:
        """The gate of ``svc``'s transfers: one at a time."""
        return self.gates.setdefault(svc, asyncio.Semaphore(1))

    def look_gate(self, svc: FamilyService) -> asyncio.Semaphore:
        """The gate of the family's look paints: ``limits.look_paints`` at a time."""
        return self.look_gates.setdefault(svc.store.uri, asyncio.Semaphore(svc.limits.look_paints))

    async def watched(self, fn: Callable[[], Any], request: Request, budget: Budget) -> Any:
        """Run ``fn`` off the event loop; cancel its budget if the client disconnects meanwhile."""
        task = asyncio.ensure_future(self.blocking(fn))
        while True:
            done, _ = await asyncio.wait({task}, timeout=0.25)
            if done:
                return task.result()
            if not budget.cancelled and await request.is_disconnected():
                budget.cancel()

    def check_edit_request(self, request: Request, multipart: bool = False) -> None:
        """Stored edits need the service's token and a JSON body (a cross-site form cannot send
        either; ``multipart``: a look's photos may come as multipart/form-data, still behind the
        token header a form cannot set): 403 when edits are off, 401 for a missing or wrong token,
        415 for another body type."""
        if not self.edit_token:
            raise Forbidden("this service is read-only: stored edits are off (start it with an edit token)")
        given = request.headers.get("x-proctex-token") or ""
        auth = request.headers.get("authorization") or ""
        if not given and auth.lower().startswith("bearer "):
            given = auth[7:].strip()
        if not hmac.compare_digest(given.encode(), self.edit_token.encode()):
            raise Unauthorized("stored edits need the service's edit token (header X-ProcTex-Token)")
        if request.method == "POST":
            ctype = request.headers.get("content-type", "").split(";")[0].strip().lower()
            if ctype != "application/json" and not (multipart and ctype == "multipart/form-data"):
                also = " or multipart/form-data (photos)" if multipart else ""
                raise UnsupportedType(f"send the edit as application/json{also}, not {ctype or 'no content type'!r}")
