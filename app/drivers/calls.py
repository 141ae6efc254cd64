"""Calls to a robot, each with a deadline: the desk never waits on a robot longer than the call allows.

A robot that stops answering (a NAOqi whose ALMotion hangs, a network that drops packets without a reset, a
ROS 2 node that never answers) must not take the desk with it. The driver core (core.py) makes every call to its
transport through `Calls`: the call runs on a *lane*, a worker thread of the robot's for one kind of call
(readings, commands, measurements, apply, life), and its caller waits at most the lane's deadline on the
driver's clock, then gets NotResponding naming the robot, the call and how long it waited. The call itself goes
on in its lane until the robot answers (a request sent over the wire cannot be taken back), and the lane serves
the calls after it in order: a halt never overtakes the move sent before it. A transport names the remote call
it is making (`calling("ALMotion.getAngles")`) so that the sentence says which one did not answer.

A stop releases at once the callers of the calls marked `abortable` (a move being sent, a look): they get
Interrupted, such a call not yet started is never made, and one under way makes no further remote call
(`calling` raises). The halt itself waits its turn behind the call under way: were it sent beside a move that
hangs, the move could still reach the robot after it.
"""

from __future__ import annotations

import math
import threading
from collections import deque
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from typing import Generic, Literal, TypeVar

from ..clock import Clock


class RobotFault(RuntimeError):
    """The robot failed, not the operator: its link was lost, it did not answer a call within its deadline, a reading
    went wrong, or a move did not arrive in time. The robot is told to stop; what was captured before stays."""


Lane = Literal["readings", "commands", "measurements", "apply", "life"]
LANES: tuple[Lane, ...] = ("readings", "commands", "measurements", "apply", "life")
T = TypeVar("T")  # what a call answers
T_co = TypeVar("T_co", covariant=True)  # a call of a lane, whatever it answers, is a Call[object]
LINGER_S = 2.0  # an idle lane's worker waits this long for its next call before it ends

_here = threading.local()  # the call a lane's worker is making (calling() names its remote call)


class NotResponding(RobotFault):
    """A call to the robot past its deadline: the robot does not answer (the call goes on in its lane)."""


class Interrupted(RobotFault):
    """A wait for a robot call that a stop ended (the call, if it had started, goes on in its lane)."""


def calling(what: str) -> None:
    """Name the remote call the transport is making now ("ALMotion.getAngles"): the sentence a robot that does not
    answer it gets. A call a stop has interrupted goes no further (Interrupted): a move sent in several remote calls
    whose first hung never makes its last once it answers. Outside a lane (a transport used on its own) it does
    nothing."""
    call = getattr(_here, "call", None)
    if call is None:
        return
    if call.interrupted:
        raise Interrupted(f"{call.name} was stopped before {what}")
    call.doing = what


@dataclass(eq=False)
class Call(Generic[T_co]):
    """One call on a lane: what it is, its result once done."""

    what: str  # the transport's method ("send"); `doing` names the remote call within it
    fn: Callable[[], T_co]
    abortable: bool
    doing: str = ""
    started: float = math.nan  # the clock's s; nan while queued
    error: BaseException | None = None
    interrupted: bool = False
    finished: threading.Event = field(default_factory=threading.Event)  # the robot answered (or the call failed)
    released: threading.Event = field(default_factory=threading.Event)  # finished, or a stop let its caller go
    value: T_co = field(init=False, repr=False)  # the answer, once finished without an error (unset before)

    @property
    def name(self) -> str:
        return self.doing or self.what


class _Lane:
    """One worker thread making one kind of call in the order they came. It starts with a call and ends once it has
    had none for LINGER_S (real time: no wait of the desk's), so an idle robot holds no thread, a polled one keeps
    its worker, and a hung call holds one."""

    def __init__(self, name: str, clock: Clock) -> None:
        self.name = name
        self.clock = clock
        self._lock = threading.Condition()
        self._queue: deque[Call[object]] = deque()
        self._current: Call[object] | None = None
        self._worker: threading.Thread | None = None

    def submit(self, call: Call[object]) -> None:
        with self._lock:
            self._queue.append(call)
            self._lock.notify()
            if self._worker is None:
                self._worker = threading.Thread(target=self._run, name=f"calls-{self.name}", daemon=True)
                self._worker.start()

    def current(self) -> Call[object] | None:
        """The call under way (None: idle)."""
        with self._lock:
            return self._current

    def interrupt(self) -> None:
        """Release the callers of abortable calls; drop those not started."""
        with self._lock:
            dropped = [c for c in self._queue if c.abortable]
            self._queue = deque(c for c in self._queue if not c.abortable)
            running = self._current if self._current is not None and self._current.abortable else None
        for call in [*dropped, *([running] if running else [])]:
            call.interrupted = True
            call.released.set()

    def _run(self) -> None:
        while True:
            with self._lock:
                if not self._queue and not self._lock.wait_for(lambda: self._queue, LINGER_S):
                    self._worker = None
                    return
                call = self._current = self._queue.popleft()
            call.started = self.clock.now()
            _here.call = call
            try:
                call.value = call.fn()
            except BaseException as exc:  # handed to the caller, whatever it is
                call.error = exc
            finally:
                _here.call = None
                with self._lock:
                    self._current = None  # before its caller goes on: its next call finds the lane free
                call.finished.set()
                call.released.set()


class Calls:
    """A robot's calls with their deadlines (`deadlines_s` by lane, the clock's seconds), for its driver."""

    def __init__(self, robot: str, clock: Clock, deadlines_s: Mapping[Lane, float]) -> None:
        unknown = set(deadlines_s) - set(LANES)
        if unknown:
            raise ValueError(f"no such lane: {', '.join(sorted(unknown))}")
        self.robot = robot
        self.clock = clock
        self.deadlines_s = dict(deadlines_s)
        self._lanes = {name: _Lane(f"{robot}-{name}", clock) for name in LANES}

    def submit(self, lane: Lane, what: str, fn: Callable[[], T], *, abortable: bool = False) -> Call[T]:
        """Queue the call on its lane; wait for it with `wait`."""
        call = Call(what, fn, abortable)
        self._lanes[lane].submit(call)
        return call

    def wait(self, lane: Lane, call: Call[T], timeout_s: float | None = None) -> T:
        """The call's value (or its exception) once the robot answered; NotResponding once the lane's deadline (or
        `timeout_s`) has passed; Interrupted when a stop released it."""
        limit_s = self.deadlines_s[lane] if timeout_s is None else timeout_s
        if not self.clock.wait_call(call.released, limit_s):
            raise NotResponding(f"{self.robot} did not answer {call.name} within {limit_s:g} s")
        if call.interrupted and not call.finished.is_set():
            raise Interrupted(f"{self.robot}: {call.name} was stopped")
        if call.error is not None:
            raise call.error
        return call.value

    def run(self, lane: Lane, what: str, fn: Callable[[], T], *, abortable: bool = False, queue: bool = True) -> T:
        """submit and wait. `queue=False`: while an earlier call of the lane is under way, NotResponding at once
        (a poll does not pile up behind a read that hangs)."""
        if not queue:
            busy = self._lanes[lane].current()
            if busy is not None:
                waited = self.clock.now() - busy.started
                raise NotResponding(f"{self.robot} has not answered {busy.name} for {waited:.1f} s")
        return self.wait(lane, self.submit(lane, what, fn, abortable=abortable))

    def busy(self, lane: Lane) -> Call[object] | None:
        """The call under way on the lane (None: idle)."""
        return self._lanes[lane].current()

    def interrupt(self) -> None:
        """A stop: the callers of abortable calls go on at once (Interrupted), those not yet started are dropped."""
        for lane in self._lanes.values():
            lane.interrupt()


@dataclass(frozen=True)
class Halt:
    """A stop as sent to one robot: `call` is the halt on the robot's command lane (None: nothing to tell, the
    driver is closed), `before` the call it waits behind when it has not started."""

    robot: str
    call: Call[None] | None
    before: Call[object] | None = None
    queued_s: float = 0.0  # how long `before` had been under way when the stop came

    @property
    def confirmed(self) -> bool:
        """The robot took the halt."""
        return self.call is None or (self.call.finished.is_set() and self.call.error is None)

    def sentence(self) -> str:
        """What the operator is told of this robot's stop."""
        if self.confirmed:
            return f"{self.robot} stopped"
        own = "If it moves, use its own emergency stop."
        assert self.call is not None
        if self.call.finished.is_set():
            return f"{self.robot}: the stop failed ({self.call.error}). {own}"
        if math.isnan(self.call.started) and self.before is not None:
            return (
                f"{self.robot} does not answer ({self.before.name} for {self.queued_s:.1f} s): the stop is queued "
                f"behind it, not confirmed. {own}"
            )
        return f"{self.robot} does not answer: the stop was sent, not confirmed. {own}"
