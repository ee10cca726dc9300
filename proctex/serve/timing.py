"""Where a request's time goes: named stages in milliseconds, as the standard ``Server-Timing``
response header carries them (W3C Server Timing: ``name;dur=12.3, other;dur=0.4``).

Each layer a request passes through appends its own entries (the FastAPI route its stages, the
transfer replica the whole app run, the ingress the body read and the forwarding round trip), so
a client can tell the hops apart from the work: a hop's cost is the layer's total less the total of
the layer inside it (``tests/bench/bench_serve.py`` reports both). Browsers show the header in their
developer tools.
"""

from __future__ import annotations

import re
import time
from contextlib import contextmanager
from typing import Iterator, Mapping

#: A stage name: a header token (letters, digits, ``-`` and ``_``), at most 32 characters.
_NAME = re.compile(r"^[A-Za-z0-9_-]{1,32}$")


class StageClock:
    """Seconds per named stage of one request, in the order they were first recorded (a stage timed
    twice adds up)."""

    def __init__(self) -> None:
        self.seconds: dict[str, float] = {}

    def add(self, name: str, seconds: float) -> None:
        """Add ``seconds`` (finite, >= 0) to stage ``name`` (:data:`_NAME`); ``ValueError`` otherwise."""
        if not _NAME.match(name):
            raise ValueError(f"a stage name is 1-32 letters, digits, '-' or '_', got {name[:40]!r}")
        if not (seconds >= 0.0 and seconds < float("inf")):
            raise ValueError(f"a stage's seconds must be finite and >= 0, got {seconds!r}")
        self.seconds[name] = self.seconds.get(name, 0.0) + float(seconds)

    @contextmanager
    def stage(self, name: str) -> Iterator[None]:
        """Time the ``with`` block as stage ``name`` (also when it raises)."""
        t0 = time.perf_counter()
        try:
            yield
        finally:
            self.add(name, time.perf_counter() - t0)

    def header(self) -> str:
        """The ``Server-Timing`` value of the stages (milliseconds, 2 decimals)."""
        return server_timing(self.seconds)


def server_timing(seconds: Mapping[str, float]) -> str:
    """``Server-Timing`` header value of ``{stage: seconds}`` (``name;dur=<ms>``, comma-separated,
    in the mapping's order); names that are no header token are left out."""
    return ", ".join(f"{name};dur={1000.0 * float(s):.2f}" for name, s in seconds.items() if _NAME.match(name) and 0.0 <= float(s) < float("inf"))


def parse_server_timing(value: str) -> dict[str, float]:
    """``{stage: milliseconds}`` of a ``Server-Timing`` header value (several headers joined by
    commas); an entry without a readable ``dur`` is left out, and a stage named twice adds up
    (two layers timing the same stage). At most 64 entries are read."""
    out: dict[str, float] = {}
    for entry in str(value).split(",")[:64]:
        name, *params = [p.strip() for p in entry.split(";")]
        if not _NAME.match(name):
            continue
        for p in params:
            key, _, v = p.partition("=")
            if key.strip().lower() == "dur":
                try:
                    ms = float(v.strip().strip('"'))
                except ValueError:
                    break
                if 0.0 <= ms < float("inf"):
                    out[name] = out.get(name, 0.0) + ms
                break
    return out
