"""Robot drivers: the one interface the desk drives a robot through.

Joint values are rad in the profile's joint order (a prismatic joint's in the profile's length unit). Limits
are checked with a safety margin before anything moves (a configuration closer to a limit than the margin is
refused, naming the joint and the limit in deg, or in the length unit), and every move runs each joint at most
at its velocity limit, all joints arriving together.

Every driver is the one core (core.py: limits, velocity limits, state from the stream of joint readings, moves
that arrive or time out, settling, stop, the detectors) over a small transport per kind of robot. A kind is a
module of this package registered by name in registry.py (`simulated`: the robot simulated by calib_core,
simulated.py; `ros2`: a robot on its own ROS 2 graph, ros2/driver.py; `naoqi`: a NAO over libqi, naoqi/driver.py);
docs/drivers.md shows what a new one holds. ros2/ and naoqi/ hold the rest of their extras too (a connection file,
the simulated robot served from another process, which sim_view.py renders for), and connection_file.py what both
connection files share. The desk makes one driver per robot that has one, from its configuration, and closes it
when the desk stops or the robot is removed.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import Protocol, runtime_checkable

import numpy as np

from calib_core import Calibration
from calib_core.errors import InputError
from calib_core.model import Profile
from calib_core.units import length_factor
from calib_core.vision import Sighting

from .calls import Halt
from .calls import RobotFault as RobotFault  # the drivers raise it; callers take it from here

DEFAULT_MARGIN_DEG = 1.0  # a revolute joint's safety margin
DEFAULT_MARGIN_M = 0.001  # a prismatic joint's


class LimitError(InputError):
    """A configuration beyond a joint limit (less the safety margin). `value`, `limit` and `margin` are in
    `unit`: deg for a revolute joint, the profile's length unit for a prismatic one. `beyond`: past the limit
    itself, not only inside the margin."""

    def __init__(self, joint: str, value: float, limit: float, side: str, margin: float, unit: str = "deg") -> None:
        self.joint = joint
        self.value = value
        self.limit = limit
        self.side = side  # "lower" or "upper"
        self.margin = margin
        self.unit = unit
        self.beyond = not (value >= limit if side == "lower" else value <= limit)
        v, lim, m = (_shown(x, unit) for x in (value, limit, margin))
        if math.isnan(value):
            message = f"{joint} is not a number"
        elif self.beyond:
            message = f"{joint} {v} {unit} is beyond its {side} limit {lim} {unit} (margin {m} {unit})"
        else:
            message = f"{joint} {v} {unit} is within the {m} {unit} safety margin of its {side} limit {lim} {unit}"
        super().__init__(message)


def _shown(value: float, unit: str) -> str:
    return f"{value:.1f}" if unit == "deg" else f"{value:.4g}"


def check_limits(profile: Profile, q: np.ndarray, margin_rad: float, margin_m: float = DEFAULT_MARGIN_M) -> None:
    """Raise LimitError for the first joint of q (rad; a prismatic joint's in the length unit) beyond its limits
    less the margin: `margin_rad` for a revolute joint, `margin_m` for a prismatic one. A joint whose range is
    narrower than twice its margin (a joint fixed at one value) must sit inside its range."""
    q = np.asarray(q, dtype=float)
    if q.shape != (len(profile.joints),):
        raise ValueError(f"expected {len(profile.joints)} joint values for {profile.name}, got shape {q.shape}")
    margins = profile.joint_margins(math.degrees(margin_rad), margin_m)
    for k, (joint, value) in enumerate(zip(profile.joints, q, strict=True)):
        m = float(margins[k])
        for side, limit, out in (
            ("lower", joint.lower, math.isnan(value) or value < joint.lower + m - 1e-12),
            ("upper", joint.upper, value > joint.upper - m + 1e-12),
        ):
            if out:
                shown = [profile.joint_to_display(k, x) for x in (value, limit)]
                margin = margin_m * length_factor("m", profile.length_unit) if joint.prismatic else margin_rad
                unit = profile.joint_display_unit(k)
                raise LimitError(joint.name, *shown, side, profile.joint_to_display(k, margin), unit)


@dataclass
class RobotStatus:
    robot: str
    connected: bool
    moving: bool
    joints_rad: np.ndarray  # the encoder readings (quantised)
    target: int
    calibration_id: str | None
    message: str
    stamp: float = 0.0  # time.monotonic() of the joint state
    wandering: bool = False


@dataclass
class Look:
    """What one look at the robot gave: its joint readings, the target it is pointed at (`set_target`), each
    sensor's sighting of the same moment (the data format's sensor first; a sensor that sees several targets,
    as the Motoman's cameras both arms' markers, gives one per target) and the images they came from (by role)."""

    readings_rad: np.ndarray
    target: int
    sightings: list[Sighting]
    images: dict[str, np.ndarray]

    @property
    def measured(self) -> bool:
        """Whether any sensor measured something."""
        return any(s.measured is not None for s in self.sightings)


class RobotDriver(Protocol):
    profile: Profile
    margin_rad: float  # the safety margin: no move is commanded closer than this to a revolute joint's limit
    margin_m: float  # and to a prismatic joint's

    def status(self) -> RobotStatus: ...

    def read_joints(self) -> np.ndarray:
        """Rad: what the encoders report (quantised)."""
        ...

    def look(self, believed: np.ndarray | None = None) -> Look:
        """The images now and every sensor's Sighting, the detectors seeded by the active calibration (or
        `believed`); a sensor without images (a tracker) gives its reading and no images."""
        ...

    def check(self, q_rad: np.ndarray) -> None:
        """Raise LimitError if q is beyond the joint limits less the safety margin."""
        ...

    def move_to(self, q_rad: np.ndarray, *, wait: bool = True, should_stop: Callable[[], bool] | None = None) -> bool:
        """Check, then move (velocity limits, linear interpolation, all joints arriving together). True on
        arrival, False if stopped; without `wait` True once the move has started."""
        ...

    def stop(self, wait_s: float = ...) -> Halt:
        """Halt motion at once (from any thread), never waiting on the robot longer than `wait_s`: the Halt says
        whether it took the stop by then (core.Driver.stop)."""
        ...

    def settled(self, for_s: float | None = None) -> bool:
        """Not moving for at least for_s (None: the robot's own settle window, its connection's `settle_s`)."""
        ...

    def wait_settled(
        self, for_s: float | None, timeout_s: float, should_stop: Callable[[], bool] | None = None
    ) -> bool:
        """Until settled(for_s): True; False when should_stop() says so; RobotFault when disconnected or not
        settled within timeout_s."""
        ...

    def apply_calibration(self, cal_id: str | None, params: np.ndarray | None) -> None: ...

    def believed_params(self) -> np.ndarray:
        """The parameters the robot works with: the active calibration's, or the nominal model."""
        ...

    def deploy(self, cal_id: str, cal: Calibration) -> str | None:
        """Put the calibration on the robot itself (a ROS 2 robot's parameter): what was done, a sentence; None
        for a robot that takes nothing. RobotFault when the robot refuses or does not answer."""
        ...

    def set_target(self, target: int) -> None:
        """Which fixture or board is in view (NAO: the left or the right foot's board)."""
        ...

    def close(self) -> None:
        """Stop, then let go of the robot (threads, connections); called when the desk stops or the robot is
        removed. The driver then reports itself disconnected."""
        ...


@runtime_checkable
class Wandering(Protocol):
    """A driver that can move the robot around by itself (the simulated one): someone else driving it."""

    def wander(self, on: bool) -> None: ...
