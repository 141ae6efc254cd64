"""A robot on its own ROS 2 graph behind the RobotDriver interface (driver kind `ros2`; specs ros2.md): the
driver core (core.py) over the robot's topics.

Options: `connection` (the connection file, app/drivers/ros2/connection.py) and `files` (the folder in the data
directory where apply writes the calibrated URDF, the offsets YAML and, with `apply.frames`, the launch file that
publishes the named links on /tf_static: frames.py). `calib serve --ros2 FILE` makes both.

Joint readings come from `/joint_states` (matched by name, rad; a prismatic joint's metres in the
profile's length unit). A move is one JointTrajectory of every profile joint, one point, `time_from_start`
the slowest joint's distance over its velocity limit (a trajectory controller interpolates one point
linearly from where the robot stands: no joint is faster than its limit), and is done when the joint
states are within `tolerance_deg` of the target (a prismatic joint: `tolerance_m`); joint states that change
less than `still_deg` (`still_m`) stand still. STOP sends the empty trajectory (the controller stops
and holds). Joint states older than `timeout_s` mean the robot is disconnected (RobotFault, the desk's
503) until they come again. A look waits for a measurement stamped later than the settled joint states
(`measurement_wait_s`), else gives a "not found" sighting saying what was missing or stale. A camera's image
goes through the board detector with the intrinsics of its CameraInfo; a stereo head's pair (left and right
stamped within `stereo_sync_s` of each other, both after the settled joint states) through the project's
stereo matching and BallFinder with the left CameraInfo's intrinsics and the right one's baseline, exactly as
the simulated Robonaut's rendered pair.
"""

from __future__ import annotations

import math
import threading
from collections import deque
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import TYPE_CHECKING, Any, Protocol

import numpy as np

from calib_core import Calibration, InputError, Profile
from calib_core.files import write_atomic
from calib_core.io import calibrated_urdf, grey_image, link_poses, offsets_yaml
from calib_core.units import length_factor
from calib_core.vision import StereoHead

from ...clock import SYSTEM_CLOCK, Clock
from .. import RobotFault
from ..calls import calling
from ..core import Command, Driver, Feed, Measurement, Motion, per_joint
from ..registry import DriverContext
from .frames import launch_file, published

if TYPE_CHECKING:
    from .connection import Connection
    from .connection import Measurement as Topics
    from .link import Link

DURATION_FACTOR = 1.05  # time_from_start this much longer than the fastest the velocity limits allow
MIN_DURATION_S = 0.1
STILL_WINDOW_S = 0.15  # joint states changed within this: moving
MATCH_WAIT_S = 3.0  # how long a move waits for the controller to subscribe to the commands
CALL_SLACK_S = 2.0  # a call's deadline beyond the waits it makes itself (a match, a measurement, a service)
_STEREO_KEEP = 4  # the latest images of each side kept for pairing by stamp


def check(profile: Profile, options: Mapping[str, Any], where: str, options_at: str) -> dict[str, Any]:
    """The options checked (InputError naming `options_at`.<option>): `connection` a connection file (for this
    profile), `files` a folder (optional)."""
    from . import require

    require()
    unknown = sorted(set(options) - {"connection", "files"})
    if unknown:
        raise InputError(f"{options_at}.{unknown[0]}: no such option of the ros2 driver (options: connection, files)")
    path = options.get("connection")
    if not isinstance(path, str) or not path:
        raise InputError(f"{options_at}.connection: expected the ROS 2 connection file")
    files = options.get("files")
    if files is not None and not isinstance(files, str):
        raise InputError(f"{options_at}.files: expected a folder")
    return {"connection": path, "files": files}


def create(profile: Profile, options: Mapping[str, Any], context: DriverContext) -> Driver:
    from .connection import check_against, load_connection, take_pending
    from .link import Link

    path = Path(options["connection"])
    conn = load_connection(path if path.is_absolute() else context.base_dir / path)
    check_against(conn, profile)
    link = take_pending(str(conn.path)) or Link(f"calib_desk_{''.join(c if c.isalnum() else '_' for c in conn.robot)}")
    files = None if options.get("files") is None else Path(options["files"])
    return ros2_driver(profile, conn, link, files=files, clock=context.clock)


class _Stamp(Protocol):
    """A builtin_interfaces/Time (a header's stamp)."""

    sec: int
    nanosec: int


class _Header(Protocol):
    stamp: _Stamp


class _JointState(Protocol):
    """What the driver reads of a sensor_msgs/JointState."""

    header: _Header
    name: Sequence[str]
    position: Sequence[float]


class _Point(Protocol):
    x: float
    y: float
    z: float


class _PointStamped(Protocol):
    """A geometry_msgs/PointStamped."""

    header: _Header
    point: _Point


class _Matched(Protocol):
    """rclpy's MatchedInfo of a publisher's matched event: how many readers it has now."""

    current_count: int


def ros2_driver(
    profile: Profile, conn: Connection, link: Link, *, files: Path | None = None, clock: Clock = SYSTEM_CLOCK
) -> Driver:
    """The driver of the robot a connection file describes, on `link` (its node on the graph)."""
    o = conn.options
    motion = Motion(
        tolerance=per_joint(profile, o["tolerance_deg"], o["tolerance_m"]),
        still=per_joint(profile, o["still_deg"], o["still_m"]),
        margin_deg=o["margin_deg"],
        margin_m=o["margin_m"],
        still_window_s=STILL_WINDOW_S,
        timeout_s=o["timeout_s"],
        duration_factor=DURATION_FACTOR,
        min_duration_s=MIN_DURATION_S,
        settle_s=o["settle_s"],
        call_timeout_s=MATCH_WAIT_S + CALL_SLACK_S,
        measure_timeout_s=o["measurement_wait_s"] + CALL_SLACK_S,
        apply_timeout_s=2 * o["apply_timeout_s"] + CALL_SLACK_S,  # the service found, then its answer
    )
    return Driver(profile, Ros2Transport(profile, conn, link, files), motion, clock=clock)


@dataclass
class _Reading:
    """The latest message of a measurement topic."""

    stamp_s: float = math.nan  # header.stamp (a stereo pair's: the older of its two)
    value: Any = None  # a point (m), an image, or a stereo pair (left, right)
    info: Any = None  # a camera's (a stereo head's left) latest CameraInfo
    right_info: Any = None  # a stereo head's right CameraInfo
    sides: dict[str, deque] = field(
        default_factory=lambda: {side: deque(maxlen=_STEREO_KEEP) for side in ("left", "right")}
    )  # a stereo head's latest images of each side, (stamp s, Image)


class Ros2Transport:
    """The robot's topics: joint states in, one JointTrajectory a move out, the empty one to stop, the
    measurement topics read for a look; apply sets a node's parameter (Deploys)."""

    def __init__(self, profile: Profile, conn: Connection, link: Link, files: Path | None) -> None:
        self.profile = profile
        self.conn = conn
        self.link = link
        self.files = files
        self.readings_from = f"joint states on {conn.joint_states}"
        self._scale = np.array(
            [length_factor("m", profile.length_unit) if j.prismatic else 1.0 for j in profile.joints]
        )
        self._lock = threading.Lock()
        self._fresh = threading.Event()  # a measurement came
        self._closing = threading.Event()
        self.controller = threading.Event()  # something subscribes to the commands
        self._joints_at = -math.inf  # when joint states last came, the clock's s
        self._readings = {m.sensor: _Reading() for m in conn.measurements}
        self._set_parameters = None

    def start(self, feed: Feed, clock: Clock) -> None:
        from geometry_msgs.msg import PointStamped
        from rcl_interfaces.srv import SetParameters
        from rclpy.event_handler import PublisherEventCallbacks
        from sensor_msgs.msg import CameraInfo, Image, JointState
        from trajectory_msgs.msg import JointTrajectory

        from .link import COMMAND_QOS, SENSOR_QOS

        self.feed, self.clock = feed, clock
        conn, node = self.conn, self.link.node
        self._trajectory_type = JointTrajectory
        matched = PublisherEventCallbacks(matched=self._on_matched)
        self._command = node.create_publisher(JointTrajectory, conn.command, COMMAND_QOS, event_callbacks=matched)
        listen = self.link.listen
        listen(JointState, conn.joint_states, SENSOR_QOS, self._on_joints)
        for m in conn.measurements:
            if m.kind == "point":
                listen(PointStamped, m.topic, SENSOR_QOS, self._on_point(m.sensor))
            elif m.kind == "image":
                assert m.info is not None  # what makes it an image (Topics.kind)
                listen(Image, m.topic, SENSOR_QOS, self._on_image(m.sensor))
                listen(CameraInfo, m.info, SENSOR_QOS, self._on_info(m.sensor))
            else:
                assert m.info is not None and m.right is not None and m.right_info is not None  # a stereo head's
                listen(Image, m.topic, SENSOR_QOS, self._on_side(m.sensor, "left"))
                listen(Image, m.right, SENSOR_QOS, self._on_side(m.sensor, "right"))
                listen(CameraInfo, m.info, SENSOR_QOS, self._on_info(m.sensor))
                listen(CameraInfo, m.right_info, SENSOR_QOS, self._on_info(m.sensor, "right_info"))
        if conn.apply_node is not None:
            self._set_parameters = node.create_client(SetParameters, f"{conn.apply_node.rstrip('/')}/set_parameters")

    # --- the graph's callbacks ------------------------------------------------------------------------
    def _on_matched(self, info: _Matched) -> None:
        """The controller subscribed to the commands (or left)."""
        if info.current_count > 0:
            self.controller.set()
        else:
            self.controller.clear()

    def _on_joints(self, msg: _JointState) -> None:
        index = {name: k for k, name in enumerate(msg.name)}
        missing = [j.name for j in self.profile.joints if j.name not in index or index[j.name] >= len(msg.position)]
        if missing:
            self.feed.on_lost(f"the joint states on {self.conn.joint_states} lack {', '.join(missing)}")
            return
        q = np.array([msg.position[index[j.name]] for j in self.profile.joints]) * self._scale
        self._joints_at = self.clock.now()
        self.feed.on_joints(q, _stamp_s(msg.header.stamp))

    def _on_point(self, sensor: str) -> Callable[[_PointStamped], None]:
        def on(msg: _PointStamped) -> None:
            with self._lock:
                r = self._readings[sensor]
                r.stamp_s, r.value = _stamp_s(msg.header.stamp), np.array([msg.point.x, msg.point.y, msg.point.z])
            self._fresh.set()

        return on

    def _on_image(self, sensor: str) -> Callable[[Any], None]:
        def on(msg: Any) -> None:
            with self._lock:
                r = self._readings[sensor]
                r.stamp_s, r.value = _stamp_s(msg.header.stamp), msg
            self._fresh.set()

        return on

    def _on_info(self, sensor: str, which: str = "info") -> Callable[[Any], None]:
        def on(msg: Any) -> None:
            with self._lock:
                setattr(self._readings[sensor], which, msg)

        return on

    def _on_side(self, sensor: str, side: str) -> Callable[[Any], None]:
        """A stereo head's image: kept, and the newest left/right pair whose stamps agree becomes the reading."""
        sync_s = self.conn.options["stereo_sync_s"]
        other = "right" if side == "left" else "left"

        def on(msg: Any) -> None:
            stamp = _stamp_s(msg.header.stamp)
            with self._lock:
                r = self._readings[sensor]
                r.sides[side].append((stamp, msg))
                match = [(s, m) for s, m in r.sides[other] if abs(s - stamp) <= sync_s]
                if match and not min(stamp, match[-1][0]) <= r.stamp_s:
                    pair = (msg, match[-1][1]) if side == "left" else (match[-1][1], msg)
                    r.stamp_s, r.value = min(stamp, match[-1][0]), pair
                    self._fresh.set()

        return on

    # --- moving ---------------------------------------------------------------------------------------
    def send(self, command: Command) -> None:
        """One JointTrajectory, once the controller subscribes (reliable delivery needs a matched reader)."""
        calling(f"the controller on {self.conn.command}")
        if self._command.get_subscription_count() == 0 and not self.clock.wait(self.controller, MATCH_WAIT_S):
            raise RobotFault(f"nothing subscribes to {self.conn.command} (is the controller running?)")
        self._command.publish(self._trajectory(command.goal, command.duration_s))

    def halt(self) -> None:
        """The empty trajectory: the controller stops and holds where it is (never a jump). A topic says nothing of
        its delivery: a robot whose joint states stopped coming is not taken to have heard it (RobotFault)."""
        calling(f"the controller on {self.conn.command}")
        msg = self._trajectory_type()
        msg.joint_names = [j.name for j in self.profile.joints]
        if not self._closing.is_set():
            self._command.publish(msg)
        silent_s = self.clock.now() - self._joints_at
        if silent_s > self.conn.options["timeout_s"]:
            since = "yet" if math.isinf(silent_s) else f"for {silent_s:.1f} s"
            raise RobotFault(
                f"the empty trajectory went out on {self.conn.command}, but no joint states came on "
                f"{self.conn.joint_states} {since}: the robot may not have it"
            )

    def _trajectory(self, goal: np.ndarray, duration_s: float) -> Any:
        from builtin_interfaces.msg import Duration
        from trajectory_msgs.msg import JointTrajectoryPoint

        msg = self._trajectory_type()  # header.stamp zero: start on receipt
        msg.joint_names = [j.name for j in self.profile.joints]
        seconds = math.floor(duration_s)
        point = JointTrajectoryPoint(
            positions=[float(v) for v in goal / self._scale],
            time_from_start=Duration(sec=int(seconds), nanosec=int((duration_s - seconds) * 1e9)),
        )
        msg.points = [point]
        return msg

    # --- seeing ---------------------------------------------------------------------------------------
    def measure(self, since_s: float, target: int) -> Measurement:
        """The data sensor's first measurement stamped after `since_s` (the joint states the robot stands at),
        waited for up to `measurement_wait_s`; else why there is none."""
        sensor = self.profile.sensors[self.profile.data.sensor]
        m = next(m for m in self.conn.measurements if m.sensor == sensor.name)
        topic = m.topic if m.kind != "stereo" else f"{m.topic} and {m.right}"
        calling(f"a measurement on {topic}")
        wait_s = self.conn.options["measurement_wait_s"]
        deadline = self.clock.now() + wait_s
        r = self._readings[sensor.name]
        while True:
            with self._lock:
                stamp, value, info, right_info = r.stamp_s, r.value, r.info, r.right_info
                latest = {side: images[-1][0] if images else math.nan for side, images in r.sides.items()}
                if stamp > since_s or self.clock.now() >= deadline:
                    break
                self._fresh.clear()  # under the lock the callbacks take: a measurement after this sets it again
            self.clock.wait(self._fresh, deadline - self.clock.now())
        if not stamp > since_s:
            if math.isnan(stamp) and m.kind == "stereo":
                return Measurement(missing=_unpaired(m, latest, self.conn.options["stereo_sync_s"], wait_s))
            if math.isnan(stamp):
                reason = f"no measurement on {topic} (none received within {wait_s:g} s)"
                carried = self.link.topic_types().get(topic)
                want = "sensor_msgs/msg/Image" if sensor.image_roles == ("image",) else "geometry_msgs/msg/PointStamped"
                if carried and want not in carried:
                    reason += f": it carries {', '.join(carried)}, not {want}"
                return Measurement(missing=reason)
            return Measurement(
                missing=f"stale measurement on {topic}: the latest is stamped {since_s - stamp:.3f} s before the "
                f"settled joint states (none newer within {wait_s:g} s)"
            )
        if m.kind == "stereo":
            return self._stereo(value, info, right_info, m)
        if sensor.image_roles == ("image",):  # a camera: one Image and its CameraInfo
            return self._image(value, info, topic)
        detail = {"sensor": topic, "stamp_after_settled_s": round(stamp - since_s, 4)}
        return Measurement(point=value * length_factor("m", self.profile.length_unit), detail=detail)

    def _image(self, msg: Any, info: Any, topic: str) -> Measurement:
        """A camera's image, with the intrinsics of its CameraInfo."""
        if info is None:
            return Measurement(missing=f"no CameraInfo for {topic} yet")
        try:
            image = grey_image(msg)
        except ValueError as exc:
            return Measurement(missing=f"{topic}: {exc}")
        sensor = self.profile.sensors[self.profile.data.sensor]
        size = sensor.image_size_px()
        if size is not None and image.shape != (size[1], size[0]):
            return Measurement(
                missing=f"{topic}: images of {image.shape[1]} x {image.shape[0]} px, but the camera of robot "
                f"'{self.profile.name}' (its intrinsics) has {size[0]} x {size[1]} px"
            )
        k = info.k
        return Measurement(images={"image": image}, intrinsics_px=(k[0], k[4], k[2], k[5]))

    def _stereo(self, pair: Any, left_info: Any, right_info: Any, m: Topics) -> Measurement:
        """A rectified pair, with the head its CameraInfo messages describe: the intrinsics from the left one's
        K, the baseline from the right one's P (P[0,3] = -fx * baseline)."""
        assert m.right_info is not None  # a stereo head's (Topics.kind)
        if left_info is None or right_info is None:
            return Measurement(missing=f"no CameraInfo for {m.topic} and {m.right} yet")
        try:
            left, right = (grey_image(msg) for msg in pair)
            if left.shape != right.shape:
                sizes = [f"{image.shape[1]} x {image.shape[0]} px" for image in (left, right)]
                raise ValueError(f"the left image is {sizes[0]}, the right one {sizes[1]}")
            head = _stereo_head(self.profile, m.sensor, left_info, right_info, left.shape, m.right_info)
        except ValueError as exc:
            return Measurement(missing=f"{m.topic} and {m.right}: {exc}")
        intrinsics = (head.fx_px, head.fy_px, head.cx_px, head.cy_px)
        return Measurement(images={"left": left, "right": right}, head=head, intrinsics_px=intrinsics)

    # --- calibration ----------------------------------------------------------------------------------
    def deploy(self, cal_id: str, cal: Calibration) -> str:
        """Write the calibrated URDF (its links named as `apply.frames` says), the offsets YAML and (with
        `apply.frames`) the launch file of the named links into the data directory, then (with `apply: {node}`) set
        the node's parameter to that URDF; RobotFault when the node refuses or does not answer. What was done, as
        a sentence for the apply history."""
        names = self.conn.apply_frames
        urdf = calibrated_urdf(self.profile, cal, names)
        poses = link_poses(urdf, names.values())
        wrote = []
        if self.files is not None:
            wrote = [f"{cal_id}.urdf", f"{cal_id}.offsets.yaml"]
            write_atomic(self.files / wrote[0], urdf)
            write_atomic(self.files / wrote[1], offsets_yaml(self.profile, cal))
            source = f"robot-selfcal: calibration {cal_id} of robot '{self.profile.name}', the links of apply.frames"
            launch = launch_file(poses, source)
            if launch is not None:
                wrote.append(f"{cal_id}.tf_static.launch.py")
                write_atomic(self.files / wrote[-1], launch)
        done = []
        if self._set_parameters is not None:
            self._set_parameter(urdf)
            node = self.conn.apply_node
            done.append(f"set {self.conn.apply_parameter} of {node} to the calibrated URDF")
            if poses:
                done.append(f"{node} publishes {published(poses)}")
            if self.files is not None:
                write_atomic(self.files / "applied.urdf", urdf)
        if wrote:
            done.append(f"wrote {', '.join(wrote[:-1])} and {wrote[-1]}")
        if len(wrote) > 2 and self._set_parameters is None:  # the launch file, for a robot without the node
            done.append(f"{wrote[-1]} publishes {published([p for p in poses if p.fixed])}")
        return "; ".join(done)

    def _set_parameter(self, urdf: str) -> None:
        from rcl_interfaces.msg import Parameter, ParameterType, ParameterValue
        from rcl_interfaces.srv import SetParameters

        timeout_s = self.conn.options["apply_timeout_s"]
        node, parameter = self.conn.apply_node, self.conn.apply_parameter
        calling(f"{node}/set_parameters")
        client = self._set_parameters
        assert client is not None
        if not client.wait_for_service(timeout_sec=timeout_s):
            raise RobotFault(
                f"apply: {node} offers no set_parameters service (waited {timeout_s:g} s); nothing applied"
            )
        value = ParameterValue(type=ParameterType.PARAMETER_STRING, string_value=urdf)
        future = client.call_async(SetParameters.Request(parameters=[Parameter(name=parameter, value=value)]))
        done = threading.Event()
        future.add_done_callback(lambda _: done.set())
        if not self.clock.wait(done, timeout_s):
            future.cancel()
            raise RobotFault(
                f"apply: {node} did not answer setting {parameter} within {timeout_s:g} s; nothing applied"
            )
        results = future.result().results
        if not results or not results[0].successful:
            reason = (results[0].reason if results else "") or "no reason given"
            raise RobotFault(f"apply: {node} refused to set {parameter} ({reason}); nothing applied")

    # --- life -----------------------------------------------------------------------------------------
    def close(self) -> None:
        """Leave the graph."""
        self._closing.set()
        self.link.close()


def _stamp_s(stamp: _Stamp) -> float:
    return float(stamp.sec) + float(stamp.nanosec) * 1e-9


def _unpaired(m: Topics, latest: dict[str, float], sync_s: float, wait_s: float) -> str:
    """Why a stereo head has no pair at all: a side never came, or the two sides' stamps never agree."""
    assert m.right is not None  # a stereo head's (Topics.kind)
    silent = [topic for side, topic in (("left", m.topic), ("right", m.right)) if math.isnan(latest[side])]
    if silent:
        return f"no measurement on {' and '.join(silent)} (none received within {wait_s:g} s)"
    return (
        f"no stereo pair on {m.topic} and {m.right}: the left and right stamps differ by "
        f"{abs(latest['left'] - latest['right']):.3f} s (more than stereo_sync_s {sync_s:g} s)"
    )


def _stereo_head(
    profile: Profile, sensor: str, left_info: Any, right_info: Any, shape: tuple[int, ...], right_topic: str
) -> StereoHead:
    """The rectified head as its CameraInfo messages describe it (ValueError saying what does not fit)."""
    fx, fy, cx, cy = (float(left_info.k[i]) for i in (0, 4, 2, 5))
    if not (fx > 0 and fy > 0):
        raise ValueError("the left CameraInfo's K has no focal length")
    p = right_info.p
    baseline_m = -float(p[3]) / float(p[0]) if p[0] else math.nan
    if not baseline_m > 0:
        raise ValueError(
            f"{right_topic}: its P gives no baseline (P[0,3] = -fx * baseline, negative for a right camera)"
        )
    head = StereoHead.from_profile(profile, profile.nominal(), sensor)  # its frame and optical axes
    return replace(
        head, fx_px=fx, fy_px=fy, cx_px=cx, cy_px=cy, width_px=shape[1], height_px=shape[0], baseline_m=baseline_m
    )
