"""Time as the desk's drivers see it: injectable, so that a test moves time on itself instead of waiting for it.

A Clock has two operations: `now()` (seconds, monotonic) and `wait(event, timeout_s)` (until the event is set
or timeout_s of this clock's seconds have passed; True if the event was set). SYSTEM_CLOCK is the real one;
ManualClock stands still until told to advance, so every wait, settle and timeout measured on it ends exactly
when a test says.
"""

from __future__ import annotations

import math
import threading
import time
from collections.abc import Callable
from typing import Protocol

_POLL_S = 0.002  # real seconds in which a ManualClock's waiter sees an event set by another thread


class Clock(Protocol):
    def now(self) -> float:
        """Seconds, monotonic (any origin)."""
        ...

    def wait(self, event: threading.Event, timeout_s: float) -> bool:
        """Until `event` is set (True) or timeout_s of this clock's seconds have passed (False)."""
        ...


class SystemClock:
    """The real time: time.monotonic() and Event.wait."""

    def now(self) -> float:
        return time.monotonic()

    def wait(self, event: threading.Event, timeout_s: float) -> bool:
        return event.wait(max(0.0, timeout_s))


SYSTEM_CLOCK = SystemClock()


class ManualClock:
    """A clock that moves only when told (advance). A thread waiting on it ends its wait when the time it waits
    for is reached or its event is set; run() drives threads that wait on it step by step."""

    def __init__(self, start_s: float = 0.0) -> None:
        self._now = float(start_s)
        self._changed = threading.Condition()
        self._deadlines: dict[threading.Thread, float] = {}  # the threads waiting, until when

    def now(self) -> float:
        with self._changed:
            return self._now

    def wait(self, event: threading.Event, timeout_s: float) -> bool:
        me = threading.current_thread()
        with self._changed:
            deadline = self._now + timeout_s
            self._deadlines[me] = deadline
            self._changed.notify_all()
            try:
                while not event.is_set():
                    if self._now >= deadline:
                        return False
                    self._changed.wait(_POLL_S)  # advance() wakes this at once
                return True
            finally:
                del self._deadlines[me]
                self._changed.notify_all()

    def advance(self, dt_s: float) -> None:
        """Move the time on by dt_s (not negative)."""
        if not dt_s >= 0:
            raise ValueError("a clock does not go back")
        with self._changed:
            self._now += dt_s
            self._changed.notify_all()

    def waiting(self) -> int:
        """How many threads wait on this clock for a time still ahead (one whose time has come is not waiting:
        it is about to go on)."""
        with self._changed:
            return self._waiting()

    def _waiting(self) -> int:
        return sum(deadline > self._now for deadline in self._deadlines.values())

    def until_waiting(self, threads: int, unless: Callable[[], bool] = lambda: False, timeout_s: float = 60.0) -> None:
        """Block until `threads` threads wait on this clock for a time ahead (they have done what they had to do
        up to now), or unless() holds (asked outside the clock's lock: it may read a driver). `timeout_s`, real
        seconds, only bounds a failure: TimeoutError."""
        give_up = time.monotonic() + timeout_s
        while not unless():
            with self._changed:
                if self._waiting() >= threads:
                    return
                self._changed.wait(_POLL_S)
                if time.monotonic() > give_up:
                    raise TimeoutError(f"{self._waiting()} threads wait on the clock at {self._now:g} s, not {threads}")

    def run(self, until: Callable[[], bool], threads: int, step_s: float = 0.02, limit_s: float = math.inf) -> None:
        """Advance step by step until `until()` holds, each step once `threads` threads wait on the clock (the
        threads that drive what `until` waits for: a driver's poller, a replay's job), so that nothing is
        skipped; AssertionError after limit_s of this clock's seconds."""
        end = self.now() + limit_s
        while True:
            self.until_waiting(threads, until)
            if until():
                return
            assert self.now() < end, f"not within {limit_s:g} s of the clock"
            self.advance(step_s)
