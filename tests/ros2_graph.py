"""Shared by the ROS 2 tests and benchmarks/ros2.py: a ROS 2 graph of this run's own (a domain id, on this
machine only), `calib sim-ros2` and `calib serve --ros2` as separate processes, and a watcher node in this
process that records every trajectory command and the joint states."""

from __future__ import annotations

import os
import random
import signal
import subprocess
import sys
import threading
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import yaml
from browser import Server, served

from calib_core.units import length_factor

ROOT = Path(__file__).resolve().parent.parent
ARM_DIR = ROOT / "docs" / "ros2"


def graph_env() -> dict[str, str]:
    """This run's graph: a domain id of its own (parallel runs do not see each other), this machine only."""
    domain = random.SystemRandom().randint(100, 230)
    return {"ROS_DOMAIN_ID": str(domain), "ROS_AUTOMATIC_DISCOVERY_RANGE": "LOCALHOST"}


def calib(*args: str) -> list[str]:
    """The command line of `calib ARGS` from this checkout."""
    return [sys.executable, "-m", "app.cli", *args]


@dataclass
class Sim:
    """`calib sim-ros2` (or another simulated robot's command: `sim-naoqi`) in its own process."""

    args: list[str]
    env: dict[str, str]
    process: subprocess.Popen | None = None
    command: str = "sim-ros2"

    def start(self, timeout_s: float = 60.0) -> Sim:
        return self.launch().ready(timeout_s)

    def launch(self) -> Sim:
        """Started, not waited for (ready())."""
        self.process = subprocess.Popen(
            calib(self.command, *self.args),
            cwd=ROOT,
            stdout=subprocess.PIPE,
            stderr=subprocess.STDOUT,
            env={**os.environ, **self.env, "PYTHONUNBUFFERED": "1"},
        )
        return self

    def ready(self, timeout_s: float = 60.0) -> Sim:
        """Once the node is on the graph."""
        assert self.process is not None
        line = _read_line(self.process, f"calib {self.command}:", timeout_s)
        if line is None:
            out = self.process.stdout.read().decode() if self.process.poll() is not None else ""  # type: ignore[union-attr]
            raise RuntimeError(f"calib {self.command} did not start: {out[-2000:]}")
        return self

    def kill(self) -> None:
        """Killed as a crash kills it: no goodbye on the graph."""
        assert self.process is not None
        self.process.kill()
        self.process.wait()

    def stop(self) -> None:
        if self.process is not None and self.process.poll() is None:
            self.process.send_signal(signal.SIGTERM)
            try:
                self.process.wait(timeout=10)
            except subprocess.TimeoutExpired:
                self.process.kill()
                self.process.wait()


def arm_sim(env: dict[str, str], *extra: str) -> Sim:
    """The demo arm (docs/ros2) on the graph, 8 times as fast as its trajectories say."""
    args = ["--robot", str(ARM_DIR / "arm-mocap.yaml"), "--urdf", str(ARM_DIR / "arm.urdf"), "--speed", "8"]
    return Sim([*args, *extra], env)


def _read_line(proc: subprocess.Popen, prefix: str, timeout_s: float) -> str | None:
    """The first line of the process's output that starts with prefix (None: it ended or the time ran out)."""
    found: list[str] = []

    def read() -> None:
        for raw in proc.stdout:  # type: ignore[union-attr]
            line = raw.decode(errors="replace")
            if line.startswith(prefix):
                found.append(line)
                return

    reader = threading.Thread(target=read, daemon=True)
    reader.start()
    reader.join(timeout_s)
    return found[0] if found else None


@contextmanager
def served_ros2(connection: Path, data_dir: Path, env: dict[str, str], *extra: str) -> Iterator[Server]:
    """`calib serve --ros2 CONNECTION` of this checkout until the block ends (SIGINT, as Ctrl-C)."""
    with served(
        data_dir,
        timeout_s=90.0,
        env={**os.environ, **env},
        command=calib(),
        extra=("--ros2", str(connection), *extra),
    ) as server:
        yield server


def wait_until(condition: Callable[[], Any], what: str, timeout_s: float = 60.0, poll_s: float = 0.02) -> Any:
    """condition()'s first true value; the timeout is only the limit of a failure (AssertionError saying what)."""
    deadline = time.monotonic() + timeout_s
    while not (value := condition()):
        assert time.monotonic() < deadline, f"{what}: not within {timeout_s:g} s"
        time.sleep(poll_s)
    return value


def wait_job(server: Server, job: str, timeout_s: float = 120.0) -> dict[str, Any]:
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        snapshot = server.get(f"/api/jobs/{job}").json()
        if snapshot["state"] in ("done", "failed", "cancelled"):
            return snapshot
        time.sleep(0.1)
    raise AssertionError(f"job {job} did not end within {timeout_s} s")


def wait_done(server: Server, job: str, timeout_s: float = 120.0) -> dict[str, Any]:
    """The job's snapshot once it ended done (AssertionError with its error otherwise)."""
    snapshot = wait_job(server, job, timeout_s)
    assert snapshot["state"] == "done", f"job {job} {snapshot['state']}: {snapshot.get('error')}"
    return snapshot


@dataclass
class Command:
    """A trajectory command as the watcher saw it, with the joint states the robot last published before."""

    joint_names: list[str]
    points: list[tuple[float, list[float]]]  # (time_from_start s, positions)
    start: dict[str, float]  # rad
    received: float  # time.monotonic()


@dataclass
class Watcher:
    """A node in the test process on the run's graph: every JointTrajectory on `command`, the latest joint
    states, and every robot_description."""

    command: str = "/joint_trajectory_controller/joint_trajectory"
    commands: list[Command] = field(default_factory=list)
    descriptions: list[str] = field(default_factory=list)
    joints: dict[str, float] = field(default_factory=dict)
    joints_at: float = 0.0
    lock: threading.Lock = field(default_factory=threading.Lock)
    moved: threading.Condition = field(init=False)  # notified on each joint state

    def __post_init__(self) -> None:
        self.moved = threading.Condition(self.lock)

    def start(self) -> Watcher:
        from sensor_msgs.msg import JointState
        from std_msgs.msg import String
        from trajectory_msgs.msg import JointTrajectory

        from app.drivers.ros2.link import COMMAND_QOS, LATCHED_QOS, SENSOR_QOS, Link

        self.link = Link(f"watcher_{os.getpid()}")
        node = self.link.node
        self._commands = node.create_subscription(JointTrajectory, self.command, self._on_command, COMMAND_QOS)
        self.link.listen(JointState, "/joint_states", SENSOR_QOS, self._on_joints)
        node.create_subscription(String, "/robot_description", self._on_description, LATCHED_QOS)
        return self

    def wait_commanders(self, count: int = 1, timeout_s: float = 60.0) -> None:
        """Until `count` publishers of the command topic (the desk's) are matched with this watcher: a command
        sent before that would not reach it (reliable, volatile)."""
        wait_until(
            lambda: self._commands.get_publisher_count() >= count, "the desk's commands reach the watcher", timeout_s
        )

    def wait_joint_states(self, timeout_s: float = 60.0) -> None:
        wait_until(lambda: self.joints_at > 0, "joint states reach the watcher", timeout_s)

    def seen_commands(self) -> list[Command]:
        with self.lock:
            return list(self.commands)

    def _on_command(self, msg: Any) -> None:
        points = [(p.time_from_start.sec + p.time_from_start.nanosec * 1e-9, list(p.positions)) for p in msg.points]
        with self.lock:
            self.commands.append(Command(list(msg.joint_names), points, dict(self.joints), time.monotonic()))

    def _on_joints(self, msg: Any) -> None:
        with self.lock:
            self.joints = dict(zip(msg.name, msg.position, strict=False))
            self.joints_at = time.monotonic()
            self.moved.notify_all()

    def _on_description(self, msg: Any) -> None:
        with self.lock:
            self.descriptions.append(msg.data)

    def positions(self, names: list[str]) -> np.ndarray:
        with self.lock:
            return np.array([self.joints[n] for n in names])

    def wait_still(self, names: list[str], for_s: float = 0.3, timeout_s: float = 30.0) -> np.ndarray:
        """The joint states once unchanged for for_s (as they arrive here), waited for joint state by joint state;
        timeout_s only bounds a failure."""
        give_up = time.monotonic() + timeout_s
        with self.lock:
            q, since = np.array([self.joints[n] for n in names]), self.joints_at
            while self.joints_at - since < for_s:
                assert self.moved.wait(give_up - time.monotonic()), "the robot did not come to rest"
                now = np.array([self.joints[n] for n in names])
                if not np.array_equal(now, q):
                    q, since = now, self.joints_at
            return q

    def set_sim_speed(self, speed: float, timeout_s: float = 10.0) -> None:
        """Set `calib sim-ros2`'s speed parameter (its next trajectories run at that speed)."""
        from rcl_interfaces.msg import Parameter, ParameterType, ParameterValue
        from rcl_interfaces.srv import SetParameters

        client = self.link.node.create_client(SetParameters, "/robot_state_publisher/set_parameters")
        try:
            assert client.wait_for_service(timeout_sec=timeout_s)
            value = ParameterValue(type=ParameterType.PARAMETER_DOUBLE, double_value=float(speed))
            future = client.call_async(SetParameters.Request(parameters=[Parameter(name="speed", value=value)]))
            answered = threading.Event()
            future.add_done_callback(lambda _: answered.set())
            assert answered.wait(timeout_s), "the simulated robot did not answer"
            assert future.result().results[0].successful
        finally:
            self.link.node.destroy_client(client)

    def close(self) -> None:
        self.link.close()


def limit_violations(
    commands: list[Command], profile: Any, margin_deg: float = 1.0, margin_m: float = 0.001
) -> list[str]:
    """Every command point outside the joint limits less the margin, or faster than a velocity limit (from the
    joint states the robot published before the command; 2% and 1 ms allowed for the time between). Commands
    are in ROS units (rad, m); the profile's prismatic joints in its length unit."""
    lower, upper = profile.limits_less_margin(margin_deg, margin_m)
    index = {j.name: k for k, j in enumerate(profile.joints)}
    to_unit = length_factor("m", profile.length_unit)
    bad = []
    for n, c in enumerate(commands):
        previous = c.start
        t_previous = 0.0
        for t, positions in c.points:
            for name, ros_value in zip(c.joint_names, positions, strict=True):
                k = index[name]
                scale = to_unit if profile.joints[k].prismatic else 1.0
                value = ros_value * scale
                if not lower[k] - 1e-9 <= value <= upper[k] + 1e-9:
                    shown = f"{profile.joint_to_display(k, value):.2f} {profile.joint_display_unit(k)}"
                    bad.append(f"command {n}: {name} {shown} outside the limits less the margin")
                if name in previous:
                    need = abs(ros_value - previous[name]) * scale / profile.joints[k].velocity
                    if need > 1.02 * (t - t_previous) + 1e-3:
                        bad.append(f"command {n}: {name} needs {need:.3f} s, given {t - t_previous:.3f} s")
            previous, t_previous = dict(zip(c.joint_names, positions, strict=True)), t
    return bad


def driver_look(profile_path: Path, q: np.ndarray, picture: np.ndarray, folder: Path) -> Any:
    """The data sensor's sighting of one look of the ROS 2 driver at a camera image `picture` (grey, H x W), handed
    to it as its subscriptions would (no graph traffic): the robot stood still at q (rad) a second before the
    image, its CameraInfo fx = fy = 600, cx = 320, cy = 240."""
    from sensor_msgs.msg import CameraInfo, Image, JointState

    from app.clock import ManualClock
    from app.drivers.ros2.connection import load_connection
    from app.drivers.ros2.driver import ros2_driver
    from app.drivers.ros2.link import Link
    from app.drivers.ros2.sim_node import Topics, connection_doc
    from calib_core import load_profile
    from calib_core.units import length_factor

    profile = load_profile(profile_path)
    doc = connection_doc(str(profile_path), "charuco", profile, Topics("/charuco"))
    (folder / "charuco.yaml").write_text(yaml.safe_dump({**doc, "measurement_wait_s": 0.05}), encoding="utf-8")
    link = Link(f"look_test_{os.getpid()}")
    clock = ManualClock()
    driver = ros2_driver(profile, load_connection(folder / "charuco.yaml"), link, clock=clock)
    robot = driver.transport
    to_m = np.array([length_factor(profile.length_unit, "m") if j.prismatic else 1.0 for j in profile.joints])
    try:
        t = link.now_s()
        for k in range(3):  # the robot stands still at q: its settled joint states (metres) stamped t - 1 s
            state = JointState(name=[j.name for j in profile.joints], position=list(map(float, q * to_m)))
            state.header.stamp.sec, state.header.stamp.nanosec = int(t - 1), k
            robot._on_joints(state)
        robot._on_info("cam")(CameraInfo(k=[600.0, 0, 320, 0, 600.0, 240, 0, 0, 1]))
        height, width = picture.shape
        image = Image(height=height, width=width, encoding="mono8", step=width, data=picture.tobytes())
        image.header.stamp.sec, image.header.stamp.nanosec = int(t), int(t % 1 * 1e9)
        robot._on_image("cam")(image)
        looks: list = []
        looking = threading.Thread(target=lambda: looks.append(driver.look()))
        looking.start()
        clock.run(lambda: not looking.is_alive(), threads=1, step_s=0.01)
        looking.join()
        return looks[0].sightings[0]
    finally:
        driver.close()
