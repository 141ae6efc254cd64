"""The desk and a robot on a ROS 2 graph, through real DDS between processes (the `ros2` extra).

    .venv/bin/python benchmarks/ros2.py               # the demo arm (docs/ros2) at its real speed
    .venv/bin/python benchmarks/ros2.py --speed 4     # quicker: trajectories run 4 times as fast

Prints: the time from `calib serve --ros2` to the robot listed by GET /api/robots (and a desk without ROS 2,
for comparison); the desk's CPU while it idles beside the robot's joint stream; command-to-motion latency (a
JointTrajectory published here until the joint states move; the robot publishes them at 100 Hz, so up to 10 ms
of it is the robot's period); measurement latency (receipt here minus header.stamp, for the mocap points and
the joint states); a 30-configuration replay's wall time against the sum of its motion times (each command's
time_from_start over the speed), the overhead per frame; the desk's memory (VmRSS) with the driver and
without. Runs on a graph of its own (a random ROS_DOMAIN_ID, this machine only).
"""

from __future__ import annotations

import argparse
import math
import os
import sys
import tempfile
import threading
import time
from pathlib import Path

import httpx
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent / "tests"))
from browser import free_port
from ros2_graph import ARM_DIR, Watcher, arm_sim, calib, graph_env, served_ros2, wait_job

IDLE_S = 5.0  # how long the desk's idle CPU is measured


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--speed", type=float, default=1.0, help="the simulated arm's speed (default 1: real time)")
    ap.add_argument("--configurations", type=int, default=30)
    args = ap.parse_args()
    env = graph_env()
    os.environ.update(env)
    graph = f"ROS_DOMAIN_ID={env['ROS_DOMAIN_ID']}, {env['ROS_AUTOMATIC_DISCOVERY_RANGE']}"
    print(f"graph: {graph}; the arm at speed {args.speed:g}")
    sim = arm_sim(env)
    sim.args[sim.args.index("--speed") + 1] = str(args.speed)
    sim.start()
    watcher = Watcher().start()
    try:
        with tempfile.TemporaryDirectory() as tmp:
            baseline_s, baseline_kb = _desk_without_ros2(Path(tmp) / "plain")
            # Started with the arm still, as a desk meets a robot: the latency test after it moves the arm.
            t0 = time.perf_counter()
            with served_ros2(ARM_DIR / "arm-connection.yaml", Path(tmp) / "data", env) as server:
                while "arm" not in {r["name"] for r in server.get("/api/robots").json()}:
                    time.sleep(0.05)
                listed_s = time.perf_counter() - t0
                print(f"calib serve --ros2 to the robot listed: {listed_s:.1f} s (without ROS 2: {baseline_s:.1f} s)")
                busy = _cpu_s(server.process.pid)
                time.sleep(IDLE_S)
                busy = (_cpu_s(server.process.pid) - busy) / IDLE_S
                print(f"the desk idle beside the robot's 100 Hz joint states: {busy:.2f} of a core ({IDLE_S:g} s)")
                latency(watcher)
                replay(server, watcher, args.configurations, args.speed)
                kb = _rss_kb(server.process.pid)
                mib, plain = kb / 1024, baseline_kb / 1024
                print(f"desk memory (VmRSS) after the replay: {mib:.0f} MiB (without ROS 2, idle: {plain:.0f} MiB)")
    finally:
        watcher.close()
        sim.stop()


def latency(watcher: Watcher, moves: int = 20) -> None:
    """Command to motion, and the age of the measurements on receipt."""
    from geometry_msgs.msg import PointStamped
    from trajectory_msgs.msg import JointTrajectory, JointTrajectoryPoint

    from app.drivers.ros2.link import COMMAND_QOS, SENSOR_QOS

    node = watcher.link.node
    ages: dict[str, list[float]] = {"mocap points": [], "joint states": []}
    lock = threading.Lock()

    def age(kind: str):
        def on(msg) -> None:
            now = node.get_clock().now().nanoseconds * 1e-9
            with lock:
                ages[kind].append(now - (msg.header.stamp.sec + msg.header.stamp.nanosec * 1e-9))

        return on

    from sensor_msgs.msg import JointState

    node.create_subscription(PointStamped, "/mocap/point", age("mocap points"), SENSOR_QOS)
    node.create_subscription(JointState, "/joint_states", age("joint states"), SENSOR_QOS)
    publisher = node.create_publisher(JointTrajectory, watcher.command, COMMAND_QOS)
    while publisher.get_subscription_count() == 0 or not watcher.joints:
        time.sleep(0.02)
    names = ["shoulder_pan", "shoulder_lift", "elbow", "wrist_1", "wrist_2", "wrist_3"]
    delays = []
    for k in range(moves):
        time.sleep(0.3)
        q0 = watcher.positions(names)
        goal = q0.copy()
        goal[2] += math.radians(5.0 if k % 2 == 0 else -5.0)
        point = JointTrajectoryPoint(positions=[float(v) for v in goal])
        point.time_from_start.nanosec = 200_000_000
        msg = JointTrajectory(joint_names=names, points=[point])
        t0 = time.perf_counter()
        publisher.publish(msg)
        while np.array_equal(watcher.positions(names), q0):
            time.sleep(0.0002)
        delays.append(time.perf_counter() - t0)
    time.sleep(0.3)
    print(f"command to motion: median {_ms(delays, 50)} ms, p90 {_ms(delays, 90)} ms ({moves} moves)")
    with lock:
        for kind, values in ages.items():
            print(f"{kind} latency (receipt - header.stamp): median {_ms(values, 50)} ms, p90 {_ms(values, 90)} ms")


def replay(server, watcher: Watcher, n: int, speed: float) -> None:
    sid = server.post("/api/sessions", json={"robot": "arm", "name": "benchmark"}).json()["id"]
    first = len(watcher.commands)
    t0 = time.perf_counter()
    job = server.post(f"/api/sessions/{sid}/replay", json={"count": n}).json()["job"]
    state = wait_job(server, job, timeout_s=600)
    wall = time.perf_counter() - t0
    assert state["state"] == "done", state
    moves = [c for c in watcher.commands[first:] if c.points]
    motion = sum(c.points[-1][0] for c in moves) / speed
    frames = server.get(f"/api/sessions/{sid}").json()["frames"]
    measured = sum(f["status"] == "measured" for f in frames)
    print(
        f"replay of {n} configurations: {wall:.1f} s wall, {motion:.1f} s of motion ({len(moves)} trajectories), "
        f"overhead {(wall - motion) / n * 1e3:.0f} ms per frame (settling 0.3 s included); {measured} measured"
    )


def _desk_without_ros2(data_dir: Path) -> tuple[float, int]:
    """The same desk's start (GET /api/robots answers) and memory without a ROS 2 robot."""
    import subprocess

    port = free_port()
    t0 = time.perf_counter()
    proc = subprocess.Popen(
        calib("serve", "--port", str(port), "--data-dir", str(data_dir)),
        cwd=ARM_DIR.parent.parent,
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
    )
    try:
        while True:
            try:
                if httpx.get(f"http://127.0.0.1:{port}/api/robots", timeout=5).status_code == 200:
                    break
            except httpx.HTTPError:
                time.sleep(0.05)
        return time.perf_counter() - t0, _rss_kb(proc.pid)
    finally:
        proc.terminate()
        proc.wait(timeout=20)


def _cpu_s(pid: int) -> float:
    """The process's user + system time so far, s."""
    fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


def _rss_kb(pid: int) -> int:
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith("VmRSS:"):
            return int(line.split()[1])
    raise RuntimeError("no VmRSS")


def _ms(values: list[float], q: float) -> str:
    return f"{np.percentile(np.asarray(values) * 1e3, q):.1f}"


if __name__ == "__main__":
    main()
