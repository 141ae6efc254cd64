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
"""

from __future__ import annotations

import math
import threading
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any, Protocol, runtime_checkable

import numpy as np

from calib_core import Calibration, FrameStatus, Profile, Sensor
from calib_core.errors import InputError
from calib_core.units import length_factor
from calib_core.vision import Sighting, StereoHead, finder_for

from ..clock import SYSTEM_CLOCK, Clock
from . import DEFAULT_MARGIN_DEG, DEFAULT_MARGIN_M, Look, RobotFault, RobotStatus, check_limits

POLL_S = 0.01  # how often a wait asks its caller whether to stop
DEFAULT_SETTLE_S = 0.3  # the robot's time its readings stay still before a capture looks


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
    detail: dict[str, Any] = field(default_factory=dict)  # a point's: where it came from
    sightings: list[Sighting] = field(default_factory=list)  # other sensors' of the same moment, measured already


class Feed(Protocol):
    """Where a transport delivers joint readings (the driver)."""

    def on_joints(self, q: np.ndarray, stamp_s: float) -> None:
        """Readings (rad; a prismatic joint's in the length unit), stamped on the robot's clock."""
        ...

    def on_lost(self, reason: str) -> None:
        """The link is lost (a sentence); the next readings bring it back."""
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
        """Stop and hold where the robot is, at once, from any thread; never raises for a lost link."""
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
    every period_s of the clock in a thread of its own, the first at once. A read that raises RobotFault tells
    the feed the link is lost, with its message, until a read succeeds again."""

    def __init__(
        self, read: Callable[[], tuple[np.ndarray, float]], feed: Feed, clock: Clock, period_s: float, name: str
    ) -> None:
        self._read, self._feed, self._clock, self._period_s = read, feed, clock, period_s
        self._lock = threading.Lock()  # one read and its delivery at a time: none overtakes another
        self._stop = threading.Event()
        self.poll()
        self._thread = threading.Thread(target=self._run, name=name, daemon=True)
        self._thread.start()

    def poll(self) -> None:
        """Read and deliver now (also a transport's way to report a change it made: a halt)."""
        with self._lock:
            try:
                q, stamp_s = self._read()
            except RobotFault as exc:
                self._feed.on_lost(str(exc))
            else:
                self._feed.on_joints(q, stamp_s)

    def _run(self) -> None:
        while not self._clock.wait(self._stop, self._period_s):
            self.poll()

    def close(self) -> None:
        self._stop.set()
        self._thread.join()


@dataclass
class _Move:
    goal: np.ndarray
    t0: float  # clock seconds
    duration_s: float
    done: threading.Event = field(default_factory=threading.Event)
    arrived: bool = False


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
        transport.start(self, clock)

    # --- the stream of readings (Feed) ----------------------------------------------------------------------
    def on_joints(self, q: np.ndarray, stamp_s: float) -> None:
        q = np.asarray(q, dtype=float)
        now = self.clock.now()
        with self._lock:
            if self._closed:
                return
            self._lost = ""
            if self._ref is None:
                self._ref, self._still_since, self._rest_at = q, now, now
            elif np.any(np.abs(q - self._ref) > self.motion.still):
                self._ref, self._still_since = q, now
            self._q, self._stamp, self._at = q, float(stamp_s), now
            move = self._move
            if move is not None and np.all(np.abs(q - move.goal) <= self.motion.tolerance):
                self._move, self._rest_at, move.arrived = None, now, True
                move.done.set()

    def on_lost(self, reason: str) -> None:
        with self._lock:
            self._lost = reason
            move, self._move = self._move, None
        if move is not None:
            move.done.set()

    # --- state ----------------------------------------------------------------------------------------------
    def _connected(self, now: float) -> bool:
        return not (self._closed or self._lost or self._q is None) and now - self._at <= self.motion.timeout_s

    def _why_not(self, now: float) -> str:
        if self._closed:
            return "disconnected: the driver was closed"
        if self._lost:
            return f"disconnected: {self._lost}"
        if self._q is None:
            return f"disconnected: no {self.transport.readings_from} yet"
        return f"disconnected: no {self.transport.readings_from} for {now - self._at:.1f} s"

    def _check_link(self) -> np.ndarray:
        """The latest readings; RobotFault when disconnected (lock held)."""
        now = self.clock.now()
        if not self._connected(now):
            raise RobotFault(f"{self.profile.name} {self._why_not(now)}")
        assert self._q is not None
        return self._q.copy()

    def status(self) -> RobotStatus:
        now = self.clock.now()
        with self._lock:
            connected = self._connected(now)
            stirring = self._still_since > self._rest_at and self._at - self._still_since <= self.motion.still_window_s
            moving = connected and (self._move is not None or stirring)
            if not connected:
                message = self._why_not(now)
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
        m = self.transport.measure(since, target)
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
        return self.transport.deploy(cal_id, cal) if isinstance(self.transport, Deploys) else None

    # --- moving ---------------------------------------------------------------------------------------------
    def check(self, q_rad: np.ndarray) -> None:
        check_limits(self.profile, q_rad, self.margin_rad, self.margin_m)

    def duration_s(self, start: np.ndarray, goal: np.ndarray) -> float:
        """The move's duration on the driver's clock: no joint faster than its velocity limit."""
        m = self.motion
        return max(m.min_duration_s, m.duration_factor * travel_s(self.profile, start, goal) / m.time_scale)

    def move_to(self, q_rad: np.ndarray, *, wait: bool = True, should_stop: Callable[[], bool] | None = None) -> bool:
        """Check, then move. True on arrival, False if stopped (or superseded by another move); without `wait`
        True once the move is sent. RobotFault when the link is lost or the move does not arrive in time (the
        robot is stopped)."""
        goal = np.asarray(q_rad, dtype=float).copy()
        self.check(goal)
        with self._command:
            with self._lock:
                start = self._check_link()
                move = _Move(goal, self.clock.now(), self.duration_s(start, goal))
                previous, self._move, self._stopped = self._move, move, False
            if previous is not None:
                previous.done.set()
            try:
                self.transport.send(Command(start, goal, move.duration_s))
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
                    f"{self.profile.name} did not arrive within {limit_s:.1f} s (not responding); the robot was stopped"
                )
        with self._lock:
            if not move.arrived and self._lost:
                self._check_link()
        return move.arrived

    def _forget(self, move: _Move) -> None:
        with self._lock:
            if self._move is move:
                self._move = None
        move.done.set()

    def stop(self) -> None:
        """Halt at once (any thread): a move under way ends, not arrived; a settle wait asks its should_stop again."""
        with self._lock:
            early = self._move
        if early is not None:
            early.done.set()  # its waiter returns now, not after the halt
        with self._command:
            with self._lock:
                move, self._move = self._move, None
            if move is not None:
                move.done.set()
            if not self._closed:
                self.transport.halt()
            with self._lock:
                self._stopped, self._rest_at = True, self.clock.now()
                wake, self._wake = self._wake, threading.Event()
            wake.set()

    # --- life -----------------------------------------------------------------------------------------------
    def close(self) -> None:
        """Stop a move under way, then let go of the robot; the driver then reports itself disconnected."""
        with self._lock:
            moving = self._move is not None
        if moving:
            self.stop()
        with self._lock:
            self._closed = True
            self._wake.set()
        self.transport.close()

    def __enter__(self) -> Driver:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
