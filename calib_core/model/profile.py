"""Robot profiles: a robot described as data (a YAML file), compiled to flat arrays for the kinematics.

A profile declares a tree of frames hanging from a base frame. Each frame is reached from its parent
by a short list of elementary transforms ("ops": a translation along or a rotation about an axis)
whose values are named calibration parameters, plus the joint reading for the op a joint drives.
Modified DH, standard DH and URDF-style joints are sugar for such op lists:

    mdh:  Trans_x(a) Rot_x(alpha) Trans_z(d) Rot_z(theta + q)            (Craig; Robonaut)
    dh:   Rot_z(offset + q) Trans_z(d) Trans_x(a) Rot_x(alpha)           (distal; Motoman)
    urdf: Trans(x, y, z) Rot_z(yaw) Rot_y(pitch) Rot_x(roll) Rot_axis(offset + q)   (NAO)
    ops:  any list such as [{ry: 0, param: CamPitch}, {tx: 0, param: LTransX}]
    registration: true   Trans(x, y, z) Rot_z(yaw) Rot_y(pitch) Rot_x(roll): the unknown pose of an
          external measuring device (a laser tracker), estimated with every calibration (Motoman)

Parameters are named `<frame>.<field>` (`shoulder_roll.theta`) unless the frame renames them
(`names: {offset: LHipYawPitch}`) or an op names its own (`param: CamPitch`). Targets (points on the
robot the sensors see: a calibrated point, a checkerboard grid, a list of fixed marker points, or
the frame's origin), sensors (measurement models: calib_core.sensors), the CSV data format and the
calibration modes (free parameters, ties, priors) complete the profile. Joints shared by several
chains, several sensors and targets need nothing special: they are frames of the one tree.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np

from ..errors import InputError
from ..sensors import Sensor
from ..units import length_factor
from .boards import Charuco


@dataclass(frozen=True)
class Parameter:
    """A calibration parameter. `nominal` is in internal units (length unit of the profile, rad, px)."""

    name: str
    kind: str  # "length", "angle", "px" or "scalar"
    nominal: float


@dataclass(frozen=True)
class Op:
    """An elementary transform: translate along / rotate about `vector` by p[param] + q[joint]."""

    kind: str  # "t" or "r"
    vector: np.ndarray
    axis: int | None  # 0, 1, 2 when `vector` is a principal axis (a fast path), else None
    param: int
    joint: int  # -1: no joint drives this op


@dataclass(frozen=True)
class Frame:
    name: str
    parent: int  # -1: the base frame
    ops: tuple[Op, ...]
    joint: int  # the joint that drives this frame, or -1
    registration: bool = False  # the pose of an external device, first estimated from the data


@dataclass(frozen=True)
class Joint:
    """A joint's limits, speed and encoder step: rad for a revolute joint, the profile's length
    unit for a prismatic one (its readings and offset are lengths)."""

    name: str
    lower: float  # rad (prismatic: length unit)
    upper: float  # rad (prismatic: length unit)
    velocity: float  # rad/s (prismatic: length unit/s)
    resolution: float = 0.0  # the encoder's step; its rounding is noise on every reading
    prismatic: bool = False
    noise: float = 0.0  # the standard deviation of a reading's own error (a reported pose's), as `lower`

    @property
    def reading_sd(self) -> float:
        """The standard deviation of a reading's error: its rounding to the step (uniform over one step) and its
        own noise."""
        return math.sqrt(self.resolution**2 / 12.0 + self.noise**2)


@dataclass(frozen=True)
class Target:
    """A point (or a grid of points) fixed to a frame that a sensor can see."""

    name: str
    frame: int
    point_params: tuple[int, int, int] | None  # a single point whose position is calibrated
    grid: np.ndarray | None  # (K, 3) fixed points in the target frame (a checkerboard's vertices)
    grid_shape: tuple[int, int] | None  # (rows, cols)
    radius: float | None  # a sphere's radius, profile length unit
    points: np.ndarray | None = None  # (K, 3) fixed points (markers; the origin), picked by vertex id
    # What a sensor looks for (the finders' registry, calib_core.vision.finders): "sphere" (a radius),
    # "checkerboard" (a grid), "sandal" (a grid under the NAO's foot), "charuco", or "point" (the device
    # reports it: a reflector, marker points).
    pattern: str = "point"
    charuco: Charuco | None = None  # a ChArUco board (its grid: the corners, its grid_shape: theirs)


@dataclass(frozen=True)
class Tie:
    follower: int
    leader: int
    sign: float


AUTO = "auto"  # the mode the data choose (calib_core.estimation.model_choice); no profile may name one so
AUTO_DESCRIPTION = (
    "the data choose: the profile's mode and the strength of its priors towards nominal that predict best "
    "in k-fold cross-validation on the training configurations"
)


@dataclass(frozen=True)
class Mode:
    name: str
    description: str
    free: tuple[int, ...]  # estimated parameters, leaders only (followers come through ties)
    ties: tuple[Tie, ...]
    priors: dict[int, float]  # parameter index -> standard deviation (internal units)
    bounds: dict[int, float] = field(default_factory=dict)  # index -> largest |change| from nominal
    sensors: tuple[int, ...] | None = None  # the sensors whose observations it fits (None: every one)
    # What a plan for it makes accurate: "task" the error over the workspace, "offsets" the joint offsets
    # (a robot whose calibration is its offsets, used in every pose: the NAO).
    plan: str = "task"


@dataclass(frozen=True)
class Marker:
    """One more measurement on each CSV row (`data.markers`): its columns (as many as the format's
    measurement, in its unit), and what it sees where it differs from the row's own: a target, a vertex
    of it, a sensor (None: the row's)."""

    columns: tuple[str, ...]
    target: int | None = None
    vertex: int | None = None
    sensor: int | None = None


@dataclass(frozen=True)
class DataFormat:
    """How a CSV row maps to observations (specs/robonaut-a.md, specs/nao.md): its measurement, and the
    markers' when the row has several (`markers`)."""

    frame_column: str | None  # None: every row is a configuration of its own
    joint_columns: dict[str, str]  # joint name -> column
    joint_unit: str
    sensor: int  # the sensor of every row (the default when a sensor column picks it)
    target: int | None  # the target of every row, or None when a column picks it
    target_column: str | None
    target_values: dict[str, int]
    point_columns: tuple[str, ...] | None  # the observed point in the target frame
    point_unit: str | None
    vertex_column: str | None
    measurement_columns: tuple[str, ...]
    measurement_unit: str
    prediction_columns: tuple[str, ...]
    target_default: int | None = None  # the target of rows when the target column is absent
    sensor_column: str | None = None  # a column naming each row's sensor (several sensors of one kind)
    sensor_values: dict[str, int] = field(default_factory=dict)  # its values -> sensor index
    joint_length_unit: str | None = None  # prismatic joints' readings (None: the profile's length unit)
    rotation: str | None = None  # a pose's orientation in the CSV (sensors.pose6d.ROTATIONS); None: no pose
    rotation_unit: str = "rad"  # the unit of its angles (a rotation vector's, roll, pitch, yaw)
    markers: tuple[Marker, ...] = ()  # more measurements on one row, after `measurement_columns`


@dataclass
class Profile:
    name: str
    title: str
    source: str
    length_unit: str
    base: str
    parameters: list[Parameter]
    frames: list[Frame]
    joints: list[Joint]
    targets: list[Target]
    sensors: list[Sensor]
    modes: dict[str, Mode]
    data: DataFormat
    simulation: dict[str, Any] = field(default_factory=dict)
    notes: tuple[str, ...] = ()  # what loading it tolerated or what a user should know (a URDF's quirks)

    def __post_init__(self) -> None:
        self._param_index = {p.name: i for i, p in enumerate(self.parameters)}
        self._frame_index = {f.name: i for i, f in enumerate(self.frames)}
        self._joint_index = {j.name: i for i, j in enumerate(self.joints)}
        # (frame, position) of every op in a fixed order: an op's id is its index here (kinematics).
        self.op_ids = [(f, k) for f, frame in enumerate(self.frames) for k in range(len(frame.ops))]
        if AUTO in self.modes:
            raise InputError(
                f"modes.{AUTO}: the name '{AUTO}' is reserved (the data choose the mode)", file=self.source
            )

    # --- look-ups -------------------------------------------------------------------------------
    @property
    def parameter_names(self) -> list[str]:
        return [p.name for p in self.parameters]

    @property
    def joint_names(self) -> list[str]:
        return [j.name for j in self.joints]

    def param(self, name: str) -> int:
        try:
            return self._param_index[name]
        except KeyError:
            raise InputError(f"unknown parameter '{name}' for robot '{self.name}'") from None

    def frame(self, name: str) -> int:
        return self._frame_index[name]

    def joint(self, name: str) -> int:
        return self._joint_index[name]

    def target(self, name: str) -> int:
        return [t.name for t in self.targets].index(name)

    def mode(self, name: str) -> Mode:
        """A mode of the profile by name, or `auto` (AUTO): the richest of them under that name, what a plan for
        `auto` makes accurate and a check of its rows counts (the calibration chooses among them:
        calib_core.estimation.model_choice)."""
        if name == AUTO and self.modes:
            richest = max(self.modes.values(), key=lambda m: len(m.free))  # the first of the largest
            return replace(richest, name=AUTO, description=f"{AUTO_DESCRIPTION} ({', '.join(self.modes)})")
        if name not in self.modes:
            known = ", ".join([*self.modes, AUTO])
            raise InputError(f"unknown mode '{name}' for robot '{self.name}' (known: {known})")
        return self.modes[name]

    def offered_modes(self) -> list[Mode]:
        """The modes a user chooses from, in order: `auto` first where the data have something to choose (several
        modes, or a mode with priors whose strength they set), then the profile's."""
        modes = list(self.modes.values())
        if len(modes) > 1 or any(m.priors for m in modes):
            return [self.mode(AUTO), *modes]
        return modes

    def nominal(self) -> np.ndarray:
        return np.array([p.nominal for p in self.parameters])

    def chain(self, frame: int) -> list[int]:
        """The frames from the base to `frame`, base side first."""
        out = []
        while frame >= 0:
            out.append(frame)
            frame = self.frames[frame].parent
        return out[::-1]

    def joints_between(self, target: int, sensor: int) -> set[int]:
        """The joints on the chains from the base to a target and to a sensor: those an observation
        of that target by that sensor depends on."""
        frames = set(self.chain(self.targets[target].frame)) | set(self.chain(self.sensors[sensor].frame))
        return {self.frames[f].joint for f in frames if self.frames[f].joint >= 0}

    def label(self, index: int) -> str:
        """The paper's notation: `shoulder_roll.d` reads d(shoulder_roll); `CamYaw` stays CamYaw."""
        name = self.parameters[index].name
        frame, dot, fieldname = name.rpartition(".")
        return f"{fieldname}({frame})" if dot else name

    # --- units at the edges ---------------------------------------------------------------------
    def unit(self, index: int) -> str:
        kind = self.parameters[index].kind
        return {"length": self.length_unit, "angle": "deg", "px": "px", "scalar": ""}[kind]

    def to_display(self, index: int, value: float) -> float:
        """Internal value -> the unit shown to people and written to files (deg for angles)."""
        return math.degrees(value) if self.parameters[index].kind == "angle" else float(value)

    def from_display(self, index: int, value: float) -> float:
        return math.radians(value) if self.parameters[index].kind == "angle" else float(value)

    def params_from_display(self, values: dict[str, float], start: np.ndarray | None = None) -> np.ndarray:
        p = self.nominal() if start is None else start.copy()
        for name, value in values.items():
            i = self.param(name)
            p[i] = self.from_display(i, value)
        return p

    def params_to_display(self, p: np.ndarray) -> dict[str, float]:
        return {q.name: self.to_display(i, p[i]) for i, q in enumerate(self.parameters)}

    def joint_display_unit(self, joint: int) -> str:
        """The unit a joint's readings and limits are shown in: deg, or the length unit (prismatic)."""
        return self.length_unit if self.joints[joint].prismatic else "deg"

    def joint_to_display(self, joint: int, value: float) -> float:
        return float(value) if self.joints[joint].prismatic else math.degrees(value)

    def joint_limits(self) -> tuple[np.ndarray, np.ndarray]:
        """Lower and upper joint limits in rad (prismatic joints: the profile's length unit)."""
        return np.array([j.lower for j in self.joints]), np.array([j.upper for j in self.joints])

    def joint_margins(self, margin_deg: float, margin_m: float) -> np.ndarray:
        """Each joint's safety margin in its own unit: `margin_deg` for a revolute joint (in rad), `margin_m` for
        a prismatic one (in the length unit); at most half the joint's range (a joint fixed at one value)."""
        to_unit = length_factor("m", self.length_unit)
        margin = np.array([margin_m * to_unit if j.prismatic else math.radians(margin_deg) for j in self.joints])
        lower, upper = self.joint_limits()
        return np.minimum(margin, (upper - lower) / 2)

    def limits_less_margin(self, margin_deg: float, margin_m: float) -> tuple[np.ndarray, np.ndarray]:
        """The joint limits less each joint's safety margin (joint_margins), in the joints' units."""
        lower, upper = self.joint_limits()
        margin = self.joint_margins(margin_deg, margin_m)
        return lower + margin, upper - margin

    def true_params(self) -> np.ndarray:
        """The simulator's hidden true robot (the profile's `simulation.truth`), internal units."""
        return self.params_from_display(self.simulation.get("truth", {}))

    def with_noise(self, noise: dict[str, Any], sensor: int | None = None) -> Profile:
        """The same robot with a sensor's observations (default: the data format's) weighed by `noise`
        (a noise model as in the YAML's `sensors[].noise`): for data measured with another precision
        than the profile assumes, such as the simulated detectors' (`simulation.detected_noise`)."""
        i = self.data.sensor if sensor is None else sensor
        sensors = list(self.sensors)
        sensors[i] = sensors[i].with_noise(noise, f"noise of sensor '{sensors[i].name}'")
        return replace(self, sensors=sensors)
