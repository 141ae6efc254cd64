"""Loading robot profiles: a built-in one by name or a YAML file, compiled to a Profile.

Every problem with a file is an InputError naming the file and the field
(`frames[3].mdh.alpha: expected a finite number`). A profile that says `urdf: robot.urdf` gets its
frames, joints and default modes from that URDF first (calib_core.model.urdf_import).
"""

from __future__ import annotations

import fnmatch
import math
from dataclasses import replace
from importlib import resources
from pathlib import Path
from typing import Any

import numpy as np

from ..errors import InputError
from ..files import read_text_file
from ..safe_yaml import MAX_YAML_BYTES, load_yaml
from ..sensors import SENSOR_MODELS, Sensor
from ..sensors.pose6d import ROTATIONS
from ..units import ANGLE_IN_RAD, LENGTH_IN_M
from .boards import read_charuco
from .profile import DataFormat, Frame, Joint, Marker, Mode, Op, Parameter, Profile, Target, Tie

BUILTIN_PROFILES = ("robonaut-a", "nao", "motoman", "arm-handeye")

AXES = {"x": 0, "y": 1, "z": 2}
JOINT_KINDS = ("revolute", "prismatic")  # a joint entry's `type`: its op rotates or translates
GRID_PATTERNS = ("checkerboard", "sandal")  # what a grid target may be: a plain board, the NAO's sandal
# A mode's `free: ["cam.intrinsics"]`: the camera's fx, fy, cx, cy and its distortion coefficients.
INTRINSICS_SUFFIX = ".intrinsics"
PLAN_GOALS = ("task", "offsets")  # a mode's `plan`: what a plan for it makes accurate (Mode.plan)

# An elementary transform before it is an Op: (t|r, vector, field or parameter name, value, jointed).
Step = tuple[str, np.ndarray, str, float, bool]


def load_profile(name_or_path: str | Path, *, urdf: str | Path | None = None) -> Profile:
    """A built-in profile by name (`robonaut-a`, `nao`) or a profile YAML file by path. `urdf`: the URDF
    file to use instead of the one its `urdf:` names (a ROS 2 robot's, received from its graph, for a
    profile that says `urdf: ros2`)."""
    text, source = _read_profile_text(name_or_path)
    doc = load_yaml(text, source)
    if not isinstance(doc, dict):
        raise InputError("a robot profile must be a YAML mapping", file=source)
    try:
        if "urdf" in doc and urdf is not None:
            doc = {**doc, "urdf": str(Path(urdf).resolve())}
        if "urdf" in doc:  # frames, joints and default modes from a URDF file
            from .urdf_import import compile_urdf_profile  # lxml: only for a profile built on a URDF

            profile = compile_urdf_profile(doc, source, lambda d: _Compiler(d, source).compile())
        else:
            profile = _Compiler(doc, source).compile()
        return replace(profile, notes=profile.notes + _truth_notes(profile))
    except InputError:
        raise
    except (TypeError, AttributeError, KeyError, ValueError, IndexError) as exc:
        # A shape the field checks did not anticipate (a list where a mapping belongs, ...).
        raise InputError(f"malformed robot profile ({exc.__class__.__name__}: {exc})", file=source) from None


# A truth value ten times nearer zero than its nominal value, and further from it than these, reads like an error
# written in place of the value (the Robonaut paper's truth moves link lengths by 4 cm, but to 1/5 of them at most).
TRUTH_ERROR_DEG = 10.0
TRUTH_ERROR_MM = 20.0
TRUTH_SHRINK = 10.0


def _truth_notes(profile: Profile) -> tuple[str, ...]:
    """`simulation.truth` holds the hidden robot's parameter values (nominal plus error), in display units. A
    value far nearer zero than its nominal and far from it (TRUTH_*) reads like an error written
    in place of the value (`elbow.z: 0.5` for an elbow.z of 419.5 mm): a note saying so, with the value meant."""
    truth = profile.simulation.get("truth")
    if not isinstance(truth, dict):
        return ()
    bound = {"angle": TRUTH_ERROR_DEG, "length": TRUTH_ERROR_MM * 1e-3 / LENGTH_IN_M[profile.length_unit]}
    notes = []
    for name, value in truth.items():
        try:
            i = profile.param(str(name))
            v = float(value)
        except (InputError, TypeError, ValueError):
            continue  # named when the simulator reads it
        nominal = profile.to_display(i, profile.parameters[i].nominal)
        far = bound.get(profile.parameters[i].kind)
        if far is not None and abs(v) * TRUTH_SHRINK < abs(nominal) and abs(v - nominal) > far:
            unit = profile.unit(i)
            notes.append(
                f"simulation.truth.{name}: {v:g} {unit} is {abs(v - nominal):.4g} {unit} from its nominal value "
                f"{nominal:.6g} {unit}; truth values are the hidden robot's parameter values, not their errors "
                f"(an error of {v:g} {unit} is {nominal + v:.6g})"
            )
    return tuple(notes)


def _read_profile_text(name_or_path: str | Path) -> tuple[str, str]:
    name = str(name_or_path)
    if name in BUILTIN_PROFILES:
        res = resources.files("calib_core.model") / "profiles" / f"{name}.yaml"
        return res.read_text(encoding="utf-8"), f"{name} (built-in)"
    path = Path(name)
    if not path.suffix and not path.exists():
        known = ", ".join(BUILTIN_PROFILES)
        raise InputError(f"unknown robot '{name}' (built-in: {known}; or give a profile file)")
    return read_text_file(path, MAX_YAML_BYTES, "robot profile file"), str(path)


class _Compiler:
    """Turns the YAML document into a Profile, naming the field of every problem."""

    def __init__(self, doc: dict, source: str) -> None:
        self.doc = doc
        self.source = source
        self.params: list[Parameter] = []
        self.sensors: list[Sensor] = []
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
        self.joints = joints
        self.joint_index = {j.name: i for i, j in enumerate(joints)}
        frames = self.compile_frames()
        self.frame_index = {f.name: i for i, f in enumerate(frames)}
        targets = [self.compile_target(t, f"targets[{i}]") for i, t in enumerate(doc.get("targets", []))]
        freed = self.intrinsics_freed()
        sensors = [
            self.compile_sensor(with_distortion(s) if _sensor_name(s) in freed else s, f"sensors[{i}]")
            for i, s in enumerate(doc.get("sensors", []))
        ]
        self.sensors = sensors
        if not sensors or not targets:
            raise self.fail("profile", "needs at least one sensor and one target")
        self.target_index = {t.name: i for i, t in enumerate(targets)}
        self.sensor_index = {s.name: i for i, s in enumerate(sensors)}
        data = self.compile_data(self.get(doc, "data", "profile"), sensors)
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
            kind = str(self.get(spec, "type", where, "revolute"))
            if kind not in JOINT_KINDS:
                raise self.fail(f"{where}.type", f"unknown joint type '{kind}' ({', '.join(JOINT_KINDS)})")
            prismatic = kind == "prismatic"
            scale = 1.0 if prismatic else self.to_rad  # prismatic: the profile's length unit as it is
            lower = self.number(self.get(spec, "lower", where), f"{where}.lower") * scale
            upper = self.number(self.get(spec, "upper", where), f"{where}.upper") * scale
            vel = self.number(self.get(spec, "velocity", where, 30.0), f"{where}.velocity") * scale
            res = self.number(spec.get("resolution", 0.0), f"{where}.resolution") * scale
            if lower > upper:
                raise self.fail(where, "lower limit above upper limit")
            out.append(Joint(str(jname), lower, upper, vel, res, prismatic))
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
        if kind == "registration":
            steps = self.registration_steps(body, joint, where)
        elif kind in ("mdh", "dh"):
            if joint >= 0 and self.joints[joint].prismatic:
                raise self.fail(
                    where, f"prismatic joint '{self.joints[joint].name}' needs a urdf or ops frame, not {kind}"
                )
            steps = self.dh_steps(kind, body, where)
        elif kind == "urdf":
            steps = self.urdf_steps(body, joint, where)
        else:
            steps = self.op_list_steps(body, fname, where)
        ops = []
        for op_kind, vector, fieldname, value, jointed in steps:
            pname = fieldname if kind == "ops" else renames.get(fieldname, f"{fname}.{fieldname}")
            pi = self.add_param(pname, "angle" if op_kind == "r" else "length", value, where)
            nonzero = np.flatnonzero(vector)
            principal = len(nonzero) == 1 and vector[nonzero[0]] == 1.0
            ops.append(Op(op_kind, vector, int(nonzero[0]) if principal else None, pi, joint if jointed else -1))
        if joint >= 0 and not any(op.joint >= 0 for op in ops):
            raise self.fail(where, "names a joint but no op is driven by it")
        if joint >= 0:
            want = "t" if self.joints[joint].prismatic else "r"
            if any(op.joint >= 0 and op.kind != want for op in ops):
                kind = "prismatic" if want == "t" else "revolute"
                motion = "a translation (tx, ty, tz)" if want == "t" else "a rotation (rx, ry, rz)"
                raise self.fail(
                    where, f"joint '{self.joints[joint].name}' is {kind}: the op it drives must be {motion}"
                )
        return ops

    def registration_steps(self, body: Any, joint: int, where: str) -> list[Step]:
        if body is not True:
            raise self.fail(f"{where}.registration", "must be true")
        if joint >= 0:
            raise self.fail(where, "a registration frame cannot be driven by a joint")
        return _pose_steps(np.zeros(3), np.zeros(3))

    def dh_steps(self, kind: str, body: Any, where: str) -> list[Step]:
        vals = {
            k: self.number(self.get(body, k, f"{where}.{kind}", 0.0), f"{where}.{kind}.{k}")
            for k in ("a", "alpha", "d")
        }
        angle_key = "theta" if kind == "mdh" else "offset"
        vals[angle_key] = self.number(
            body.get(angle_key, body.get("theta", body.get("offset", 0.0))), f"{where}.{kind}.{angle_key}"
        )
        e = np.eye(3)
        a = ("t", e[0], "a", vals["a"], False)
        alpha = ("r", e[0], "alpha", vals["alpha"] * self.to_rad, False)
        d = ("t", e[2], "d", vals["d"], False)
        th = ("r", e[2], angle_key, vals[angle_key] * self.to_rad, True)
        return [a, alpha, d, th] if kind == "mdh" else [th, d, a, alpha]

    def urdf_steps(self, body: Any, joint: int, where: str) -> list[Step]:
        xyz = self.vector(body.get("xyz", [0, 0, 0]), f"{where}.urdf.xyz")
        rpy = self.vector(body.get("rpy", [0, 0, 0]), f"{where}.urdf.rpy") * self.to_rad
        steps = _pose_steps(xyz, rpy)
        if joint >= 0 or "axis" in body:
            axis = self.vector(self.get(body, "axis", f"{where}.urdf"), f"{where}.urdf.axis")
            norm = np.linalg.norm(axis)
            if norm < 1e-9:
                raise self.fail(f"{where}.urdf.axis", "must not be zero")
            offset = self.number(body.get("offset", 0.0), f"{where}.urdf.offset")
            if joint >= 0 and self.joints[joint].prismatic:  # Trans_axis(offset + q), a length
                steps.append(("t", axis / norm, "offset", offset, True))
            else:
                steps.append(("r", axis / norm, "offset", offset * self.to_rad, True))
        return steps

    def op_list_steps(self, body: Any, fname: str, where: str) -> list[Step]:
        if not isinstance(body, list):
            raise self.fail(f"{where}.ops", "expected a list")
        steps = []
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
            steps.append((op_kind, np.eye(3)[AXES[axis_name]], pname, value, bool(op.get("joint", False))))
        return steps

    def compile_target(self, spec: dict, where: str) -> Target:
        tname = str(self.get(spec, "name", where))
        fname = str(self.get(spec, "frame", where))
        if fname not in self.frame_index:
            raise self.fail(f"{where}.frame", f"unknown frame '{fname}'")
        point_params = None
        grid = None
        shape = None
        points = None
        charuco = None
        if sum(k in spec for k in ("point", "grid", "points", "charuco")) > 1:
            raise self.fail(where, "needs at most one of point, grid, points, charuco")
        if "points" in spec:
            pts = spec["points"]
            if not isinstance(pts, list) or not pts:
                raise self.fail(f"{where}.points", "expected a list of [x, y, z]")
            points = np.array([self.vector(v, f"{where}.points[{k}]") for k, v in enumerate(pts)])
        elif not any(k in spec for k in ("point", "grid", "charuco")):
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
        if "charuco" in spec:
            charuco = read_charuco(spec["charuco"], self, f"{where}.charuco")
            grid, shape = charuco.corners(), charuco.shape
        radius = spec.get("radius")
        return Target(
            tname,
            self.frame_index[fname],
            point_params,
            grid,
            shape,
            None if radius is None else self.number(radius, f"{where}.radius"),
            points,
            self.pattern(spec, where),
            charuco,
        )

    def pattern(self, spec: dict, where: str) -> str:
        """What a sensor looks for on a target (`Target.pattern`): a grid's `pattern` (checkerboard, or the
        NAO's sandal), else what the target is."""
        if "pattern" in spec:
            if "grid" not in spec:
                raise self.fail(f"{where}.pattern", "only a grid target has a pattern (checkerboard or sandal)")
            if spec["pattern"] not in GRID_PATTERNS:
                raise self.fail(
                    f"{where}.pattern", f"expected one of {', '.join(GRID_PATTERNS)}, got {spec['pattern']!r}"
                )
            return str(spec["pattern"])
        if "charuco" in spec:
            return "charuco"
        if "grid" in spec:
            return "checkerboard"
        return "sphere" if "radius" in spec else "point"

    def intrinsics_freed(self) -> set[str]:
        """The sensors whose `<name>.intrinsics` some mode frees (their lens is calibrated with the arm)."""
        out = set()
        for mode in (self.doc.get("modes") or {}).values():
            for item in (mode.get("free") or []) if isinstance(mode, dict) else []:
                if isinstance(item, str) and item.endswith(INTRINSICS_SUFFIX):
                    out.add(item.removesuffix(INTRINSICS_SUFFIX))
        return out

    def compile_sensor(self, spec: dict, where: str) -> Sensor:
        sname = str(self.get(spec, "name", where))
        fname = str(self.get(spec, "frame", where))
        if fname not in self.frame_index:
            raise self.fail(f"{where}.frame", f"unknown frame '{fname}'")
        model = str(self.get(spec, "model", where))
        if model not in SENSOR_MODELS:
            raise self.fail(f"{where}.model", f"unknown sensor model '{model}' ({', '.join(SENSOR_MODELS)})")
        try:
            return SENSOR_MODELS[model].from_spec(spec, self, sname, self.frame_index[fname], where)
        except InputError as exc:  # a noise model's check names the field, not the file
            raise InputError(exc.message, file=self.source) from None

    def compile_data(self, spec: dict, sensors: list[Sensor]) -> DataFormat:
        where = "data"
        jcols = {str(k): str(v) for k, v in self.get(spec, "joints", where).items()}
        for jn in jcols:
            if jn not in self.joint_index:
                raise self.fail(f"{where}.joints", f"'{jn}' is not a joint")
        joint_unit = str(spec.get("joint_unit", "deg"))
        if joint_unit not in ANGLE_IN_RAD:
            raise self.fail(f"{where}.joint_unit", f"unknown unit '{joint_unit}' ({', '.join(ANGLE_IN_RAD)})")
        joint_length_unit = spec.get("joint_length_unit")
        if joint_length_unit is not None and str(joint_length_unit) not in LENGTH_IN_M:
            raise self.fail(
                f"{where}.joint_length_unit", f"unknown unit '{joint_length_unit}' ({', '.join(LENGTH_IN_M)})"
            )
        sensor = self.index_of(self.get(spec, "sensor", where), self.sensor_index, f"{where}.sensor", "sensor")
        svalues = {
            str(k): self.index_of(v, self.sensor_index, f"{where}.sensors.{k}", "sensor")
            for k, v in (spec.get("sensors") or {}).items()
        }
        if svalues and not spec.get("sensor_column"):
            raise self.fail(where, "names sensors by value but has no sensor_column")
        target = spec.get("target")
        if target is not None:
            target = self.index_of(target, self.target_index, f"{where}.target", "target")
        tvalues = {
            str(k): self.index_of(v, self.target_index, f"{where}.targets.{k}", "target")
            for k, v in (spec.get("targets") or {}).items()
        }
        if target is None and not spec.get("target_column"):
            raise self.fail(where, "needs a target or a target_column")
        default = spec.get("target_default")
        if default is not None and str(default) not in tvalues:
            raise self.fail(f"{where}.target_default", f"'{default}' is not one of the targets' values")
        named = [sensors[i] for i in sorted({sensor, *svalues.values()})]
        rotation, rotation_unit = self.compile_rotation(spec, named, joint_unit)
        columns, unit = self.compile_measurement(spec, named, rotation)
        point_columns, point_unit = self.compile_point(spec)
        markers = self.compile_markers(spec, sensors, len(columns), named[0])
        frame_column = spec.get("frame_column", "frame")
        return DataFormat(
            frame_column=None if frame_column is None else str(frame_column),
            joint_columns=jcols,
            joint_unit=joint_unit,
            sensor=sensor,
            target=target,
            target_column=spec.get("target_column"),
            target_values=tvalues,
            point_columns=point_columns,
            point_unit=point_unit,
            vertex_column=spec.get("vertex_column"),
            measurement_columns=columns,
            measurement_unit=unit,
            prediction_columns=self.columns(
                self.get(spec, "prediction_columns", where), f"{where}.prediction_columns", len(columns)
            ),
            target_default=None if default is None else tvalues[str(default)],
            sensor_column=spec.get("sensor_column"),
            sensor_values=svalues,
            joint_length_unit=None if joint_length_unit is None else str(joint_length_unit),
            rotation=rotation,
            rotation_unit=rotation_unit,
            markers=markers,
        )

    def compile_rotation(self, spec: dict, named: list[Sensor], joint_unit: str) -> tuple[str | None, str]:
        """How the measurement columns give a pose's orientation (`measurement.rotation`: rotvec by default,
        quaternion or rpy) and the unit of its angles (`measurement.angle_unit`, default the joints'), for a
        format of pose sensors; (None, rad) for any other."""
        where = "data.measurement"
        meas = self.get(spec, "measurement", "data")
        poses = {bool(s.rotation_axes) for s in named}
        if len(poses) > 1:
            raise self.fail("data.sensors", "the sensors of one CSV format must all measure poses, or none")
        if not poses.pop():
            for key in ("rotation", "angle_unit"):
                if isinstance(meas, dict) and key in meas:
                    raise self.fail(
                        f"{where}.{key}",
                        f"only a pose's measurement has one ({named[0].name} is a {named[0].kind} sensor)",
                    )
            return None, "rad"
        rotation = str(meas.get("rotation", "rotvec"))
        if rotation not in ROTATIONS:
            raise self.fail(f"{where}.rotation", f"unknown rotation '{rotation}' ({', '.join(ROTATIONS)})")
        unit = str(meas.get("angle_unit", joint_unit))
        if unit not in ANGLE_IN_RAD:
            raise self.fail(f"{where}.angle_unit", f"unknown unit '{unit}' ({', '.join(ANGLE_IN_RAD)})")
        return rotation, unit

    def compile_measurement(self, spec: dict, named: list[Sensor], rotation: str | None) -> tuple[tuple[str, ...], str]:
        """The measurement columns and their unit, checked against every sensor the format names."""
        where = "data.measurement"
        meas = self.get(spec, "measurement", "data")
        columns = self.columns(self.get(meas, "columns", where), f"{where}.columns")
        for s in named:
            count = s.dim if rotation is None else 3 + ROTATIONS[rotation]
            if len(columns) != count:
                numbers = "1 number" if count == 1 else f"{count} numbers"
                how = "" if rotation is None else f" (x, y, z and a {rotation})"
                raise self.fail(
                    f"{where}.columns",
                    f"a {s.kind} sensor ('{s.name}') measures {numbers}{how}, not {len(columns)}",
                )
        units = {s.unit for s in named}
        if len(units) > 1:
            raise self.fail("data.sensors", f"the sensors of one CSV format must measure in one unit, not {units}")
        unit = str(meas.get("unit", next(iter(units))))
        if (unit != "px" and unit not in LENGTH_IN_M) or (unit == "px") != (named[0].unit == "px"):
            raise self.fail(f"{where}.unit", f"'{unit}' is not a unit of {named[0].name}'s measurements")
        return columns, unit

    def compile_markers(self, spec: dict, sensors: list[Sensor], count: int, row_sensor: Sensor) -> tuple[Marker, ...]:
        """`data.markers`: more measurements on each row, each `{columns: [...]}` of as many columns as the
        measurement, with an optional `target` (name), `vertex` (a point of it) and `sensor` (name, one
        that measures as the row's sensor does)."""
        value = spec.get("markers")
        if value is None:
            return ()
        if not isinstance(value, list) or not value:
            raise self.fail("data.markers", "expected a list of {columns: [...]}")
        out = []
        for k, m in enumerate(value):
            where = f"data.markers[{k}]"
            columns = self.columns(self.get(m, "columns", where), f"{where}.columns", count)
            unknown = sorted(set(m) - {"columns", "target", "vertex", "sensor"})
            if unknown:
                raise self.fail(f"{where}.{unknown[0]}", "not a field of a marker (columns, target, vertex, sensor)")
            target = (
                None
                if m.get("target") is None
                else self.index_of(m["target"], self.target_index, f"{where}.target", "target")
            )
            sensor = (
                None
                if m.get("sensor") is None
                else self.index_of(m["sensor"], self.sensor_index, f"{where}.sensor", "sensor")
            )
            if sensor is not None and (sensors[sensor].dim, sensors[sensor].unit) != (row_sensor.dim, row_sensor.unit):
                raise self.fail(
                    f"{where}.sensor",
                    f"'{m['sensor']}' does not measure what {row_sensor.name} does (as many numbers, one unit)",
                )
            vertex = None
            if m.get("vertex") is not None:
                vertex = int(self.number(m["vertex"], f"{where}.vertex"))
                if vertex != m["vertex"] or vertex < 0:
                    raise self.fail(f"{where}.vertex", f"expected a point's index (0, 1, ...), got {m['vertex']!r}")
            out.append(Marker(columns, target, vertex, sensor))
        return tuple(out)

    def compile_point(self, spec: dict) -> tuple[tuple[str, ...] | None, str | None]:
        """The columns of the observed point in the target frame, and their length unit (or none)."""
        point = spec.get("point")
        if point is None:
            return None, None
        columns = self.columns(self.get(point, "columns", "data.point"), "data.point.columns", 3)
        unit = str(point.get("unit", self.length_unit))
        if unit not in LENGTH_IN_M:
            raise self.fail("data.point.unit", f"unknown unit '{unit}' ({', '.join(LENGTH_IN_M)})")
        return columns, unit

    def index_of(self, name: Any, index: dict[str, int], where: str, what: str) -> int:
        if str(name) not in index:
            raise self.fail(where, f"unknown {what} '{name}'")
        return index[str(name)]

    def columns(self, value: Any, where: str, count: int | None = None) -> tuple[str, ...]:
        """A list of column names (of `count` names when given)."""
        if not isinstance(value, list) or not value or not all(isinstance(c, str) and c for c in value):
            raise self.fail(where, f"expected a list of column names, got {value!r}")
        if count is not None and len(value) != count:
            raise self.fail(where, f"expected {count} column names, got {len(value)}")
        return tuple(value)

    def compile_mode(self, name: str, spec: dict, where: str) -> Mode:
        names = list(self.index)

        def expand(patterns: list, w: str) -> list[int]:
            """Names or glob patterns, in order; {pattern: P, nonzero: true} skips zero nominals."""
            out = []
            for k, item in enumerate(patterns):
                pat, nonzero = (
                    (item.get("pattern"), bool(item.get("nonzero"))) if isinstance(item, dict) else (item, False)
                )
                hits = [n for n in names if fnmatch.fnmatchcase(n, str(pat))] or self.lens_params(str(pat))
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
        sensors = None
        if "sensors" in spec:
            listed = spec["sensors"]
            if not isinstance(listed, list) or not listed:
                raise self.fail(f"{where}.sensors", f"expected a list of sensor names, got {listed!r}")
            sensors = tuple(
                self.index_of(n, self.sensor_index, f"{where}.sensors[{k}]", "sensor") for k, n in enumerate(listed)
            )
        plan = str(spec.get("plan", "task"))
        if plan not in PLAN_GOALS:
            raise self.fail(f"{where}.plan", f"expected one of {', '.join(PLAN_GOALS)}, got {plan!r}")
        return Mode(name, str(spec.get("description", "")), tuple(free), tuple(ties), priors, bounds, sensors, plan)

    def lens_params(self, pattern: str) -> list[str]:
        """`<sensor>.intrinsics`: the names of that sensor's intrinsics and distortion coefficients."""
        sensor = next((s for s in self.sensors if f"{s.name}{INTRINSICS_SUFFIX}" == pattern), None)
        return [] if sensor is None else [self.params[i].name for i in sensor.direct_params()]

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


def _sensor_name(spec: Any) -> str | None:
    return str(spec.get("name")) if isinstance(spec, dict) else None


def with_distortion(spec: Any) -> Any:
    """A pinhole camera whose intrinsics a mode frees, with OpenCV's five distortion coefficients (zero) where the
    profile gives none: a camera nobody calibrated has none to write, and the calibration estimates them."""
    if isinstance(spec, dict) and spec.get("model") == "pinhole" and "distortion" not in spec:
        return {**spec, "distortion": {}}
    return spec


def _pose_steps(xyz: np.ndarray, rpy: np.ndarray) -> list[Step]:
    """Trans(x, y, z) Rot_z(yaw) Rot_y(pitch) Rot_x(roll): a URDF origin, a registration's pose."""
    e = np.eye(3)
    steps: list[Step] = [("t", e[k], "xyz"[k], float(xyz[k]), False) for k in range(3)]
    return steps + [("r", e[2 - k], ("yaw", "pitch", "roll")[k], float(rpy[2 - k]), False) for k in range(3)]
