"""The clocks code that waits is given (app/clock.py): the manual one moves only when a test advances it, runs
the calls that come due in order and wakes the waits whose time has come, never earlier (a condition wait, the
job runner's; an event wait, the drivers'); it counts the threads waiting on it for a time ahead and run() drives
such a thread step by step; a wait nothing ends fails the test instead of hanging it. The system clock keeps the
same contract on wall time."""

from __future__ import annotations

import threading

import pytest

from app.clock import SYSTEM_CLOCK, ClockStalled, ManualClock, SystemClock, wait_for


def waiter(clock: ManualClock, cond: threading.Condition, ready, timeout_s: float | None, name: str) -> tuple:
    """A thread named `name` in wait_for on `clock`; its (result, clock time at the end) land in the list."""
    out: list[tuple[bool, float]] = []

    def run() -> None:
        with cond:
            out.append((wait_for(clock, cond, ready, timeout_s), clock.now()))

    thread = threading.Thread(target=run, name=name)
    thread.start()
    clock.until_thread_waits(name)
    return thread, out


def test_a_wait_ends_when_its_timeout_has_passed_on_the_clock_and_not_before() -> None:
    clock, cond = ManualClock(start=100.0), threading.Condition()
    thread, out = waiter(clock, cond, lambda: False, 10.0, "timed")
    clock.advance(9.5)
    clock.until_thread_waits("timed")  # still waiting: 0.5 s of its timeout are left
    assert out == []
    clock.advance(0.5)
    thread.join()
    assert out == [(False, 110.0)]


def test_a_wait_ends_at_the_change_it_waits_for_with_no_time_passing() -> None:
    clock, cond = ManualClock(), threading.Condition()
    flag = []
    thread, out = waiter(clock, cond, lambda: bool(flag), None, "changed")
    with cond:
        cond.notify_all()  # a change that does not make it ready: it waits on
    clock.until_thread_waits("changed")
    with cond:
        flag.append(True)
        cond.notify_all()
    thread.join()
    assert out == [(True, 0.0)]


def test_calls_run_in_order_as_their_time_comes_and_a_cancelled_one_never() -> None:
    clock = ManualClock()
    ran: list[tuple[str, float]] = []
    clock.call_later(3.0, lambda: ran.append(("c", clock.now())))
    clock.call_later(1.0, lambda: ran.append(("a", clock.now())))
    clock.call_later(2.0, lambda: ran.append(("b", clock.now()))).cancel()
    clock.call_later(1.5, lambda: clock.call_later(0.5, lambda: ran.append(("made by a call", clock.now()))))
    clock.advance(0.5)
    assert ran == []
    clock.advance(2.0)  # to 2.5: each runs at its own time
    assert ran == [("a", 1.0), ("made by a call", 2.0)] and clock.now() == 2.5
    clock.advance(0.5)
    assert ran[-1] == ("c", 3.0) and len(ran) == 3
    with pytest.raises(ValueError, match="does not go back"):
        clock.advance(-1.0)


def test_a_wait_nothing_ends_fails_the_test_rather_than_hanging_it() -> None:
    clock, cond = ManualClock(stall_s=0.05), threading.Condition()
    with cond, pytest.raises(ClockStalled, match=r"a wait of 30 s on the manual clock saw no change in 0\.05 s"):
        wait_for(clock, cond, lambda: False, 30.0)
    with pytest.raises(ClockStalled, match="thread 'nobody' did not wait on the manual clock"):
        clock.until_thread_waits("nobody")


def test_the_system_clock_keeps_the_contract_on_wall_time() -> None:
    clock, cond = SystemClock(), threading.Condition()
    t0 = clock.now()
    with cond:
        assert wait_for(clock, cond, lambda: False, 0.0) is False
        assert wait_for(clock, cond, lambda: True, None) is True
    called = threading.Event()
    clock.call_later(0.0, called.set)
    assert called.wait(30.0) and clock.now() >= t0
    never = threading.Event()
    clock.call_later(60.0, never.set).cancel()
    assert not never.is_set()


def test_an_event_wait_ends_when_the_clock_reaches_its_time_or_its_event_is_set() -> None:
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
    with pytest.raises(ClockStalled, match="0 threads wait on the clock"):
        clock.until_waiting(1, timeout_s=0.05)


def test_the_system_clock_waits_on_an_event() -> None:
    event = threading.Event()
    event.set()
    assert SYSTEM_CLOCK.wait(event, 10.0) is True
    assert SYSTEM_CLOCK.wait(threading.Event(), -1.0) is False
    assert SYSTEM_CLOCK.now() <= SYSTEM_CLOCK.now()


def test_a_thread_whose_event_is_set_is_no_longer_counted_as_waiting() -> None:
    """Set its event and a waiter is about to go on: counting it would let a test's run() move time on before the
    thread has seen its event (a driver test read a move's arrival one step late that way, under load)."""
    clock = ManualClock()
    event = threading.Event()
    waiter = threading.Thread(target=lambda: clock.wait(event, 1.0))
    waiter.start()
    clock.until_waiting(1)
    event.set()
    assert clock.waiting() == 0  # at once, whether or not the thread has woken yet
    waiter.join()
