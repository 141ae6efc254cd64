"""A profile's kinematic chain: its `joints:` and `frames:` sections as Joints and Frames.

A frame follows its parent and takes one of five forms (`mdh`, `dh`, `urdf`, `ops`, `registration`), each read
as elementary transforms (`Step`s) that become the frame's Ops: each with its parameter, added to the reader's
in the frames' order, and the joint that drives it, if any.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from .field_reader import FieldReader
from .profile import Frame, Joint, Op

AXES = {"x": 0, "y": 1, "z": 2}
JOINT_KINDS = ("revolute", "prismatic")  # a joint entry's `type`: its op rotates or translates

# An elementary transform before it is an Op: (t|r, vector, field or parameter name, value, jointed).
Step = tuple[str, np.ndarray, str, float, bool]


def compile_joints(read: FieldReader, doc: dict) -> list[Joint]:
    """`joints:`, each with its limits, velocity, resolution and reading noise in internal units (rad, or the length
    unit)."""
    out = []
    for jname, spec in (doc.get("joints") or {}).items():
        where = f"joints.{jname}"
        kind = str(read.get(spec, "type", where, "revolute"))
        if kind not in JOINT_KINDS:
            raise read.fail(f"{where}.type", f"unknown joint type '{kind}' ({', '.join(JOINT_KINDS)})")
        prismatic = kind == "prismatic"
        scale = 1.0 if prismatic else read.to_rad  # prismatic: the profile's length unit as it is
        lower = read.number(read.get(spec, "lower", where), f"{where}.lower") * scale
        upper = read.number(read.get(spec, "upper", where), f"{where}.upper") * scale
        vel = read.number(read.get(spec, "velocity", where, 30.0), f"{where}.velocity") * scale
        res = read.number(spec.get("resolution", 0.0), f"{where}.resolution") * scale
        noise = read.number(spec.get("noise", 0.0), f"{where}.noise") * scale
        if lower > upper:
            raise read.fail(where, "lower limit above upper limit")
        if res < 0 or noise < 0:
            raise read.fail(f"{where}.{'resolution' if res < 0 else 'noise'}", "must not be negative")
        out.append(Joint(str(jname), lower, upper, vel, res, prismatic, noise))
    return out


def compile_frames(read: FieldReader, doc: dict, joints: list[Joint]) -> list[Frame]:
    """`frames:`, each after its parent (the profile's `base` is the root)."""
    frames: list[Frame] = []
    names: dict[str, int] = {}
    joint_index = {j.name: i for i, j in enumerate(joints)}
    base = str(doc.get("base", "base"))
    for i, spec in enumerate(read.get(doc, "frames", "profile")):
        where = f"frames[{i}]"
        fname = str(read.get(spec, "name", where))
        parent_name = str(read.get(spec, "parent", where))
        if parent_name == base:
            parent = -1
        elif parent_name in names:
            parent = names[parent_name]
        else:
            raise read.fail(
                f"{where}.parent",
                f"unknown frame '{parent_name}' (frames must follow their parent)",
            )
        joint = -1
        if "joint" in spec:
            jname = str(spec["joint"])
            if jname not in joint_index:
                raise read.fail(f"{where}.joint", f"'{jname}' has no entry under joints")
            joint = joint_index[jname]
        renames = spec.get("names", {}) or {}
        ops = _compile_ops(read, spec, fname, joint, joints, renames, where)
        names[fname] = len(frames)
        frames.append(Frame(fname, parent, tuple(ops), joint, bool(spec.get("registration", False))))
    return frames


def _compile_ops(
    read: FieldReader, spec: dict, fname: str, joint: int, joints: list[Joint], renames: dict, where: str
) -> list[Op]:
    """A frame's Ops from the one form it is given in; `joint`: the one that drives it (its index), or -1."""
    kinds = [k for k in ("mdh", "dh", "urdf", "ops", "registration") if k in spec]
    if len(kinds) != 1:
        raise read.fail(where, "needs exactly one of mdh, dh, urdf, ops, registration")
    kind = kinds[0]
    body = spec[kind]
    driver = joints[joint] if joint >= 0 else None
    if kind == "registration":
        steps = _registration_steps(read, body, driver, where)
    elif kind in ("mdh", "dh"):
        if driver is not None and driver.prismatic:
            raise read.fail(where, f"prismatic joint '{driver.name}' needs a urdf or ops frame, not {kind}")
        steps = _dh_steps(read, kind, body, where)
    elif kind == "urdf":
        steps = _urdf_steps(read, body, driver, where)
    else:
        steps = _op_list_steps(read, body, fname, where)
    ops = []
    for op_kind, vector, fieldname, value, jointed in steps:
        pname = fieldname if kind == "ops" else renames.get(fieldname, f"{fname}.{fieldname}")
        pi = read.add_param(pname, "angle" if op_kind == "r" else "length", value, where)
        nonzero = np.flatnonzero(vector)
        principal = len(nonzero) == 1 and vector[nonzero[0]] == 1.0
        ops.append(Op(op_kind, vector, int(nonzero[0]) if principal else None, pi, joint if jointed else -1))
    if driver is not None and not any(op.joint >= 0 for op in ops):
        raise read.fail(where, "names a joint but no op is driven by it")
    if driver is not None:
        want = "t" if driver.prismatic else "r"
        if any(op.joint >= 0 and op.kind != want for op in ops):
            kind = "prismatic" if want == "t" else "revolute"
            motion = "a translation (tx, ty, tz)" if want == "t" else "a rotation (rx, ry, rz)"
            raise read.fail(where, f"joint '{driver.name}' is {kind}: the op it drives must be {motion}")
    return ops


def _registration_steps(read: FieldReader, body: Any, driver: Joint | None, where: str) -> list[Step]:
    if body is not True:
        raise read.fail(f"{where}.registration", "must be true")
    if driver is not None:
        raise read.fail(where, "a registration frame cannot be driven by a joint")
    return _pose_steps(np.zeros(3), np.zeros(3))


def _dh_steps(read: FieldReader, kind: str, body: Any, where: str) -> list[Step]:
    vals = {
        k: read.number(read.get(body, k, f"{where}.{kind}", 0.0), f"{where}.{kind}.{k}") for k in ("a", "alpha", "d")
    }
    angle_key = "theta" if kind == "mdh" else "offset"
    vals[angle_key] = read.number(
        body.get(angle_key, body.get("theta", body.get("offset", 0.0))), f"{where}.{kind}.{angle_key}"
    )
    e = np.eye(3)
    a = ("t", e[0], "a", vals["a"], False)
    alpha = ("r", e[0], "alpha", vals["alpha"] * read.to_rad, False)
    d = ("t", e[2], "d", vals["d"], False)
    th = ("r", e[2], angle_key, vals[angle_key] * read.to_rad, True)
    return [a, alpha, d, th] if kind == "mdh" else [th, d, a, alpha]


def _urdf_steps(read: FieldReader, body: Any, driver: Joint | None, where: str) -> list[Step]:
    xyz = read.vector(body.get("xyz", [0, 0, 0]), f"{where}.urdf.xyz")
    rpy = read.vector(body.get("rpy", [0, 0, 0]), f"{where}.urdf.rpy") * read.to_rad
    steps = _pose_steps(xyz, rpy)
    if driver is not None or "axis" in body:
        axis = read.vector(read.get(body, "axis", f"{where}.urdf"), f"{where}.urdf.axis")
        norm = np.linalg.norm(axis)
        if norm < 1e-9:
            raise read.fail(f"{where}.urdf.axis", "must not be zero")
        offset = read.number(body.get("offset", 0.0), f"{where}.urdf.offset")
        if driver is not None and driver.prismatic:  # Trans_axis(offset + q), a length
            steps.append(("t", axis / norm, "offset", offset, True))
        else:
            steps.append(("r", axis / norm, "offset", offset * read.to_rad, True))
    return steps


def _op_list_steps(read: FieldReader, body: Any, fname: str, where: str) -> list[Step]:
    if not isinstance(body, list):
        raise read.fail(f"{where}.ops", "expected a list")
    steps = []
    for k, op in enumerate(body):
        w = f"{where}.ops[{k}]"
        key = [x for x in op if x in ("tx", "ty", "tz", "rx", "ry", "rz")] if isinstance(op, dict) else []
        if len(key) != 1:
            raise read.fail(w, "needs exactly one of tx, ty, tz, rx, ry, rz")
        op_kind, axis_name = key[0][0], key[0][1]
        value = read.number(op[key[0]], f"{w}.{key[0]}")
        if op_kind == "r":
            value *= read.to_rad
        pname = str(op["param"]) if "param" in op else f"{fname}.{key[0]}{k}"
        steps.append((op_kind, np.eye(3)[AXES[axis_name]], pname, value, bool(op.get("joint", False))))
    return steps


def _pose_steps(xyz: np.ndarray, rpy: np.ndarray) -> list[Step]:
    """Trans(x, y, z) Rot_z(yaw) Rot_y(pitch) Rot_x(roll): a URDF origin, a registration's pose."""
    e = np.eye(3)
    steps: list[Step] = [("t", e[k], "xyz"[k], float(xyz[k]), False) for k in range(3)]
    return steps + [("r", e[2 - k], ("yaw", "pitch", "roll")[k], float(rpy[2 - k]), False) for k in range(3)]
