"""Locks on a family store in an S3 object store, for processes on any nodes: lease objects written
with S3's conditional writes (``If-None-Match: *`` to create, ``If-Match: <etag>`` to replace), so
that of two writers racing for a lease exactly one wins, whatever node each runs on.

A lease is a small JSON object at ``<store>/<name>`` (``.edit.lock``, ``.build.lock``): who holds it
(what, pid, host, since), a random token and when it expires, in the S3 server's clock (its ``Date``
header, so that no two nodes' clocks are compared). Its holder renews it every third of its time to
live; one that dies stops renewing, and the lease is free once it expires (taken over by a
conditional replace, so two waiters never both take it). Released, it is replaced by a released
record rather than deleted: its ETag then changes on every take and every release, which is what a
reader checks (:class:`ReadCheck`) to know that no writer ran while it read.

Shared holders (an edit, which keeps builds out but not other edits' readers) write their own lease
under ``<name>.shared/``; an exclusive taker that finds a live one there gives its lease back and
waits, and a shared taker that finds the exclusive lease live removes its own and waits: both write
before they look, so two never both proceed (S3 is strongly consistent for writes and listings).

Only ``s3://`` stores have these (:func:`supports_leases`); other object stores have no conditional
writes that pyarrow or boto3 reach, and refuse edits.

Fenced on the holder's side: while a lease is held, every write and delete its thread makes on the
store first checks that the lease was renewed less than its time to live minus 5 s ago (this
process's own clock, started before the server's time was read, so never later than the server's
expiry), or renews it then (which succeeds only if nobody wrote the lease meanwhile): a holder whose
lease was taken while it was cut off from the store (or frozen) writes nothing more and gets
:class:`LeaseLost`; one whose lease nobody took goes on. Writes by other processes on the holder's behalf (a build's Ray workers) are not
fenced; the server itself refuses nothing to a writer that does not ask it to."""

from __future__ import annotations

import contextlib
import email.utils
import json
import os
import socket
import threading
import time
import uuid
from dataclasses import dataclass
from typing import Any, Callable, Iterator
from urllib.parse import parse_qs, urlsplit

from proctex.store.layout import FamilyStore, fence, wait_for

#: Seconds a lease lives unless renewed (renewed every third of it while its block runs).
TTL = 30.0

_CLIENTS: dict[tuple[str | None, str], Any] = {}
_CLIENTS_LOCK = threading.Lock()


#: Seconds before a lease's time to live at which its holder stops writing under it (:meth:`Lease.check`).
FENCE_MARGIN = 5.0


class LeaseLost(ValueError):
    """A lease that may have expired while held (not renewed within its time to live), or was taken."""


@dataclass(frozen=True)
class Target:
    """Where a store's leases live: the S3 client, the bucket and the key prefix (the store's root)."""

    client: Any
    bucket: str
    prefix: str
    uri: str = ""

    def key(self, name: str) -> str:
        return f"{self.prefix}/{name}" if self.prefix else name


def supports_leases(store: FamilyStore) -> bool:
    """Whether ``store`` is an ``s3://`` store (leases by conditional writes)."""
    return store.uri.split("://", 1)[0].lower() == "s3" if "://" in store.uri else False


def s3_client(endpoint: str | None, region: str) -> Any:
    """A boto3 S3 client (one per endpoint and region, per process; boto3 clients are thread-safe).
    ``endpoint`` None: boto3's own resolution (``AWS_ENDPOINT_URL``, else AWS). Credentials: boto3's
    chain (``AWS_ACCESS_KEY_ID`` / ``AWS_SECRET_ACCESS_KEY``, profiles, instance roles)."""
    with _CLIENTS_LOCK:
        client = _CLIENTS.get((endpoint, region))
        if client is None:
            import boto3
            from botocore.config import Config

            client = boto3.session.Session().client(
                "s3", endpoint_url=endpoint, region_name=region, config=Config(connect_timeout=5, read_timeout=15, retries={"max_attempts": 4, "mode": "standard"}, s3={"addressing_style": "path"})
            )
            _CLIENTS[(endpoint, region)] = client
        return client


def target(store: FamilyStore) -> Target:
    """The lease target of an ``s3://bucket/prefix[?endpoint_override=host:port&scheme=http&region=r]``
    store: the endpoint, scheme and region from the URI's query where given, else the environment
    (``AWS_ENDPOINT_URL``, ``AWS_REGION`` / ``AWS_DEFAULT_REGION``), as pyarrow resolves them."""
    if not supports_leases(store):
        raise ValueError(f"{store.uri}: leases need an s3:// store")
    parts = urlsplit(store.uri)
    query = {k: v[-1] for k, v in parse_qs(parts.query).items()}
    endpoint = None
    if query.get("endpoint_override"):
        host = query["endpoint_override"]
        endpoint = host if "://" in host else f"{query.get('scheme', 'https')}://{host}"
    region = query.get("region") or os.environ.get("AWS_REGION") or os.environ.get("AWS_DEFAULT_REGION") or "us-east-1"
    bucket, _, prefix = store.base.strip("/").partition("/")
    return Target(s3_client(endpoint, region), bucket, prefix.strip("/"), store.uri)


def _server_time(response: dict[str, Any]) -> float:
    """The S3 server's clock (epoch seconds) from a response's ``Date`` header (this node's clock
    when the header is missing)."""
    date = response.get("ResponseMetadata", {}).get("HTTPHeaders", {}).get("date")
    try:
        return email.utils.parsedate_to_datetime(date).timestamp() if date else time.time()
    except (TypeError, ValueError):
        return time.time()


def _code(exc: BaseException) -> str:
    return str(getattr(exc, "response", {}).get("Error", {}).get("Code", "")) if hasattr(exc, "response") else ""


def _is_precondition(exc: BaseException) -> bool:
    return _code(exc) in ("PreconditionFailed", "412", "ConditionalRequestConflict", "409")


def _is_missing(exc: BaseException) -> bool:
    return _code(exc) in ("NoSuchKey", "404", "NotFound")


@dataclass(frozen=True)
class LeaseState:
    """A lease object as read: its ETag (None: no object), its record, and the server's time."""

    etag: str | None
    record: dict[str, Any]
    now: float

    @property
    def live(self) -> bool:
        """Held and not expired (in the server's clock)."""
        return bool(self.etag) and not self.record.get("released", True) and float(self.record.get("expires", 0)) > self.now

    def holder(self) -> str:
        r = self.record
        return f"{r.get('what', 'a process')} (pid {r.get('pid')} on {r.get('host')}, since {r.get('since')})"


def read_lease(t: Target, name: str) -> LeaseState:
    """The lease ``name`` as it is now (one GET; waiting for the store while it does not answer)."""
    return wait_for(t.uri, f"read the lease {name}", lambda: _read_lease(t, name))


def _read_lease(t: Target, name: str) -> LeaseState:
    from botocore.exceptions import ClientError

    try:
        r = t.client.get_object(Bucket=t.bucket, Key=t.key(name))
    except ClientError as exc:
        if _is_missing(exc):
            return LeaseState(None, {}, _server_time(exc.response))
        raise
    try:
        record = json.loads(r["Body"].read())
        record = record if isinstance(record, dict) else {}
    except ValueError:
        record = {}  # a damaged lease is a free one (its ETag still guards the replace)
    return LeaseState(r["ETag"], record, _server_time(r))


def _put(t: Target, name: str, record: dict[str, Any], etag: str | None) -> str | None:
    """Write a lease record only if the object is still ``etag`` (None: only if there is none);
    its new ETag, or None when another writer got there first."""
    from botocore.exceptions import ClientError

    cond = {"IfMatch": etag} if etag else {"IfNoneMatch": "*"}
    body = json.dumps(record).encode()
    try:
        return wait_for(t.uri, f"write the lease {name}", lambda: t.client.put_object(Bucket=t.bucket, Key=t.key(name), Body=body, ContentType="application/json", **cond)["ETag"])
    except ClientError as exc:
        if _is_precondition(exc) or (etag and _is_missing(exc)):
            return None
        raise


def _record(what: str, now: float, ttl: float, token: str) -> dict[str, Any]:
    return {"what": what, "pid": os.getpid(), "host": socket.gethostname(), "since": time.strftime("%Y-%m-%dT%H:%M:%S"), "token": token, "expires": now + ttl, "released": False}


class Lease:
    """A held lease: renewed by a thread every ``ttl / 3`` s until :meth:`release`."""

    def __init__(self, t: Target, name: str, what: str, etag: str, record: dict[str, Any], ttl: float, since: float | None = None) -> None:
        self.t, self.name, self.what, self.etag, self.record, self.ttl = t, name, what, etag, record, ttl
        self.lost: str | None = None
        #: this process's monotonic clock before the server's time of the last take or renewal was read
        self.renewed_at = since if since is not None else time.monotonic()
        self._stop = threading.Event()
        self._lock = threading.Lock()
        self._thread = threading.Thread(target=self._renew_loop, name=f"lease {name}", daemon=True)
        self._thread.start()

    def renew(self) -> bool:
        """Extend the lease (a conditional replace); False (and :attr:`lost` set) when it was taken."""
        with self._lock:
            if self.lost or self.etag is None:
                return False
            started = time.monotonic()
            now = read_lease(self.t, self.name).now
            record = {**self.record, "expires": now + self.ttl}
            etag = _put(self.t, self.name, record, self.etag) or _ours(self.t, self.name, record)
            if etag is None:
                self.lost = f"{self.name} expired and was taken by another process"
                return False
            self.etag, self.record, self.renewed_at = etag, record, started
            return True

    def check(self) -> None:
        """:class:`LeaseLost` unless the lease is still surely held: not lost, and renewed less than
        its time to live minus :data:`FENCE_MARGIN` ago, or renewed now (a conditional replace that
        succeeds only if nobody wrote the lease since: nobody held it meanwhile)."""
        if self.lost:
            raise LeaseLost(f"{self.t.uri}: {self.lost}; {self.what} writes no more")
        limit = self.ttl - min(FENCE_MARGIN, self.ttl / 3)
        if time.monotonic() - self.renewed_at <= limit:
            return
        try:
            self.renew()
        except Exception:
            pass  # the store does not answer: judged by the age below
        if self.lost:
            raise LeaseLost(f"{self.t.uri}: {self.lost}; {self.what} writes no more")
        age = time.monotonic() - self.renewed_at
        if age > limit:
            raise LeaseLost(
                f"{self.t.uri}: the {self.name} lease was not renewed for {age:.0f} s of its {self.ttl:.0f} s (the store did not "
                f"answer, or this process stalled); another process may hold it now, so {self.what} writes no more"
            )

    def _renew_loop(self) -> None:
        while not self._stop.wait(self.ttl / 3):
            try:
                if not self.renew():
                    return
            except Exception:  # the store is unreachable for now: try again at the next tick
                continue

    def release(self) -> None:
        """Give the lease back: replaced by a released record (a new ETag), if still ours."""
        self._stop.set()
        self._thread.join(timeout=self.ttl)
        with self._lock:
            if self.etag is not None and not self.lost:
                try:
                    _put(self.t, self.name, {"released": True, "token": uuid.uuid4().hex, "by": self.what}, self.etag)
                except Exception:
                    pass  # unreachable: the lease expires by itself
            self.etag = None


def try_take(t: Target, name: str, what: str, ttl: float = TTL) -> tuple[Lease | None, LeaseState]:
    """Take lease ``name`` if it is free (absent, released or expired): ``(lease, state)``; else
    ``(None, the live lease's state)``. Of several processes taking it at once, one gets it."""
    started = time.monotonic()
    state = read_lease(t, name)
    if state.live:
        return None, state
    token = uuid.uuid4().hex
    record = _record(what, state.now, ttl, token)
    etag = _put(t, name, record, state.etag) or _ours(t, name, record)
    if etag is None:
        return None, read_lease(t, name)
    return Lease(t, name, what, etag, record, ttl, since=started), state


def _ours(t: Target, name: str, record: dict[str, Any]) -> str | None:
    """The lease's ETag if it holds ``record`` (a write that landed although its answer was lost,
    so that its retry found its own write and was refused), else None."""
    state = read_lease(t, name)
    same = state.record.get("token") == record["token"] and state.record.get("expires") == record["expires"]
    return state.etag if same else None


def _shared_live(t: Target, name: str) -> list[LeaseState]:
    """The live shared leases under ``<name>.shared/``."""
    folder = t.key(f"{name}.shared/")
    keys = [o["Key"] for page in t.client.get_paginator("list_objects_v2").paginate(Bucket=t.bucket, Prefix=folder) for o in page.get("Contents", [])]
    live = []
    for key in keys:
        state = read_lease(t, key[len(t.prefix) + 1 :] if t.prefix else key)
        if state.live:
            live.append(state)
        elif state.etag:  # a shared holder that died: its lease goes (unless it changed meanwhile)
            with contextlib.suppress(Exception):
                t.client.delete_object(Bucket=t.bucket, Key=key, IfMatch=state.etag)
    return live


_CHECKED: set[tuple[int, str]] = set()


class NoConditionalWrites(ValueError):
    """An S3 server that ignores conditional writes (leases would not exclude anyone)."""


def check_conditional_writes(t: Target) -> None:
    """Once per client and bucket: write a probe object twice with ``If-None-Match: *``; a server
    that lets the second write through ignores conditional writes, and no lease would hold there:
    :class:`NoConditionalWrites` (a ``ValueError``) naming the store."""
    if (id(t.client), t.bucket) in _CHECKED:
        return
    probe = f".lease-probe-{uuid.uuid4().hex}"
    first = _put(t, probe, {"probe": True}, None)
    second = _put(t, probe, {"probe": True, "again": True}, None)
    with contextlib.suppress(Exception):
        t.client.delete_object(Bucket=t.bucket, Key=t.key(probe))
    if first is None or second is not None:
        raise NoConditionalWrites(
            f"{t.uri}: this S3 server ignores conditional writes (If-None-Match), so a lock there would hold no one "
            "out; edit families in a local folder or on a server that has them (AWS S3, SeaweedFS, MinIO)"
        )
    _CHECKED.add((id(t.client), t.bucket))


@contextlib.contextmanager
def hold(store: FamilyStore, name: str, what: str, shared: bool = False, timeout: float = 0.0, busy: Callable[[str], Exception] = ValueError, ttl: float = TTL) -> Iterator[Lease]:
    """Hold lease ``name`` of an S3 store while the block runs (exclusive, or ``shared`` with other
    shared holders), waiting up to ``timeout`` s, then ``busy(message naming the holder)``."""
    t = target(store)
    check_conditional_writes(t)
    deadline = time.monotonic() + timeout
    delay = 0.02
    while True:
        if shared:
            mine = f"{name}.shared/{uuid.uuid4().hex}"
            lease, _ = try_take(t, mine, what, ttl)
            exclusive = read_lease(t, name)
            if lease is not None and not exclusive.live:
                break
            if lease is not None:
                lease.release()
                with contextlib.suppress(Exception):
                    t.client.delete_object(Bucket=t.bucket, Key=t.key(mine))
            blocker = exclusive
        else:
            lease, state = try_take(t, name, what, ttl)
            if lease is not None:
                others = _shared_live(t, name)
                if not others:
                    break
                lease.release()
                blocker = others[0]
            else:
                blocker = state
        if time.monotonic() >= deadline:
            raise busy(f"{store.uri} is held by {blocker.holder()}; {what} refused")
        time.sleep(delay)
        delay = min(delay * 1.5, 0.5)
    try:
        with fence(store.base, lease.check):  # this thread writes nothing once the lease may be gone
            yield lease
    finally:
        lease.release()
        if shared:
            with contextlib.suppress(Exception):
                t.client.delete_object(Bucket=t.bucket, Key=t.key(mine))


class StoreChanged(ValueError):
    """A writer changed the store while a reader read it (read again)."""


class ReadCheck:
    """A reader's check that no exclusive holder of lease ``name`` ran while it read: waits (up to
    ``timeout`` s) until none holds it, notes its ETag, and on leaving raises :class:`StoreChanged`
    when the lease was taken since (its ETag changed) or is held now."""

    def __init__(self, store: FamilyStore, name: str, timeout: float = 60.0) -> None:
        self.t, self.name, self.timeout = target(store), name, timeout

    def __enter__(self) -> "ReadCheck":
        deadline = time.monotonic() + self.timeout
        while True:
            state = read_lease(self.t, self.name)
            if not state.live:
                self.etag = state.etag
                return self
            if time.monotonic() >= deadline:
                raise StoreChanged(f"{self.name} stays held by {state.holder()}; read refused")
            time.sleep(0.05)

    def __exit__(self, kind, exc, tb) -> bool:
        state = read_lease(self.t, self.name)
        if state.etag != self.etag or state.live:
            raise StoreChanged(f"the store changed while it was read ({state.holder() if state.live else 'an edit ended'}); read it again") from exc
        return False
