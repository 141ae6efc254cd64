"""The driver every robot kind shares (Driver), over a small transport of its own (Transport).

The core keeps all that does not depend on how the robot is reached: the joint limits less the safety margins
(every configuration is checked before it is commanded), the velocity limits (a move lasts as long as its
slowest joint needs at its limit), the believed calibration and the target in view, and the robot's state
from its stream of joint readings. Readings that keep coming mean connected; a move has arrived when every
reading is within its joint's tolerance of the goal, and is not responding when it has not arrived within its
duration and a slack; readings that change less than their joint's `still` threshold for a while mean settled.
The core also runs the detectors on what the transport measured after the robot stood still.

A transport sends a move, halts, delivers joint readings (pushed as they come, or polled by a Poller) and
measures (images or a point, stamped after the readings it is asked about); nothing else. Every wait, settle and
timeout is measured on the driver's clock (app/clock.py), which a test can drive.

The core never waits on the robot longer than a deadline: every call to the transport goes through the robot's
`Calls` (calls.py), which say which call did not answer and how long they waited, and keep the calls in order (a
halt never overtakes the move before it). A stop does not wait for the robot either: it releases a move being sent
and a look, queues the halt, and answers whether the robot took it within `wait_s` (Halt). Readings are checked at
the edge: one that is not a number, or beyond its joint's limit by more than `Motion.reading_slack`, is a fault
that names the joint and ends the move under way; images are checked before a detector sees them.
"""

from __future__ import annotations

import contextlib
import math
import threading
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from functools import partial
from typing import Protocol, runtime_checkable

import numpy as np

from calib_core import Calibration, FrameStatus, Profile, Sensor
from calib_core.errors import InputError
from calib_core.units import length_factor
from calib_core.vision import MAX_IMAGE_PX, Detail, Sighting, StereoHead, finder_for

from ..clock import SYSTEM_CLOCK, Clock
from . import DEFAULT_MARGIN_DEG, DEFAULT_MARGIN_M, Look, RobotFault, RobotStatus, check_limits
from .calls import Call, Calls, Halt, Interrupted, Lane, NotResponding

POLL_S = 0.01  # how often a wait asks its caller whether to stop
DEFAULT_SETTLE_S = 0.3  # the robot's time its readings stay still before a capture looks
STOP_WAIT_S = 0.15  # how long a stop waits for the robot to take the halt before it answers "not confirmed"
READING_SLACK_DEG = 5.0  # a reading may stray this far past its joint's limit (a prismatic joint's: READING_SLACK_M)
READING_SLACK_M = 0.005


@dataclass(frozen=True)
class Command:
    """A move: from the latest readings `start` to `goal` (rad; a prismatic joint's in the length unit) in
    duration_s, every joint at most at its velocity limit, all arriving together."""

    start: np.ndarray
    goal: np.ndarray
    duration_s: float


@dataclass
class Measurement:
    """What the transport measured after the readings it was asked about: images, or a point, or why none."""

    images: dict[str, np.ndarray] = field(default_factory=dict)  # "image", or a stereo head's "left" and "right"
    intrinsics_px: tuple[float, float, float, float] | None = None  # fx, fy, cx, cy of the camera (None: believed)
    head: StereoHead | None = None  # the stereo head that took "left" and "right"
    point: np.ndarray | None = None  # a point sensor's reading (3,), the profile's length unit, sensor frame
    missing: str = ""  # why there is nothing to detect in
    detail: Detail = field(default_factory=dict)  # a point's: where it came from
    sightings: list[Sighting] = field(default_factory=list)  # other sensors' of the same moment, measured already


class Feed(Protocol):
    """Where a transport delivers joint readings (the driver)."""

    calls: Calls  # the robot's calls with their deadlines: a Poller reads through them

    def on_joints(self, q: np.ndarray, stamp_s: float) -> None:
        """Readings (rad; a prismatic joint's in the length unit), stamped on the robot's clock."""
        ...

    def on_lost(self, reason: str, *, responding: bool = True) -> None:
        """The link is lost (a sentence; `responding=False`: the robot does not answer a call); the next readings
        bring it back."""
        ...


class Transport(Protocol):
    readings_from: str  # what the readings are, for "no ... for 2.0 s": "joint states on /joint_states"

    def start(self, feed: Feed, clock: Clock) -> None:
        """Begin delivering joint readings to `feed`, the first before returning if it can."""
        ...

    def send(self, command: Command) -> None:
        """Start the move and return (RobotFault, a sentence, when it cannot be sent)."""
        ...

    def halt(self) -> None:
        """Stop and hold where the robot is, at once; RobotFault when the robot could not be told."""
        ...

    def measure(self, since_s: float, target: int) -> Measurement:
        """The data sensor's measurement stamped after `since_s` (the latest readings' stamp), of `target`."""
        ...

    def close(self) -> None:
        """Let go of the robot: no readings after this."""
        ...


@runtime_checkable
class Deploys(Protocol):
    """A transport that puts a calibration on the robot itself; returns what it did, a sentence."""

    def deploy(self, cal_id: str, cal: Calibration) -> str: ...


@dataclass(frozen=True)
class Motion:
    """How a kind of robot moves and reports: per joint, in internal units (rad, or the length unit)."""

    tolerance: np.ndarray  # a move has arrived when every reading is this close to its goal
    still: np.ndarray  # readings that change less than this stand still
    margin_deg: float = DEFAULT_MARGIN_DEG  # no move closer than this to a revolute joint's limit
    margin_m: float = DEFAULT_MARGIN_M  # nor to a prismatic joint's
    still_window_s: float = 0.0  # readings changed within this: moving
    timeout_s: float = math.inf  # no readings for this long: disconnected
    move_slack_s: float = 5.0  # a move may overrun its duration by this before the robot is not responding
    duration_factor: float = 1.0  # a move is commanded this much longer than the velocity limits need
    min_duration_s: float = 0.0
    time_scale: float = 1.0  # the robot's clock runs this much faster than the driver's (a simulation)
    settle_s: float = DEFAULT_SETTLE_S  # a capture looks once the readings stayed still this long (robot's time)
    call_timeout_s: float = 5.0  # a reading, a move sent, a halt, a close: the robot answers within this
    measure_timeout_s: float = 30.0  # a measurement (the transport's own wait for an image included)
    apply_timeout_s: float = 30.0  # a calibration put on the robot (deploy)
    reading_slack: np.ndarray | None = None  # per joint: how far past its limit a reading may be (None: defaults)


def per_joint(profile: Profile, deg: float, m: float) -> np.ndarray:
    """A threshold per joint in internal units: deg for a revolute joint, m for a prismatic one."""
    to_unit = length_factor("m", profile.length_unit)
    return np.array([m * to_unit if j.prismatic else math.radians(deg) for j in profile.joints])


def travel_s(profile: Profile, start: np.ndarray, goal: np.ndarray) -> float:
    """The seconds the slowest joint needs from start to goal at its velocity limit."""
    velocity = np.array([j.velocity for j in profile.joints])
    delta = np.abs(np.asarray(goal, float) - start)
    if np.any((delta > 0) & (velocity <= 0)):
        raise InputError("a joint to move has no velocity limit above 0")
    return float(np.max(np.where(delta > 0, delta / np.where(velocity > 0, velocity, 1), 0), initial=0.0))


def reads_points(sensor: Sensor) -> bool:
    """A sensor that reports 3-D points with no image to detect them in (a laser tracker)."""
    return sensor.reading == "direct" and sensor.dim == 3


def readable_targets(profile: Profile) -> list[int]:
    """The targets a point-reading sensor can be pointed at: those its data format names (the Motoman's
    reflector on either arm, its `reflector_arm` column), else every single-point target."""
    named = sorted(set(profile.data.target_values.values()))
    return named or [t for t, target in enumerate(profile.targets) if target.grid is None and target.points is None]


def first_target(profile: Profile) -> int:
    """The target in view at the start: a point sensor's first readable one, else the first."""
    if reads_points(profile.sensors[profile.data.sensor]):
        return (readable_targets(profile) or [0])[0]
    return 0


def not_found(profile: Profile, target: int, reason: str) -> Sighting:
    """The data sensor's sighting that found nothing, and why."""
    sensor = profile.data.sensor
    return Sighting(
        sensor, target, FrameStatus.NOT_FOUND, reason, None, np.zeros((0, 3)), np.zeros(0, int), {"reason": reason}
    )


class Poller:
    """Joint readings for a transport that must ask for them (the simulated robot, NAOqi's getAngles): `read()`
    every period_s of the clock in a thread of its own, the first at once, through the feed's calls (a read that
    does not answer within its deadline: the robot is not responding; while it still hangs, the next polls say so
    at once). A read that raises RobotFault tells the feed the link is lost, with its message, until a read
    succeeds again.

    A transport that knows when its robot is at rest (`resting()`: the simulated robot, whose readings then do not
    change) is read every `rest_period_s` instead meanwhile, and calls `wake()` when it starts to move: the first
    read of the move comes at once, the next ones every period_s."""

    def __init__(
        self,
        read: Callable[[], tuple[np.ndarray, float]],
        feed: Feed,
        clock: Clock,
        period_s: float,
        name: str,
        *,
        resting: Callable[[], bool] | None = None,
        rest_period_s: float | None = None,
    ) -> None:
        self._read, self._feed, self._clock, self._period_s = read, feed, clock, period_s
        self._resting, self._rest_period_s = resting, rest_period_s or period_s
        self._lock = threading.Lock()  # one read and its delivery at a time: none overtakes another
        self._stopped = False
        self._wake = threading.Event()  # set by wake() and close(): the wait under way ends at once
        self.poll()
        self._thread = threading.Thread(target=self._run, name=name, daemon=True)
        self._thread.start()

    def poll(self) -> None:
        """Read and deliver now (also a transport's way to report a change it made: a halt)."""
        with self._lock:
            try:
                q, stamp_s = self._feed.calls.run("readings", "joint readings", self._read, queue=False)
            except NotResponding as exc:
                self._feed.on_lost(str(exc), responding=False)
            except RobotFault as exc:
                self._feed.on_lost(str(exc))
            else:
                self._feed.on_joints(q, stamp_s)

    def wake(self) -> None:
        """The robot starts to move: read now, and every period_s from then."""
        self._wake.set()

    def _run(self) -> None:
        while True:
            resting = self._resting is not None and self._resting()
            if self._clock.wait(self._wake, self._rest_period_s if resting else self._period_s):
                self._wake.clear()
            if self._stopped:
                return
            self.poll()

    def close(self) -> None:
        self._stopped = True
        self._wake.set()
        self._thread.join()


@dataclass
class _Move:
    goal: np.ndarray
    t0: float  # clock seconds
    duration_s: float
    done: threading.Event = field(default_factory=threading.Event)
    arrived: bool = False
    fault: str = ""  # a reading that ended it (not a number, beyond a limit)
    lost: str = ""  # the link lost, or the robot not answering, that ended it


class Driver:
    """A robot behind the RobotDriver interface (app/drivers/__init__.py), reached through `transport`."""

    def __init__(
        self,
        profile: Profile,
        transport: Transport,
        motion: Motion,
        *,
        clock: Clock = SYSTEM_CLOCK,
        target: int | None = None,
    ) -> None:
        if motion.time_scale <= 0 or motion.margin_deg < 0 or motion.margin_m < 0:
            raise ValueError("time_scale must be positive and the margins not negative")
        self.profile = profile
        self.transport = transport
        self.motion = motion
        self.clock = clock
        self.margin_rad = math.radians(motion.margin_deg)
        self.margin_m = float(motion.margin_m)
        self.move_slack_s = motion.move_slack_s
        self._lock = threading.Lock()  # the state below
        self._command = threading.Lock()  # one command to the transport at a time: a stop never cuts into a send
        self._q: np.ndarray | None = None  # the latest readings
        self._stamp = math.nan  # their stamp, the robot's clock
        self._at = -math.inf  # when they came, this driver's clock
        self._ref: np.ndarray | None = None  # the readings stillness is measured from
        self._still_since = -math.inf
        self._rest_at = -math.inf  # the last arrival or stop: changes before it are not motion
        self._lost = ""
        self._closed = False
        self._move: _Move | None = None
        self._stopped = False
        self._cal_id: str | None = None
        self._believed = profile.nominal()
        self._target = first_target(profile) if target is None else target
        self._wake = threading.Event()  # set by a stop or a close: the settle wait under way looks again at once
        self._bad = ""  # the latest readings' fault (not a number, beyond a limit): nothing moves until good ones
        self._halt: Call[None] | None = None  # the latest halt sent
        self._limits = profile.joint_limits()
        self._slack = (
            motion.reading_slack
            if motion.reading_slack is not None
            else per_joint(profile, READING_SLACK_DEG, READING_SLACK_M)
        )
        deadlines: dict[Lane, float] = {"readings": motion.call_timeout_s, "commands": motion.call_timeout_s}
        deadlines |= {"measurements": motion.measure_timeout_s, "apply": motion.apply_timeout_s}
        self.calls = Calls(profile.name, clock, deadlines | {"life": motion.call_timeout_s})
        transport.start(self, clock)

    # --- the stream of readings (Feed) ----------------------------------------------------------------------
    def on_joints(self, q: np.ndarray, stamp_s: float) -> None:
        q = np.asarray(q, dtype=float)
        now = self.clock.now()
        bad = self._reading_fault(q)
        with self._lock:
            if self._closed:
                return
            self._lost, self._bad = "", bad
            if bad:  # never the latest readings; the stillness starts again from the next good ones
                self._ref, self._at = None, now
                move, self._move = self._move, None
                if move is not None:
                    move.fault = bad
                    move.done.set()
                return
            if self._ref is None:
                self._ref, self._still_since, self._rest_at = q, now, now
            elif np.any(np.abs(q - self._ref) > self.motion.still):
                self._ref, self._still_since = q, now
            self._q, self._stamp, self._at = q, float(stamp_s), now
            move = self._move
            if move is not None and np.all(np.abs(q - move.goal) <= self.motion.tolerance):
                self._move, self._rest_at, move.arrived = None, now, True
                move.done.set()

    def on_lost(self, reason: str, *, responding: bool = True) -> None:
        with self._lock:
            self._lost = reason if responding else f"not responding: {reason}"
            move, self._move = self._move, None
            if move is not None:  # it ends with this sentence, whatever the polls after it say
                move.lost = reason if not responding else f"{self.profile.name} disconnected: {reason}"
        if move is not None:
            move.done.set()

    def _reading_fault(self, q: np.ndarray) -> str:
        """Why readings cannot be the robot's pose (a sentence naming the joint), or ""."""
        profile, name = self.profile, self.profile.name
        if q.shape != (len(profile.joints),):
            return f"{name} sent {q.size} joint readings, not its {len(profile.joints)} joints'"
        lower, upper = self._limits
        wrong = ~np.isfinite(q) | (q < lower - self._slack) | (q > upper + self._slack)
        if not wrong.any():
            return ""
        k = int(np.flatnonzero(wrong)[0])
        joint, value, unit = profile.joints[k].name, float(q[k]), profile.joint_display_unit(k)
        if not math.isfinite(value):
            return f"{name} reads {joint} {value} (not a number): a sensor fault; nothing moves until it reads again"
        side, limit = ("lower", lower[k]) if value < lower[k] else ("upper", upper[k])
        shown = [profile.joint_to_display(k, x) for x in (value, limit, self._slack[k])]
        return (
            f"{name} reads {joint} {shown[0]:.1f} {unit}, beyond its {side} limit {shown[1]:.1f} {unit} by more than "
            f"the {shown[2]:g} {unit} a reading may stray: a sensor fault; nothing moves until it reads again"
        )

    # --- state ----------------------------------------------------------------------------------------------
    def _connected(self, now: float) -> bool:
        ok = not (self._closed or self._lost or self._bad or self._q is None)
        return ok and now - self._at <= self.motion.timeout_s

    def _why_not(self, now: float) -> str:
        if self._closed:
            return "disconnected: the driver was closed"
        if self._lost.startswith("not responding: "):
            return self._lost
        if self._lost:
            return f"disconnected: {self._lost}"
        if self._bad:
            return f"faulty readings: {self._bad}"
        hung = self.calls.busy("readings")
        if hung is not None and self._q is not None:  # the readings stopped because the robot does not answer
            return f"not responding: {self.profile.name} has not answered {hung.name} for {now - hung.started:.1f} s"
        if self._q is None:
            return f"disconnected: no {self.transport.readings_from} yet"
        return f"disconnected: no {self.transport.readings_from} for {now - self._at:.1f} s"

    def _check_link(self) -> np.ndarray:
        """The latest readings; RobotFault when disconnected (lock held)."""
        now = self.clock.now()
        if not self._connected(now):
            why = self._why_not(now)
            if why.startswith("not responding: ") or (self._bad and not self._lost):
                raise RobotFault(why.removeprefix("not responding: ").removeprefix("faulty readings: "))  # names it
            raise RobotFault(f"{self.profile.name} {why}")
        assert self._q is not None
        return self._q.copy()

    def status(self) -> RobotStatus:
        now = self.clock.now()
        with self._lock:
            connected = self._connected(now)
            stirring = self._still_since > self._rest_at and self._at - self._still_since <= self.motion.still_window_s
            halting = self._halt is not None and not self._halt.finished.is_set()  # not yet taken by the robot
            moving = connected and (self._move is not None or stirring or halting)
            if not connected:
                message = self._why_not(now)
            elif halting:
                message = "stopping: the robot has not yet taken the stop"
            else:
                message = "moving" if moving else "stopped" if self._stopped else "idle"
            q = self._q if self._q is not None else np.clip(0.0, *self.profile.joint_limits())
            return RobotStatus(
                robot=self.profile.name,
                connected=connected,
                moving=moving,
                joints_rad=q.copy(),
                target=self._target,
                calibration_id=self._cal_id,
                message=message,
                stamp=self._at,
            )

    def read_joints(self) -> np.ndarray:
        with self._lock:
            return self._check_link()

    def settled(self, for_s: float | None = None) -> bool:
        """No move under way and the readings still for for_s of the robot's time (None: `Motion.settle_s`)."""
        for_s = self.motion.settle_s if for_s is None else for_s
        now = self.clock.now()
        with self._lock:
            still_s = (self._at - self._still_since) * self.motion.time_scale
            return self._connected(now) and self._move is None and still_s >= for_s

    def wait_settled(
        self, for_s: float | None, timeout_s: float, should_stop: Callable[[], bool] | None = None
    ) -> bool:
        """Until settled(for_s): True; False when should_stop() says so; RobotFault when disconnected or not
        settled within timeout_s."""
        deadline = self.clock.now() + timeout_s
        while not self.settled(for_s):
            with self._lock:
                wake = self._wake  # before should_stop: a stop after it (a cancel comes first) sets this one
            if should_stop is not None and should_stop():
                return False
            with self._lock:
                self._check_link()
            if self.clock.now() > deadline:
                raise RobotFault(f"{self.profile.name} did not settle within {timeout_s:g} s")
            self.clock.wait(wake, POLL_S)
        return True

    # --- seeing ---------------------------------------------------------------------------------------------
    def look(self, believed: np.ndarray | None = None) -> Look:
        """The data sensor's measurement after the readings now, through the detector seeded by the believed
        calibration (or `believed`), then what the other sensors measured of the same moment."""
        with self._lock:
            q, since, target = self._check_link(), self._stamp, self._target
            p = (self._believed if believed is None else np.asarray(believed, float)).copy()
        measure = partial(self.transport.measure, since, target)
        m = self.calls.run("measurements", "measure", measure, abortable=True)
        unusable = _unusable(m.images)
        if unusable:  # neither searched nor kept
            m = Measurement(missing=m.missing or unusable, sightings=m.sightings)
        sighting = self._sight(q, target, p, m)
        return Look(q, sighting.target, [sighting, *m.sightings], m.images)

    def _sight(self, q: np.ndarray, target: int, p: np.ndarray, m: Measurement) -> Sighting:
        profile = self.profile
        if m.missing:
            return not_found(profile, target, m.missing)
        sensor = profile.sensors[profile.data.sensor]
        if m.intrinsics_px is not None and sensor.intrinsics is not None:
            p[list(sensor.intrinsics)] = m.intrinsics_px
        if m.point is not None:
            fixed = profile.targets[target].points  # a reflector: its frame's origin, as a CSV row's point
            points = np.full((1, 3), np.nan) if fixed is None else fixed[[0]]
            return Sighting(
                profile.data.sensor, target, FrameStatus.MEASURED, "ok", m.point[None], points, np.array([-1]), m.detail
            )
        finder = finder_for(profile, profile.data.sensor, target)
        if finder is None:
            return not_found(profile, target, f"no finder for {profile.targets[target].name} in {sensor.name}'s images")
        return finder.find(p, q, m.images, m.head)

    def set_target(self, target: int) -> None:
        profile = self.profile
        if not 0 <= target < len(profile.targets):
            raise ValueError(f"{profile.name} has targets 0..{len(profile.targets) - 1}, not {target}")
        sensor = profile.sensors[profile.data.sensor]
        if reads_points(sensor) and target not in readable_targets(profile):
            names = ", ".join(profile.targets[t].name for t in readable_targets(profile))
            raise InputError(f"the {sensor.name} reads {names}, not {profile.targets[target].name}")
        with self._lock:
            self._target = int(target)

    # --- calibration ----------------------------------------------------------------------------------------
    def apply_calibration(self, cal_id: str | None, params: np.ndarray | None) -> None:
        p = self.profile.nominal() if params is None else np.asarray(params, float).copy()
        if p.shape != (len(self.profile.parameters),):
            raise ValueError(f"expected {len(self.profile.parameters)} parameters for {self.profile.name}")
        with self._lock:
            self._cal_id, self._believed = cal_id, p

    def believed_params(self) -> np.ndarray:
        with self._lock:
            return self._believed.copy()

    def deploy(self, cal_id: str, cal: Calibration) -> str | None:
        """Put the calibration on the robot itself, if its transport can (RobotFault when that fails): what was
        done, a sentence; None for a robot that takes nothing."""
        if not isinstance(self.transport, Deploys):
            return None
        return self.calls.run("apply", "deploy", partial(self.transport.deploy, cal_id, cal))

    # --- moving ---------------------------------------------------------------------------------------------
    def check(self, q_rad: np.ndarray) -> None:
        check_limits(self.profile, q_rad, self.margin_rad, self.margin_m)

    def duration_s(self, start: np.ndarray, goal: np.ndarray) -> float:
        """The move's duration on the driver's clock: no joint faster than its velocity limit."""
        m = self.motion
        return max(m.min_duration_s, m.duration_factor * travel_s(self.profile, start, goal) / m.time_scale)

    def move_to(self, q_rad: np.ndarray, *, wait: bool = True, should_stop: Callable[[], bool] | None = None) -> bool:
        """Check, then move. True on arrival, False if stopped (or superseded by another move); without `wait`
        True once the move is sent. RobotFault when the link is lost, the robot does not take the move within its
        deadline, a reading goes wrong, or the move does not arrive in time (the robot is told to stop)."""
        goal = np.asarray(q_rad, dtype=float).copy()
        self.check(goal)
        with self._command:  # the move and a stop reach the command lane in the order they were decided
            with self._lock:
                start = self._check_link()
                move = _Move(goal, self.clock.now(), self.duration_s(start, goal))
                previous, self._move, self._stopped = self._move, move, False
            if previous is not None:
                previous.done.set()
            send = partial(self.transport.send, Command(start, goal, move.duration_s))
            call = self.calls.submit("commands", "send", send, abortable=True)
        try:
            self.calls.wait("commands", call)
        except Interrupted:  # a stop came while the move was being sent
            self._forget(move)
            return False
        except NotResponding as exc:
            self._forget(move)
            self.stop()
            raise RobotFault(f"{exc}; the robot was told to stop") from None
        except RobotFault as exc:
            self._forget(move)
            raise RobotFault(f"{self.profile.name}: {exc}") from None
        except BaseException:
            self._forget(move)
            raise
        if not wait:
            return True
        limit_s = move.duration_s + self.move_slack_s
        while not self.clock.wait(move.done, POLL_S):
            with self._lock:
                connected = self._connected(self.clock.now())
            if should_stop is not None and should_stop():
                self.stop()
            elif not connected:
                self.stop()
                with self._lock:
                    self._check_link()
            elif self.clock.now() - move.t0 > limit_s:
                self.stop()
                raise RobotFault(
                    f"{self.profile.name} did not arrive within {limit_s:.1f} s (not responding); the robot was told "
                    "to stop"
                )
        if move.fault:
            self.stop()
            raise RobotFault(f"{move.fault}; the robot was told to stop")
        if move.lost:
            raise RobotFault(move.lost)
        return move.arrived

    def _forget(self, move: _Move) -> None:
        with self._lock:
            if self._move is move:
                self._move = None
        move.done.set()

    def stop(self, wait_s: float = STOP_WAIT_S) -> Halt:
        """Halt at once, from any thread, never waiting on the robot past `wait_s` of the clock: a move under way
        ends (not arrived), a move being sent and a look are let go of (and a move not yet sent is never sent), a
        settle wait asks its should_stop again, and the halt goes to the robot behind the command before it. The
        Halt says whether the robot took it within `wait_s`."""
        with self._lock:
            move, self._move = self._move, None
            self._stopped, self._rest_at = True, self.clock.now()
            wake, self._wake = self._wake, threading.Event()
            closed = self._closed
        if move is not None:
            move.done.set()  # its waiter returns now, not after the halt
        wake.set()
        if closed:
            self.calls.interrupt()
            return Halt(self.profile.name, None)
        with self._command:  # no move is sent between letting go of the one being sent and queueing the halt
            self.calls.interrupt()
            before = self.calls.busy("commands")
            halt = self._halt
            if halt is None or halt.finished.is_set():  # one not yet taken is this stop too
                halt = self._halt = self.calls.submit("commands", "halt", self._halt_robot)
        queued_s = 0.0 if before is None else self.clock.now() - before.started
        self.clock.wait_call(halt.finished, wait_s)
        return Halt(self.profile.name, halt, before if before is not halt else None, queued_s)

    def _halt_robot(self) -> None:
        """The halt, on the command lane: the readings up to where the robot halted are not motion."""
        self.transport.halt()
        with self._lock:
            self._rest_at = self.clock.now()

    # --- life -----------------------------------------------------------------------------------------------
    def close(self) -> None:
        """Stop a move under way, then let go of the robot (within the call deadline: a robot that does not
        answer is let go of all the same); the driver then reports itself disconnected."""
        with self._lock:
            moving = self._move is not None
        if moving:
            self.stop()
        with self._lock:
            self._closed = True
            self._wake.set()
        self.calls.interrupt()
        with contextlib.suppress(RobotFault):
            self.calls.run("life", "close", self.transport.close)

    def __enter__(self) -> Driver:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def _unusable(images: Mapping[str, object]) -> str:
    """Why a transport's images cannot go to a detector (not a grey uint8 array, or too large), or "": whatever
    it sent, which its type need not have been."""
    for role, image in images.items():
        name = "the image" if role == "image" else f"the {role} image"
        if not isinstance(image, np.ndarray) or image.ndim != 2 or image.dtype != np.uint8:
            kind = f"a {image.dtype} array of shape {image.shape}" if isinstance(image, np.ndarray) else type(image)
            return f"{name} is {kind}, not a grey image of 8-bit pixels"
        height, width = image.shape
        if height * width > MAX_IMAGE_PX:
            return f"{name} is {width} x {height} px, more than the {MAX_IMAGE_PX / 1e6:.0f} MP a camera sends"
        if min(height, width) == 0:
            return f"{name} is empty ({width} x {height} px)"
    return ""
