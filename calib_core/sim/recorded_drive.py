"""A simulated robot's drive recorded as a ROS 1 or ROS 2 bag (rosbags): what `calib import-bag` reads from a
real robot, made without one, for the tests and the sample bag (scripts/make_samples.py).

The robot drives through poses and holds each; its joint states are published at 50 Hz (the encoders'
rounding plus a flicker of one step), its camera images at a given rate, rendered by the simulator at
wherever the robot is, moving or not.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path

import cv2
import numpy as np
from rosbags.rosbag1 import Writer as Writer1
from rosbags.rosbag2 import Writer as Writer2
from rosbags.typesys import Stores, get_typestore

from ..model.loader import load_profile
from .simulator import SimulatedRobot

EPOCH_NS = 1_700_000_000 * 10**9
JOINT_RATE_HZ = 50.0


# --- a drive ------------------------------------------------------------------------------------------


@dataclass
class Drive:
    """A robot driven through poses (rad, the readings the robot reports unrounded), holding each."""

    robot: SimulatedRobot
    poses_rad: np.ndarray  # (P, n_joints)
    targets: np.ndarray  # (P,)
    hold_s: float
    move_s: float
    pause_at: int | None = None  # in this move the robot stops halfway (0.45 s: too short to count)
    joint_times_s: np.ndarray = field(init=False)
    joint_readings_rad: np.ndarray = field(init=False)

    def holds(self) -> list[tuple[float, float]]:
        return [
            (k * (self.hold_s + self.move_s), k * (self.hold_s + self.move_s) + self.hold_s) for k in range(len(self))
        ]

    def __len__(self) -> int:
        return len(self.poses_rad)

    @property
    def duration_s(self) -> float:
        return len(self) * self.hold_s + (len(self) - 1) * self.move_s

    def at(self, t_s: float) -> tuple[np.ndarray, int]:
        """Where the robot is at time t, and the target of the pose it is nearest in time."""
        period = self.hold_s + self.move_s
        k = min(int(t_s // period), len(self) - 1)
        into = t_s - k * period
        if into <= self.hold_s or k == len(self) - 1:
            return self.poses_rad[k].copy(), int(self.targets[k])
        s = (into - self.hold_s) / self.move_s
        w = 0.5 - 0.5 * math.cos(math.pi * s)  # smooth start and stop
        if self.pause_at == k:  # two smooth half moves, 0.45 of the move time still between them
            u = min(s / 0.275, 1.0) if s < 0.725 else (s - 0.725) / 0.275
            w = (0.0 if s < 0.725 else 0.5) + 0.25 - 0.25 * math.cos(math.pi * u)
        q = (1 - w) * self.poses_rad[k] + w * self.poses_rad[k + 1]
        return q, int(self.targets[k if w < 0.5 else k + 1])

    def record_joints(self, rng: np.random.Generator) -> None:
        self.joint_times_s = np.arange(0.0, self.duration_s, 1 / JOINT_RATE_HZ)
        q = np.array([self.at(t)[0] for t in self.joint_times_s])
        flicker = rng.normal(0.0, math.radians(0.03), q.shape)  # near a step's edge the reading flips
        self.joint_readings_rad = self.robot.readings(q + flicker)


def make_drive(profile_name: str, n_poses: int, seed: int, **kwargs) -> Drive:
    """n_poses the simulated robot can measure (spread over its plan), its joint states recorded."""
    profile = load_profile(profile_name)
    robot = SimulatedRobot.from_profile(profile, seed=seed)
    q, targets = robot.configurations(n_poses)
    pick = np.linspace(0, len(q) - 1, n_poses).round().astype(int)  # NAO: both legs' boards
    recorded = Drive(robot, q[pick], targets[pick], **kwargs)
    recorded.record_joints(np.random.default_rng(seed))
    return recorded


@dataclass
class Images:
    """Camera images of a drive: per role, times (s from the start) and pictures (grey uint8)."""

    times_s: np.ndarray
    pictures: dict[str, list[np.ndarray]]


def camera_images(drive: Drive, rate_hz: float, *, start_s: float = 0.11, seed: int = 1) -> Images:
    """The data sensor's images every 1 / rate_hz s from start_s, each drawn by the finder of the target the
    drive shows then (calib_core.vision.finders), its noise from a stream seeded by `seed`."""
    times = np.arange(start_s, drive.duration_s, 1 / rate_hz)
    rng = np.random.default_rng(seed)
    robot = drive.robot
    roles = robot.profile.sensors[robot.profile.data.sensor].image_roles
    pictures: dict[str, list[np.ndarray]] = {role: [] for role in roles}
    for t in times:
        q, target = drive.at(t)
        rendered = robot.finder(target).render(robot.true_params, q, rng)
        for role in roles:
            pictures[role].append(rendered.images[role])
    return Images(times, pictures)


# --- writing bags ----------------------------------------------------------------------------------------------


@dataclass
class BagSpec:
    ros: int  # 1 or 2
    joint_topic: str = "/joint_states"
    image_topics: dict[str, str] = field(default_factory=lambda: {"image": "/camera/image"})
    compressed: bool = False  # sensor_msgs/CompressedImage (JPEG) instead of Image (mono8)
    jpeg_quality: int = 95
    stamps: bool = True  # header stamps; False: zero stamps, the bag's record times only
    drop_joint: str | None = None  # leave this joint out of every message
    names: dict[str, str] = field(default_factory=dict)  # profile joint -> name in the messages


def write_bag(path: Path, drive: Drive, images: Images, spec: BagSpec) -> Path:
    """The drive as a ROS 1 or ROS 2 bag; images are received 30 ms after their stamp."""
    store = get_typestore(Stores.ROS1_NOETIC if spec.ros == 1 else Stores.ROS2_HUMBLE)
    types = store.types
    Time, Header = types["builtin_interfaces/msg/Time"], types["std_msgs/msg/Header"]
    serialize = store.serialize_ros1 if spec.ros == 1 else store.serialize_cdr

    def header(t_s: float, seq: int) -> object:
        ns = EPOCH_NS + round(t_s * 1e9) if spec.stamps else 0
        stamp = Time(sec=ns // 10**9, nanosec=ns % 10**9)
        return Header(seq=seq, stamp=stamp, frame_id="") if spec.ros == 1 else Header(stamp=stamp, frame_id="")

    messages = []  # (record time ns, topic, type, message)
    prof = drive.robot.profile
    names = [spec.names.get(j.name, j.name) for j in prof.joints]
    keep = [i for i, j in enumerate(prof.joints) if j.name != spec.drop_joint]
    JointState = types["sensor_msgs/msg/JointState"]
    for k, (t, q) in enumerate(zip(drive.joint_times_s, drive.joint_readings_rad, strict=True)):
        msg = JointState(
            header=header(t, k),
            name=[names[i] for i in keep],
            position=q[keep].astype(np.float64),
            velocity=np.zeros(0),
            effort=np.zeros(0),
        )
        messages.append((EPOCH_NS + round(t * 1e9) + 2_000_000, spec.joint_topic, JointState.__msgtype__, msg))
    for role, topic in spec.image_topics.items():
        for k, (t, picture) in enumerate(zip(images.times_s, images.pictures[role], strict=True)):
            if spec.compressed:
                ok, buf = cv2.imencode(".jpg", picture, [cv2.IMWRITE_JPEG_QUALITY, spec.jpeg_quality])
                if not ok:
                    raise ValueError("OpenCV could not encode an image as JPEG")
                typ = types["sensor_msgs/msg/CompressedImage"]
                msg = typ(header=header(t, k), format="jpeg", data=buf.ravel())
            else:
                typ = types["sensor_msgs/msg/Image"]
                h, w = picture.shape
                msg = typ(
                    header=header(t, k),
                    height=h,
                    width=w,
                    encoding="mono8",
                    is_bigendian=0,
                    step=w,
                    data=picture.ravel(),
                )
            messages.append((EPOCH_NS + round(t * 1e9) + 30_000_000, topic, typ.__msgtype__, msg))
    messages.sort(key=lambda m: m[0])
    writer = Writer1(path) if spec.ros == 1 else Writer2(path, version=9)
    with writer:
        conns = {}
        for _, topic, typ, _ in messages:
            if topic not in conns:
                conns[topic] = writer.add_connection(topic, typ, typestore=store)
        for ns, topic, typ, msg in messages:
            writer.write(conns[topic], ns, serialize(msg, typ))
    return path
