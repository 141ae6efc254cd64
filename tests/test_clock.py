"""The drivers' clock (app/clock.py): a ManualClock's waits end exactly when it is advanced to their time or their
event is set, it counts the threads waiting on it for a time ahead, and run() drives such a thread step by step;
the system clock's wait is an Event's."""

from __future__ import annotations

import threading

import pytest

from app.clock import SYSTEM_CLOCK, ManualClock


def test_a_wait_ends_when_the_clock_reaches_its_time_or_its_event_is_set() -> None:
    clock = ManualClock(10.0)
    event = threading.Event()
    ended: list[tuple[bool, float]] = []
    waiter = threading.Thread(target=lambda: ended.append((clock.wait(event, 1.0), clock.now())))
    waiter.start()
    clock.until_waiting(1)
    clock.advance(0.999)
    assert clock.waiting() == 1 and waiter.is_alive()  # its time has not come
    clock.advance(0.001)
    waiter.join()
    assert ended == [(False, 11.0)]
    waiter = threading.Thread(target=lambda: ended.append((clock.wait(event, 5.0), clock.now())))
    waiter.start()
    clock.until_waiting(1)
    event.set()
    waiter.join()
    assert ended[1] == (True, 11.0)  # no time passed
    with pytest.raises(ValueError, match="does not go back"):
        clock.advance(-1.0)


def test_run_advances_step_by_step_once_the_threads_wait_again() -> None:
    clock = ManualClock()
    ticks: list[float] = []
    stop = threading.Event()

    def tick() -> None:  # a poller: one tick every 0.125 s of the clock (binary fractions: exact sums)
        while not clock.wait(stop, 0.125):
            ticks.append(clock.now())

    ticker = threading.Thread(target=tick)
    ticker.start()
    clock.run(lambda: len(ticks) >= 5, threads=1, step_s=0.0625)
    stop.set()
    ticker.join()
    assert ticks == [0.125, 0.25, 0.375, 0.5, 0.625]  # none skipped, none early
    assert clock.now() == 0.625
    with pytest.raises(AssertionError, match="not within 1 s of the clock"):
        clock.run(lambda: False, threads=0, step_s=0.5, limit_s=1.0)
    with pytest.raises(TimeoutError, match="0 threads wait on the clock"):
        clock.until_waiting(1, timeout_s=0.05)


def test_the_system_clock_waits_on_the_event() -> None:
    event = threading.Event()
    event.set()
    assert SYSTEM_CLOCK.wait(event, 10.0) is True
    assert SYSTEM_CLOCK.wait(threading.Event(), -1.0) is False
    assert SYSTEM_CLOCK.now() <= SYSTEM_CLOCK.now()
