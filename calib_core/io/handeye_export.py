"""Where a hand-eye result goes on a robot (`calib export --calibration cal.json` of a `calib handeye` output): the
camera's pose as a ROS 2 launch file that publishes it on /tf_static, a URDF joint to paste into the robot's
description, or easy_handeye's calibration YAML. Use one of them: the launch file when the robot's description is
not yours to change, the URDF joint when it is (robot_state_publisher then publishes it), the YAML where
easy_handeye's publisher already runs.

The camera's frame is the one the calibration used: OpenCV's optical frame (x right, y down, z forward), ROS's
`*_optical_frame`. The parent is the flange (eye-in-hand) or the robot's base (eye-to-hand).
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from ..errors import InputError
from ..estimation.handeye import zyx_angles
from .ros_tf import FRAME_NAME, StaticTransform, quaternion, static_tf_launch

HANDEYE_FORMATS = ("ros2-static-tf", "urdf-joint", "easy-handeye")


def read_handeye(path: str | Path) -> tuple[str, np.ndarray]:
    """A `calib handeye` output: its setup and the camera's pose (4, 4) in m (in the flange or the base)."""
    try:
        d = json.loads(Path(path).read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError) as exc:
        raise InputError(f"cannot be read ({exc.__class__.__name__})", file=str(path)) from None
    except json.JSONDecodeError as exc:
        raise InputError(f"not valid JSON ({exc.msg})", file=str(path), line=exc.lineno) from None
    setup = d.get("setup") if isinstance(d, dict) else None
    name = {"eye-in-hand": "camera_in_flange", "eye-to-hand": "camera_in_base"}.get(setup or "")
    if name is None:
        raise InputError("not a calib handeye output (its setup is not eye-in-hand or eye-to-hand)", file=str(path))
    try:
        T = np.array(d[name]["matrix"], float)
        scale = {"mm": 1e-3, "m": 1.0}[d[name].get("unit", "mm")]
    except (KeyError, TypeError, ValueError):
        raise InputError(f"{name}: expected a 4 x 4 matrix and its unit", file=str(path)) from None
    if T.shape != (4, 4) or not np.all(np.isfinite(T)):
        raise InputError(f"{name}.matrix: expected a 4 x 4 matrix of finite numbers", file=str(path))
    T[:3, 3] *= scale
    return str(setup), T


def export_handeye(setup: str, T: np.ndarray, fmt: str, parent: str, child: str) -> str:
    """The camera's pose T (4, 4, m) in `parent` as `fmt` (HANDEYE_FORMATS), `child` the camera's optical frame."""
    for option, frame in (("--parent", parent), ("--child", child)):
        if not FRAME_NAME.fullmatch(frame):
            raise InputError(f"{option} {frame!r}: a frame name (letters, digits, _ and /)")
    x, y, z = (float(v) for v in T[:3, 3])
    qx, qy, qz, qw = quaternion(T[:3, :3])
    source = f"calib handeye ({setup}): the camera's optical frame {child} in {parent}"
    if fmt == "ros2-static-tf":
        return static_tf_launch([StaticTransform(parent, child, T, "calib_handeye")], source)
    if fmt == "urdf-joint":
        yaw, pitch, roll = zyx_angles(T[:3, :3])  # URDF's rpy: R = Rz(yaw) Ry(pitch) Rx(roll)
        return (
            f'<!-- {source}: paste into the robot\'s URDF (and a <link name="{child}"/>) -->\n'
            f'<joint name="{child.replace("/", "_")}_joint" type="fixed">\n'
            f'  <parent link="{parent}"/>\n'
            f'  <child link="{child}"/>\n'
            f'  <origin xyz="{x!r} {y!r} {z!r}" rpy="{roll!r} {pitch!r} {yaw!r}"/>\n'
            "</joint>\n"
        )
    if fmt == "easy-handeye":
        in_hand = setup == "eye-in-hand"
        frames = (
            f"  robot_base_frame: {'base_link' if in_hand else parent}\n"
            f"  robot_effector_frame: {parent if in_hand else 'tool0'}\n"
            f"  tracking_base_frame: {child}\n"
            "  tracking_marker_frame: board\n"
        )
        return (
            f"# {source}, in easy_handeye's calibration form (its publisher reads it)\n"
            f"parameters:\n  eye_on_hand: {'true' if in_hand else 'false'}\n{frames}"
            f"transformation:\n  x: {x!r}\n  y: {y!r}\n  z: {z!r}\n  qx: {qx!r}\n  qy: {qy!r}\n  qz: {qz!r}\n"
            f"  qw: {qw!r}\n"
        )
    raise InputError(f"--format {fmt!r}: a hand-eye result exports as {', '.join(HANDEYE_FORMATS)}")
