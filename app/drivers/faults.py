"""The fault harness: what a simulated robot can be told to do wrong, the same words for every kind.

The desk's simulated robot (simulated.py, `SimulatedDriver.inject_fault`), the simulated NAO served over libqi
(naoqi/sim.py, its CalibSim service's `fault`, `calib sim-naoqi --fault`) and the simulated ROS 2 robot node
(ros2/sim_node.py, its `fault` parameter, `calib sim-ros2 --fault`) each hold a FaultSwitch and apply it where
a real robot would fail: its joint readings, its answers, its moves and its images. A fault is armed now, or
after the robot's next `after_moves` moves (so that a replay captures frames before it strikes), and stays until
it is cleared (`drop` and `stall` strike one move: the next, or the one after those `after_moves`). Written as
text: `kind[:joint][:value]`, or `slow:SECONDS`.
"""

from __future__ import annotations

import math
import threading
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from calib_core import InputError

KINDS = {
    "hang": "every call to the robot blocks until the fault is cleared (a stuck NAOqi, packets dropped)",
    "slow": "every call answers only after SECONDS",
    "drop": "the connection is lost halfway through the next move",
    "stall": "the next move never arrives (a jammed joint, a lost command)",
    "nan": "JOINT reads NaN",
    "beyond": "JOINT reads VALUE rad (default 3.0: beyond the limits of any NAO joint)",
    "malformed_image": "the camera's image does not fit its own size",
    "huge_image": "the camera sends a 6000 x 5000 px image (30 MP)",
    "refuse": "the robot refuses to move (a NAO's stiffness stays off, a controller rejects the trajectory)",
}
HUGE_PX = (6000, 5000)  # width, height: beyond the 25 MP a desk's detector takes
BEYOND_RAD = 3.0


@dataclass(frozen=True)
class Fault:
    kind: str
    joint: str | None = None  # nan, beyond: the joint whose reading goes wrong (None: the first)
    value: float = BEYOND_RAD  # beyond: the reading, rad
    delay_s: float = 0.0  # slow: how long each call takes


def parse_fault(text: str, where: str = "fault") -> Fault:
    """`hang`, `slow:0.5`, `nan:LHipYawPitch`, `beyond:LHipYawPitch:3.0`, ...; InputError naming `where`."""
    kind, *rest = text.strip().split(":")
    if kind not in KINDS:
        raise InputError(f"{where}: unknown fault '{kind}' (known: {', '.join(KINDS)})")
    try:
        if kind == "slow":
            (seconds,) = rest
            fault = Fault(kind, delay_s=float(seconds))
            if not 0 < fault.delay_s < 3600:
                raise ValueError
            return fault
        if kind in ("nan", "beyond"):
            joint = rest[0] if rest and rest[0] else None
            value = float(rest[1]) if len(rest) > 1 else BEYOND_RAD
            if len(rest) > 2 or not math.isfinite(value):
                raise ValueError
            return Fault(kind, joint, value)
    except ValueError:
        raise InputError(f"{where}: expected {kind}{':SECONDS' if kind == 'slow' else '[:JOINT][:VALUE]'}") from None
    if rest:
        raise InputError(f"{where}: the fault '{kind}' takes no value")
    return Fault(kind)


class FaultSwitch:
    """The fault a simulated robot has now (any thread): armed at once or after some moves, until cleared."""

    def __init__(self, names: list[str]) -> None:
        self.names = names
        self._lock = threading.Lock()
        self._fault: Fault | None = None
        self._moves_left = 0  # moves to let through before the armed fault strikes
        self._active = False  # it strikes now
        self._cleared = threading.Event()
        self._cleared.set()

    def arm(self, fault: Fault | None, after_moves: int = 0, where: str = "fault") -> None:
        """Have `fault` strike now (`after_moves` 0), or from the move after the robot's next `after_moves` moves
        (None: clear it); InputError naming `where` for a joint the robot does not have."""
        if fault is not None and fault.joint is not None and fault.joint not in self.names:
            raise InputError(f"{where}: no joint {fault.joint} (joints: {', '.join(self.names)})")
        if after_moves < 0:
            raise InputError(f"{where}: the moves before it must not be negative")
        with self._lock:
            self._fault, self._moves_left, self._active = fault, after_moves, after_moves == 0
            if fault is None:
                self._cleared.set()
            else:
                self._cleared.clear()

    def now(self, *kinds: str) -> Fault | None:
        """The fault striking now, if it is one of `kinds` (none given: any)."""
        with self._lock:
            fault = self._fault if self._active else None
        return fault if fault is not None and (not kinds or fault.kind in kinds) else None

    def moved(self) -> Fault | None:
        """A move begins: the fault it strikes, if one of a move (drop, stall, refuse) strikes now; drop and stall
        strike that move only."""
        with self._lock:
            if self._fault is None:
                return None
            if not self._active and self._moves_left > 0:
                self._moves_left -= 1
                return None
            self._active = True
            fault = self._fault
            if fault.kind in ("drop", "stall"):
                self._fault = None
                self._cleared.set()
        return fault if fault.kind in ("drop", "stall", "refuse") else None

    def answer(self, wait: Callable[[threading.Event, float], bool] | None = None) -> None:
        """Where a call to the robot is answered: blocks while `hang` lasts (on no clock: a robot that hangs waits
        for nobody's time), waits `delay_s` for `slow` (`wait`: the robot's clock's event wait, default real time)."""
        fault = self.now("hang", "slow")
        if fault is None:
            return
        if fault.kind == "hang":
            self._cleared.wait()
        else:
            (wait or (lambda event, s: event.wait(s)))(threading.Event(), fault.delay_s)

    def image(self, grey: np.ndarray) -> np.ndarray:
        """The camera's grey image as the fault makes it: one that does not fit its own size (a flat run of
        float64s), or a 30 MP one."""
        fault = self.now("malformed_image", "huge_image")
        if fault is None:
            return grey
        if fault.kind == "huge_image":
            return np.zeros(HUGE_PX[::-1], np.uint8)
        return np.zeros(grey.size // 2, float)

    def reading(self, q: np.ndarray) -> np.ndarray:
        """The joint readings as the fault makes them (nan, beyond)."""
        fault = self.now("nan", "beyond")
        if fault is None:
            return q
        q = np.array(q, float)
        k = self.names.index(fault.joint) if fault.joint is not None else 0
        q[k] = math.nan if fault.kind == "nan" else fault.value
        return q
