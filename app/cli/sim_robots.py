"""The simulated robots as real ones are reached: sim-ros2 (a ROS 2 node) and sim-naoqi (a NAO over libqi), each
serving until interrupted.
"""

from __future__ import annotations

import argparse
import os
from collections.abc import Callable
from pathlib import Path

import yaml

from calib_core import InputError, write_atomic
from calib_core.model import BUILTIN_PROFILES

from .common import Command, load_robot


def _sim_ros2_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--robot", required=True, help="a built-in robot (nao, motoman) or a profile file")
    p.add_argument("--urdf", help="the robot's URDF, for a profile that says urdf: ros2")
    p.add_argument("--seed", type=int, default=1, help="the hidden truth's and the noise's seed (default 1)")
    p.add_argument("--day", type=int, default=1, help="a later day: the joint offsets drifted (default 1)")
    p.add_argument("--speed", type=float, default=1.0, help="times the trajectories' timing (default 1)")
    p.add_argument("--rate", type=float, default=100.0, help="joint states per second (default 100)")
    p.add_argument("--namespace", default="", help="every topic and the node under this (/nao: robots side by side)")
    p.add_argument("--name", help="the robot's name in --connection-out (default: the profile's)")
    p.add_argument("--connection-out", metavar="FILE", help="write the desk's connection file for this node")
    p.add_argument("--refuse-apply", action="store_true", help="refuse every new robot_description (tests)")
    p.add_argument(
        "--stall-apply", action="store_true", help="never answer a new robot_description while running (tests)"
    )
    p.add_argument("--fault", help="what it does wrong (the fault harness: hang, slow:S, drop, nan:JOINT, ...)")
    p.add_argument("--fault-after", type=int, default=0, metavar="N", help="the fault strikes after N trajectories")


def _sim_naoqi_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--robot", default="nao", help="the built-in nao (default) or a NAO profile file")
    p.add_argument("--url", default="tcp://127.0.0.1:9559", help="where it listens (default tcp://127.0.0.1:9559)")
    p.add_argument("--seed", type=int, default=1, help="the hidden truth's and the noise's seed (default 1)")
    p.add_argument("--day", type=int, default=1, help="a later day: the joint offsets drifted (default 1)")
    p.add_argument("--speed", type=float, default=1.0, help="times the moves' speed (default 1)")
    p.add_argument("--name", help="the robot's name in --connection-out (default: the profile's)")
    p.add_argument("--connection-out", metavar="FILE", help="write the desk's connection file for this robot")
    p.add_argument(
        "--stiffness-off",
        action="append",
        default=[],
        metavar="JOINT",
        help="a joint whose stiffness stays off (tests)",
    )
    p.add_argument("--image-size", metavar="WxH", help="serve images of this size whatever is asked (tests)")
    p.add_argument(
        "--lacks", action="append", default=[], metavar="SERVICE.METHOD", help="a call it does not offer (tests)"
    )
    p.add_argument("--fault", help="what it does wrong (the fault harness: hang, slow:S, drop, nan:JOINT, ...)")
    p.add_argument("--fault-after", type=int, default=0, metavar="N", help="the fault strikes after N moves")


def _sim_ros2(args: argparse.Namespace) -> int:

    from ..drivers.ros2 import require

    require()
    from ..drivers.faults import parse_fault
    from ..drivers.ros2.sim_node import SimNode, Topics, connection_doc, load_sim_profile

    if not 0.1 <= args.speed <= 100 or not 1 <= args.rate <= 1000 or not 1 <= args.day <= 1000:
        raise InputError("--speed must be in 0.1..100, --rate in 1..1000 and --day in 1..1000")
    namespace = args.namespace.rstrip("/")
    if namespace and (not namespace.startswith("/") or not namespace[1:].replace("_", "").replace("/", "").isalnum()):
        raise InputError(f"--namespace {args.namespace!r}: expected a ROS 2 namespace like /nao")
    topics = Topics(namespace)
    fault = parse_fault(args.fault, "--fault") if args.fault else None
    profile, urdf = load_sim_profile(args.robot, None if args.urdf is None else Path(args.urdf))
    node = SimNode(
        profile,
        urdf,
        seed=args.seed,
        day=args.day,
        speed=args.speed,
        rate_hz=args.rate,
        refuse_apply=args.refuse_apply,
        stall_apply=args.stall_apply,
        topics=topics,
        fault=fault,
        fault_after=args.fault_after,
    )
    if args.connection_out:
        ref = args.robot if args.robot in BUILTIN_PROFILES else str(Path(args.robot).resolve())
        doc = connection_doc(ref, args.name or profile.name, profile, topics, args.speed)
        write_atomic(Path(args.connection_out), yaml.safe_dump(doc, sort_keys=False))
    domain = os.environ.get("ROS_DOMAIN_ID", "0")
    return _until_stopped(f"calib sim-ros2: {profile.name} on ROS_DOMAIN_ID={domain} (Ctrl-C ends it)", node.close)


def _sim_naoqi(args: argparse.Namespace) -> int:

    from ..drivers.naoqi import require

    require()
    from ..drivers.faults import parse_fault
    from ..drivers.naoqi.sim import SimNao, serve

    if not 0.1 <= args.speed <= 100 or not 1 <= args.day <= 1000:
        raise InputError("--speed must be in 0.1..100 and --day in 1..1000")
    if not args.url.startswith("tcp://"):
        raise InputError(f"--url {args.url!r}: expected tcp://host:port")
    size = None
    if args.image_size is not None:
        width, sep, height = args.image_size.partition("x")
        if not (sep and width.isdigit() and height.isdigit() and int(width) > 0 and int(height) > 0):
            raise InputError(f"--image-size {args.image_size!r}: expected WIDTHxHEIGHT in px, e.g. 320x240")
        size = (int(width), int(height))
    profile = load_robot(args)
    unknown = [j for j in args.stiffness_off if j not in [joint.name for joint in profile.joints]]
    if unknown:
        raise InputError(f"--stiffness-off {unknown[0]}: no such joint of {profile.name}")
    nao = SimNao(
        profile,
        seed=args.seed,
        day=args.day,
        speed=args.speed,
        stiffness_off=args.stiffness_off,
        image_size=size,
        lacks=args.lacks,
    )
    if args.fault:
        nao.faults.arm(parse_fault(args.fault, "--fault"), args.fault_after, "--fault")
    try:
        session = serve(nao, args.url)
    except RuntimeError as exc:
        raise InputError(f"--url {args.url}: cannot listen there ({exc})") from None
    if args.connection_out:
        ref = args.robot if args.robot in BUILTIN_PROFILES else str(Path(args.robot).resolve())
        from ..drivers.core import DEFAULT_SETTLE_S

        doc = {"robot": args.name or profile.name, "profile": ref, "url": args.url, "camera": 1}
        doc["settle_s"] = round(DEFAULT_SETTLE_S / args.speed, 6)  # the robot's time: it moves --speed times as fast
        write_atomic(Path(args.connection_out), yaml.safe_dump(doc, sort_keys=False))
    return _until_stopped(f"calib sim-naoqi: {profile.name} at {args.url} (Ctrl-C ends it)", session.close)


def _until_stopped(ready: str, close: Callable[[], object]) -> int:
    """A simulated robot's process: says it is `ready`, serves until SIGTERM or Ctrl-C, then close()."""
    import signal
    import threading

    done = threading.Event()
    signal.signal(signal.SIGTERM, lambda *_: done.set())
    print(ready, flush=True)
    try:
        done.wait()
    finally:
        close()
    return 0


# This module's subcommands, which app/cli/__init__.py's COMMANDS lists in calib --help's order.
SIM_ROS2 = Command(
    "sim-ros2", "a simulated robot as a ROS 2 node (the ros2 extra), until interrupted", _sim_ros2_arguments, _sim_ros2
)
SIM_NAOQI = Command(
    "sim-naoqi",
    "the simulated NAO served over libqi (the naoqi extra), until interrupted",
    _sim_naoqi_arguments,
    _sim_naoqi,
)
