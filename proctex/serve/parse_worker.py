"""A mesh reader in a process of its own: uploads are parsed here, so a parse that runs past its
request's deadline (or whose client gave up) is stopped by killing the process, which a thread
cannot be, and its memory is capped (``RLIMIT_AS``).

:class:`MeshReader` (the serving side) starts ``python -m proctex.serve.parse_worker`` and speaks
to it over its standard input and output: length-prefixed pickles, one request and one answer at a
time."""

from __future__ import annotations

import os
import pickle
import select
import struct
import subprocess
import sys
import threading
import time
from typing import Any, Callable

HEADER = struct.Struct("<Q")
MEMORY = 3 * 2**30  # bytes of address space a reader may use


class ReadTimeout(Exception):
    """The reader ran past its deadline, or its request was cancelled (it was killed)."""


def _send(stream, obj: Any) -> None:
    blob = pickle.dumps(obj, protocol=pickle.HIGHEST_PROTOCOL)
    stream.write(HEADER.pack(len(blob)) + blob)
    stream.flush()


def _recv_exact(stream, n: int) -> bytes:
    parts, got = [], 0
    while got < n:
        chunk = stream.read(n - got)
        if not chunk:
            raise EOFError("the mesh reader closed its pipe")
        parts.append(chunk)
        got += len(chunk)
    return b"".join(parts)


def _serve(memory: int) -> None:  # pragma: no cover - runs in the worker process
    import resource

    try:
        resource.setrlimit(resource.RLIMIT_AS, (memory, memory))
    except (ValueError, OSError):
        pass
    inp, out = sys.stdin.buffer, sys.stdout.buffer
    sys.stdout = sys.stderr  # a stray print must not corrupt the answers
    from proctex.geometry.meshio import load_mesh_bytes

    try:  # the compiled OBJ reader, loaded before the first upload waits on it
        from proctex.geometry.obj_kernels import warm

        warm()
    except ImportError:
        pass

    while True:
        head = inp.read(HEADER.size)
        if len(head) < HEADER.size:
            return
        request = pickle.loads(_recv_exact(inp, HEADER.unpack(head)[0]))
        try:
            shape, _ = load_mesh_bytes(request["data"], request["name"], groups=request.get("groups", False))
            reply: tuple = (True, shape)
        except MemoryError:
            reply = (False, "MemoryError", f"reading it needs more than {memory // 2**20} MiB")
        except Exception as exc:  # the file's fault: named to the client
            reply = (False, type(exc).__name__, str(exc)[:500])
        _send(out, reply)


class MeshReader:
    """One reader process, started on first use (:meth:`warm` starts it ahead) and again after it
    was killed or died; one read at a time (a lock)."""

    def __init__(self, memory: int = MEMORY) -> None:
        self.memory = memory
        self._proc: subprocess.Popen | None = None
        self._lock = threading.Lock()
        self.kills = 0

    def warm(self) -> None:
        with self._lock:
            self._ensure()

    def _ensure(self) -> subprocess.Popen:
        if self._proc is None or self._proc.poll() is not None:
            env = {**os.environ, "PYTHONPATH": os.pathsep.join(p for p in sys.path if p)}
            self._proc = subprocess.Popen([sys.executable, "-m", "proctex.serve.parse_worker", str(self.memory)], stdin=subprocess.PIPE, stdout=subprocess.PIPE, env=env)
        return self._proc

    def _kill(self) -> None:
        if self._proc is not None:
            self._proc.kill()
            self._proc.wait()
            self._proc = None
            self.kills += 1

    def read(self, data: bytes, name: str, groups: bool = False, seconds: float = 30.0, cancelled: Callable[[], bool] = lambda: False) -> Any:
        """The :class:`~proctex.geometry.shape.Shape` of ``data`` (:func:`proctex.geometry.meshio.load_mesh_bytes`
        in the reader). ``ValueError`` for a file the reader refused (its message); :class:`ReadTimeout`
        when it ran past ``seconds`` or ``cancelled()`` turned true (the reader is killed). The
        seconds count from the call: a reader's start and the upload's way through the pipe (which
        waits on the reader taking it) are in them."""
        if cancelled():
            raise ReadTimeout("the request was cancelled")
        with self._lock:
            t0 = time.monotonic()
            proc = self._ensure()

            def stop_if_over() -> None:
                gone = cancelled()
                if gone or time.monotonic() - t0 > seconds:
                    self._kill()
                    raise ReadTimeout("the request was cancelled" if gone else f"reading the mesh ran past {seconds:g} s")

            blob = pickle.dumps({"data": data, "name": name, "groups": groups}, protocol=pickle.HIGHEST_PROTOCOL)
            message = memoryview(HEADER.pack(len(blob)) + blob)
            fd = proc.stdin.fileno()
            os.set_blocking(fd, False)  # an upload larger than the pipe waits on the reader (its start)
            try:
                while len(message):
                    stop_if_over()
                    _, ready, _ = select.select([], [fd], [], 0.05)
                    if ready:
                        try:
                            message = message[os.write(fd, message) :]
                        except BlockingIOError:
                            pass
            except (BrokenPipeError, OSError):
                self._kill()
                raise ValueError("the mesh reader could not take the upload; try again") from None
            fd = proc.stdout.fileno()
            while True:
                stop_if_over()
                ready, _, _ = select.select([fd], [], [], 0.05)
                if ready:
                    break
            try:
                reply = pickle.loads(_recv_exact(proc.stdout, HEADER.unpack(_recv_exact(proc.stdout, HEADER.size))[0]))
            except (EOFError, pickle.UnpicklingError, struct.error):
                self._kill()  # it died reading (the memory cap's kill, a crash)
                raise ValueError("the mesh reader stopped while reading the upload (too large to read)") from None
        if reply[0]:
            return reply[1]
        raise ValueError(f"{reply[1]}: {reply[2]}" if reply[1] != "ValueError" else reply[2])

    def close(self) -> None:
        with self._lock:
            if self._proc is not None and self._proc.poll() is None:
                self._proc.kill()
                self._proc.wait()
            self._proc = None


#: The process's reader (one per serving process).
READER = MeshReader()


if __name__ == "__main__":  # pragma: no cover
    _serve(int(sys.argv[1]) if len(sys.argv) > 1 else MEMORY)
