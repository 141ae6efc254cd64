"""The connection file's `apply.frames` (an extension of specs ros2.md): the names a ROS robot's TF gives the
calibrated URDF's links, and what apply then puts on /tf_static.

    apply: {node: /robot_state_publisher, parameter: robot_description,
            frames: {camera_mount: camera_color_optical_frame, tool0: flange}}

Each entry renames a profile frame's link in the URDF apply sets and writes (every reference to the link follows);
a link's parent is the link of its profile frame's parent, named by its own entry when it has one. The node
publishes each named link on a fixed joint on /tf_static (in its parent) and one on a moving joint on /tf. A pinhole
camera's frame of `convention: z-forward` is OpenCV's optical frame, ROS's `*_optical_frame` (REP 103: z forward,
x right, y down); one of `x-forward` is the camera's body frame (x forward, y left, z up: ROS's `camera_link`).

A robot without robot_state_publisher takes the launch file apply writes beside the URDF
(`<calibration>.tf_static.launch.py`): a tf2_ros static_transform_publisher for each named link on a fixed joint.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

from calib_core import InputError, Profile
from calib_core.io import FRAME_NAME, LinkPose, StaticTransform, static_tf_launch


def read_frames(spec: Any, file: str) -> dict[str, str]:
    """`apply.frames` as written: {profile frame: link name} (InputError naming the entry)."""
    if not isinstance(spec, dict) or not spec:
        raise InputError(
            "apply.frames: expected {profile frame: link name}, e.g. {camera_mount: camera_optical_frame}", file=file
        )
    frames = {}
    for frame, link in spec.items():
        name = link.strip() if isinstance(link, str) else link
        if not isinstance(name, str) or not FRAME_NAME.fullmatch(name):
            raise InputError(
                f"apply.frames.{frame}: expected a link name (a letter or _, then letters, digits, _ and /), "
                f"got {link!r}",
                file=file,
            )
        frames[str(frame)] = name
    return frames


def check_frames(frames: Mapping[str, str], profile: Profile, links: Sequence[str], file: str) -> None:
    """Each entry names a frame of the profile that is a link of its calibrated URDF (`links`), and no two links end
    up with one name (InputError naming the entry)."""
    names = [profile.base, *(f.name for f in profile.frames)]
    for frame, link in frames.items():
        where = f"apply.frames.{frame}"
        if frame not in names:
            raise InputError(f"{where}: no such frame in the profile (frames: {', '.join(names)})", file=file)
        if frame not in links:
            raise InputError(f"{where}: the calibrated URDF has no link for this frame", file=file)
        other = next((k for k in links if k != frame and frames.get(k, k) == link), None)
        if other in frames:
            raise InputError(f"{where}: '{link}' is the name apply.frames.{other} gives too", file=file)
        if other is not None:
            raise InputError(f"{where}: '{link}' is the name of another link of the calibrated URDF", file=file)


def published(poses: Sequence[LinkPose]) -> str:
    """What robot_state_publisher does with the named links: "camera_optical_frame under tool0 on /tf_static"."""
    parts = []
    for fixed, topic in ((True, "/tf_static"), (False, "/tf")):
        some = [f"{p.child} under {p.parent}" for p in poses if p.fixed == fixed]
        if some:
            parts.append(f"{_and(some)} on {topic}")
    return _and(parts)


def launch_file(poses: Sequence[LinkPose], source: str) -> str | None:
    """The launch file of the named links on fixed joints (None: there is none)."""
    fixed = [StaticTransform(p.parent, p.child, p.T, f"calib_tf_{p.child.replace('/', '_')}") for p in poses if p.fixed]
    return static_tf_launch(fixed, source) if fixed else None


def _and(items: Sequence[str]) -> str:
    return items[0] if len(items) == 1 else f"{', '.join(items[:-1])} and {items[-1]}"
