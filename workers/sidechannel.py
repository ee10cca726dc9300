"""The front's side channel into the transfer replicas on its own node: each replica listens on a
Unix socket in a directory the front made (mode 0700: only the user running Ray connects), and
the front sends a forwarded request there, a length-prefixed pickle each way, instead of through
a Serve handle. Serve still starts, checks, replaces and stops the replicas; this is only the
data path, and the handle stays the way for what it does not cover (no socket yet, another node,
a multiplexed deployment).

Why: on 2 cores a Serve handle's round trip with an 850 KB answer took 7.5 ms (median; the
router, Ray's core worker threads on both sides, the call's own messages), the same answer over a
Unix socket into the same replica's event loop 0.7 ms (a session script, alternated in one run).

The guarantees of the handle's path hold here:

- A replica lost under a request (its socket closes or resets mid-answer) raises
  :class:`ReplicaLost`, which :func:`workers.serve.lost` counts as lost: the ingress retries an
  idempotent request once, where the next send picks another replica.
- A replica that cannot be reached before anything was sent (a stale socket of a replica that
  died, none listening yet) is no loss: the request goes through the handle instead.
- A cancelled request (its client went away, its budget ran out in the ingress) closes its
  connection, and the replica cancels the app's run (:func:`workers.ingress.call_app`: the
  transfer's budget is cancelled, as for a cancelled handle call).
- One request per connection at a time; idle connections are kept per replica and a replica is
  chosen by fewest requests under way (ties at random).
"""

from __future__ import annotations

import asyncio
import contextlib
import os
import pickle
import random
import struct
import time
from pathlib import Path
from typing import Any, Awaitable, Callable

HEADER = struct.Struct("<Q")
#: The largest message either side reads (a request body within the service's limits is far less).
MAX_MESSAGE = 1 << 30
#: How often the front looks for replicas' sockets anew (seconds), besides after a failure.
RESCAN_SECONDS = 1.0


class ReplicaLost(ConnectionError):
    """The replica's connection closed or failed after the request was sent: it was lost."""


class Unreachable(ConnectionError):
    """No replica's socket could take the request before anything was sent."""


def socket_name(node: str, pid: int) -> str:
    """The socket file name of the replica process ``pid`` on node ``node`` (Ray's node id, hex):
    short, for a Unix socket path's 108 bytes."""
    return f"{node[:16]}.{int(pid)}.sock"


async def _read_message(reader: asyncio.StreamReader) -> Any:
    (n,) = HEADER.unpack(await reader.readexactly(HEADER.size))
    if n > MAX_MESSAGE:
        raise ValueError(f"a side-channel message of {n} bytes is over {MAX_MESSAGE}")
    return pickle.loads(await reader.readexactly(n))


def _write_message(writer: asyncio.StreamWriter, obj: Any) -> None:
    blob = pickle.dumps(obj, protocol=pickle.HIGHEST_PROTOCOL)
    writer.write(HEADER.pack(len(blob)))
    writer.write(blob)


async def listen(directory: str, node: str, forward: Callable[[Any], Awaitable[Any]]) -> asyncio.AbstractServer:
    """The replica's side: a Unix socket server in ``directory`` (named by :func:`socket_name`) on
    the running event loop, answering each request with ``await forward(request)``. A connection
    that closes while its request runs cancels that run."""

    async def connection(reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        try:
            while True:
                try:
                    request = await _read_message(reader)
                except (asyncio.IncompleteReadError, ConnectionError, ValueError, pickle.UnpicklingError):
                    return
                run = asyncio.ensure_future(forward(request))
                gone = asyncio.ensure_future(reader.read(1))  # b"" at EOF: the front gave the request up
                await asyncio.wait({run, gone}, return_when=asyncio.FIRST_COMPLETED)
                if not run.done():
                    run.cancel()
                    with contextlib.suppress(BaseException):
                        await run
                    return
                gone.cancel()
                with contextlib.suppress(BaseException):
                    await gone
                exc = run.exception()
                _write_message(writer, ("error", f"{type(exc).__name__}: {exc}"[:500]) if exc is not None else ("ok", run.result()))
                await writer.drain()
        except (ConnectionError, OSError):
            return
        finally:
            writer.close()

    path = Path(directory) / socket_name(node, os.getpid())
    with contextlib.suppress(FileNotFoundError):
        path.unlink()  # a socket left by an earlier process with this pid
    return await asyncio.start_unix_server(connection, path=str(path), limit=1 << 20)


def _identity(path: Path) -> tuple[str, int]:
    """``(path, inode)`` of a socket file (inode -1 when it is gone): a replica started later
    with the same pid makes a new file, another inode."""
    try:
        return str(path), os.stat(path).st_ino
    except OSError:
        return str(path), -1


class SideChannel:
    """The front's side: sends forwarded requests to the replicas listening in ``directory`` on
    node ``node`` (:func:`listen`). Use it from one event loop. With ``replicas`` (the
    deployment's count) it takes requests only while that many sockets are on this node: where
    some replicas run on other nodes, every request goes through the handle, whose router
    spreads them over all (the side channel would leave the other nodes' replicas idle). A replica
    of this node found dead still counts until its replacement listens: its requests go to the
    others here (the handle's router would not know yet that it died, and could send a retry to
    it)."""

    def __init__(self, directory: str, node: str, replicas: int = 0) -> None:
        self.directory, self.prefix, self.replicas = Path(directory), node[:16] + ".", int(replicas)
        self.idle: dict[str, list[tuple[asyncio.StreamReader, asyncio.StreamWriter]]] = {}
        self.busy: dict[str, int] = {}
        self.paths: list[str] = []
        self.scanned = float("-inf")
        self.sent = self.lost = 0
        self.departed = 0  # replicas of this node found dead since all listened (their replacements come)
        self.dead: set[tuple[str, int]] = set()  # sockets whose replica was lost under a request

    def _scan(self, force: bool = False) -> list[str]:
        if force or time.monotonic() - self.scanned > RESCAN_SECONDS:
            try:
                self.paths = sorted(str(p) for p in self.directory.glob(self.prefix + "*.sock") if _identity(p) not in self.dead)
            except OSError:
                self.paths = []
            self.scanned = time.monotonic()
        return self.paths

    def _forget(self, path: str, stale: bool) -> None:
        """Drop ``path``'s idle connections; a ``stale`` socket (nobody listens) is removed."""
        for _, writer in self.idle.pop(path, []):
            writer.close()
        if path in self.paths:
            self.paths.remove(path)
        if stale:
            with contextlib.suppress(OSError):
                os.unlink(path)

    def _pick(self, paths: list[str]) -> str:
        least = min(self.busy.get(p, 0) for p in paths)
        return random.choice([p for p in paths if self.busy.get(p, 0) == least])

    async def _connect(self) -> tuple[str, asyncio.StreamReader, asyncio.StreamWriter]:
        """A connection to the replica with the fewest requests under way (counted from here on:
        the caller takes one off when done); :class:`Unreachable` when none takes it."""
        tried: set[str] = set()
        forced = False
        while True:
            found = self._scan(force=forced)
            if len(found) >= self.replicas:
                self.departed = 0  # every replica listens (again): the count holds as given
            elif len(found) + self.departed < self.replicas:
                if not forced:
                    forced = True
                    continue
                raise Unreachable(f"{len(found)} of {self.replicas} transfer replicas listen on this node")
            paths = [p for p in found if p not in tried]
            if not paths:
                if not forced:  # none known: look again before giving up (a replica may have come)
                    forced = True
                    continue
                raise Unreachable("no transfer replica listens on this node's side channel")
            path = self._pick(paths)
            pool = self.idle.get(path)
            while pool:
                reader, writer = pool.pop()
                if not reader.at_eof() and not writer.is_closing():
                    self.busy[path] = self.busy.get(path, 0) + 1
                    return path, reader, writer
                writer.close()
            self.busy[path] = self.busy.get(path, 0) + 1  # counted while connecting: the next pick sees it
            try:
                reader, writer = await asyncio.open_unix_connection(path, limit=1 << 20)
                return path, reader, writer
            except (ConnectionRefusedError, FileNotFoundError):
                self.busy[path] -= 1
                self._forget(path, stale=True)  # its replica died: nobody listens there
                self.departed += 1  # still this node's: the others take its requests until it is replaced
            except OSError:
                self.busy[path] -= 1
                self._forget(path, stale=False)
            tried.add(path)
            forced = True

    async def send(self, request: Any) -> Any:
        """The replica's answer to ``request``; :class:`Unreachable` when no replica took it
        (nothing was sent), :class:`ReplicaLost` when the replica's connection failed after it
        was sent, ``RuntimeError`` for an error the replica raised."""
        path, reader, writer = await self._connect()  # counted busy there
        done = False
        try:
            _write_message(writer, request)
            await writer.drain()
            self.sent += 1
            status, answer = await _read_message(reader)
            done = True
        except (asyncio.IncompleteReadError, ConnectionError, OSError, ValueError, pickle.UnpicklingError) as exc:
            self.lost += 1
            # never again: a dying process's socket may still take a connection (and reset it)
            self.dead.add(_identity(Path(path)))
            self.departed += 1
            self._forget(path, stale=False)
            raise ReplicaLost(f"the transfer replica's side channel failed: {type(exc).__name__}") from exc
        finally:
            self.busy[path] -= 1
            if not done:
                writer.close()  # also on cancel: the replica sees the close and cancels the run
        self.idle.setdefault(path, []).append((reader, writer))
        if status != "ok":
            raise RuntimeError(f"the transfer replica failed: {answer}")
        return answer

    def close(self) -> None:
        """Close every idle connection."""
        for path in list(self.idle):
            for _, writer in self.idle.pop(path):
                writer.close()
