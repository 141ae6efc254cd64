"""Time for code that waits: a driver's move, settle and timeout; a job's time limit, grace period and a wait
for a change.

Such code is given a `Clock` rather than reading `time.monotonic`: `SYSTEM_CLOCK` is the real one;
`ManualClock` stands still until a test advances it, so a test of a time-out neither waits seconds of wall
time nor fails on a loaded machine because a limit passed too early. A clock waits two ways: on an Event
(`wait`, what the drivers' threads do) and on a Condition the waiter holds (`wait_condition`, what the job
runner does); and it calls a function after a delay (`call_later`, the runner's time limits).
"""

from __future__ import annotations

import heapq
import itertools
import math
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Protocol

_POLL_S = 0.002  # real seconds in which a ManualClock's event waiter sees an event set by another thread


class Timer(Protocol):
    def cancel(self) -> None:
        """The call does not happen (if it has not yet)."""


class Clock(Protocol):
    def now(self) -> float:
        """Seconds on a monotonic scale (only differences mean anything)."""

    def wait(self, event: threading.Event, timeout_s: float) -> bool:
        """Until `event` is set (True) or `timeout_s` of this clock's seconds have passed (False)."""

    def wait_call(self, event: threading.Event, timeout_s: float) -> bool:
        """`wait` for work under way on another thread (a call to a robot, app/drivers/calls.py): the same wait,
        but a ManualClock does not count its waiter among the threads waiting for time, since the thread doing
        the work is the one to count."""

    def wait_condition(self, cond: threading.Condition, timeout_s: float | None) -> None:
        """Called holding `cond`, like `cond.wait`: returns once `cond` is notified or `timeout_s` of this clock
        has passed (None: no timeout), or spuriously; `wait_for` loops."""

    def call_later(self, delay_s: float, fn: Callable[[], object]) -> Timer:
        """Call `fn` (on some thread) once `delay_s` of this clock has passed."""


def wait_for(clock: Clock, cond: threading.Condition, ready: Callable[[], bool], timeout_s: float | None) -> bool:
    """`cond.wait_for(ready, timeout_s)` on `clock`'s time; called holding `cond`. The last value of `ready()`."""
    deadline = None if timeout_s is None else clock.now() + timeout_s
    while not (result := ready()):
        left = None if deadline is None else deadline - clock.now()
        if left is not None and left <= 0:
            break
        clock.wait_condition(cond, left)
    return result


class SystemClock:
    """The real clock: time.monotonic, Event.wait, Condition.wait, threading.Timer."""

    def now(self) -> float:
        return time.monotonic()

    def wait(self, event: threading.Event, timeout_s: float) -> bool:
        return event.wait(max(0.0, timeout_s))

    wait_call = wait

    def wait_condition(self, cond: threading.Condition, timeout_s: float | None) -> None:
        cond.wait(timeout_s)

    def call_later(self, delay_s: float, fn: Callable[[], object]) -> Timer:
        timer = threading.Timer(max(0.0, delay_s), fn)
        timer.daemon = True  # a pending time limit never holds the interpreter at exit
        timer.start()
        return timer


SYSTEM_CLOCK = SystemClock()


class ClockStalled(AssertionError):
    """A wait on a ManualClock that nothing ended within its stall limit of wall time: a test waits for a change
    that does not come, or forgot to advance the clock. Raised in the waiting thread, so the test fails rather
    than hangs."""


@dataclass(order=True)
class _Call:
    at: float
    seq: int
    fn: Callable[[], object] = field(compare=False)
    cancelled: bool = field(default=False, compare=False)

    def cancel(self) -> None:
        self.cancelled = True


@dataclass(eq=False)
class _Waiter:
    cond: threading.Condition | None  # None: an event waiter, woken by the clock's own condition
    deadline: float | None
    thread: str
    event: threading.Event | None = None  # an event waiter's: once set, the thread is about to go on
    counted: bool = True  # False: it waits for work under way elsewhere (wait_call), not for time


class ManualClock:
    """A clock for tests: its time moves only by `advance`, which runs the calls that come due (in the advancing
    thread, in order) and wakes the waits whose time has come. A condition wait with a timeout that sees neither a
    notification nor its timeout within `stall_s` of wall time raises ClockStalled. `until_waiting` and `run` drive
    threads that wait on it step by step (a driver's poller, a replay's job)."""

    def __init__(self, start: float = 0.0, *, stall_s: float = 60.0) -> None:
        self.stall_s = stall_s
        self._now = float(start)
        self._calls: list[_Call] = []
        self._seq = itertools.count()
        self._waiters: set[_Waiter] = set()
        self._state = threading.Condition()  # guards the above; notified when a wait starts or ends, time moves

    def now(self) -> float:
        with self._state:
            return self._now

    def advance(self, seconds: float) -> None:
        """Move time on by `seconds`: each call due meanwhile runs at its time (seeing it as `now`, so a call it
        makes due within the step runs too), then the waits due wake."""
        if not seconds >= 0:
            raise ValueError("a clock does not go back")
        with self._state:
            target = self._now + seconds
        while True:
            with self._state:
                if not self._calls or self._calls[0].at > target:
                    self._now = target
                    due = [w.cond for w in self._waiters if w.cond is not None and _due(w, target)]
                    self._state.notify_all()  # event waiters look at the time again
                    break
                call = heapq.heappop(self._calls)
                self._now = max(self._now, call.at)
            if not call.cancelled:
                call.fn()
        for cond in due:
            with cond:  # taken once the waiter is inside cond.wait: the notification cannot be missed
                cond.notify_all()

    def wait(self, event: threading.Event, timeout_s: float, *, counted: bool = True) -> bool:
        with self._state:
            waiter = _Waiter(None, self._now + timeout_s, threading.current_thread().name, event, counted)
            self._waiters.add(waiter)
            self._state.notify_all()
            try:
                while not event.is_set():
                    if self._now >= waiter.deadline:
                        return False
                    self._state.wait(_POLL_S)  # advance() wakes this at once; an event set elsewhere within _POLL_S
                return True
            finally:
                self._waiters.discard(waiter)
                self._state.notify_all()

    def wait_call(self, event: threading.Event, timeout_s: float) -> bool:
        """`wait`, not counted by `waiting` and `until_waiting`: the thread doing the work waits on the clock itself
        when it waits for time (a robot's transport between two images), or not at all (it computes)."""
        return self.wait(event, timeout_s, counted=False)

    def wait_condition(self, cond: threading.Condition, timeout_s: float | None) -> None:
        with self._state:
            deadline = None if timeout_s is None else self._now + timeout_s
            if deadline is not None and deadline <= self._now:
                return
            waiter = _Waiter(cond, deadline, threading.current_thread().name)
            self._waiters.add(waiter)
            self._state.notify_all()
        try:
            notified = cond.wait(None if deadline is None else self.stall_s)
            if deadline is not None and not notified and self.now() < deadline:
                raise ClockStalled(
                    f"a wait of {timeout_s:g} s on the manual clock saw no change in {self.stall_s:g} s of wall "
                    "time: advance the clock, or the change waited for does not come"
                )
        finally:
            with self._state:
                self._waiters.discard(waiter)
                self._state.notify_all()

    def call_later(self, delay_s: float, fn: Callable[[], object]) -> Timer:
        with self._state:
            call = _Call(self._now + max(0.0, delay_s), next(self._seq), fn)
            heapq.heappush(self._calls, call)
        return call

    # --- a test's hold on the threads that wait on the clock ----------------------------------------------
    def waiting(self) -> int:
        """How many threads wait on this clock for a time still ahead (one whose time has come, or whose event is
        set, is not waiting: it is about to go on, and counting it would let a test move time on under it)."""
        with self._state:
            return self._waiting()

    def _waiting(self) -> int:
        return sum(
            w.counted
            and (w.deadline is None or w.deadline > self._now)
            and not (w.event is not None and w.event.is_set())
            for w in self._waiters
        )

    def until_waiting(self, threads: int, unless: Callable[[], bool] = lambda: False, timeout_s: float = 60.0) -> None:
        """Block until `threads` threads wait on this clock for a time ahead (they have done what they had to do
        up to now), or unless() holds (asked outside the clock's lock: it may read a driver). `timeout_s`, real
        seconds, only bounds a failure: ClockStalled."""
        give_up = time.monotonic() + timeout_s
        while not unless():
            with self._state:
                if self._waiting() >= threads:
                    return
                self._state.wait(_POLL_S)
                if time.monotonic() > give_up:
                    raise ClockStalled(f"{self._waiting()} threads wait on the clock at {self._now:g} s, not {threads}")

    def until_thread_waits(self, thread: str) -> None:
        """Block until the thread of that name waits on this clock (a test's sign that a job is held at a
        pause, say). ClockStalled after `stall_s` of wall time."""
        with self._state:
            if not self._state.wait_for(lambda: any(w.thread == thread for w in self._waiters), self.stall_s):
                raise ClockStalled(f"thread '{thread}' did not wait on the manual clock within {self.stall_s:g} s")

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


def _due(waiter: _Waiter, at: float) -> bool:
    return waiter.deadline is not None and waiter.deadline <= at
