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
the frame's origin), sensors (a 3-D point sensor or a pinhole camera), the CSV data format and the
calibration modes (free parameters, ties, priors) complete the profile. Joints shared by several
chains, several sensors and targets need nothing special: they are frames of the one tree.
"""

from __future__ import annotations

import fnmatch
import math
from dataclasses import dataclass, field, replace
from importlib import resources
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from .errors import InputError
from .units import ANGLE_IN_RAD, LENGTH_IN_M

BUILTIN_PROFILES = ("robonaut-a", "nao", "motoman")

AXES = {"x": 0, "y": 1, "z": 2}


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
    name: str
    lower: float  # rad
    upper: float  # rad
    velocity: float  # rad/s
    resolution: float = 0.0  # rad: the encoder's step; its rounding is noise on every reading


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


@dataclass(frozen=True)
class Sensor:
    """A sensor fixed to a frame: `point3d` measures 3-D points, `pinhole` projects them to pixels."""

    name: str
    frame: int
    model: str
    convention: str  # "x-forward" (robot: x forward, y left, z up) or "z-forward" (OpenCV)
    intrinsics: tuple[int, int, int, int] | None  # parameter indices of fx, fy, cx, cy
    distortion: tuple[int, ...] | None  # parameter indices of k1, k2, p1, p2, k3 (and k4, k5, k6)
    image: tuple[int, int] | None  # width, height in px
    R_frame_optical: np.ndarray  # the OpenCV optical frame's axes in the sensor frame
    range: tuple[float, float] | None  # visible distances, profile length unit
    baseline: float | None  # stereo baseline, profile length unit
    noise: dict[str, float]  # the measurement noise model the calibration weighs observations by


@dataclass(frozen=True)
class Tie:
    follower: int
    leader: int
    sign: float


@dataclass(frozen=True)
class Mode:
    name: str
    description: str
    free: tuple[int, ...]  # estimated parameters, leaders only (followers come through ties)
    ties: tuple[Tie, ...]
    priors: dict[int, float]  # parameter index -> standard deviation (internal units)
    bounds: dict[int, float] = field(default_factory=dict)  # index -> largest |change| from nominal


@dataclass(frozen=True)
class DataFormat:
    """How a CSV row maps to an observation (specs/robonaut-a.md, specs/nao.md)."""

    frame_column: str | None  # None: every row is a configuration of its own
    joint_columns: dict[str, str]  # joint name -> column
    joint_unit: str
    sensor: int
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

    def __post_init__(self) -> None:
        self._param_index = {p.name: i for i, p in enumerate(self.parameters)}
        self._frame_index = {f.name: i for i, f in enumerate(self.frames)}
        self._joint_index = {j.name: i for i, j in enumerate(self.joints)}

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
        if name not in self.modes:
            known = ", ".join(self.modes)
            raise InputError(f"unknown mode '{name}' for robot '{self.name}' (known: {known})")
        return self.modes[name]

    def nominal(self) -> np.ndarray:
        return np.array([p.nominal for p in self.parameters])

    def chain(self, frame: int) -> list[int]:
        """The frames from the base to `frame`, base side first."""
        out = []
        while frame >= 0:
            out.append(frame)
            frame = self.frames[frame].parent
        return out[::-1]

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

    def joint_limits(self) -> tuple[np.ndarray, np.ndarray]:
        """Lower and upper joint limits in rad."""
        return np.array([j.lower for j in self.joints]), np.array([j.upper for j in self.joints])

    def true_params(self) -> np.ndarray:
        """The simulator's hidden true robot (the profile's `simulation.truth`), internal units."""
        return self.params_from_display(self.simulation.get("truth", {}))

    def with_noise(self, noise: dict[str, Any]) -> Profile:
        """The same robot with the data sensor's observations weighed by `noise` (a noise model as in
        the YAML's `sensors[].noise`): for data measured with another precision than the profile
        assumes, such as the simulated detectors' (`simulation.detected_noise`)."""
        i = self.data.sensor
        sensors = list(self.sensors)
        sensors[i] = replace(sensors[i], noise=noise_model(noise, sensors[i], f"noise of sensor '{sensors[i].name}'"))
        return replace(self, sensors=sensors)


NOISE_MODELS = ("isotropic", "stereo")


def noise_model(noise: dict[str, Any], sensor: Sensor, where: str) -> dict[str, Any]:
    """A checked copy of a sensor's noise model; InputError naming `where` and the field if it is wrong.

    isotropic: `sigma` in the measurement's unit (px, or the length unit). stereo: a point3d sensor
    with intrinsics and a baseline; `pixel` (lateral) and `disparity` noise in px."""
    out: dict[str, Any] = {str(k): v for k, v in noise.items()}
    kind = out.get("model", "isotropic")
    if kind not in NOISE_MODELS:
        raise InputError(f"{where}.model: unknown noise model '{kind}' ({', '.join(NOISE_MODELS)})")
    if kind == "stereo" and (
        sensor.model != "point3d" or sensor.intrinsics is None or sensor.baseline is None or sensor.range is None
    ):
        raise InputError(f"{where}: the stereo noise model needs a point3d sensor with intrinsics, a baseline, a range")
    wanted = {"isotropic": ("sigma",), "stereo": ("pixel", "disparity")}[kind]
    for k, v in out.items():
        if k == "model":
            continue
        if k not in wanted:
            raise InputError(f"{where}.{k}: not a field of the {kind} noise model ({', '.join(wanted)})")
        if isinstance(v, bool) or not isinstance(v, int | float) or not math.isfinite(v) or v <= 0:
            raise InputError(f"{where}.{k}: expected a positive number, got {v!r}")
        out[k] = float(v)
    missing = [k for k in wanted if k not in out]
    if missing:
        raise InputError(f"{where}.{missing[0]}: the {kind} noise model needs it")
    return out


# --- loading ------------------------------------------------------------------------------------


def load_profile(name_or_path: str | Path) -> Profile:
    """A built-in profile by name (`robonaut-a`, `nao`) or a profile YAML file by path."""
    text, source = _read_profile_text(name_or_path)
    try:
        doc = yaml.safe_load(text)
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        line = mark.line + 1 if mark is not None else None
        raise InputError(f"not valid YAML ({getattr(exc, 'problem', exc)})", file=source, line=line) from None
    if not isinstance(doc, dict):
        raise InputError("a robot profile must be a YAML mapping", file=source)
    try:
        if "urdf" in doc:  # frames, joints and default modes from a URDF file (calib_core.urdf_import)
            from .urdf_import import compile_urdf_profile

            return compile_urdf_profile(doc, source, lambda d: _Compiler(d, source).compile())
        return _Compiler(doc, source).compile()
    except InputError:
        raise
    except (TypeError, AttributeError, KeyError, ValueError, IndexError) as exc:
        # A shape the field checks did not anticipate (a list where a mapping belongs, ...).
        raise InputError(f"malformed robot profile ({exc.__class__.__name__}: {exc})", file=source) from None


def _read_profile_text(name_or_path: str | Path) -> tuple[str, str]:
    name = str(name_or_path)
    if name in BUILTIN_PROFILES:
        res = resources.files("calib_core") / "profiles" / f"{name}.yaml"
        return res.read_text(encoding="utf-8"), f"{name} (built-in)"
    path = Path(name)
    if not path.suffix and not path.exists():
        known = ", ".join(BUILTIN_PROFILES)
        raise InputError(f"unknown robot '{name}' (built-in: {known}; or give a profile file)")
    try:
        return path.read_text(encoding="utf-8"), str(path)
    except FileNotFoundError:
        raise InputError("robot profile file does not exist", file=str(path)) from None
    except (OSError, UnicodeDecodeError) as exc:
        raise InputError(f"cannot read robot profile ({exc.__class__.__name__})", file=str(path)) from None


class _Compiler:
    """Turns the YAML document into a Profile, naming the field of every problem."""

    def __init__(self, doc: dict, source: str) -> None:
        self.doc = doc
        self.source = source
        self.params: list[Parameter] = []
        self.index: dict[str, int] = {}

    def fail(self, where: str, message: str) -> InputError:
        return InputError(f"{where}: {message}", file=self.source)

    def get(self, mapping: Any, key: str, where: str, default: Any = ...) -> Any:
        if not isinstance(mapping, dict):
            raise self.fail(where, "expected a mapping")
        if key not in mapping:
            if default is ...:
                raise self.fail(f"{where}.{key}", "missing")
            return default
        return mapping[key]

    def number(self, value: Any, where: str) -> float:
        if isinstance(value, bool) or not isinstance(value, int | float) or not math.isfinite(value):
            raise self.fail(where, f"expected a finite number, got {value!r}")
        return float(value)

    def vector(self, value: Any, where: str) -> np.ndarray:
        if not isinstance(value, list) or len(value) != 3:
            raise self.fail(where, f"expected [x, y, z], got {value!r}")
        return np.array([self.number(v, f"{where}[{i}]") for i, v in enumerate(value)])

    def add_param(self, name: str, kind: str, nominal: float, where: str) -> int:
        if name in self.index:
            raise self.fail(where, f"parameter '{name}' is defined twice")
        self.index[name] = len(self.params)
        self.params.append(Parameter(name, kind, nominal))
        return self.index[name]

    def add_params(
        self, prefix: str, kind: str, mapping: Any, keys: tuple[str, ...], where: str, default: Any = ...
    ) -> tuple[int, ...]:
        """Parameters `<prefix>.<key>` from the numbers of a mapping (a point, intrinsics, ...)."""
        return tuple(
            self.add_param(
                f"{prefix}.{k}", kind, self.number(self.get(mapping, k, where, default), f"{where}.{k}"), where
            )
            for k in keys
        )

    def compile(self) -> Profile:
        doc = self.doc
        name = str(self.get(doc, "name", "profile"))
        units = self.get(doc, "units", "profile", {"length": "m", "angle": "deg"})
        self.length_unit = self.get(units, "length", "units", "m")
        self.angle_unit = self.get(units, "angle", "units", "deg")
        if self.length_unit not in LENGTH_IN_M:
            raise self.fail("units.length", f"unknown unit '{self.length_unit}' (m, cm, mm)")
        if self.angle_unit not in ANGLE_IN_RAD:
            raise self.fail("units.angle", f"unknown unit '{self.angle_unit}' (deg, rad)")
        self.to_rad = ANGLE_IN_RAD[self.angle_unit]

        joints = self.compile_joints()
        self.joint_index = {j.name: i for i, j in enumerate(joints)}
        frames = self.compile_frames()
        self.frame_index = {f.name: i for i, f in enumerate(frames)}
        targets = [self.compile_target(t, f"targets[{i}]") for i, t in enumerate(doc.get("targets", []))]
        sensors = [self.compile_sensor(s, f"sensors[{i}]") for i, s in enumerate(doc.get("sensors", []))]
        if not sensors or not targets:
            raise self.fail("profile", "needs at least one sensor and one target")
        self.target_index = {t.name: i for i, t in enumerate(targets)}
        self.sensor_index = {s.name: i for i, s in enumerate(sensors)}
        data = self.compile_data(self.get(doc, "data", "profile"), joints)
        modes = {
            str(k): self.compile_mode(str(k), v, f"modes.{k}") for k, v in self.get(doc, "modes", "profile").items()
        }
        return Profile(
            name=name,
            title=str(doc.get("title", name)),
            source=self.source,
            length_unit=self.length_unit,
            base=str(doc.get("base", "base")),
            parameters=self.params,
            frames=frames,
            joints=joints,
            targets=targets,
            sensors=sensors,
            modes=modes,
            data=data,
            simulation=doc.get("simulation", {}) or {},
        )

    def compile_joints(self) -> list[Joint]:
        out = []
        for jname, spec in (self.doc.get("joints") or {}).items():
            where = f"joints.{jname}"
            lower = self.number(self.get(spec, "lower", where), f"{where}.lower") * self.to_rad
            upper = self.number(self.get(spec, "upper", where), f"{where}.upper") * self.to_rad
            vel = self.number(self.get(spec, "velocity", where, 30.0), f"{where}.velocity") * self.to_rad
            res = self.number(spec.get("resolution", 0.0), f"{where}.resolution") * self.to_rad
            if lower > upper:
                raise self.fail(where, "lower limit above upper limit")
            out.append(Joint(str(jname), lower, upper, vel, res))
        return out

    def compile_frames(self) -> list[Frame]:
        frames: list[Frame] = []
        names: dict[str, int] = {}
        base = str(self.doc.get("base", "base"))
        for i, spec in enumerate(self.get(self.doc, "frames", "profile")):
            where = f"frames[{i}]"
            fname = str(self.get(spec, "name", where))
            parent_name = str(self.get(spec, "parent", where))
            if parent_name == base:
                parent = -1
            elif parent_name in names:
                parent = names[parent_name]
            else:
                raise self.fail(
                    f"{where}.parent",
                    f"unknown frame '{parent_name}' (frames must follow their parent)",
                )
            joint = -1
            if "joint" in spec:
                jname = str(spec["joint"])
                if jname not in self.joint_index:
                    raise self.fail(f"{where}.joint", f"'{jname}' has no entry under joints")
                joint = self.joint_index[jname]
            renames = spec.get("names", {}) or {}
            ops = self.compile_ops(spec, fname, joint, renames, where)
            names[fname] = len(frames)
            frames.append(Frame(fname, parent, tuple(ops), joint, bool(spec.get("registration", False))))
        return frames

    def compile_ops(self, spec: dict, fname: str, joint: int, renames: dict, where: str) -> list[Op]:
        kinds = [k for k in ("mdh", "dh", "urdf", "ops", "registration") if k in spec]
        if len(kinds) != 1:
            raise self.fail(where, "needs exactly one of mdh, dh, urdf, ops, registration")
        kind = kinds[0]
        body = spec[kind]
        steps: list[tuple[str, np.ndarray, str, float, bool]] = []  # (t|r, vector, field, value, jointed)
        e = np.eye(3)
        if kind == "registration":
            if body is not True:
                raise self.fail(f"{where}.registration", "must be true")
            if joint >= 0:
                raise self.fail(where, "a registration frame cannot be driven by a joint")
            steps = [("t", e[k], "xyz"[k], 0.0, False) for k in range(3)]
            steps += [("r", e[2], "yaw", 0.0, False), ("r", e[1], "pitch", 0.0, False), ("r", e[0], "roll", 0.0, False)]
        elif kind in ("mdh", "dh"):
            vals = {
                k: self.number(self.get(body, k, f"{where}.{kind}", 0.0), f"{where}.{kind}.{k}")
                for k in ("a", "alpha", "d")
            }
            angle_key = "theta" if kind == "mdh" else "offset"
            vals[angle_key] = self.number(
                body.get(angle_key, body.get("theta", body.get("offset", 0.0))),
                f"{where}.{kind}.{angle_key}",
            )
            a = ("t", e[0], "a", vals["a"], False)
            alpha = ("r", e[0], "alpha", vals["alpha"] * self.to_rad, False)
            d = ("t", e[2], "d", vals["d"], False)
            th = ("r", e[2], angle_key, vals[angle_key] * self.to_rad, True)
            steps = [a, alpha, d, th] if kind == "mdh" else [th, d, a, alpha]
        elif kind == "urdf":
            xyz = self.vector(body.get("xyz", [0, 0, 0]), f"{where}.urdf.xyz")
            rpy = self.vector(body.get("rpy", [0, 0, 0]), f"{where}.urdf.rpy") * self.to_rad
            steps = [("t", e[k], "xyz"[k], xyz[k], False) for k in range(3)]
            steps += [
                ("r", e[2], "yaw", rpy[2], False),
                ("r", e[1], "pitch", rpy[1], False),
                ("r", e[0], "roll", rpy[0], False),
            ]
            if joint >= 0 or "axis" in body:
                axis = self.vector(self.get(body, "axis", f"{where}.urdf"), f"{where}.urdf.axis")
                norm = np.linalg.norm(axis)
                if norm < 1e-9:
                    raise self.fail(f"{where}.urdf.axis", "must not be zero")
                offset = self.number(body.get("offset", 0.0), f"{where}.urdf.offset") * self.to_rad
                steps.append(("r", axis / norm, "offset", offset, True))
        else:
            if not isinstance(body, list):
                raise self.fail(f"{where}.ops", "expected a list")
            for k, op in enumerate(body):
                w = f"{where}.ops[{k}]"
                key = [x for x in op if x in ("tx", "ty", "tz", "rx", "ry", "rz")] if isinstance(op, dict) else []
                if len(key) != 1:
                    raise self.fail(w, "needs exactly one of tx, ty, tz, rx, ry, rz")
                op_kind, axis_name = key[0][0], key[0][1]
                value = self.number(op[key[0]], f"{w}.{key[0]}")
                if op_kind == "r":
                    value *= self.to_rad
                pname = str(op["param"]) if "param" in op else f"{fname}.{key[0]}{k}"
                steps.append((op_kind, e[AXES[axis_name]], pname, value, bool(op.get("joint", False))))
        ops = []
        for op_kind, vector, fieldname, value, jointed in steps:
            pname = fieldname if kind == "ops" else renames.get(fieldname, f"{fname}.{fieldname}")
            pi = self.add_param(pname, "angle" if op_kind == "r" else "length", value, where)
            nonzero = np.flatnonzero(vector)
            principal = len(nonzero) == 1 and vector[nonzero[0]] == 1.0
            ops.append(
                Op(
                    op_kind,
                    vector,
                    int(nonzero[0]) if principal else None,
                    pi,
                    joint if jointed else -1,
                )
            )
        if joint >= 0 and not any(op.joint >= 0 for op in ops):
            raise self.fail(where, "names a joint but no op is driven by it")
        return ops

    def compile_target(self, spec: dict, where: str) -> Target:
        tname = str(self.get(spec, "name", where))
        fname = str(self.get(spec, "frame", where))
        if fname not in self.frame_index:
            raise self.fail(f"{where}.frame", f"unknown frame '{fname}'")
        point_params = None
        grid = None
        shape = None
        points = None
        if sum(k in spec for k in ("point", "grid", "points")) > 1:
            raise self.fail(where, "needs at most one of point, grid, points")
        if "points" in spec:
            pts = spec["points"]
            if not isinstance(pts, list) or not pts:
                raise self.fail(f"{where}.points", "expected a list of [x, y, z]")
            points = np.array([self.vector(v, f"{where}.points[{k}]") for k, v in enumerate(pts)])
        elif "point" not in spec and "grid" not in spec:
            points = np.zeros((1, 3))  # the frame's origin (a reflector at the end of a DH row)
        if "point" in spec:
            point_params = self.add_params(tname, "length", spec["point"], ("x", "y", "z"), f"{where}.point")
        if "grid" in spec:
            g = spec["grid"]
            cols = int(self.number(self.get(g, "cols", f"{where}.grid"), f"{where}.grid.cols"))
            rows = int(self.number(self.get(g, "rows", f"{where}.grid"), f"{where}.grid.rows"))
            s = self.number(self.get(g, "spacing", f"{where}.grid"), f"{where}.grid.spacing")
            c = self.vector(g.get("center", [0, 0, 0]), f"{where}.grid.center")
            r, k = np.divmod(np.arange(rows * cols), cols)
            grid = np.stack(
                [
                    c[0] + s * (k - (cols - 1) / 2),
                    c[1] + s * ((rows - 1) / 2 - r),
                    np.full(r.shape, c[2]),
                ],
                axis=1,
            )
            shape = (rows, cols)
        radius = spec.get("radius")
        return Target(
            tname,
            self.frame_index[fname],
            point_params,
            grid,
            shape,
            None if radius is None else self.number(radius, f"{where}.radius"),
            points,
        )

    def compile_sensor(self, spec: dict, where: str) -> Sensor:
        sname = str(self.get(spec, "name", where))
        fname = str(self.get(spec, "frame", where))
        if fname not in self.frame_index:
            raise self.fail(f"{where}.frame", f"unknown frame '{fname}'")
        model = str(self.get(spec, "model", where))
        if model not in ("point3d", "pinhole"):
            raise self.fail(f"{where}.model", f"unknown sensor model '{model}' (point3d, pinhole)")
        convention = str(spec.get("convention", "z-forward"))
        if convention not in ("x-forward", "z-forward"):
            raise self.fail(f"{where}.convention", "must be x-forward or z-forward")
        intr = None
        if "intrinsics" in spec:
            intr = self.add_params(sname, "px", spec["intrinsics"], ("fx", "fy", "cx", "cy"), f"{where}.intrinsics")
        elif model == "pinhole":
            raise self.fail(where, "a pinhole sensor needs intrinsics")
        dist = None
        if "distortion" in spec:
            # OpenCV's order: k1 k2 p1 p2 k3, and k4 k5 k6 of the rational model when any is given.
            rational = isinstance(spec["distortion"], dict) and any(k in spec["distortion"] for k in ("k4", "k5", "k6"))
            keys = ("k1", "k2", "p1", "p2", "k3") + (("k4", "k5", "k6") if rational else ())
            dist = self.add_params(sname, "scalar", spec["distortion"], keys, f"{where}.distortion", default=0.0)
        # The optical frame's axes in the sensor frame; x-forward: x_cv = -y, y_cv = -z, z_cv = x.
        R_opt = np.array([[0.0, 0, 1], [-1, 0, 0], [0, -1, 0]]) if convention == "x-forward" else np.eye(3)
        if "optical" in spec:
            o = spec["optical"]
            z = self.vector(self.get(o, "z", f"{where}.optical"), f"{where}.optical.z")
            x = self.vector(self.get(o, "x", f"{where}.optical"), f"{where}.optical.x")
            if abs(z @ x) > 1e-9 or abs(np.linalg.norm(z) - 1) > 1e-9 or abs(np.linalg.norm(x) - 1) > 1e-9:
                raise self.fail(f"{where}.optical", "x and z must be orthogonal unit vectors")
            R_opt = np.stack([x, np.cross(z, x), z], axis=1)
        noise = {str(k): v for k, v in (spec.get("noise") or {}).items()}
        kind = noise.get("model", "isotropic")
        if kind not in ("isotropic", "stereo"):
            raise self.fail(f"{where}.noise.model", f"unknown noise model '{kind}' (isotropic, stereo)")
        if kind == "stereo" and (model != "point3d" or "intrinsics" not in spec or "baseline" not in spec):
            raise self.fail(
                f"{where}.noise",
                "the stereo noise model needs a point3d sensor with intrinsics and a baseline",
            )
        for k, v in noise.items():
            if k != "model":
                noise[k] = self.number(v, f"{where}.noise.{k}")
        image = spec.get("image")
        rng = spec.get("range")
        baseline = spec.get("baseline")
        return Sensor(
            sname,
            self.frame_index[fname],
            model,
            convention,
            intr,
            dist,
            None if image is None else (int(image[0]), int(image[1])),
            R_opt,
            None if rng is None else (self.number(rng[0], f"{where}.range"), self.number(rng[1], f"{where}.range")),
            None if baseline is None else self.number(baseline, f"{where}.baseline"),
            noise,
        )

    def compile_data(self, spec: dict, joints: list[Joint]) -> DataFormat:
        where = "data"
        jcols = {str(k): str(v) for k, v in self.get(spec, "joints", where).items()}
        for jn in jcols:
            if jn not in self.joint_index:
                raise self.fail(f"{where}.joints", f"'{jn}' is not a joint")
        sensor = str(self.get(spec, "sensor", where))
        if sensor not in self.sensor_index:
            raise self.fail(f"{where}.sensor", f"unknown sensor '{sensor}'")
        target = spec.get("target")
        if target is not None and target not in self.target_index:
            raise self.fail(f"{where}.target", f"unknown target '{target}'")
        tvalues = {}
        for k, v in (spec.get("targets") or {}).items():
            if v not in self.target_index:
                raise self.fail(f"{where}.targets.{k}", f"unknown target '{v}'")
            tvalues[str(k)] = self.target_index[v]
        if target is None and not spec.get("target_column"):
            raise self.fail(where, "needs a target or a target_column")
        default = spec.get("target_default")
        if default is not None and str(default) not in tvalues:
            raise self.fail(f"{where}.target_default", f"'{default}' is not one of the targets' values")
        meas = self.get(spec, "measurement", where)
        point = spec.get("point")
        return DataFormat(
            frame_column=None if spec.get("frame_column", "frame") is None else str(spec.get("frame_column", "frame")),
            joint_columns=jcols,
            joint_unit=str(spec.get("joint_unit", "deg")),
            sensor=self.sensor_index[sensor],
            target=None if target is None else self.target_index[target],
            target_column=spec.get("target_column"),
            target_values=tvalues,
            point_columns=None if point is None else tuple(point["columns"]),
            point_unit=None if point is None else str(point.get("unit", self.length_unit)),
            vertex_column=spec.get("vertex_column"),
            measurement_columns=tuple(self.get(meas, "columns", f"{where}.measurement")),
            measurement_unit=str(meas.get("unit", self.length_unit)),
            prediction_columns=tuple(self.get(spec, "prediction_columns", where)),
            target_default=None if default is None else tvalues[str(default)],
        )

    def compile_mode(self, name: str, spec: dict, where: str) -> Mode:
        names = list(self.index)

        def expand(patterns: list, w: str) -> list[int]:
            """Names or glob patterns, in order; {pattern: P, nonzero: true} skips zero nominals."""
            out = []
            for k, item in enumerate(patterns):
                pat, nonzero = (
                    (item.get("pattern"), bool(item.get("nonzero"))) if isinstance(item, dict) else (item, False)
                )
                hits = [n for n in names if fnmatch.fnmatchcase(n, str(pat))]
                if not hits:
                    raise self.fail(f"{w}[{k}]", f"'{pat}' matches no parameter")
                out += [self.index[h] for h in hits if not nonzero or self.params[self.index[h]].nominal != 0.0]
            return out

        free = expand(spec.get("free", []), f"{where}.free")
        ties = []
        for k, t in enumerate(spec.get("ties", []) or []):
            w = f"{where}.ties[{k}]"
            f, lead = str(self.get(t, "follower", w)), str(self.get(t, "leader", w))
            for n in (f, lead):
                if n not in self.index:
                    raise self.fail(w, f"unknown parameter '{n}'")
            ties.append(Tie(self.index[f], self.index[lead], self.number(t.get("sign", 1), f"{w}.sign")))
        followers = {t.follower for t in ties}
        free = list(dict.fromkeys(i for i in free if i not in followers))
        priors = self.per_parameter(spec, "priors", names, where)
        bounds = self.per_parameter(spec, "bounds", names, where)
        return Mode(name, str(spec.get("description", "")), tuple(free), tuple(ties), priors, bounds)

    def per_parameter(self, spec: dict, key: str, names: list[str], where: str) -> dict[int, float]:
        """{name or glob pattern: positive number in the profile's units} -> {index: internal units}."""
        out = {}
        for pname, value in (spec.get(key) or {}).items():
            hits = [n for n in names if fnmatch.fnmatchcase(n, str(pname))]
            if not hits:
                raise self.fail(f"{where}.{key}", f"'{pname}' matches no parameter")
            v = self.number(value, f"{where}.{key}.{pname}")
            if v <= 0:
                raise self.fail(f"{where}.{key}.{pname}", f"must be positive, got {v}")
            for i in (self.index[h] for h in hits):
                out[i] = v * (self.to_rad if self.params[i].kind == "angle" else 1.0)
        return out
