"""The ROS 2 connection file (specs ros2.md) and what `calib serve --ros2` does with it before the desk starts.

    robot: iiwa                       # the robot's name on the desk
    profile: iiwa-mocap.yaml          # a profile file (relative to this file) or a built-in profile's name;
                                      # `urdf: ros2` in it: the URDF received on description_topic
    description_topic: /robot_description
    joint_states: /joint_states
    command: /joint_trajectory_controller/joint_trajectory
    measurements: {mocap: {topic: /mocap/marker}}       # or {topic: .../image_raw, info: .../camera_info}
    # a stereo head (extension): {left: .../left/image_rect, left_info: .../left/camera_info,
    #                             right: .../right/image_rect, right_info: .../right/camera_info}
    apply: {node: /robot_state_publisher, parameter: robot_description}   # optional
    # extension: frames: {camera_mount: camera_color_optical_frame} (frames.py), the node optional with it

Extensions of the contract (optional, with their defaults): `wait_s: 30` (how long `calib serve` waits for
the robot's description and joint states), `timeout_s: 1.0` (joint states older than this: disconnected),
`tolerance_deg: 0.1` (a move has arrived within this of its target), `still_deg: 0.005` (joint states that
change less than this stand still: above the encoders' jitter), `tolerance_m: 0.0005` and `still_m: 0.00005`
(the same for prismatic joints, in metres), `measurement_wait_s: 2.0` (how long a
capture waits for a measurement newer than the settling), `margin_deg: 1.0` and `margin_m: 0.001` (the joint
limits' safety margin, revolute and prismatic), `apply_timeout_s: 5.0` (the parameter call),
`stereo_sync_s: 0.005` (a stereo pair's left and right images are one exposure when their stamps differ by at
most this), `settle_s: 0.3` (a capture looks once the joint states stayed still this long: more for a robot
that sways after a move; `calib sim-ros2 --speed N` writes 0.3 / N, its robot settling N times as fast).

A stereo head's entry (an extension of the contract) names its rectified pair: two sensor_msgs/Image topics
and their CameraInfo (the left's K gives the intrinsics, the right's P the baseline, as a ROS stereo driver or
stereo_image_proc publishes them).

A Meeting listens for the robot from the first moment; connect() then checks everything on the live graph
before the desk starts (the description is a URDF the profile compiles with, the joint states name every joint
of the profile, each topic that exists has the type the contract says) and only then writes the received URDF
and the profile that uses it into the data directory (`ros2/<robot>/`). The URDF first received is the nominal
model, kept there: a later start that receives the calibrated URDF the desk applied keeps the stored nominal
one.
"""

from __future__ import annotations

import tempfile
import threading
import time
from collections.abc import Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import TYPE_CHECKING, Protocol, TypedDict

import yaml

from calib_core import InputError, Profile, load_profile
from calib_core.files import write_atomic
from calib_core.model import BUILTIN_PROFILES
from calib_core.safe_yaml import read_yaml

from ..connection_file import profile_ref, read_connection
from ..core import DEFAULT_SETTLE_S
from . import require
from .frames import check_frames, read_frames

if TYPE_CHECKING:
    from ..registry import Options
    from .link import Link

FIELDS = ("robot", "profile", "description_topic", "joint_states", "command", "measurements", "apply")
OPTIONS = {
    "wait_s": 30.0,
    "timeout_s": 1.0,
    "tolerance_deg": 0.1,
    "tolerance_m": 0.0005,
    "still_deg": 0.005,
    "still_m": 0.00005,
    "measurement_wait_s": 2.0,
    "margin_deg": 1.0,
    "margin_m": 0.001,
    "apply_timeout_s": 5.0,
    "stereo_sync_s": 0.005,
    "settle_s": DEFAULT_SETTLE_S,
}
URDF_FROM_GRAPH = "ros2"  # a profile's `urdf: ros2`
TYPES = {
    "description": "std_msgs/msg/String",
    "joint_states": "sensor_msgs/msg/JointState",
    "command": "trajectory_msgs/msg/JointTrajectory",
    "point": "geometry_msgs/msg/PointStamped",
    "image": "sensor_msgs/msg/Image",
    "info": "sensor_msgs/msg/CameraInfo",
}


STEREO_KEYS = ("left", "left_info", "right", "right_info")


@dataclass(frozen=True)
class Measurement:
    sensor: str
    topic: str  # a point sensor's PointStamped, a camera's Image, a stereo head's left Image
    info: str | None = None  # a camera's (a stereo head's left) CameraInfo topic
    right: str | None = None  # a stereo head's right Image ...
    right_info: str | None = None  # ... and its CameraInfo

    @property
    def kind(self) -> str:
        """ "point", "image" or "stereo"."""
        return "stereo" if self.right is not None else "image" if self.info is not None else "point"

    def topics(self) -> dict[str, tuple[str, str]]:
        """Its topics: the field name in the connection file -> (topic, the contract's type)."""
        if self.kind == "stereo":
            assert self.info is not None and self.right is not None and self.right_info is not None
            pairs = zip(STEREO_KEYS, (self.topic, self.info, self.right, self.right_info), strict=True)
            return {key: (topic, TYPES["info" if key.endswith("info") else "image"]) for key, topic in pairs}
        if self.kind == "image":
            assert self.info is not None
            return {"topic": (self.topic, TYPES["image"]), "info": (self.info, TYPES["info"])}
        return {"topic": (self.topic, TYPES["point"])}


@dataclass(frozen=True)
class Connection:
    path: Path
    robot: str
    profile: str  # a built-in profile's name or an absolute path
    description_topic: str
    joint_states: str
    command: str
    measurements: tuple[Measurement, ...]
    apply_node: str | None = None
    apply_parameter: str | None = None
    options: dict[str, float] = field(default_factory=lambda: dict(OPTIONS))
    apply_frames: dict[str, str] = field(default_factory=dict)  # profile frame -> its link's name (frames.py)

    @property
    def urdf_from_graph(self) -> bool:
        """The profile says `urdf: ros2`."""
        if self.profile in BUILTIN_PROFILES:
            return False
        doc = read_yaml(Path(self.profile), "robot profile file")
        return isinstance(doc, dict) and doc.get("urdf") == URDF_FROM_GRAPH

    def load_profile(self, urdf: Path | None) -> Profile:
        """The robot's profile, named after the robot; `urdf`: the URDF received (for `urdf: ros2`)."""
        if self.urdf_from_graph and urdf is None:
            raise InputError(f"profile {self.profile} says urdf: ros2 and no URDF was received", file=str(self.path))
        profile = load_profile(self.profile, urdf=urdf if self.urdf_from_graph else None)
        return replace(profile, name=self.robot)


def load_connection(path: Path) -> Connection:
    """Read and check a connection file; InputError naming the file and the field."""
    path = Path(path).resolve()
    file = str(path)
    doc = read_connection(path, "ROS 2 connection file", "robot, profile, topics", FIELDS + tuple(OPTIONS))
    profile = profile_ref(_text(doc, "profile", file), path)
    topics = {k: _topic(doc, k, file) for k in ("description_topic", "joint_states", "command")}
    items = doc.get("measurements")
    if not isinstance(items, dict) or not items:
        raise InputError("measurements: expected one entry per sensor, {sensor: {topic: ...}}", file=file)
    measurements = []
    for sensor, spec in items.items():
        where = f"measurements.{sensor}"
        if isinstance(spec, dict) and set(spec) == set(STEREO_KEYS):
            left, left_info, right, right_info = (_topic(spec, key, file, where) for key in STEREO_KEYS)
            measurements.append(Measurement(str(sensor), left, left_info, right, right_info))
            continue
        if not isinstance(spec, dict) or set(spec) - {"topic", "info"} or "topic" not in spec:
            raise InputError(
                f"{where}: expected {{topic: ...}}, {{topic: ..., info: ...}} or a stereo pair "
                "{left: ..., left_info: ..., right: ..., right_info: ...}",
                file=file,
            )
        info = _topic(spec, "info", file, where) if "info" in spec else None
        measurements.append(Measurement(str(sensor), _topic(spec, "topic", file, where), info))
    apply_node = apply_parameter = None
    frames: dict[str, str] = {}
    if doc.get("apply") is not None:
        spec = doc["apply"]
        keys = set(spec) if isinstance(spec, dict) else None  # node and parameter, frames with or without them
        if keys not in ({"node", "parameter"}, {"node", "parameter", "frames"}, {"frames"}):
            raise InputError(
                "apply: expected {node: /robot_state_publisher, parameter: robot_description}, optionally with "
                "frames: {profile frame: link name}",
                file=file,
            )
        if "node" in spec:
            apply_node = _topic(spec, "node", file, "apply")
            apply_parameter = _text(spec, "parameter", file, "apply")
        if "frames" in spec:
            frames = read_frames(spec["frames"], file)
    options = dict(OPTIONS)
    for key in OPTIONS:
        if key in doc:
            value = doc[key]
            if isinstance(value, bool) or not isinstance(value, int | float) or not 0 < value < 1e6:
                raise InputError(f"{key}: expected a positive number, got {value!r}", file=file)
            options[key] = float(value)
    conn = Connection(
        path, doc["robot"], profile, *topics.values(), tuple(measurements), apply_node, apply_parameter, options, frames
    )
    if not conn.urdf_from_graph:
        check_against(conn, conn.load_profile(None))
    return conn


def check_against(conn: Connection, profile: Profile, urdf: Path | None = None) -> None:
    """The connection's sensors and apply.frames against the robot's profile (InputError naming the field); `urdf`:
    the URDF received, which a profile of `urdf: ros2` was loaded with."""
    _check_sensors(conn, profile)
    if conn.apply_frames:
        from calib_core.io import calibrated_links

        check_frames(conn.apply_frames, profile, calibrated_links(profile, urdf), str(conn.path))


def _check_sensors(conn: Connection, profile: Profile) -> None:
    from calib_core.vision import finders_served, found_targets  # OpenCV: only once a profile is checked

    file = str(conn.path)
    names = [s.name for s in profile.sensors]
    for m in conn.measurements:
        if m.sensor not in names:
            raise InputError(
                f"measurements.{m.sensor}: no such sensor in the profile (sensors: {', '.join(names)})", file=file
            )
        sensor = profile.sensors[names.index(m.sensor)]
        # What travels on the topics: the images one reading takes (Sensor.image_roles), or a point.
        pair, camera = sensor.image_roles == ("left", "right"), sensor.image_roles == ("image",)
        if m.kind == "stereo" and not pair:
            raise InputError(f"measurements.{m.sensor}: a stereo pair for a sensor that is no stereo head", file=file)
        if camera and m.info is None:
            raise InputError(f"measurements.{m.sensor}: a camera needs `info` (its CameraInfo topic)", file=file)
        if pair and m.kind != "stereo":
            raise InputError(
                f"measurements.{m.sensor}: a stereo head needs its pair {{left: ..., left_info: ..., right: ..., "
                "right_info: ...}",
                file=file,
            )
        if not (pair or camera or (not sensor.image_roles and sensor.dim == 3)):
            raise InputError(
                f"measurements.{m.sensor}: the ROS 2 driver reads point sensors (PointStamped), cameras "
                f"(Image + CameraInfo) and stereo heads (two of each), not a {sensor.reading} sensor",
                file=file,
            )
    data_sensor = profile.sensors[profile.data.sensor].name
    if data_sensor not in {m.sensor for m in conn.measurements}:
        raise InputError(f"measurements: the profile's data sensor '{data_sensor}' needs a topic", file=file)
    if profile.sensors[profile.data.sensor].image_roles and not found_targets(profile, profile.data.sensor):
        raise InputError(
            f"measurements.{data_sensor}: no finder sees the profile's targets in its images "
            f"(finders: {finders_served()})",
            file=file,
        )


# --- before the desk starts ---------------------------------------------------------------------------------

_pending: dict[str, Link] = {}  # connection path -> the link connect() opened, taken by the driver
_pending_lock = threading.Lock()


def take_pending(path: str) -> Link | None:
    """The link connect() opened for this connection file (None when there is none)."""
    with _pending_lock:
        return _pending.pop(path, None)


def robot_dir(data_dir: Path, robot: str) -> Path:
    return Path(data_dir) / "ros2" / robot


class _Text(Protocol):
    """What a meeting reads of a std_msgs/String (the robot description)."""

    data: str


class _Names(Protocol):
    """What a meeting reads of a sensor_msgs/JointState."""

    name: Sequence[str]


class Met(TypedDict, total=False):
    """What a meeting received: the description's text, the joint states' names (each missing until it came)."""

    urdf: str
    joints: list[str]


class Meeting:
    """A robot being met: its link open and listening for its description and joint states, which DDS delivers
    while the caller does other work (a late joiner waits up to seconds for a latched description)."""

    def __init__(self, conn: Connection) -> None:
        require()
        from sensor_msgs.msg import JointState
        from std_msgs.msg import String

        from .link import LATCHED_QOS, SENSOR_QOS, Link

        self.conn = conn
        self.link = Link(f"calib_desk_{_node_name(conn.robot)}")
        self.got: Met = {}
        self._ready = threading.Event()
        self._listening = [
            self.link.listen(String, conn.description_topic, LATCHED_QOS, self._on_description),
            self.link.listen(JointState, conn.joint_states, SENSOR_QOS, self._on_joints),
        ]
        print(
            f"calib serve: waiting for {conn.robot} on the ROS 2 graph ({conn.description_topic}, {conn.joint_states})"
        )

    def _on_description(self, msg: _Text) -> None:
        self.got.setdefault("urdf", msg.data)  # the first received is the nominal one
        self._ready.set()

    def _on_joints(self, msg: _Names) -> None:
        self.got["joints"] = list(msg.name)
        self._ready.set()

    def wait(self) -> Met:
        """What came within the connection's wait_s ({urdf, joints}, either missing if it did not); the
        listeners stop then (the joint states go on to the driver's listener alone)."""
        deadline = time.monotonic() + self.conn.options["wait_s"]
        while not ("urdf" in self.got and "joints" in self.got) and time.monotonic() < deadline:
            self._ready.wait(0.05)
            self._ready.clear()
        for stop in self._listening:
            stop()
        return self.got.copy()

    def close(self) -> None:
        self.link.close()


def connect(meeting: Meeting, data_dir: Path) -> tuple[str, Options]:
    """Meet the robot on its graph (what `meeting` receives) and check it (InputError naming what is wrong;
    nothing is written then). Returns the profile reference the desk loads the robot with and the driver's
    options; the link stays open for the driver."""
    conn, link = meeting.conn, meeting.link
    try:
        got = meeting.wait()
        wait_s = conn.options["wait_s"]
        hint = "is the robot running, with the same ROS_DOMAIN_ID and discovery range as the desk?"
        if "urdf" not in got:
            raise InputError(
                f"no robot description on {conn.description_topic} within {wait_s:g} s: {hint}", file=str(conn.path)
            )
        if "joints" not in got:
            raise InputError(f"no joint states on {conn.joint_states} within {wait_s:g} s: {hint}", file=str(conn.path))
        data_dir = Path(data_dir).resolve()
        folder = robot_dir(data_dir, conn.robot)
        urdf_text = _nominal(folder, got["urdf"])
        with tempfile.TemporaryDirectory() as tmp:
            received = Path(tmp) / "robot_description.urdf"
            received.write_text(urdf_text, encoding="utf-8")
            try:
                profile = conn.load_profile(received)
            except InputError as exc:
                if exc.file != str(received):
                    raise
                line = f", line {exc.line}" if exc.line else ""
                raise InputError(
                    f"the robot description on {conn.description_topic} is not a URDF this robot's profile can use "
                    f"(the message's text{line}): {exc.message}",
                    file=str(conn.path),
                ) from None
            check_against(conn, profile, received if conn.urdf_from_graph else None)
        missing = [j.name for j in profile.joints if j.name not in got["joints"]]
        if missing:
            raise InputError(
                f"the joint states on {conn.joint_states} name {', '.join(got['joints']) or 'no joint'}; the profile's "
                f"joint(s) {', '.join(missing)} are not among them (names are matched to the URDF's joints)",
                file=str(conn.path),
            )
        _check_types(conn, link)
        if conn.urdf_from_graph:
            nominal = folder / "nominal.urdf"
            if not nominal.is_file() or nominal.read_text(encoding="utf-8") != urdf_text:
                write_atomic(nominal, urdf_text)
            doc = read_yaml(Path(conn.profile), "robot profile file")
            doc["urdf"] = "nominal.urdf"
            write_atomic(folder / "profile.yaml", yaml.safe_dump(doc, sort_keys=False))
            ref = str((folder / "profile.yaml").relative_to(data_dir))  # the desk loads it relative to its data
        else:
            write_atomic(folder / "nominal.urdf", urdf_text)
            ref = conn.profile
    except BaseException:
        link.close()
        raise
    with _pending_lock:
        _pending[str(conn.path)] = link
    return ref, {"connection": str(conn.path), "files": str(folder)}


def _nominal(folder: Path, received: str) -> str:
    """The nominal URDF: the one received, unless it is the calibrated URDF this desk applied last (the robot
    re-publishes what apply set), whose nominal one is kept."""
    applied, nominal = folder / "applied.urdf", folder / "nominal.urdf"
    if applied.is_file() and nominal.is_file() and applied.read_text(encoding="utf-8") == received:
        return nominal.read_text(encoding="utf-8")
    return received


def _check_types(conn: Connection, link: Link, settle_s: float = 2.0) -> None:
    """Each topic of the connection that the graph knows must carry the contract's type (the graph is given
    up to settle_s to show every measurement topic: discovery lags behind the first messages)."""
    topics = {topic for m in conn.measurements for topic, _ in m.topics().values()}
    deadline = time.monotonic() + settle_s
    types = link.topic_types()
    while not topics <= set(types) and time.monotonic() < deadline:
        time.sleep(0.05)
        types = link.topic_types()
    want = [
        ("description_topic", conn.description_topic, TYPES["description"]),
        ("joint_states", conn.joint_states, TYPES["joint_states"]),
        ("command", conn.command, TYPES["command"]),
    ]
    for m in conn.measurements:
        want += [(f"measurements.{m.sensor}.{key}", topic, type_) for key, (topic, type_) in m.topics().items()]
    for where, topic, expected in want:
        have = types.get(topic)
        if have and expected not in have:
            raise InputError(f"{where}: {topic} carries {', '.join(have)}, not {expected}", file=str(conn.path))


def _node_name(robot: str) -> str:
    return "".join(c if c.isalnum() or c == "_" else "_" for c in robot)


def _text(doc: dict, key: str, file: str, where: str = "") -> str:
    value = doc.get(key)
    name = f"{where}.{key}" if where else key
    if not isinstance(value, str) or not value.strip():
        raise InputError(f"{name}: expected a name, got {value!r}", file=file)
    return value.strip()


def _topic(doc: dict, key: str, file: str, where: str = "") -> str:
    value = _text(doc, key, file, where)
    name = f"{where}.{key}" if where else key
    if not value.startswith("/") or any(c.isspace() for c in value):
        raise InputError(f"{name}: expected an absolute ROS 2 name like /joint_states, got {value!r}", file=file)
    return value
