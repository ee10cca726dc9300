"""Locks on a family store, across processes on one machine: a ``flock`` on a lock file in the store
folder, released by the kernel when its holder exits (a lock of a dead process is simply free: no
stale lock survives its process). Its latest holder is written beside it (what, pid, host, since)
so a refused caller is told who holds it. An ``s3://`` store has the same locks as lease objects
written with S3's conditional writes (:mod:`proctex.store.leases`), for processes on any nodes;
other object stores have none: :func:`store_lock` yields False there."""

from __future__ import annotations

import contextlib
import json
import os
import socket
import time
from typing import Callable, Iterator

from proctex.store.layout import FamilyStore, StoreLayout


class StoreBusy(ValueError):
    """The store is locked by another process (who holds it: in the message)."""


def is_local(store: FamilyStore) -> bool:
    return "://" not in store.uri or store.uri.startswith("file://")


def holder(store: FamilyStore, name: str) -> str:
    """Who holds lock ``name``, as written when it was taken ("" when unknown)."""
    try:
        with open(os.path.join(store.base, name + ".owner")) as fh:
            o = json.load(fh)
        return f"{o.get('what', 'a process')} (pid {o.get('pid')} on {o.get('host')}, since {o.get('since')})"
    except (OSError, ValueError, AttributeError):
        return ""


@contextlib.contextmanager
def store_lock(store: FamilyStore, name: str, what: str, shared: bool = False, timeout: float = 0.0, busy: Callable[[str], Exception] = StoreBusy, note: bool | None = None) -> Iterator[bool]:
    """Hold lock ``name`` (a file in the store folder) while the block runs: ``shared`` with other
    shared holders, else alone; wait up to ``timeout`` seconds, then raise ``busy(message)`` naming
    the holder. ``note``: write who holds it (default: exclusive holders only; a reader writes
    nothing). On an ``s3://`` store: a lease (:func:`proctex.store.leases.hold`), and for a reader
    (``shared`` without ``note``) a check that no exclusive holder ran while the block read
    (:class:`proctex.store.leases.ReadCheck`: :class:`~proctex.store.leases.StoreChanged` when one
    did; read again). Yields False (and locks nothing) for another object store, or a read-only
    folder taken shared."""
    import fcntl

    if not is_local(store):
        from proctex.store import leases

        if not leases.supports_leases(store):
            yield False
        elif shared and not note:
            with leases.ReadCheck(store, name, timeout=max(timeout, 1.0)):
                yield True
        else:
            with leases.hold(store, name, what, shared=shared, timeout=timeout, busy=busy):
                yield True
        return
    os.makedirs(store.base, exist_ok=True)
    path = os.path.join(store.base, name)
    try:
        fd = os.open(path, os.O_RDWR | os.O_CREAT, 0o644)
    except OSError as exc:
        if shared:  # a read-only store folder: nobody writes it, nothing to wait for
            yield False
            return
        raise ValueError(f"{store.uri}: cannot take the {what} lock ({exc})") from exc
    try:
        deadline = time.monotonic() + timeout
        while True:
            try:
                fcntl.flock(fd, (fcntl.LOCK_SH if shared else fcntl.LOCK_EX) | fcntl.LOCK_NB)
                break
            except BlockingIOError:
                if time.monotonic() >= deadline:
                    who = holder(store, name)
                    raise busy(f"{store.uri} is held by {who or 'another process'}; {what} refused") from None
                time.sleep(0.01)
        if note if note is not None else not shared:
            owner = {"what": what, "pid": os.getpid(), "host": socket.gethostname(), "since": time.strftime("%Y-%m-%dT%H:%M:%S")}
            try:  # the latest holder's note
                with open(path + ".owner", "w") as fh:
                    json.dump(owner, fh)
            except OSError:
                pass  # the lock holds without its note
        yield True
    finally:
        os.close(fd)  # releases the lock


def build_lock(store: FamilyStore, what: str = "a build") -> contextlib.AbstractContextManager:
    """The store's build lock, exclusive and refused at once when held (:class:`StoreBusy` naming
    the holder: another build, or an edit)."""
    return store_lock(store, StoreLayout.BUILD_LOCK, what)
