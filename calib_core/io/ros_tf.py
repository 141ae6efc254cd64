"""A calibrated URDF's links under the names a ROS robot's TF uses, where each named link stands, and a ROS 2 launch
file that publishes such poses on /tf_static.

robot_state_publisher publishes each fixed joint of the URDF it is given on /tf_static (the child link in the parent
link) and each moving joint on /tf; a robot without one takes the launch file: one tf2_ros
static_transform_publisher per pose.
"""

from __future__ import annotations

import re
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass

import numpy as np
from lxml import etree

from ..model.kinematics import axis_angle

FRAME_NAME = re.compile(r"[A-Za-z_][A-Za-z0-9_/]*")  # a TF frame name (a URDF link's as robot_state_publisher sends it)
_AXES = np.eye(3)


@dataclass(frozen=True)
class LinkPose:
    """A link where its joint puts it: `child` in `parent`, T (4, 4, m; a moving joint's at position 0)."""

    parent: str
    child: str
    fixed: bool  # a fixed joint: robot_state_publisher publishes it on /tf_static (else on /tf)
    T: np.ndarray


def link_names(urdf: str) -> list[str]:
    """The names of a URDF document's links, in the file's order."""
    return [el.get("name", "") for el in _root(urdf).findall("link")]


def rename_links(root: etree._Element, names: Mapping[str, str]) -> None:
    """Rename links of a URDF's <robot> element in place (old -> new) and every reference to them: joints' parent and
    child, gazebo tags' reference."""
    refs = [("link", "name"), ("joint/parent", "link"), ("joint/child", "link"), ("gazebo", "reference")]
    for path, attribute in refs:
        for el in root.findall(path):
            old = el.get(attribute)
            if old in names:
                el.set(attribute, names[old])


def link_poses(urdf: str, children: Iterable[str]) -> list[LinkPose]:
    """Where the URDF's joint of each of these links puts it (the root link has none: it is left out)."""
    joints = {child.get("link"): el for el in _root(urdf).findall("joint") if (child := el.find("child")) is not None}
    poses = []
    for child in children:
        el = joints.get(child)
        if el is None:
            continue
        origin = el.find("origin")
        xyz, rpy = ("0 0 0", "0 0 0") if origin is None else (origin.get("xyz", "0 0 0"), origin.get("rpy", "0 0 0"))
        roll, pitch, yaw = (float(v) for v in rpy.split())
        T = np.eye(4)
        T[:3, :3] = axis_angle(_AXES[2], yaw) @ axis_angle(_AXES[1], pitch) @ axis_angle(_AXES[0], roll)
        T[:3, 3] = [float(v) for v in xyz.split()]
        parent = el.find("parent")
        poses.append(LinkPose("" if parent is None else parent.get("link", ""), child, el.get("type") == "fixed", T))
    return poses


@dataclass(frozen=True)
class StaticTransform:
    """One static_transform_publisher: `child` at T (4, 4, m) in `parent`, a node named `node`."""

    parent: str
    child: str
    T: np.ndarray
    node: str


def static_tf_launch(transforms: Sequence[StaticTransform], source: str) -> str:
    """A ROS 2 Python launch file that publishes each transform on /tf_static (tf2_ros static_transform_publisher:
    translation in m, rotation as a unit quaternion); `source` says where the poses come from (its first line)."""
    nodes = []
    for t in transforms:
        x, y, z = (float(v) for v in t.T[:3, 3])
        qx, qy, qz, qw = quaternion(t.T[:3, :3])
        pose = (("x", x), ("y", y), ("z", z), ("qx", qx), ("qy", qy), ("qz", qz), ("qw", qw))
        args = [f'"--{k}", "{v!r}"' for k, v in pose]
        nodes.append(
            "        Node(\n"
            '            package="tf2_ros",\n'
            '            executable="static_transform_publisher",\n'
            f'            name="{t.node}",\n'
            f"            arguments=[{', '.join(args)},\n"
            f'                       "--frame-id", "{t.parent}", "--child-frame-id", "{t.child}"],\n'
            "        ),\n"
        )
    return (
        f"# {source}: published on /tf_static.\n"
        "from launch import LaunchDescription\n"
        "from launch_ros.actions import Node\n\n\n"
        "def generate_launch_description():\n"
        "    return LaunchDescription([\n"
        f"{''.join(nodes)}"
        "    ])\n"
    )


def quaternion(R: np.ndarray) -> tuple[float, float, float, float]:
    """R as a unit quaternion (x, y, z, w), w >= 0."""
    from scipy.spatial.transform import Rotation

    q = Rotation.from_matrix(R).as_quat()
    q = q if q[3] >= 0 else -q
    return float(q[0]), float(q[1]), float(q[2]), float(q[3])


def _root(urdf: str) -> etree._Element:
    return etree.fromstring(urdf.encode("utf-8"), etree.XMLParser(resolve_entities=False, no_network=True))
