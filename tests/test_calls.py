"""Calls to a robot with deadlines (app/drivers/calls.py), on a ManualClock: a caller never waits past its
deadline, the sentence names the robot, the remote call and the wait, a lane keeps its calls in order behind one
that hangs, and a stop lets the callers of abortable calls go at once."""

from __future__ import annotations

import threading

import pytest

from app.clock import ManualClock
from app.drivers.calls import Calls, Interrupted, NotResponding, calling


class Robot:
    """A robot whose calls block until the test lets them answer."""

    def __init__(self) -> None:
        self.answer = threading.Event()
        self.called = threading.Event()  # a call reached the robot
        self.made: list[str] = []

    def call(self, name: str, value: object = None, remote: str = "") -> object:
        if remote:
            calling(remote)
        self.made.append(name)
        self.called.set()
        self.answer.wait()
        return value


def _in_thread(fn) -> tuple[threading.Thread, dict]:
    out: dict = {}

    def run() -> None:
        try:
            out["value"] = fn()
        except BaseException as exc:
            out["error"] = exc

    thread = threading.Thread(target=run, name="caller", daemon=True)
    thread.start()
    return thread, out


def test_a_call_that_answers_gives_its_value_and_its_error() -> None:
    calls = Calls("nao-3", ManualClock(), {"readings": 1.0})
    assert calls.run("readings", "joint readings", lambda: 42) == 42
    with pytest.raises(ZeroDivisionError):
        calls.run("readings", "joint readings", lambda: 1 / 0)


def test_a_call_past_its_deadline_names_the_robot_the_call_and_the_wait_and_the_lane_keeps_its_order() -> None:
    clock, robot = ManualClock(), Robot()
    calls = Calls("nao-3", clock, {"commands": 2.0})
    send = calls.submit("commands", "send", lambda: robot.call("send", remote="ALMotion.setStiffnesses"))
    halt = calls.submit("commands", "halt", lambda: robot.call("halt", "halted"))
    thread, out = _in_thread(lambda: calls.wait("commands", send))
    assert robot.called.wait(5)  # the send has reached the robot (and named its remote call)
    clock.until_thread_waits("caller")
    assert clock.waiting() == 0  # a caller waits for work under way, not for time: a test's run() does not count it
    clock.advance(1.9)
    assert thread.is_alive()
    clock.advance(0.2)
    thread.join(5)
    assert isinstance(out["error"], NotResponding)
    assert str(out["error"]) == "nao-3 did not answer ALMotion.setStiffnesses within 2 s"
    assert robot.made == ["send"]  # the halt waits behind the send: it never overtakes it
    robot.answer.set()
    assert calls.wait("commands", halt) == "halted"
    assert robot.made == ["send", "halt"]


def test_a_poll_behind_a_read_that_hangs_says_so_at_once() -> None:
    clock, robot = ManualClock(), Robot()
    calls = Calls("nao-3", clock, {"readings": 1.0})
    calls.submit("readings", "joint readings", lambda: robot.call("read", remote="ALMotion.getAngles"))
    assert robot.called.wait(5)
    clock.advance(3.25)
    with pytest.raises(NotResponding, match=r"^nao-3 has not answered ALMotion.getAngles for 3.2 s$"):
        calls.run("readings", "joint readings", lambda: 0, queue=False)
    assert robot.made == ["read"]  # no second read piled up behind the first
    robot.answer.set()


def test_a_stop_lets_the_callers_of_abortable_calls_go_and_drops_those_not_started() -> None:
    clock, robot = ManualClock(), Robot()
    calls = Calls("nao-3", clock, {"commands": 5.0, "measurements": 5.0})
    first = calls.submit("commands", "send", lambda: robot.call("send 1"), abortable=True)
    second = calls.submit("commands", "send", lambda: robot.call("send 2"), abortable=True)
    look = calls.submit("measurements", "measure", lambda: robot.call("measure"), abortable=True)
    waiting = [
        _in_thread(lambda call=call, lane=lane: calls.wait(lane, call))
        for lane, call in (("commands", first), ("measurements", look))
    ]
    clock.until_thread_waits("caller")
    calls.interrupt()
    halt = calls.submit("commands", "halt", lambda: robot.call("halt", "halted"))
    for thread, out in waiting:
        thread.join(5)  # at once: the clock never moved
        assert isinstance(out["error"], Interrupted) and "was stopped" in str(out["error"])
    with pytest.raises(Interrupted):
        calls.wait("commands", second, 0.0)
    robot.answer.set()
    assert calls.wait("commands", halt) == "halted"
    assert "send 2" not in robot.made and robot.made[-1] == "halt"  # the move not yet sent never was
