"""A robot on its own ROS 2 graph behind the RobotDriver interface (driver kind `ros2`; specs ros2.md).

Options: `connection` (the connection file, app/ros2/connection.py) and `files` (the folder in the data
directory where apply writes the calibrated URDF and the offsets YAML). `calib serve --ros2 FILE` makes
both.

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
import time
from collections import deque
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np

from calib_core import Calibration, InputError, Profile
from calib_core.files import write_atomic
from calib_core.io.camera_images import grey_image
from calib_core.io.export import calibrated_urdf, offsets_yaml
from calib_core.units import length_factor
from calib_core.vision.sighting import Sighting, sight_board, sight_fixture
from calib_core.vision.stereo import StereoHead, depth_from_pair

from . import Look, RobotFault, RobotStatus, check_limits
from .registry import DriverContext

MOVE_SLACK_S = 5.0  # a move may overrun its planned duration by this before the robot counts as not responding
DURATION_FACTOR = 1.05  # time_from_start this much longer than the fastest the velocity limits allow
MIN_DURATION_S = 0.1
STILL_WINDOW_S = 0.15  # joint states unchanged for this long: not moving
MATCH_WAIT_S = 3.0  # how long a move waits for the controller to subscribe to the commands
_POLL_S = 0.005
_STEREO_KEEP = 4  # the latest images of each side kept for pairing by stamp


def check(profile: Profile, options: Mapping[str, Any], where: str) -> dict[str, Any]:
    """The options checked: `connection` a connection file (for this profile), `files` a folder (optional)."""
    from ..ros2 import require

    require()
    unknown = sorted(set(options) - {"connection", "files"})
    if unknown:
        raise InputError(f"{where}.{unknown[0]}: no such option of the ros2 driver (options: connection, files)")
    path = options.get("connection")
    if not isinstance(path, str) or not path:
        raise InputError(f"{where}.connection: expected the ROS 2 connection file")
    files = options.get("files")
    if files is not None and not isinstance(files, str):
        raise InputError(f"{where}.files: expected a folder")
    return {"connection": path, "files": files}


def create(profile: Profile, options: Mapping[str, Any], context: DriverContext) -> Ros2Driver:
    from ..ros2.connection import check_against, load_connection, take_pending
    from ..ros2.link import Link

    path = Path(options["connection"])
    conn = load_connection(path if path.is_absolute() else context.base_dir / path)
    check_against(conn, profile)
    link = take_pending(str(conn.path)) or Link(f"calib_desk_{''.join(c if c.isalnum() else '_' for c in conn.robot)}")
    return Ros2Driver(profile, conn, link, files=None if options.get("files") is None else Path(options["files"]))


@dataclass
class _Move:
    goal: np.ndarray
    t0: float
    duration_s: float
    done: threading.Event = field(default_factory=threading.Event)
    arrived: bool = False


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


class Ros2Driver:
    def __init__(self, profile: Profile, conn: Any, link: Any, *, files: Path | None = None) -> None:
        from geometry_msgs.msg import PointStamped
        from rcl_interfaces.srv import SetParameters
        from sensor_msgs.msg import CameraInfo, Image, JointState
        from trajectory_msgs.msg import JointTrajectory

        from ..ros2.link import COMMAND_QOS, SENSOR_QOS

        self.profile = profile
        self.conn = conn
        self.link = link
        self.files = files
        self.margin_rad = math.radians(conn.options["margin_deg"])
        self.margin_m = float(conn.options["margin_m"])
        self._scale = np.array(
            [length_factor("m", profile.length_unit) if j.prismatic else 1.0 for j in profile.joints]
        )
        prismatic = np.array([j.prismatic for j in profile.joints], bool)
        # Per joint, in its internal unit (rad, or the profile's length unit for a prismatic joint): how close
        # a move must come to its target, and what change of the readings is still standing still.
        self._tolerance = np.where(
            prismatic, conn.options["tolerance_m"] * self._scale, math.radians(conn.options["tolerance_deg"])
        )
        self._still = np.where(
            prismatic, conn.options["still_m"] * self._scale, math.radians(conn.options["still_deg"])
        )
        self._velocity = np.array([j.velocity for j in profile.joints])
        self._lock = threading.Lock()
        self._q: np.ndarray | None = None
        self._js_stamp = math.nan  # header.stamp of the latest joint states (s, the robot's clock)
        self._js_at = -math.inf  # time.monotonic() it came
        self._ref = None  # the readings stillness is measured from
        self._still_since = time.monotonic()
        self._mismatch = ""
        self._move: _Move | None = None
        self._stopped = False
        self._cal_id: str | None = None
        self._believed = profile.nominal()
        self._target = _first_target(profile)
        self._readings = {m.sensor: _Reading() for m in conn.measurements}
        self._arrived = threading.Condition(self._lock)
        self._closed = False
        node = link.node
        self._trajectory_type = JointTrajectory
        self._command = node.create_publisher(JointTrajectory, conn.command, COMMAND_QOS)
        node.create_subscription(JointState, conn.joint_states, self._on_joints, SENSOR_QOS)
        for m in conn.measurements:
            if m.kind == "point":
                node.create_subscription(PointStamped, m.topic, self._on_point(m.sensor), SENSOR_QOS)
            elif m.kind == "image":
                node.create_subscription(Image, m.topic, self._on_image(m.sensor), SENSOR_QOS)
                node.create_subscription(CameraInfo, m.info, self._on_info(m.sensor), SENSOR_QOS)
            else:
                node.create_subscription(Image, m.topic, self._on_side(m.sensor, "left"), SENSOR_QOS)
                node.create_subscription(Image, m.right, self._on_side(m.sensor, "right"), SENSOR_QOS)
                node.create_subscription(CameraInfo, m.info, self._on_info(m.sensor), SENSOR_QOS)
                node.create_subscription(CameraInfo, m.right_info, self._on_info(m.sensor, "right_info"), SENSOR_QOS)
        self._set_parameters = None
        if conn.apply_node is not None:
            self._set_parameters = node.create_client(SetParameters, f"{conn.apply_node.rstrip('/')}/set_parameters")

    # --- the graph's callbacks ------------------------------------------------------------------------
    def _on_joints(self, msg: Any) -> None:
        index = {name: k for k, name in enumerate(msg.name)}
        missing = [j.name for j in self.profile.joints if j.name not in index or index[j.name] >= len(msg.position)]
        now = time.monotonic()
        with self._lock:
            if missing:
                self._mismatch = f"the joint states on {self.conn.joint_states} lack {', '.join(missing)}"
                return
            self._mismatch = ""
            q = np.array([msg.position[index[j.name]] for j in self.profile.joints]) * self._scale
            if self._ref is None or np.any(np.abs(q - self._ref) > self._still):
                self._ref = q
                self._still_since = now
            self._q = q
            self._js_stamp = _stamp_s(msg.header.stamp)
            self._js_at = now
            move = self._move
            if move is not None and np.all(np.abs(q - move.goal) <= self._tolerance):
                move.arrived = True
                move.done.set()
                self._move = None
            self._arrived.notify_all()

    def _on_point(self, sensor: str) -> Callable[[Any], None]:
        def on(msg: Any) -> None:
            with self._lock:
                r = self._readings[sensor]
                r.stamp_s, r.value = _stamp_s(msg.header.stamp), np.array([msg.point.x, msg.point.y, msg.point.z])

        return on

    def _on_image(self, sensor: str) -> Callable[[Any], None]:
        def on(msg: Any) -> None:
            with self._lock:
                r = self._readings[sensor]
                r.stamp_s, r.value = _stamp_s(msg.header.stamp), msg

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
                    self._arrived.notify_all()

        return on

    # --- state ----------------------------------------------------------------------------------------
    def _connected(self, now: float) -> bool:
        return not self._closed and not self._mismatch and now - self._js_at <= self.conn.options["timeout_s"]

    def _why_not(self, now: float) -> str:
        if self._closed:
            return "disconnected"
        if self._mismatch:
            return f"disconnected: {self._mismatch}"
        if self._q is None:
            return f"disconnected: no joint states on {self.conn.joint_states} yet"
        return f"disconnected: no joint states on {self.conn.joint_states} for {now - self._js_at:.1f} s"

    def status(self) -> RobotStatus:
        now = time.monotonic()
        with self._lock:
            connected = self._connected(now)
            moving = connected and (self._move is not None or now - self._still_since < STILL_WINDOW_S)
            if not connected:
                message = self._why_not(now)
            else:
                message = "moving" if moving else "stopped" if self._stopped else "idle"
            q = self._q if self._q is not None else np.clip(0.0, *self.profile.joint_limits())
            return RobotStatus(
                robot=self.profile.name,
                connected=connected,
                moving=moving,
                joints_rad=q.copy(),
                target=self._target,
                calibration_id=self._cal_id,
                message=message,
                stamp=self._js_at,
            )

    def _check_link(self) -> None:
        """RobotFault when disconnected (lock held)."""
        now = time.monotonic()
        if not self._connected(now):
            raise RobotFault(f"{self.profile.name} {self._why_not(now)}")

    def read_joints(self) -> np.ndarray:
        with self._lock:
            self._check_link()
            assert self._q is not None
            return self._q.copy()

    def settled(self, for_s: float = 0.3) -> bool:
        """Joint states unchanged for for_s (s), no move under way."""
        now = time.monotonic()
        with self._lock:
            return self._connected(now) and self._move is None and now - self._still_since >= for_s

    # --- seeing ---------------------------------------------------------------------------------------
    def look(self, believed: np.ndarray | None = None) -> Look:
        """The data sensor's first measurement stamped after the joint states the robot stands at now."""
        sensor = self.profile.sensors[self.profile.data.sensor]
        m = next(m for m in self.conn.measurements if m.sensor == sensor.name)
        topic = m.topic if m.kind != "stereo" else f"{m.topic} and {m.right}"
        wait_s = self.conn.options["measurement_wait_s"]
        with self._lock:
            self._check_link()
            assert self._q is not None
            q, since, target = self._q.copy(), self._js_stamp, self._target
            p = (self._believed if believed is None else np.asarray(believed, float)).copy()
            deadline = time.monotonic() + wait_s
            r = self._readings[sensor.name]
            while not r.stamp_s > since and time.monotonic() < deadline:
                self._arrived.wait(_POLL_S)
            stamp, value, info, right_info = r.stamp_s, r.value, r.info, r.right_info
            latest = {side: images[-1][0] if images else math.nan for side, images in r.sides.items()}
        if not stamp > since:
            if math.isnan(stamp) and m.kind == "stereo":
                reason = _unpaired(m, latest, self.conn.options["stereo_sync_s"], wait_s)
            elif math.isnan(stamp):
                reason = f"no measurement on {topic} (none received within {wait_s:g} s)"
                carried = self.link.topic_types().get(topic)
                want = "sensor_msgs/msg/Image" if sensor.reading == "image" else "geometry_msgs/msg/PointStamped"
                if carried and want not in carried:
                    reason += f": it carries {', '.join(carried)}, not {want}"
            else:
                reason = (
                    f"stale measurement on {topic}: the latest is stamped {since - stamp:.3f} s before the settled "
                    f"joint states (none newer within {wait_s:g} s)"
                )
            return Look(q, target, _not_found(self.profile, target, reason), {})
        if m.kind == "stereo":
            return self._look_stereo(q, p, value, info, right_info, m)
        if sensor.reading == "image":
            return self._look_image(q, target, p, value, info, topic)
        measured = value[None] * length_factor("m", self.profile.length_unit)
        fixed = self.profile.targets[target].points
        points = np.full((1, 3), np.nan) if fixed is None else fixed[[0]]
        detail = {"sensor": topic, "stamp_after_settled_s": round(stamp - since, 4)}
        return Look(q, target, Sighting(target, "measured", "ok", measured, points, np.array([-1]), detail), {})

    def _look_image(self, q: np.ndarray, target: int, p: np.ndarray, msg: Any, info: Any, topic: str) -> Look:
        """Run the board detector on a camera image, with the intrinsics of its CameraInfo."""
        sensor = self.profile.sensors[self.profile.data.sensor]
        if info is None:
            return Look(q, target, _not_found(self.profile, target, f"no CameraInfo for {topic} yet"), {})
        try:
            image = grey_image(msg)
        except ValueError as exc:
            return Look(q, target, _not_found(self.profile, target, f"{topic}: {exc}"), {})
        if sensor.intrinsics is not None:
            k = info.k
            p[list(sensor.intrinsics)] = [k[0], k[4], k[2], k[5]]
        sighting = sight_board(self.profile, p, q, target, image)
        return Look(q, target, sighting, {"image": image})

    def _look_stereo(self, q: np.ndarray, p: np.ndarray, pair: Any, left_info: Any, right_info: Any, m: Any) -> Look:
        """Stereo matching and the BallFinder on a rectified pair, seeded by the believed kinematics; the
        intrinsics from the left CameraInfo's K, the baseline from the right one's P (P[0,3] = -fx * baseline)."""
        target = self.profile.data.target if self.profile.data.target is not None else 0
        sensor = self.profile.sensors[self.profile.data.sensor]
        if left_info is None or right_info is None:
            return Look(
                q, target, _not_found(self.profile, target, f"no CameraInfo for {m.topic} and {m.right} yet"), {}
            )
        try:
            left, right = (grey_image(msg) for msg in pair)
            if left.shape != right.shape:
                sizes = [f"{image.shape[1]} x {image.shape[0]} px" for image in (left, right)]
                raise ValueError(f"the left image is {sizes[0]}, the right one {sizes[1]}")
            head = _stereo_head(self.profile, sensor.name, left_info, right_info, left.shape, m.right_info)
        except ValueError as exc:
            return Look(q, target, _not_found(self.profile, target, f"{m.topic} and {m.right}: {exc}"), {})
        if sensor.intrinsics is not None:
            p[list(sensor.intrinsics)] = [head.fx_px, head.fy_px, head.cx_px, head.cy_px]
        depth_m = depth_from_pair(left, right, head)
        sighting = sight_fixture(self.profile, p, q, depth_m, head)
        return Look(q, target, sighting, {"left": left, "right": right})

    # --- calibration ----------------------------------------------------------------------------------
    def apply_calibration(self, cal_id: str | None, params: np.ndarray | None) -> None:
        p = self.profile.nominal() if params is None else np.asarray(params, float).copy()
        with self._lock:
            self._cal_id, self._believed = cal_id, p

    def believed_params(self) -> np.ndarray:
        with self._lock:
            return self._believed.copy()

    def deploy(self, cal_id: str, cal: Calibration) -> str:
        """Write the calibrated URDF and the offsets YAML into the data directory, then (with `apply:`) set the
        node's parameter to that URDF; RobotFault when the node refuses or does not answer. What was done, as
        a sentence for the apply history."""
        urdf = calibrated_urdf(self.profile, cal)
        done = []
        if self.files is not None:
            write_atomic(self.files / f"{cal_id}.urdf", urdf)
            write_atomic(self.files / f"{cal_id}.offsets.yaml", offsets_yaml(self.profile, cal))
            done.append(f"wrote {cal_id}.urdf and {cal_id}.offsets.yaml")
        if self._set_parameters is not None:
            self._set_parameter(urdf)
            done.insert(0, f"set {self.conn.apply_parameter} of {self.conn.apply_node} to the calibrated URDF")
            if self.files is not None:
                write_atomic(self.files / "applied.urdf", urdf)
        return "; ".join(done)

    def _set_parameter(self, urdf: str) -> None:
        from rcl_interfaces.msg import Parameter, ParameterType, ParameterValue
        from rcl_interfaces.srv import SetParameters

        timeout_s = self.conn.options["apply_timeout_s"]
        node, parameter = self.conn.apply_node, self.conn.apply_parameter
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
        if not done.wait(timeout_s):
            future.cancel()
            raise RobotFault(
                f"apply: {node} did not answer setting {parameter} within {timeout_s:g} s; nothing applied"
            )
        results = future.result().results
        if not results or not results[0].successful:
            reason = (results[0].reason if results else "") or "no reason given"
            raise RobotFault(f"apply: {node} refused to set {parameter} ({reason}); nothing applied")

    def set_target(self, target: int) -> None:
        if not 0 <= target < len(self.profile.targets):
            raise ValueError(f"{self.profile.name} has targets 0..{len(self.profile.targets) - 1}, not {target}")
        with self._lock:
            self._target = int(target)

    # --- moving ---------------------------------------------------------------------------------------
    def check(self, q_rad: np.ndarray) -> None:
        check_limits(self.profile, q_rad, self.margin_rad, self.margin_m)

    def duration_s(self, start: np.ndarray, goal: np.ndarray) -> float:
        """The move's time_from_start: no joint faster than its velocity limit."""
        delta = np.abs(goal - start)
        if np.any((delta > 0) & (self._velocity <= 0)):
            raise InputError("a joint to move has no velocity limit above 0")
        slowest = np.max(np.where(delta > 0, delta / np.where(self._velocity > 0, self._velocity, 1), 0))
        return max(MIN_DURATION_S, DURATION_FACTOR * float(slowest))

    def move_to(self, q_rad: np.ndarray, *, wait: bool = True, should_stop: Callable[[], bool] | None = None) -> bool:
        goal = np.asarray(q_rad, dtype=float)
        self.check(goal)
        self._wait_for_controller()
        with self._lock:
            self._check_link()
            assert self._q is not None
            duration = self.duration_s(self._q, goal)
            move = _Move(goal.copy(), time.monotonic(), duration)
            self._command.publish(self._trajectory(goal, duration))
            self._move, self._stopped = move, False
        if not wait:
            return True
        limit_s = duration + MOVE_SLACK_S
        while not move.done.wait(_POLL_S):
            now = time.monotonic()
            with self._lock:
                connected = self._connected(now)
            if should_stop is not None and should_stop():
                self.stop()
            elif not connected:
                self._abandon(move)
                with self._lock:
                    self._check_link()
            elif now - move.t0 > limit_s:
                self._abandon(move)
                raise RobotFault(
                    f"{self.profile.name} did not arrive within {limit_s:.1f} s (not responding); the robot was stopped"
                )
        return move.arrived

    def stop(self) -> None:
        """The empty trajectory: the controller stops and holds where it is (never a jump)."""
        msg = self._trajectory_type()
        msg.joint_names = [j.name for j in self.profile.joints]
        with self._lock:
            move, self._move = self._move, None
            self._stopped = True
            if not self._closed:
                self._command.publish(msg)
        if move is not None:
            move.done.set()

    def _abandon(self, move: _Move) -> None:
        self.stop()
        move.done.set()

    def _wait_for_controller(self) -> None:
        """Commands go out only once the controller subscribes (reliable delivery needs a matched reader)."""
        deadline = time.monotonic() + MATCH_WAIT_S
        while self._command.get_subscription_count() == 0:
            if time.monotonic() > deadline:
                raise RobotFault(
                    f"{self.profile.name}: nothing subscribes to {self.conn.command} (is the controller running?)"
                )
            time.sleep(0.02)

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

    # --- life -----------------------------------------------------------------------------------------
    def close(self) -> None:
        """Stop a move under way, then leave the graph; the driver reports itself disconnected."""
        with self._lock:
            moving = self._move is not None
        if moving:
            self.stop()
        with self._lock:
            self._closed = True
        self.link.close()


def _first_target(profile: Profile) -> int:
    from .simulated import readable_targets, reads_points

    if reads_points(profile.sensors[profile.data.sensor]):
        return (readable_targets(profile) or [0])[0]
    return 0


def _not_found(profile: Profile, target: int, reason: str) -> Sighting:
    return Sighting(target, "not found", reason, None, np.zeros((0, 3)), np.zeros(0, int), {"reason": reason})


def _stamp_s(stamp: Any) -> float:
    return float(stamp.sec) + float(stamp.nanosec) * 1e-9


def _unpaired(m: Any, latest: dict[str, float], sync_s: float, wait_s: float) -> str:
    """Why a stereo head has no pair at all: a side never came, or the two sides' stamps never agree."""
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
