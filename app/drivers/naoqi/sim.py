"""The simulated NAO served over libqi (`calib sim-naoqi`): what a real NAO's NAOqi offers the desk.

Its services answer the calls of specs naoqi.md as NAOqi 2.x does: ALMotion (getAngles, getLimits,
setStiffnesses, getStiffnesses, angleInterpolationWithSpeed: every joint arriving together at the fraction of
its maximum speed that the slowest one needs, returning when done or killed; killTasksUsingResources: hold where
it is), ALVideoDevice (subscribeCamera, getImageRemote, unsubscribe: the lower camera's image rendered at the
true pose, exposed only while the robot stands still, its bytes a `str` of one character per byte as libqi's
Python bindings carry them), ALPreferenceManager (setValue, getValue). A NAO starts without stiffness: a joint
without it does not move. Its hidden truth is the profile's simulation (calib_core.sim.SimulatedRobot with
`seed`, drifted for a later `day`), as `calib sim-ros2`'s.

CalibSim is the simulation's own service (no NAOqi's): the moves it was asked for, for the tests to check
against the limits, and the fault harness (app/drivers/faults.py): `fault(text, after_moves)` makes the robot
hang, answer slowly, drop the connection mid-move, stall, read NaN or beyond a limit, send a malformed or a huge
image, or keep its stiffness off, until `fault("", 0)` clears it.
"""

from __future__ import annotations

import math
import threading
import time
from collections.abc import Sequence
from typing import Any

import cv2
import numpy as np

from calib_core import Profile
from calib_core.sim import SimulatedRobot

from ..faults import HUGE_PX, FaultSwitch, parse_fault
from ..sim_view import home, render_in_view
from . import require

SIZES = {0: (160, 120), 1: (320, 240), 2: (640, 480), 3: (1280, 960)}  # ALVideoDevice's resolutions, px
LAYERS = {0: 1, 9: 2, 11: 3, 13: 3}  # colour space -> bytes a pixel


class SimNao:
    """The robot's state, shared by its services (any thread)."""

    def __init__(
        self,
        profile: Profile,
        *,
        seed: int = 1,
        day: int = 1,
        speed: float = 1.0,
        stiffness_off: Sequence[str] = (),
        image_size: tuple[int, int] | None = None,
        lacks: Sequence[str] = (),
    ) -> None:
        self.profile = profile
        self.sim = SimulatedRobot.from_profile(profile, seed=seed).on_day(day)
        self.speed = float(speed)
        self.names = [j.name for j in profile.joints]
        self.lo, self.hi = profile.joint_limits()
        self.max_speed = np.array([j.velocity for j in profile.joints])
        self.image_size = image_size  # served whatever is asked (a camera set up otherwise)
        self.lacks = set(lacks)  # "Service.method" calls it does not offer (an older or a trimmed NAOqi)
        self.refuses = np.isin(self.names, list(stiffness_off))  # joints whose stiffness stays off
        self.lock = threading.Lock()
        self.q = home(profile, self.sim)
        self.move: tuple[float, np.ndarray, np.ndarray, float, threading.Event] | None = None  # t0, from, to, s, done
        self.still_since = time.monotonic()
        self.stiffness = np.zeros(len(self.names))
        self.preferences: dict[tuple[str, str], Any] = {}
        self.commands: list[list[Any]] = []  # [from, to, fraction] per move asked for
        self.rendered: tuple[np.ndarray, np.ndarray] | None = None  # (q, grey)
        self.exposure: tuple[float, np.ndarray] | None = None  # (monotonic s, grey) the latest image
        self.faults = FaultSwitch(self.names)
        self.move_fault: Any = None  # what the fault harness does to the move under way (set as the desk stiffens)
        self.drop: Any = lambda: None  # ends the connection (serve sets it: the session's close)

    def index(self, names: Sequence[str]) -> list[int]:
        unknown = [n for n in names if n not in self.names]
        if unknown:
            raise RuntimeError(f"ALMotion: unknown joint(s) {', '.join(unknown)}")
        return [self.names.index(n) for n in names]

    def position(self, now: float) -> np.ndarray:
        """The true joint angles now (lock held); a move that ended becomes the pose."""
        if self.move is None:
            return self.q.copy()
        t0, start, goal, duration, done = self.move
        s = 1.0 if duration <= 0 else min(1.0, (now - t0) / duration)
        q = start + (goal - start) * s
        if s >= 1.0:
            self.q, self.move, self.still_since = q, None, now
            done.set()
        return q

    def interpolate(self, names: Sequence[str], angles: Sequence[float], fraction: float) -> None:
        """angleInterpolationWithSpeed: until the move is done, killed or superseded."""
        done, duration = self.start_move(names, angles, fraction)
        while not done.wait(duration):
            with self.lock:
                self.position(time.monotonic())
            duration = 0.005

    def start_move(
        self, names: Sequence[str], angles: Sequence[float], fraction: float
    ) -> tuple[threading.Event, float]:
        k = self.index(names)
        if len(angles) != len(k) or not 0 < fraction <= 1:
            raise RuntimeError("ALMotion: one angle a joint and a speed fraction in (0, 1]")
        now = time.monotonic()
        fault, self.move_fault = self.move_fault, None
        with self.lock:
            start = self.position(now)
            goal = start.copy()
            goal[k] = np.clip(np.asarray(angles, float), self.lo[k], self.hi[k])  # ALMotion clamps to its limits
            self.commands.append([start.tolist(), [float(a) for a in angles], float(fraction)])
            goal = np.where(self.stiffness >= 0.5, goal, start)  # a joint without stiffness does not move
            if fault is not None and fault.kind == "stall":
                goal = start  # it never gets there
            duration = float(np.max(np.abs(goal - start) / (fraction * self.max_speed))) / self.speed
            if fault is not None and fault.kind == "drop":  # halfway, it halts and the connection is gone
                goal, duration = (start + goal) / 2, duration / 2
                threading.Timer(duration, self.drop).start()
            if self.move is not None:
                self.move[4].set()
            done = threading.Event()
            self.move = (now, start, goal, duration, done)
            return done, duration

    def kill(self) -> None:
        now = time.monotonic()
        with self.lock:
            q = self.position(now)
            if self.move is not None:
                self.move[4].set()
            self.q, self.move, self.still_since = q, None, now

    def image(self, space: int, fps: int) -> list[Any] | None:
        """getImageRemote's answer: the latest exposure, a new one rendered when the robot has stood still since
        its time (a moving robot's images are blurred, and the desk takes none); None before the first."""
        now = time.monotonic()
        exposed = math.floor(now * fps) / fps
        with self.lock:
            q = self.position(now)
            fresh = self.move is None and exposed >= self.still_since
            latest = self.exposure
        if fresh and (latest is None or latest[0] < exposed):
            rendered = self.rendered
            if rendered is None or not np.array_equal(rendered[0], q):
                rendered = (q, render_in_view(self.profile, self.sim, q)[0])
                self.rendered = rendered
            grey = rendered[1]
            if self.image_size is not None:
                grey = cv2.resize(grey, self.image_size, interpolation=cv2.INTER_AREA)
            with self.lock:
                self.exposure = latest = (exposed, grey)
        if latest is None:
            return None
        grey = latest[1]
        fault = self.faults.now("malformed_image", "huge_image")
        if fault is not None and fault.kind == "huge_image":
            grey = np.zeros(HUGE_PX[::-1], np.uint8)
        data = _encoded(grey, space)
        if fault is not None and fault.kind == "malformed_image":
            data = data[: len(data) // 3]  # fewer bytes than its size says
        stamp = time.time() - (now - latest[0])  # the robot's clock: seconds since the epoch
        seconds = math.floor(stamp)
        return [grey.shape[1], grey.shape[0], LAYERS[space], space, seconds, round((stamp - seconds) * 1e6), data]


def _encoded(grey: np.ndarray, space: int) -> str:
    """The image in a NAOqi colour space, as a str of one character per byte."""
    if space == 0:
        pixels = grey
    elif space == 9:  # Y U Y V: the luma every other byte, no colour
        pixels = np.dstack([grey, np.full_like(grey, 128)])
    else:
        pixels = np.dstack([grey] * 3)
    return np.ascontiguousarray(pixels).tobytes().decode("latin-1")


def services(nao: SimNao) -> dict[str, Any]:
    """The robot's services by name, ready to register on a libqi session."""
    qi = require()

    answer = nao.faults.answer  # every call: hang or slow when told

    @qi.multiThreaded()
    class ALMotion:
        def getAngles(self, names: list[str], useSensors: bool) -> list[float]:
            answer()
            k = nao.index(names)
            with nao.lock:
                q = nao.position(time.monotonic())
            return [float(v) for v in nao.faults.reading(nao.sim.readings(q))[k]]

        def getLimits(self, name: str) -> list[list[float]]:
            (k,) = nao.index([name])
            return [[float(nao.lo[k]), float(nao.hi[k]), float(nao.max_speed[k]), 1.0]]

        def setStiffnesses(self, names: Any, stiffnesses: Any) -> None:
            answer()
            names = [names] if isinstance(names, str) else names
            k = nao.index(names)
            nao.move_fault = nao.faults.moved()  # a move begins: the desk stiffens the joints first
            refuses = nao.refuses[k] | (nao.faults.now("refuse") is not None)
            with nao.lock:
                nao.stiffness[k] = np.where(refuses, 0.0, np.broadcast_to(stiffnesses, len(k)))

        def getStiffnesses(self, names: list[str]) -> list[float]:
            answer()
            k = nao.index(names)
            with nao.lock:
                return [float(v) for v in nao.stiffness[k]]

        def angleInterpolationWithSpeed(self, names: list[str], angles: list[float], fraction: float) -> None:
            answer()
            nao.interpolate(names, angles, fraction)

        def killTasksUsingResources(self, names: list[str]) -> None:
            answer()
            nao.index(names)
            nao.kill()

    @qi.multiThreaded()
    class ALVideoDevice:
        def __init__(self) -> None:
            self._handles: dict[str, tuple[int, int]] = {}
            self._lock = threading.Lock()

        def subscribeCamera(self, name: str, camera: int, resolution: int, space: int, fps: int) -> str:
            if camera != 1 or resolution not in SIZES or space not in LAYERS or not 1 <= fps <= 30:
                raise RuntimeError(
                    "ALVideoDevice: the simulated NAO has the lower camera (1) in kYuv, kYUV422, kRGB, kBGR"
                )
            with self._lock:
                handle = f"{name}_{len(self._handles)}"
                self._handles[handle] = (space, fps)
            return handle

        def getImageRemote(self, handle: str) -> list[Any] | None:
            answer()
            with self._lock:
                space, fps = self._handles[handle]
            return nao.image(space, fps)

        def unsubscribe(self, handle: str) -> bool:
            with self._lock:
                return self._handles.pop(handle, None) is not None

    @qi.multiThreaded()
    class ALPreferenceManager:
        def setValue(self, domain: str, setting: str, value: Any) -> None:
            with nao.lock:
                nao.preferences[(domain, setting)] = value

        def getValue(self, domain: str, setting: str) -> Any:
            with nao.lock:
                return nao.preferences.get((domain, setting))

    @qi.multiThreaded()
    class CalibSim:
        def commands(self) -> list[list[Any]]:
            with nao.lock:
                return list(nao.commands)

        def fault(self, text: str, after_moves: int) -> None:
            """The fault harness: `text` as faults.py writes it ("" clears it), after `after_moves` moves."""
            nao.faults.arm(parse_fault(text) if text else None, after_moves)

    offered = {}
    for cls in (ALMotion, ALVideoDevice, ALPreferenceManager, CalibSim):
        lacking = {call.partition(".")[2] for call in nao.lacks if call.startswith(f"{cls.__name__}.")}
        if lacking:  # the same service without those methods
            kept = {k: v for k, v in vars(cls).items() if k == "__init__" or not k.startswith("__")}
            cls = qi.multiThreaded()(type(cls.__name__, (), {k: v for k, v in kept.items() if k not in lacking}))
        offered[cls.__name__] = cls()
    return offered


def serve(nao: SimNao, url: str) -> Any:
    """A libqi session listening at `url` with its own service directory and the robot's services; close() it
    to end. RuntimeError when it cannot listen there."""
    qi = require()
    session = qi.Session()
    session.listenStandalone(url)
    for name, service in services(nao).items():
        session.registerService(name, service)
    nao.drop = session.close
    return session
