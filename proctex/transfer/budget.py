"""A request's budget: a deadline and a cancel switch that long work checks between its steps.

The run-time path (:func:`proctex.transfer.apply.transfer` and the part matching under it) calls
:meth:`Budget.check` before each expensive step; a request whose client went away is cancelled from
outside (:meth:`Budget.cancel`), one that runs past its seconds stops with :class:`OverBudget`.
"""

from __future__ import annotations

import threading
import time
from dataclasses import dataclass, field


class OverBudget(ValueError):
    """Work stopped: past its time budget, or cancelled (:attr:`cancelled`)."""

    def __init__(self, message: str, cancelled: bool = False) -> None:
        super().__init__(message)
        self.cancelled = cancelled


@dataclass
class Budget:
    """``seconds`` of work from creation (None: no limit) and a cancel switch (thread-safe)."""

    seconds: float | None = None
    start: float = field(default_factory=time.monotonic)
    _cancelled: threading.Event = field(default_factory=threading.Event, repr=False)

    def __post_init__(self) -> None:
        if self.seconds is not None and not (self.seconds > 0):
            raise ValueError(f"a budget needs seconds > 0 (or None), got {self.seconds!r}")

    def cancel(self) -> None:
        self._cancelled.set()

    @property
    def cancelled(self) -> bool:
        return self._cancelled.is_set()

    def elapsed(self) -> float:
        return time.monotonic() - self.start

    def check(self, what: str) -> None:
        """Raise :class:`OverBudget` naming ``what`` was under way if cancelled or past the deadline."""
        if self._cancelled.is_set():
            raise OverBudget(f"cancelled while {what}", cancelled=True)
        if self.seconds is not None and self.elapsed() > self.seconds:
            raise OverBudget(f"over the time budget of {self.seconds:g} s while {what}")
