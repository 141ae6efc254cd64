"""The simulated robot behind the RobotDriver interface (driver kind `simulated`).

Options (desk configuration file, `driver: {kind: simulated, ...}`): `seed` (the robot's hidden truth and
noise, default 1) and `day` (1: as the profile's truth; later days drift the joint offsets as
`calib simulate --day` does). The desk's `--sim-speed` is its time scale.
"""

from __future__ import annotations

import math
import threading
import time
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from calib_core.errors import InputError
from calib_core.model.profile import Profile, Sensor
from calib_core.sim.simulator import SimulatedRobot
from calib_core.vision.sampling import Sampler
from calib_core.vision.visibility import Visibility

from . import DEFAULT_MARGIN_DEG, DEFAULT_MARGIN_M, LimitError, Look, RobotFault, RobotStatus, check_limits
from .registry import DriverContext

MOVE_SLACK_S = 5.0  # real seconds a move may overrun its planned duration before the robot counts as not responding
_WAIT_POLL_S = 0.01  # how often a waiting move_to asks its caller whether to stop
_WANDER_POOL = 24  # visible configurations the wander picks from
_WANDER_PAUSE_S = (0.5, 2.0)  # robot time between wander moves
OPTIONS = {"seed": 1, "day": 1}  # and their defaults


def can_simulate(profile: Profile) -> bool:
    """Whether the simulator can stand in for the robot: the profile has a simulation section and its data
    sensor is one the simulator renders (a stereo head or a camera; calib_core.simulator's capture) or reads
    directly (a point sensor without images, like the Motoman's laser tracker; reads_points)."""
    sensor = profile.sensors[profile.data.sensor]
    return bool(profile.simulation) and (sensor.reading in ("stereo", "image") or reads_points(sensor))


def check(profile: Profile, options: Mapping[str, Any], where: str) -> dict[str, Any]:
    """The options with their defaults; InputError (`where`: the field) for a profile the simulator cannot
    stand in for, an unknown option or a value out of range."""
    if not can_simulate(profile):
        raise InputError(
            f"{where}: {profile.name} cannot be simulated (its profile has no simulation section for its sensor)"
        )
    unknown = sorted(set(options) - set(OPTIONS))
    if unknown:
        raise InputError(f"{where}.{unknown[0]}: no such option of the simulated driver (options: seed, day)")
    out = {**OPTIONS, **options}
    for key, lowest in (("seed", 0), ("day", 1)):
        value = out[key]
        if isinstance(value, bool) or not isinstance(value, int) or not lowest <= value <= 2**31:
            raise InputError(f"{where}.{key}: expected a whole number from {lowest}, got {value!r}")
    return out


def create(profile: Profile, options: Mapping[str, Any], context: DriverContext) -> SimulatedDriver:
    """A simulated robot from checked options (check)."""
    return SimulatedDriver(profile, seed=options["seed"], day=options["day"], time_scale=context.time_scale)


def reads_points(sensor: Sensor) -> bool:
    """A sensor that reports 3-D points with no image to detect them in (a laser tracker): the simulated robot
    reads it directly, with its noise, instead of rendering and detecting."""
    return sensor.reading == "direct" and sensor.dim == 3


def also_read(profile: Profile) -> list[int]:
    """The sensors besides the data format's that each look reads too, directly from the truth with the profile's
    noise (`SimulatedRobot.read`): those that report points or take images (the Motoman's two cameras, which have
    no image size to render). A plane measures only what touches it: it is never read here."""
    return [
        s
        for s, sensor in enumerate(profile.sensors)
        if s != profile.data.sensor and (reads_points(sensor) or sensor.reading != "direct")
    ]


def readable_targets(profile: Profile) -> list[int]:
    """The targets a point-reading sensor can be pointed at: those its data format names (the Motoman's
    reflector on either arm, its `reflector_arm` column), else every single-point target."""
    named = sorted(set(profile.data.target_values.values()))
    return named or [t for t, target in enumerate(profile.targets) if target.grid is None and target.points is None]


@dataclass
class _Move:
    start: np.ndarray
    goal: np.ndarray
    t0: float  # time.monotonic()
    duration_s: float  # real seconds (robot time / time_scale)
    owner: str  # "operator" or "wander"
    done: threading.Event = field(default_factory=threading.Event)
    arrived: bool = False
    stalled: bool = False  # an injected fault: the robot never gets there
    drops_link: bool = False  # an injected fault: the link is lost halfway

    def position(self, now: float) -> tuple[np.ndarray, bool]:
        if self.stalled:
            return self.start.copy(), False
        s = 1.0 if self.duration_s <= 0 else min(1.0, (now - self.t0) / self.duration_s)
        return self.start + (self.goal - self.start) * s, s >= 1.0


class SimulatedDriver:
    """A simulated robot over calib_core's SimulatedRobot.

    Its true parameters are hidden (the profile's simulation truth; `day` > 1 drifts the joint offsets as
    `calib simulate --day` does, so seed 1 day 2 is the robot of the sample session robonaut-a-day2). A motion
    thread moves the true joint angles at rate_hz; `time_scale` speeds the robot's clock (moves, pauses and
    settling) for tests and demos. `look()` renders what the data format's sensor sees at the true pose and
    runs the detector seeded by the calibration the robot was given, so a better calibration finds the fixture
    better; a sensor without images (a laser tracker, `reads_points`) is read directly: the true position of the
    target it is pointed at (`set_target`: the Motoman's reflector on the right or the left arm), with the
    profile's `simulation.noise.point`. The other sensors (`also_read`) read, in the same look, every target
    other than the data format's that they see a point of (the Motoman's cameras: both arms' marker faces).
    """

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
    ) -> None:
        if time_scale <= 0 or rate_hz <= 0 or margin_deg < 0 or margin_m < 0:
            raise ValueError("time_scale and rate_hz must be positive and margin_deg, margin_m not negative")
        self.profile = profile
        self.time_scale = float(time_scale)
        self.rate_hz = float(rate_hz)
        self.margin_rad = math.radians(margin_deg)
        self.margin_m = float(margin_m)
        self.move_slack_s = float(move_slack_s)
        robot = SimulatedRobot.from_profile(profile, seed=seed).on_day(day)
        self._sim = robot  # renders and detects, or reads a tracker (its rng is guarded by _render_lock)
        self._reads = reads_points(profile.sensors[profile.data.sensor])
        self._also = also_read(profile)
        data_targets = set(profile.data.target_values.values()) | {profile.data.target}
        self._other_targets = np.array([t for t in range(len(profile.targets)) if t not in data_targets], int)
        self._planner = Sampler(Visibility(profile, robot.true_params), np.random.default_rng(seed + 1))
        self._seed = seed
        self._velocity = np.array([j.velocity for j in profile.joints])
        self._lock = threading.Lock()
        self._render_lock = threading.Lock()
        self._planner_lock = threading.Lock()
        q0, t0 = (np.asarray(start_rad, float), 0) if start_rad is not None else self._home()
        self.check(q0)
        self._q = q0.copy()  # true joint angles (unquantised readings)
        self._stamp = time.monotonic()
        self._still_since = self._stamp
        self._target = t0
        self._move: _Move | None = None
        self._cal_id: str | None = None
        self._believed = profile.nominal()
        self._stopped = False
        self._link_lost = False
        self._operator_moves = 0
        self._fault: tuple[str, int] | None = None  # (kind, the operator move it strikes)
        self._wander_stop: threading.Event | None = None
        self._wander_thread: threading.Thread | None = None
        self._closed = threading.Event()
        self._thread = threading.Thread(target=self._run, name=f"motion-{profile.name}", daemon=True)
        self._thread.start()

    # --- lifecycle ----------------------------------------------------------------------------------
    def close(self) -> None:
        """Stop motion and the threads; the driver then reports itself disconnected."""
        self.stop()
        self._closed.set()
        self._thread.join()
        wander = self._wander_thread
        if wander is not None:
            wander.join()

    def __enter__(self) -> SimulatedDriver:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    # --- state --------------------------------------------------------------------------------------
    def status(self) -> RobotStatus:
        with self._lock:
            q, stamp, moving = self._q.copy(), self._stamp, self._move is not None
            wandering = self._wander_stop is not None and not self._wander_stop.is_set()
            closed = self._closed.is_set()
            if closed:
                message = "disconnected"
            elif self._link_lost:
                message = "disconnected: the link to the robot was lost"
            elif wandering:
                message = "wandering: someone else drives the robot"
            elif moving:
                message = "moving"
            elif self._stopped:
                message = "stopped"
            else:
                message = "idle"
            return RobotStatus(
                robot=self.profile.name,
                connected=not (closed or self._link_lost),
                moving=moving,
                joints_rad=self._sim.readings(q),
                target=self._target,
                calibration_id=self._cal_id,
                message=message,
                stamp=stamp,
                wandering=wandering,
            )

    def read_joints(self) -> np.ndarray:
        with self._lock:
            self._check_link()
            return self._sim.readings(self._q)

    def settled(self, for_s: float = 0.3) -> bool:
        """Not moving for at least for_s of robot time (real time for_s / time_scale)."""
        with self._lock:
            still = self._move is None
            return still and (time.monotonic() - self._still_since) * self.time_scale >= for_s

    def true_joints_rad(self) -> np.ndarray:
        """The hidden true joint angles (simulation only: for tests and a ground-truth view)."""
        with self._lock:
            return self._q.copy()

    def true_params(self) -> np.ndarray:
        """The hidden true parameters (simulation only: for tests and a ground-truth view)."""
        return self._sim.true_params.copy()

    # --- seeing -------------------------------------------------------------------------------------
    def look(self, believed: np.ndarray | None = None) -> Look:
        with self._lock:
            self._check_link()
            q, target = self._q.copy(), self._target
            p = (self._believed if believed is None else np.asarray(believed, float)).copy()
        with self._render_lock:
            if self._reads:
                first, images = self._sim.read(q, target, self.profile.data.sensor), {}
            else:
                cap = self._sim.capture(0, q, target, p)
                first, images = cap.sighting, cap.images
            others = [self._sim.read(q, t, s) for s in self._also for t in self._seen_by(q, s)]
        return Look(self._sim.readings(q), target, [first, *others], images)

    def _seen_by(self, q: np.ndarray, sensor: int) -> list[int]:
        """The targets besides the data format's of which `sensor` sees a point at true joint angles q."""
        targets = self._other_targets
        if not len(targets):
            return []
        seen = Visibility(self.profile, self._sim.true_params).points(
            np.repeat(q[None], len(targets), 0), targets, sensor
        )
        return [int(t) for t in targets[seen.any(axis=1)]]

    def apply_calibration(self, cal_id: str | None, params: np.ndarray | None) -> None:
        p = self.profile.nominal() if params is None else np.asarray(params, float).copy()
        if p.shape != (len(self.profile.parameters),):
            raise ValueError(f"expected {len(self.profile.parameters)} parameters for {self.profile.name}")
        with self._lock:
            self._cal_id = cal_id
            self._believed = p

    def believed_params(self) -> np.ndarray:
        with self._lock:
            return self._believed.copy()

    def set_target(self, target: int) -> None:
        if not 0 <= target < len(self.profile.targets):
            raise ValueError(f"{self.profile.name} has targets 0..{len(self.profile.targets) - 1}, not {target}")
        if self._reads and target not in readable_targets(self.profile):
            names = ", ".join(self.profile.targets[t].name for t in readable_targets(self.profile))
            sensor = self.profile.sensors[self.profile.data.sensor].name
            raise InputError(f"the {sensor} reads {names}, not {self.profile.targets[target].name}")
        with self._lock:
            self._target = int(target)

    # --- moving -------------------------------------------------------------------------------------
    def check(self, q_rad: np.ndarray) -> None:
        check_limits(self.profile, q_rad, self.margin_rad, self.margin_m)

    def move_to(self, q_rad: np.ndarray, *, wait: bool = True, should_stop: Callable[[], bool] | None = None) -> bool:
        """The operator's (or a replay's) move: it ends a wander."""
        q = np.asarray(q_rad, dtype=float)
        self.check(q)
        self.wander(False)
        move = self._begin(q, "operator")
        if not wait:
            return True
        limit_s = move.duration_s + self.move_slack_s
        while not move.done.wait(_WAIT_POLL_S):
            if should_stop is not None and should_stop():
                self.stop()
            elif time.monotonic() - move.t0 > limit_s:
                self.stop()
                raise RobotFault(
                    f"{self.profile.name} did not arrive within {limit_s:.1f} s (not responding); the robot was stopped"
                )
        with self._lock:
            self._check_link()
        return move.arrived

    def jog(self, joint_name: str, value_deg: float) -> None:
        """Move one joint to value_deg, the others held where they are headed; does not wait."""
        with self._lock:
            q = (self._move.goal if self._move is not None else self._q).copy()
        q[self.profile.joint(joint_name)] = math.radians(value_deg)
        self.move_to(q, wait=False)

    def stop(self) -> None:
        with self._lock:
            if self._wander_stop is not None:
                self._wander_stop.set()
            self._halt(time.monotonic())
            self._stopped = True

    def wander(self, on: bool) -> None:
        """Start or stop a scripted wander through random visible configurations, with pauses: the robot
        driven by someone else. Stopping it halts the wander's current move."""
        with self._lock:
            running = self._wander_stop is not None and not self._wander_stop.is_set()
            if on == running or self._closed.is_set():
                return
            if not on:
                assert self._wander_stop is not None
                self._wander_stop.set()
                if self._move is not None and self._move.owner == "wander":
                    self._halt(time.monotonic())
                return
            self._check_link()
            stop = threading.Event()
            self._wander_stop = stop
            self._stopped = False
            self._wander_thread = threading.Thread(
                target=self._wander, args=(stop,), name=f"wander-{self.profile.name}", daemon=True
            )
            self._wander_thread.start()

    # --- faults (simulation only: for tests and demos) ----------------------------------------------
    def inject_fault(self, kind: str, *, after_moves: int = 0) -> None:
        """Make a later move fail as a real robot's can. The move after the next `after_moves` operator moves:
        "disconnect" loses the link halfway (the robot halts and reports itself disconnected until
        reconnect()); "stall" never arrives (a jammed joint, a lost command), so move_to times out."""
        if kind not in ("disconnect", "stall") or after_moves < 0:
            raise ValueError(f"unknown fault '{kind}' or negative after_moves")
        with self._lock:
            self._fault = (kind, self._operator_moves + after_moves + 1)

    def reconnect(self) -> None:
        """The link is back (after an injected disconnect)."""
        with self._lock:
            self._link_lost = False

    def _check_link(self) -> None:
        """Raise RobotFault when the link is lost (lock held)."""
        if self._link_lost:
            raise RobotFault(f"{self.profile.name} disconnected (the link to the robot was lost)")

    # --- internals ----------------------------------------------------------------------------------
    def _home(self) -> tuple[np.ndarray, int]:
        """A starting pose with the target in view."""
        qs, targets = self._visible_configurations(8)
        if len(qs):
            return qs[0], int(targets[0])
        lo, hi = self.profile.joint_limits()
        return (lo + hi) / 2, 0

    def _visible_configurations(self, n: int) -> tuple[np.ndarray, np.ndarray]:
        """Configurations whose target the true robot sees, within the limits less the margin."""
        with self._planner_lock:
            qs, targets = self._planner.configurations(n)
        ok = []
        for q in qs:
            try:
                self.check(q)
            except LimitError:
                ok.append(False)
            else:
                ok.append(True)
        return qs[ok], targets[ok]

    def _begin(self, goal: np.ndarray, owner: str) -> _Move:
        with self._lock:
            return self._begin_locked(goal, owner)

    def _begin_locked(self, goal: np.ndarray, owner: str) -> _Move:
        """Every motion starts here (operator, replay, wander): checked against the limits once more."""
        if self._closed.is_set():
            raise RuntimeError(f"the {self.profile.name} driver is closed")
        self._check_link()
        self.check(goal)
        now = time.monotonic()
        self._halt(now)
        delta = np.abs(goal - self._q)
        if np.any((delta > 0) & (self._velocity <= 0)):
            raise ValueError("a joint to move has no velocity limit above 0")
        robot_s = float(np.max(np.where(delta > 0, delta / np.where(self._velocity > 0, self._velocity, 1), 0)))
        move = _Move(self._q.copy(), goal.copy(), now, robot_s / self.time_scale, owner)
        if owner == "operator":
            self._operator_moves += 1
            if self._fault is not None and self._fault[1] == self._operator_moves:
                move.stalled, move.drops_link = self._fault[0] == "stall", self._fault[0] == "disconnect"
                self._fault = None
        self._move = move
        self._stopped = False
        return move

    def _halt(self, now: float) -> None:
        """End the current move where it is now (lock held)."""
        move = self._move
        if move is None:
            return
        self._q, _ = move.position(now)
        self._stamp = now
        self._still_since = now
        self._move = None
        move.done.set()

    def _run(self) -> None:
        period = 1.0 / self.rate_hz
        while not self._closed.wait(period):
            with self._lock:
                move = self._move
                if move is None:
                    continue
                now = time.monotonic()
                self._q, arrived = move.position(now)
                self._stamp = now
                if move.drops_link and (arrived or now - move.t0 >= move.duration_s / 2):
                    self._link_lost = True
                    self._halt(now)
                elif arrived:
                    self._q = move.goal.copy()
                    self._move = None
                    self._still_since = now
                    move.arrived = True
                    move.done.set()

    def _wander(self, stop: threading.Event) -> None:
        rng = np.random.default_rng(self._seed + 2)
        qs, targets = self._visible_configurations(_WANDER_POOL)
        while len(qs) and not stop.is_set():
            k = int(rng.integers(len(qs)))
            with self._lock:
                # Checked under the lock that wander(False) takes: no wander move starts after it.
                if stop.is_set() or self._closed.is_set() or self._link_lost:
                    break
                try:
                    move = self._begin_locked(qs[k], "wander")
                except LimitError:
                    break  # the pool is checked already; should it hold a bad one, the wander ends
                self._target = int(targets[k])
            while not move.done.wait(_WAIT_POLL_S) and not stop.is_set():
                pass
            if not move.arrived:
                break
            stop.wait(rng.uniform(*_WANDER_PAUSE_S) / self.time_scale)
