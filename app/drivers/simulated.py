"""The simulated robot behind the RobotDriver interface (driver kind `simulated`): the driver core over the
robot that calib_core simulates.

Options (desk configuration file, `driver: {kind: simulated, ...}`): `seed` (the robot's hidden truth and
noise, default 1) and `day` (1: as the profile's truth; later days drift the joint offsets as
`calib simulate --day` does). The desk's `--sim-speed` is its time scale.
"""

from __future__ import annotations

import math
import threading
from collections.abc import Callable, Mapping
from dataclasses import dataclass, replace
from typing import Any

import numpy as np

from calib_core.errors import InputError
from calib_core.model import Profile
from calib_core.sim import SimulatedRobot
from calib_core.vision import Sampler, Visibility, found_targets

from ..clock import SYSTEM_CLOCK, Clock
from . import DEFAULT_MARGIN_DEG, DEFAULT_MARGIN_M, LimitError, RobotFault, RobotStatus, check_limits
from .core import Command, Driver, Feed, Measurement, Motion, Poller, reads_points, travel_s
from .faults import Fault, FaultSwitch, parse_fault
from .registry import DriverContext

MOVE_SLACK_S = 5.0  # seconds a move may overrun its planned duration before the robot counts as not responding
_WANDER_POOL = 24  # visible configurations the wander picks from
_WANDER_PAUSE_S = (0.5, 2.0)  # robot time between wander moves
# At rest (no move under way, no wander, none for REST_AFTER_S of the clock: past any settle) the readings do not
# change and are read REST_RATE_HZ times a second: four robots polled at 50 Hz had an idle desk spend 5.7% of a
# core, 1.0% now (benchmarks/idle_desk.py). A move wakes the poller at once.
REST_AFTER_S = 1.0
REST_RATE_HZ = 5.0
OPTIONS = {"seed": 1, "day": 1}  # and their defaults
LOST = "the link to the robot was lost"


def can_simulate(profile: Profile) -> bool:
    """Whether the simulator can stand in for the robot: the profile has a simulation section and its data
    sensor is one the simulator renders (it has a finder for one of its targets: calib_core.vision.finders) or
    reads directly (a point sensor without images, like the Motoman's laser tracker; reads_points)."""
    sensor = profile.sensors[profile.data.sensor]
    return bool(profile.simulation) and (bool(found_targets(profile, profile.data.sensor)) or reads_points(sensor))


def also_read(profile: Profile) -> list[int]:
    """The sensors besides the data format's that each look reads too, directly from the truth with the profile's
    noise (`SimulatedRobot.read`): those that report points or take images (the Motoman's two cameras, whose
    ArUco faces the simulator does not render). A plane measures only what touches it: it is never read here."""
    return [
        s
        for s, sensor in enumerate(profile.sensors)
        if s != profile.data.sensor and (reads_points(sensor) or sensor.reading != "direct")
    ]


def check(profile: Profile, options: Mapping[str, Any], where: str, options_at: str) -> dict[str, Any]:
    """The options with their defaults; InputError for a profile the simulator cannot stand in for (naming
    `where`, the driver's field), an unknown option or a value out of range (naming `options_at`.<option>)."""
    if not can_simulate(profile):
        raise InputError(
            f"{where}: {profile.name} cannot be simulated (its profile has no simulation section for its sensor)"
        )
    unknown = sorted(set(options) - set(OPTIONS))
    if unknown:
        raise InputError(f"{options_at}.{unknown[0]}: no such option of the simulated driver (options: seed, day)")
    out = {**OPTIONS, **options}
    for key, lowest in (("seed", 0), ("day", 1)):
        value = out[key]
        if isinstance(value, bool) or not isinstance(value, int) or not lowest <= value <= 2**31:
            raise InputError(f"{options_at}.{key}: expected a whole number from {lowest}, got {value!r}")
    return out


def create(profile: Profile, options: Mapping[str, Any], context: DriverContext) -> SimulatedDriver:
    """A simulated robot from checked options (check)."""
    return SimulatedDriver(
        profile, seed=options["seed"], day=options["day"], time_scale=context.time_scale, clock=context.clock
    )


@dataclass
class _Move:
    start: np.ndarray
    goal: np.ndarray
    t0: float  # clock seconds
    duration_s: float
    owner: str  # "operator" or "wander"
    stalled: bool = False  # an injected fault: the robot never gets there
    drops_link: bool = False  # an injected fault: the link is lost halfway

    def position(self, now: float) -> tuple[np.ndarray, bool]:
        if self.stalled:
            return self.start.copy(), False
        s = 1.0 if self.duration_s <= 0 else min(1.0, (now - self.t0) / self.duration_s)
        return self.start + (self.goal - self.start) * s, s >= 1.0


class SimulatedTransport:
    """The simulated robot itself: true joint angles that follow each move linearly on the clock, encoder
    readings polled at rate_hz, the sensor rendered (or a tracker read) at the true pose, injected faults, and a
    wander that drives it through visible configurations by itself (someone else driving it)."""

    readings_from = "joint readings"

    def __init__(
        self,
        profile: Profile,
        seed: int,
        day: int,
        time_scale: float,
        rate_hz: float,
        margin_rad: float,
        margin_m: float,
    ) -> None:
        self.profile = profile
        self.time_scale, self.rate_hz = time_scale, rate_hz
        self.margin_rad, self.margin_m = margin_rad, margin_m
        robot = SimulatedRobot.from_profile(profile, seed=seed).on_day(day)
        self.sim = robot  # renders, reads a tracker (its rng guarded by _render_lock)
        self._planner = Sampler(Visibility(profile, robot.true_params), np.random.default_rng(seed + 1))
        self._also = also_read(profile)
        data_targets = set(profile.data.target_values.values()) | {profile.data.target}
        self._other_targets = np.array([t for t in range(len(profile.targets)) if t not in data_targets], int)
        self._seed = seed
        self._reads = reads_points(profile.sensors[profile.data.sensor])
        self._lock = threading.Lock()
        self._render_lock = threading.Lock()
        self._planner_lock = threading.Lock()
        self._q = np.zeros(len(profile.joints))  # true joint angles when no move is under way
        self._move: _Move | None = None
        self._link_lost = False
        self.faults = FaultSwitch(profile.joint_names)  # what it is told to do wrong (the fault harness)
        self.aim: Callable[[int], None] = lambda target: None  # the driver's set_target: where the wander looks
        self._wander_stop: threading.Event | None = None
        self._wander_thread: threading.Thread | None = None

    def home(self) -> tuple[np.ndarray, int]:
        """A starting pose with the target in view."""
        qs, targets = self.visible_configurations(8)
        if len(qs):
            return qs[0], int(targets[0])
        lo, hi = self.profile.joint_limits()
        return (lo + hi) / 2, 0

    def place(self, q: np.ndarray) -> None:
        """Stand at q before start (checked against the limits less the margin)."""
        self._check(q)
        self._q = np.asarray(q, float).copy()

    def visible_configurations(self, n: int) -> tuple[np.ndarray, np.ndarray]:
        """Configurations whose target the true robot sees, within the limits less the margin."""
        with self._planner_lock:
            qs, targets = self._planner.configurations(n)
        ok = []
        for q in qs:
            try:
                self._check(q)
            except LimitError:
                ok.append(False)
            else:
                ok.append(True)
        return qs[ok], targets[ok]

    def _check(self, q: np.ndarray) -> None:
        check_limits(self.profile, q, self.margin_rad, self.margin_m)

    # --- Transport ------------------------------------------------------------------------------------------
    def start(self, feed: Feed, clock: Clock) -> None:
        self.clock = clock
        self._moved_at = clock.now()
        self._poller = Poller(
            self._read,
            feed,
            clock,
            1.0 / self.rate_hz,
            f"motion-{self.profile.name}",
            resting=self._resting,
            rest_period_s=1.0 / min(self.rate_hz, REST_RATE_HZ),
        )

    def _resting(self) -> bool:
        return self._move is None and not self.wandering and self.clock.now() - self._moved_at >= REST_AFTER_S

    def _read(self) -> tuple[np.ndarray, float]:
        self.faults.answer(self.clock.wait)
        with self._lock:
            now = self.clock.now()
            q = self._advance(now)
            if self._link_lost:
                raise RobotFault(LOST)
            return self.faults.reading(self.sim.readings(q)), now

    def send(self, command: Command) -> None:
        """The operator's (or a replay's) move: it ends a wander."""
        self.faults.answer(self.clock.wait)
        with self._lock:
            self._end_wander()
            if self._link_lost:
                raise RobotFault(LOST)
            fault = self.faults.moved()
            if fault is not None and fault.kind == "refuse":
                raise RobotFault("the robot refused the move (its motors are off); nothing was moved")
            move = self._begin(command.goal, "operator", command.duration_s)
            if fault is not None:
                move.stalled, move.drops_link = fault.kind == "stall", fault.kind == "drop"

    def halt(self) -> None:
        self.faults.answer(self.clock.wait)
        with self._lock:
            self._end_wander()
            self._advance(self.clock.now())
            self._move = None
        self._poller.poll()  # the readings where it halted, before anyone asks

    def measure(self, since_s: float, target: int) -> Measurement:
        """Rendered (or read) now: after any readings; the other sensors (`also_read`) read at the same pose."""
        self.faults.answer(self.clock.wait)
        with self._lock:
            q = self._advance(self.clock.now()).copy()
        with self._render_lock:
            others = [self.sim.read(q, t, s) for s in self._also for t in self._seen_by(q, s)]
            if self._reads:  # a tracker: the true target position with its noise, no image, no detector
                measured = self.sim.measure(q[None], np.array([target])).data.measured[0]
                return Measurement(point=measured, detail={"sensor": "read directly"}, sightings=others)
            images, head = self.sim.render(q, target)
        images = {role: self.faults.image(image) for role, image in images.items()}
        return Measurement(images=images, head=head, sightings=others)

    def _seen_by(self, q: np.ndarray, sensor: int) -> list[int]:
        """The targets besides the data format's of which `sensor` sees a point at true joint angles q."""
        targets = self._other_targets
        if not len(targets):
            return []
        view = Visibility(self.profile, self.sim.true_params)
        seen = view.points(np.repeat(q[None], len(targets), axis=0), targets, sensor)
        return [int(t) for t in targets[seen.any(axis=1)]]

    def close(self) -> None:
        self.wander(False)
        thread = self._wander_thread
        if thread is not None:
            thread.join()
        self._poller.close()

    # --- what only a simulation does ------------------------------------------------------------------------
    def true_joints_rad(self) -> np.ndarray:
        with self._lock:
            return self._advance(self.clock.now()).copy()

    @property
    def wandering(self) -> bool:
        return self._wander_stop is not None and not self._wander_stop.is_set()

    def wander(self, on: bool) -> None:
        """Start or stop the wander (stopping leaves the robot where the wander's move has taken it)."""
        with self._lock:
            if on == self.wandering:
                return
            if not on:
                self._end_wander()
                return
            if self._link_lost:
                raise RobotFault(LOST)
            stop = threading.Event()
            self._wander_stop = stop
            self._wander_thread = threading.Thread(
                target=self._wander, args=(stop,), name=f"wander-{self.profile.name}", daemon=True
            )
            self._wander_thread.start()

    def reconnect(self) -> None:
        with self._lock:
            self._link_lost = False
        self._poller.poll()

    # --- internals ------------------------------------------------------------------------------------------
    def _advance(self, now: float) -> np.ndarray:
        """The true joint angles now, the move under way followed (lock held)."""
        move = self._move
        if move is None:
            return self._q
        self._moved_at = now
        self._q, arrived = move.position(now)
        if move.drops_link and (arrived or now - move.t0 >= move.duration_s / 2):
            self._link_lost, self._move = True, None  # and it halts there
        elif arrived:
            self._q, self._move = move.goal.copy(), None
        return self._q

    def _begin(self, goal: np.ndarray, owner: str, duration_s: float | None = None) -> _Move:
        """Every motion starts here (operator, replay, wander): checked against the limits once more. Without
        `duration_s`: as fast as the velocity limits allow."""
        self._check(goal)
        now = self.clock.now()
        start = self._advance(now).copy()
        if duration_s is None:
            duration_s = travel_s(self.profile, start, goal) / self.time_scale
        move = _Move(start, np.asarray(goal, float).copy(), now, duration_s, owner)
        self._move, self._moved_at = move, now
        self._poller.wake()
        return move

    def _end_wander(self) -> None:
        """Lock held: the wander stops, and its move under way halts where it is."""
        if self._wander_stop is not None:
            self._wander_stop.set()
        if self._move is not None and self._move.owner == "wander":
            self._advance(self.clock.now())
            self._move = None

    def _wander(self, stop: threading.Event) -> None:
        rng = np.random.default_rng(self._seed + 2)
        qs, targets = self.visible_configurations(_WANDER_POOL)
        try:
            while len(qs) and not stop.is_set():
                k = int(rng.integers(len(qs)))
                with self._lock:
                    if stop.is_set() or self._link_lost:  # under the lock wander(False) takes: no move after it
                        return
                    try:
                        move = self._begin(qs[k], "wander")
                    except LimitError:
                        return  # the pool is checked already; should it hold a bad one, the wander ends
                self.aim(int(targets[k]))
                pause_s = rng.uniform(*_WANDER_PAUSE_S) / self.time_scale
                if self.clock.wait(stop, move.duration_s) or self.clock.wait(stop, pause_s):
                    return
        finally:
            stop.set()  # ended by itself too: no longer wandering


class SimulatedDriver(Driver):
    """A simulated robot over calib_core's SimulatedRobot.

    Its true parameters are hidden (the profile's simulation truth; `day` > 1 drifts the joint offsets as
    `calib simulate --day` does, so seed 1 day 2 is the robot of the sample session robonaut-a-day2).
    `time_scale` speeds the robot's clock (moves, pauses and settling) for tests and demos. `look()` renders
    what the sensor sees at the true pose and runs the detector seeded by the calibration the robot was given,
    so a better calibration finds the fixture better; a sensor without images (a laser tracker,
    `reads_points`) is read directly: the true position of the target it is pointed at (`set_target`: the
    Motoman's reflector on the right or the left arm), with the profile's `simulation.noise.point`. The other
    sensors (`also_read`) read, in the same look, every target other than the data format's that they see a point
    of (the Motoman's cameras: the marker faces of either arm inside their images).
    """

    transport: SimulatedTransport

    def __init__(
        self,
        profile: Profile,
        *,
        seed: int = 0,
        day: int = 1,
        time_scale: float = 1.0,
        rate_hz: float = 50.0,
        margin_deg: float = DEFAULT_MARGIN_DEG,
        margin_m: float = DEFAULT_MARGIN_M,
        start_rad: np.ndarray | None = None,
        move_slack_s: float = MOVE_SLACK_S,
        clock: Clock = SYSTEM_CLOCK,
    ) -> None:
        if time_scale <= 0 or rate_hz <= 0:
            raise ValueError("time_scale and rate_hz must be positive")
        margin_rad = math.radians(margin_deg)
        robot = SimulatedTransport(profile, seed, day, time_scale, rate_hz, margin_rad, margin_m)
        q0, t0 = (np.asarray(start_rad, float), 0) if start_rad is not None else robot.home()
        robot.place(q0)
        step = np.array([j.resolution for j in profile.joints])
        motion = Motion(
            tolerance=step / 2 + 1e-12,  # the goal's own reading
            still=np.zeros(len(step)),  # any change of a reading is motion
            margin_deg=margin_deg,
            margin_m=margin_m,
            move_slack_s=move_slack_s,
            time_scale=time_scale,
        )
        super().__init__(profile, robot, motion, clock=clock, target=t0)
        robot.aim = self.set_target

    def status(self) -> RobotStatus:
        st = super().status()
        if not self.transport.wandering:
            return st
        message = "wandering: someone else drives the robot" if st.connected else st.message
        return replace(st, wandering=True, message=message)

    def wander(self, on: bool) -> None:
        """Start or stop a scripted wander through random visible configurations, with pauses: the robot
        driven by someone else. Stopping it stops the robot."""
        if self._closed:
            return
        if on:
            self.transport.wander(True)
        elif self.transport.wandering:
            self.stop()

    def inject_fault(self, fault: str | Fault | None, *, after_moves: int = 0) -> None:
        """Make the robot fail as a real one can (faults.py: `hang`, `slow:0.5`, `nan:elbow_pitch`, ...), from its
        move after the next `after_moves` operator moves; None clears it. `drop` loses the link halfway through
        that move (the robot halts and reports itself disconnected until reconnect()); `stall` never arrives, so
        move_to times out."""
        if after_moves < 0:
            raise ValueError("negative after_moves")
        self.transport.faults.arm(parse_fault(fault) if isinstance(fault, str) else fault, after_moves)

    def reconnect(self) -> None:
        """The link is back (after an injected disconnect)."""
        self.transport.reconnect()

    def true_joints_rad(self) -> np.ndarray:
        """The hidden true joint angles (simulation only: for tests and a ground-truth view)."""
        return self.transport.true_joints_rad()

    def true_params(self) -> np.ndarray:
        """The hidden true parameters (simulation only: for tests and a ground-truth view)."""
        return self.transport.sim.true_params.copy()
