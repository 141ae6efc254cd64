"""The CPU a desk's ROS 2 link spends on each message it listens to (the `ros2` extra): `Link.listen`'s thread of its
own against a subscription spun by rclpy's executor (as every listened topic was), alternating, one at a time.

    .venv/bin/python benchmarks/ros2_listen.py [--rate 100] [--joints 26] [--seconds 10] [--runs 2]

A process of its own publishes sensor_msgs/JointState (`--joints` names, NAO's 26 by default) at `--rate` Hz on a
graph of this run's own (a random ROS_DOMAIN_ID, this machine only); this process listens and prints, per way and
run, the messages a second it received, its CPU in % of a core and in ms a message.
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent.parent / "tests"))
from ros2_graph import graph_env

PUBLISHER = """
import sys, time
from sensor_msgs.msg import JointState
from app.drivers.ros2.link import Link
rate, joints = float(sys.argv[1]), int(sys.argv[2])
link = Link("listen_bench_talker")
publisher = link.node.create_publisher(JointState, "/joint_states", 10)  # as calib sim-ros2 publishes them
msg = JointState(name=[f"joint_{k}" for k in range(joints)], position=[0.0] * joints)
print("ready", flush=True)
due = time.monotonic()
while True:
    due += 1 / rate
    time.sleep(max(0.0, due - time.monotonic()))
    msg.header.stamp = link.node.get_clock().now().to_msg()
    publisher.publish(msg)
"""


def measure(way: str, seconds: float) -> tuple[float, float, float]:
    """Messages a second, % of a core, ms of CPU a message, of one link listening `way`."""
    from sensor_msgs.msg import JointState

    from app.drivers.ros2.link import SENSOR_QOS, Link

    count = [0]

    def heard(msg: object) -> None:
        count[0] += 1

    link = Link(f"listen_bench_{way}")
    try:
        if way == "listen":
            link.listen(JointState, "/joint_states", SENSOR_QOS, heard)
        else:
            link.node.create_subscription(JointState, "/joint_states", heard, SENSOR_QOS)
        deadline = time.monotonic() + 30
        while count[0] < 10:  # matched and streaming
            assert time.monotonic() < deadline, "no joint states from the publisher"
            time.sleep(0.05)
        n0, cpu0, t0 = count[0], time.process_time(), time.monotonic()
        time.sleep(seconds)
        n, cpu, t = count[0] - n0, time.process_time() - cpu0, time.monotonic() - t0
    finally:
        link.close()
    return n / t, 100 * cpu / t, 1000 * cpu / max(n, 1)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--rate", type=float, default=100.0, help="the joint states' rate, Hz")
    ap.add_argument("--joints", type=int, default=26)
    ap.add_argument("--seconds", type=float, default=10.0, help="each measurement's length")
    ap.add_argument("--runs", type=int, default=2)
    args = ap.parse_args()
    os.environ.update(graph_env())
    root = Path(__file__).resolve().parent.parent
    talker = subprocess.Popen(
        [sys.executable, "-c", PUBLISHER, str(args.rate), str(args.joints)],
        cwd=root,
        env={**os.environ, "PYTHONPATH": str(root)},
        stdout=subprocess.PIPE,
        text=True,
    )
    try:
        assert talker.stdout is not None and talker.stdout.readline().strip() == "ready", "the publisher did not start"
        print(f"JointState of {args.joints} joints at {args.rate:g} Hz, {args.seconds:g} s a measurement")
        for run in range(args.runs):
            for way in ("listen", "executor"):
                rate, core, per = measure(way, args.seconds)
                print(f"run {run + 1} {way:>8}: {rate:6.1f} msg/s  {core:5.1f}% of a core  {per:.3f} ms a message")
    finally:
        talker.terminate()
        talker.wait()


if __name__ == "__main__":
    main()
