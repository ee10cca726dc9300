"""The families a server holds: :class:`Catalog` finds the families under a root folder or URI
(every sub-folder with a ``family.json``), keeps their services cached (all of them, or only those a
replica serves when it is ``lazy``: Serve's multiplexing then decides which) and reloads one when
its build stamp changes (a rebuild or an edit); a damaged family is isolated. :class:`Watchdog` tells
a stuck transfer from a busy one."""

from __future__ import annotations

import errno
import math
import re
import threading
import time

from proctex.serve.service import FamilyService, Limits, NotFound, Unavailable
from proctex.store.layout import FamilyStore, StoreLayout
from proctex.store.family import Family


class Watchdog:
    """The transfers under way in this process, to tell a stuck one from a busy one: a transfer
    running longer than ``stuck_after`` seconds (far past its budget: the budget is checked between
    steps, so only a step that never returns gets there) marks the process unhealthy."""

    def __init__(self, stuck_after: float = 90.0) -> None:
        self.stuck_after = stuck_after
        self._running: dict[int, float] = {}
        self._lock = threading.Lock()
        self._next = 0

    def begin(self) -> int:
        with self._lock:
            self._next += 1
            self._running[self._next] = time.monotonic()
            return self._next

    def end(self, token: int) -> None:
        with self._lock:
            self._running.pop(token, None)

    def running(self) -> int:
        with self._lock:
            return len(self._running)

    def oldest(self) -> float:
        """Seconds the longest-running transfer has run (0 when none runs)."""
        with self._lock:
            return time.monotonic() - min(self._running.values()) if self._running else 0.0

    def stuck(self) -> bool:
        return self.oldest() > self.stuck_after


#: Family names the catalog serves: a folder name, no path, no oddities.
FAMILY_NAME = re.compile(r"[A-Za-z0-9][A-Za-z0-9._-]{0,127}")


class Catalog:
    """The families under a root folder or URI, served from a cache reloaded on rebuilds.

    ``check_every``: seconds between build-stamp checks of a cached family (0: every request).
    ``recheck_after``: a family that failed to load (a damaged file) is tried again after this many
    seconds, then twice as long each time it fails again (at most ``recheck_max``): damage repaired
    on disk is noticed without a restart.
    """

    def __init__(self, root: str, limits: Limits | None = None, check_every: float = 2.0, lazy: bool = False, device: str = "cpu", recheck_after: float = 5.0, recheck_max: float = 300.0) -> None:
        self.root = FamilyStore(root)
        self.limits = limits or Limits()
        self.check_every = check_every
        self.device = device  # where the families' networks run
        self.lazy = lazy  # health() loads nothing (a replica holds only the families it serves)
        self._cache: dict[str, tuple[FamilyService, float]] = {}
        self._broken: dict[str, tuple[str, str, float, float]] = {}  # name -> (build stamp, why, next try, back-off)
        self.recheck_after, self.recheck_max = recheck_after, recheck_max
        self._lock = threading.Lock()
        self.loads = 0

    def names(self) -> list[str]:
        """Families under the root (sub-folders holding a family.json), sorted."""
        try:
            return [n for n in self.root.listdir() if FAMILY_NAME.fullmatch(n) and self._is_family(n)]
        except OSError:
            return []

    def _is_family(self, name: str) -> bool:
        """A sub-folder holding a family.json; one that cannot be read counts too (it is listed and
        answers 503 naming the permission problem, rather than vanishing from the list)."""
        if name.startswith("."):
            return False
        try:
            return self.root.exists(f"{name}/{StoreLayout.STATE}")
        except OSError as exc:
            return isinstance(exc, PermissionError) or exc.errno in (errno.EACCES, errno.EPERM) or "ermission denied" in str(exc)

    def store(self, name: str) -> FamilyStore:
        if not isinstance(name, str) or not FAMILY_NAME.fullmatch(name) or not self._is_family(name):
            shown = name if isinstance(name, str) and len(name) <= 80 else f"{str(name)[:80]}..."
            raise NotFound(f"unknown family {shown!r}; families: {', '.join(self.names()) or '(none)'}")
        return self.root.child(name)

    def invalidate(self, name: str) -> None:
        """Check family ``name``'s build stamp on its next :meth:`get` (after an edit here)."""
        with self._lock:
            cached = self._cache.get(name)
            if cached is not None:
                self._cache[name] = (cached[0], -math.inf)

    def get(self, name: str) -> FamilyService:
        """The service of family ``name`` (loaded or reloaded as needed)."""
        now = time.monotonic()
        with self._lock:
            held = self._held(name, now)
            if held is not None:
                return held
            cached = self._cache.get(name)
            store = self.store(name)
            try:
                family = Family.open(store)  # read once: the version, the check and the load share it
                stamp = family.version
            except Exception as exc:  # family.json itself damaged
                raise self._mark_broken(name, "", exc) from exc
            if cached is not None and stamp == cached[0].stamp:
                self._cache[name] = (cached[0], now)
                return cached[0]
            if not family.done("paint"):
                raise NotFound(f"family {name!r} is not built yet (no painted template)")
            broken = self._broken.get(name)
            if broken is not None and broken[0] == stamp and time.monotonic() < broken[2]:
                raise Unavailable(broken[1])  # tried again once its back-off has passed
            try:
                service = FamilyService(store, name, self.limits, device=self.device, family=family)
            except Exception as exc:  # a damaged file of this family: the others are still served
                raise self._mark_broken(name, stamp, exc) from exc
            self._broken.pop(name, None)
            self._cache[name] = (service, now)
            self.loads += 1
            return service

    def fresh(self, name: str) -> FamilyService | None:
        """Family ``name``'s service when it is held and its build stamp was checked less than
        ``check_every`` ago, without waiting and without any I/O (what :meth:`get` answers at once,
        so an event loop may ask); None otherwise (also while another thread holds the catalog:
        ask :meth:`get` from a thread then)."""
        if not self._lock.acquire(blocking=False):
            return None
        try:
            return self._held(name, time.monotonic())
        finally:
            self._lock.release()

    def _held(self, name: str, now: float) -> FamilyService | None:
        """The held service of ``name`` whose stamp was checked less than ``check_every`` before
        ``now`` (the lock held), else None."""
        cached = self._cache.get(name)
        return cached[0] if cached is not None and now - cached[1] < self.check_every else None

    def loaded(self) -> list[str]:
        """The families held now, sorted."""
        with self._lock:
            return sorted(self._cache)

    def forget(self, name: str, service: FamilyService | None = None) -> None:
        """Drop family ``name`` from the cache (only if it is ``service``, when given): whoever keeps
        the families per replica (Serve's multiplexing LRU) says so when it lets one go."""
        with self._lock:
            cached = self._cache.get(name)
            if cached is not None and (service is None or cached[0] is service):
                del self._cache[name]

    def _mark_broken(self, name: str, stamp: str, exc: BaseException) -> Unavailable:
        why = f"family {name!r} is unavailable: {type(exc).__name__}: {str(exc)[:500]}"
        before = self._broken.get(name)
        delay = min(2 * before[3], self.recheck_max) if before is not None and before[0] == stamp else self.recheck_after
        self._broken[name] = (stamp, why, time.monotonic() + delay, delay)
        self._cache.pop(name, None)
        return Unavailable(why)

    def health(self) -> dict[str, str]:
        """Per family under the root: "ok", "not built", or why it is unavailable (a damaged file,
        named). Each is loaded if it was not, unless the catalog is ``lazy``: then a family not held
        here is "ok" when it is built and not known to be damaged (it is checked when first served)."""
        out = {}
        for name in self.names():
            try:
                if self.lazy and name not in self._cache:
                    out[name] = self._unloaded_health(name)
                    continue
                self.get(name)
                out[name] = "ok"
            except NotFound as exc:
                out[name] = "not built" if "not built" in str(exc) else str(exc)
            except ValueError as exc:
                out[name] = str(exc)
        return out

    def _unloaded_health(self, name: str) -> str:
        store = self.store(name)
        try:
            family = Family.open(store)
            if not family.done("paint"):
                return "not built"
            broken = self._broken.get(name)
            return broken[1] if broken is not None and broken[0] == family.version else "ok"
        except Exception as exc:  # family.json itself damaged
            return f"family {name!r} is unavailable: {type(exc).__name__}: {str(exc)[:500]}"
