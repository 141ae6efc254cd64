"""A simulated robot as a ROS 2 node (`calib sim-ros2`): what a real robot's graph offers the desk.

It publishes the robot's URDF on /robot_description (transient local, as robot_state_publisher does, and
again whenever its `robot_description` parameter is set), the encoder readings on /joint_states at
`rate_hz`, and what its sensor measures: a point sensor's (laser tracker, motion capture) PointStamped in
metres on /<sensor>/point, a camera's rendered image and CameraInfo on /<sensor>/image_raw and
/<sensor>/camera_info, or a stereo head's rendered rectified pair (Robonaut) on /<sensor>/left/image_rect and
/<sensor>/right/image_rect with their CameraInfo on /<sensor>/left/camera_info and /<sensor>/right/camera_info
(both images of a pair stamped alike; the right P carries the baseline). It executes
trajectory_msgs/JointTrajectory from /joint_trajectory_controller/joint_trajectory as a ros2_control
trajectory controller does with positions only: linear interpolation from where it stands, each point at its
time_from_start (divided by `speed`, a parameter that may be set while it runs); an empty trajectory stops
and holds. A trajectory naming an
unknown joint or a point beyond a joint limit is refused whole (logged), as a controller refuses it.

The fault harness (app/drivers/faults.py): the parameter `fault` (text as faults.py writes it, "" clears it;
`fault_after_moves` trajectories before it strikes, set first) makes the robot hang (no joint states, no images,
no motion: its motion and sensor callbacks block, its parameters still answer), answer slowly (its trajectories
and images come late), go silent halfway
through the next move (drop, until cleared), stall, read NaN or beyond a limit, send a malformed or a huge image,
or refuse every trajectory.

Its hidden truth is the profile's simulation (calib_core.sim.SimulatedRobot with `seed`; `day` > 1 drifts the
joint offsets as the desk's simulated robots and `calib simulate --day` do): the desk that calibrates it should
find those parameters.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from calib_core import InputError, Profile, load_profile
from calib_core.io import to_urdf
from calib_core.model import BUILTIN_PROFILES
from calib_core.safe_yaml import read_yaml
from calib_core.sim import SimulatedRobot
from calib_core.units import length_factor
from calib_core.vision import StereoHead, found_targets

from ..core import DEFAULT_SETTLE_S
from ..faults import HUGE_PX, Fault, FaultSwitch, parse_fault
from ..sim_view import home, render_in_view
from . import require

COMMAND_TOPIC = "/joint_trajectory_controller/joint_trajectory"
POINT_HZ = 50.0
IMAGE_HZ = 5.0


@dataclass(frozen=True)
class Topics:
    """The node's names, all under `namespace` ("" or "/nao": several robots on one graph)."""

    namespace: str = ""

    @property
    def description(self) -> str:
        return f"{self.namespace}/robot_description"

    @property
    def joint_states(self) -> str:
        return f"{self.namespace}/joint_states"

    @property
    def command(self) -> str:
        return f"{self.namespace}{COMMAND_TOPIC}"

    @property
    def node(self) -> str:
        return f"{self.namespace}/robot_state_publisher"

    def measurement(self, sensor: str, kind: str) -> dict[str, str]:
        """The topics of a sensor of this kind ("point", "image" or "stereo"), as the connection file names them."""
        at = f"{self.namespace}/{sensor}"
        if kind == "stereo":
            return {
                f"{side}{key}": f"{at}/{side}/{name}"
                for side in ("left", "right")
                for key, name in (("", "image_rect"), ("_info", "camera_info"))
            }
        if kind == "image":
            return {"topic": f"{at}/image_raw", "info": f"{at}/camera_info"}
        return {"topic": f"{at}/point"}


def load_sim_profile(robot: str, urdf: Path | None) -> tuple[Profile, str]:
    """The profile (a built-in name or a file; `urdf` for a profile that says `urdf: ros2`) and the URDF
    text the node publishes (the profile's own URDF, a built-in's shipped one, or one drawn from the model)."""
    from ...store.profiles import builtin_urdf

    if robot in BUILTIN_PROFILES:
        profile = load_profile(robot)
        shipped = builtin_urdf(robot)
        return profile, shipped.read_text(encoding="utf-8") if shipped else to_urdf(profile)
    path = Path(robot)
    doc = read_yaml(path, "robot profile file") if path.is_file() else None
    says = doc.get("urdf") if isinstance(doc, dict) else None
    if says == "ros2" and urdf is None:
        raise InputError("the profile says urdf: ros2: give the robot's URDF with --urdf", file=str(path))
    profile = load_profile(path, urdf=urdf)
    if isinstance(says, str):
        source = urdf if urdf is not None else path.parent / says
        return profile, Path(source).read_text(encoding="utf-8")
    return profile, to_urdf(profile)


def connection_doc(
    profile_ref: str, robot: str, profile: Profile, topics: Topics, speed: float = 1.0
) -> dict[str, Any]:
    """A connection file for the desk that matches this node (`calib sim-ros2 --connection-out`): its settle window
    the default one in the robot's time, which runs `speed` times as fast."""
    sensor = profile.sensors[profile.data.sensor]
    return {
        "robot": robot,
        "profile": profile_ref,
        "description_topic": topics.description,
        "joint_states": topics.joint_states,
        "command": topics.command,
        "measurements": {sensor.name: topics.measurement(sensor.name, sensor_kind(profile))},
        "apply": {"node": topics.node, "parameter": "robot_description"},
        "settle_s": round(DEFAULT_SETTLE_S / speed, 6),
    }


def sensor_kind(profile: Profile) -> str:
    """How the node publishes the profile's data sensor: "stereo" (a pair of images), "image" or "point"; a
    sensor publishes images when its finder renders them (calib_core.vision.finders). InputError: it cannot."""
    from ..core import reads_points

    sensor = profile.sensors[profile.data.sensor]
    if found_targets(profile, profile.data.sensor):
        return "stereo" if sensor.image_roles == ("left", "right") else "image"
    if reads_points(sensor):
        return "point"
    raise InputError(f"{profile.name}: its {sensor.name} ({sensor.reading}) cannot be simulated on ROS 2 yet")


class SimNode:
    """The simulated robot on the graph, until close()."""

    def __init__(
        self,
        profile: Profile,
        urdf: str,
        *,
        seed: int = 1,
        day: int = 1,
        speed: float = 1.0,
        rate_hz: float = 100.0,
        refuse_apply: bool = False,
        stall_apply: bool = False,
        topics: Topics = Topics(),
        fault: Fault | None = None,
        fault_after: int = 0,
    ) -> None:
        require()
        from geometry_msgs.msg import PointStamped
        from rcl_interfaces.msg import SetParametersResult
        from rclpy.callback_groups import MutuallyExclusiveCallbackGroup
        from rclpy.parameter import Parameter
        from sensor_msgs.msg import CameraInfo, Image, JointState
        from std_msgs.msg import String
        from trajectory_msgs.msg import JointTrajectory

        from .link import COMMAND_QOS, LATCHED_QOS, Link

        self.profile = profile
        self.sim = SimulatedRobot.from_profile(profile, seed=seed).on_day(day)  # as the desk's robot of that day
        self.speed = float(speed)
        self.refuse_apply = refuse_apply
        self.stall_apply = stall_apply
        self._closing = threading.Event()
        self.topics = topics
        from ..core import first_target

        sensor = profile.sensors[profile.data.sensor]
        self.kind = sensor_kind(profile)
        self.target = first_target(profile)
        self._lock = threading.Lock()
        lo, hi = profile.joint_limits()
        self._lo, self._hi = lo, hi
        self._scale = np.array(
            [length_factor(profile.length_unit, "m") if j.prismatic else 1.0 for j in profile.joints]
        )
        self._q = home(profile, self.sim)
        self._plan: list[tuple[float, np.ndarray]] | None = None  # (s after start, q) from where it stood
        self._t0 = 0.0
        self.faults = FaultSwitch([j.name for j in profile.joints])
        self.faults.arm(fault, fault_after, "--fault")  # before it is on the graph: a wrong one is said at once
        self._silent_at = np.inf  # monotonic s from which it publishes nothing (a drop halfway through a move)
        self.link = Link(
            "robot_state_publisher",
            threads=3,  # the parameter services, the motion, the sensor: a stalled one stops neither other
            namespace=topics.namespace or None,
            parameter_overrides=[Parameter("robot_description", value=urdf)],
        )
        node = self.link.node
        node.declare_parameter("robot_description", urdf)
        node.declare_parameter("speed", self.speed)  # the trajectories' timing divided by this, from the next one
        node.declare_parameter("fault", "")  # the fault harness: what the robot does wrong ("" nothing)
        node.declare_parameter("fault_after_moves", 0)
        self._description = node.create_publisher(String, topics.description, LATCHED_QOS)
        self._joints = node.create_publisher(JointState, topics.joint_states, 10)
        self._string, self._joint_state = String, JointState
        # The commands in a group of their own (the joint states and a point sensor's measurements come from threads
        # of their own: `_every`): a parameter call that stalls (the default group's services) or a render (the
        # sensor's group) does not hold them up.
        motion = MutuallyExclusiveCallbackGroup()
        node.create_subscription(
            JointTrajectory, topics.command, self._on_trajectory, COMMAND_QOS, callback_group=motion
        )

        def check_parameters(params: list[Any]) -> Any:
            for p in params:
                if p.name == "speed" and not (isinstance(p.value, float) and 0 < p.value <= 100):
                    return SetParametersResult(successful=False, reason="speed: a number in (0, 100]")
                if p.name == "fault":
                    try:
                        parse_fault(p.value) if p.value else None
                    except (InputError, AttributeError) as exc:
                        return SetParametersResult(successful=False, reason=str(exc))
                if p.name != "robot_description":
                    continue
                if self.stall_apply:  # accepted, never answered while the node lives (a hung robot_state_publisher)
                    self._closing.wait()
                    return SetParametersResult(successful=False, reason="the node is closing")
                if self.refuse_apply:
                    return SetParametersResult(successful=False, reason="this robot takes no new description")
                text = p.value if isinstance(p.value, str) else ""
                if "<robot" not in text:
                    return SetParametersResult(successful=False, reason="not a URDF")
            return SetParametersResult(successful=True)

        def republish(params: list[Any]) -> None:
            for p in params:
                if p.name == "robot_description":
                    self._description.publish(String(data=p.value))
                elif p.name == "speed":
                    self.speed = float(p.value)
                elif p.name == "fault":
                    after = int(node.get_parameter("fault_after_moves").value)
                    self._silent_at = np.inf
                    self.faults.arm(parse_fault(p.value) if p.value else None, after)

        node.add_on_set_parameters_callback(check_parameters)
        node.add_post_set_parameters_callback(republish)
        self._description.publish(String(data=urdf))
        measurement = topics.measurement(sensor.name, self.kind)
        # Rendering takes a few hundred ms: in a group of its own the joint states and commands go on meanwhile.
        sensing = MutuallyExclusiveCallbackGroup()
        if self.kind != "point":
            images = ("topic",) if self.kind == "image" else ("left", "right")
            infos = ("info",) if self.kind == "image" else ("left_info", "right_info")
            self._images = [node.create_publisher(Image, measurement[key], 5) for key in images]
            self._infos = [node.create_publisher(CameraInfo, measurement[key], 5) for key in infos]
            self._image_type, self._info_type = Image, CameraInfo
            node.create_timer(1.0 / IMAGE_HZ, self._publish_images, callback_group=sensing)
        else:
            self._point = node.create_publisher(PointStamped, measurement["topic"], 10)
            self._point_type = PointStamped
        self._threads = [threading.Thread(target=self._every, args=(1.0 / rate_hz, self._tick), name="joint-states")]
        if self.kind == "point":
            self._threads.append(
                threading.Thread(target=self._every, args=(1.0 / POINT_HZ, self._publish_point), name="points")
            )
        self._frame = sensor.name
        self._rendered: tuple[np.ndarray, list[np.ndarray]] | None = None  # (the pose, its images)
        for thread in self._threads:
            thread.daemon = True
            thread.start()

    # --- commands ---------------------------------------------------------------------------------------
    def _on_trajectory(self, msg: Any) -> None:
        names = [j.name for j in self.profile.joints]
        self.faults.answer()
        if self._silent():
            return
        with self._lock:
            q = self._position(time.monotonic())
            if not msg.points:  # stop and hold
                self._q, self._plan = q, None
                return
            fault = self.faults.moved()
            if fault is not None and fault.kind == "refuse":
                return self._refuse("the controller is told to refuse every trajectory (fault harness)")
            unknown = [n for n in msg.joint_names if n not in names]
            if unknown:
                return self._refuse(f"unknown joint(s) {', '.join(unknown)}")
            index = [names.index(n) for n in msg.joint_names]
            plan: list[tuple[float, np.ndarray]] = [(0.0, q)]
            for point in msg.points:
                if len(point.positions) != len(index):
                    return self._refuse("a point's positions do not match its joint names")
                goal = plan[-1][1].copy()
                goal[index] = np.asarray(point.positions, float) * (1 / self._scale[index])
                if np.any(goal < self._lo) or np.any(goal > self._hi):
                    return self._refuse("a point beyond a joint limit")
                t = (point.time_from_start.sec + point.time_from_start.nanosec * 1e-9) / self.speed
                if t < plan[-1][0]:
                    return self._refuse("time_from_start goes back")
                plan.append((t, goal))
            if fault is not None and fault.kind == "stall":
                plan = [(0.0, q), (plan[-1][0], q)]  # it never gets there
            self._q, self._plan, self._t0 = q, plan, time.monotonic()
            if fault is not None and fault.kind == "drop":
                self._silent_at = self._t0 + plan[-1][0] / 2

    def _refuse(self, why: str) -> None:
        self.link.node.get_logger().error(f"trajectory refused: {why}")

    def _position(self, now: float) -> np.ndarray:
        """The true joint angles now (lock held)."""
        if self._plan is None:
            return self._q.copy()
        t = now - self._t0
        for (t0, q0), (t1, q1) in zip(self._plan, self._plan[1:], strict=False):
            if t <= t1:
                s = 1.0 if t1 <= t0 else (t - t0) / (t1 - t0)
                return q0 + (q1 - q0) * max(0.0, s)
        return self._plan[-1][1].copy()

    # --- publishing -------------------------------------------------------------------------------------
    def _silent(self) -> bool:
        """Dropped: it publishes and takes nothing (halted where it was) until the fault is cleared."""
        now = time.monotonic()
        if now < self._silent_at:
            return False
        with self._lock:
            self._q, self._plan = self._position(min(now, self._silent_at)), None
        return True

    def _every(self, period_s: float, tick: Callable[[], None]) -> None:
        """tick() every `period_s` (the joint states, a point sensor's measurement), from a thread of its own until
        close(): a timer of rclpy's executor took 1.2 ms of CPU to call a tick of 0.04 ms (NAO's joint states at
        100 Hz: 13% of a core, 2% at 10 Hz). A tick late (a hang, a loaded machine) is followed by the next one's
        period, not by a burst."""
        due = time.monotonic()
        while not self._closing.is_set():
            tick()
            due, now = due + period_s, time.monotonic()
            if due < now:
                due = now + period_s
            self._closing.wait(due - now)

    def _tick(self) -> None:
        if self.faults.now("hang"):  # slow: its commands and images come late, its joint states at their rate
            self.faults.answer()
        if self._silent():
            return
        now = time.monotonic()
        with self._lock:
            q = self._position(now)
            if self._plan is not None and now - self._t0 >= self._plan[-1][0]:
                self._q, self._plan = q, None
        msg = self._joint_state()
        msg.header.stamp = self.link.node.get_clock().now().to_msg()
        msg.name = [j.name for j in self.profile.joints]
        msg.position = [float(v) for v in self.faults.reading(self.sim.readings(q)) * self._scale]
        self._joints.publish(msg)

    def _true_q(self) -> np.ndarray:
        with self._lock:
            return self._position(time.monotonic())

    def _publish_point(self) -> None:
        stamp = self.link.node.get_clock().now().to_msg()
        q = self._true_q()
        measured = self.sim.measure(q[None], np.array([self.target])).data.measured[0, :3]
        msg = self._point_type()
        msg.header.stamp, msg.header.frame_id = stamp, self._frame
        x, y, z = measured * length_factor(self.profile.length_unit, "m")
        msg.point.x, msg.point.y, msg.point.z = float(x), float(y), float(z)
        self._point.publish(msg)

    def _publish_images(self) -> None:
        """What the camera (the stereo head) sees, rendered while the robot stands still (a moving robot's images
        would be blurred, and no capture takes them); a stereo pair's two images and infos stamped alike."""
        self.faults.answer()
        if self._silent():
            return
        stamp = self.link.node.get_clock().now().to_msg()
        with self._lock:
            if self._plan is not None:
                return
            q = self._q.copy()
        if self._rendered is None or not np.array_equal(self._rendered[0], q):  # a still scene: rendered once
            self._rendered = (q, render_in_view(self.profile, self.sim, q))
        sensor = self.profile.sensors[self.profile.data.sensor]
        fx, fy, cx, cy = (float(self.sim.true_params[i]) for i in sensor.intrinsics or ())
        # The right camera of a rectified pair: P[0,3] = -fx * baseline (m), as a ROS stereo driver says it.
        shifts = [0.0] if self.kind == "image" else [0.0, -fx * self._baseline_m()]
        fault = self.faults.now("malformed_image", "huge_image")
        for image, shift, images, infos in zip(self._rendered[1], shifts, self._images, self._infos, strict=True):
            if fault is not None and fault.kind == "huge_image":
                image = np.zeros(HUGE_PX[::-1], np.uint8)
            msg = self._image_type()
            msg.header.stamp, msg.header.frame_id = stamp, self._frame
            msg.height, msg.width = image.shape[:2]
            msg.encoding, msg.step = "mono8", image.shape[1]
            msg.data = image.tobytes()
            if fault is not None and fault.kind == "malformed_image":
                msg.data = msg.data[: len(msg.data) // 3]  # fewer bytes than its size says
            info = self._info_type()
            info.header = msg.header
            info.height, info.width = msg.height, msg.width
            info.k = [fx, 0.0, cx, 0.0, fy, cy, 0.0, 0.0, 1.0]
            info.p = [fx, 0.0, cx, shift, 0.0, fy, cy, 0.0, 0.0, 0.0, 1.0, 0.0]
            images.publish(msg)
            infos.publish(info)

    def _baseline_m(self) -> float:
        return StereoHead.from_profile(self.profile, self.sim.true_params, self._frame).baseline_m

    def close(self) -> None:
        self._closing.set()
        self.faults.arm(None)  # a hung callback ends
        for thread in self._threads:
            thread.join(timeout=5.0)  # its last joint states and points published before the node goes
        self.link.close()
