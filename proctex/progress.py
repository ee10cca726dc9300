"""Per-stage progress lines (done/total, rate, ETA) on stderr; silent when ``quiet``."""

from __future__ import annotations

import sys
import time
from typing import Iterable, Iterator, TypeVar

T = TypeVar("T")


class Progress:
    """Prints ``stage  done/total  rate/s  ETA`` lines, at most every ``interval`` seconds."""

    def __init__(self, stage: str, total: int, quiet: bool = False, interval: float = 1.0, stream=None) -> None:
        self.stage, self.total, self.quiet, self.interval = stage, total, quiet, interval
        self.stream = stream or sys.stderr
        self.done = 0
        self.start = time.perf_counter()
        self._last = -1.0

    def update(self, n: int = 1) -> None:
        self.done += n
        now = time.perf_counter()
        if self.done >= self.total or now - self._last >= self.interval:
            self._last = now
            self._print(now)

    def _print(self, now: float) -> None:
        if self.quiet:
            return
        elapsed = max(now - self.start, 1e-9)
        rate = self.done / elapsed
        eta = (self.total - self.done) / rate if rate > 0 else float("inf")
        tail = "done" if self.done >= self.total else f"ETA {eta:.0f}s"
        print(f"[{self.stage}] {self.done}/{self.total}  {rate:.2f}/s  {elapsed:.1f}s  {tail}", file=self.stream, flush=True)


def track(items: Iterable[T], stage: str, total: int, quiet: bool = False) -> Iterator[T]:
    """Iterate ``items`` with a :class:`Progress` for ``stage``."""
    bar = Progress(stage, total, quiet)
    for item in items:
        yield item
        bar.update()
