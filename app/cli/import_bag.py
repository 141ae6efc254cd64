"""calib import-bag: a session folder from a ROS 1 or ROS 2 bag (still poses, images, detections), or with --tf
what calib handeye takes.
"""

from __future__ import annotations

import argparse
import shlex
import sys
import time
from pathlib import Path

from calib_core import InputError

from .common import Command, check_writable, load_calibration, load_robot


def _import_bag_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("bag", help="the ROS 1 .bag file, or the ROS 2 bag folder (or its .db3 / .mcap file)")
    p.add_argument("--robot", help="built-in profile (robonaut-a, nao) or a profile YAML file (not with --tf)")
    p.add_argument("--out", required=True, help="the session folder to write (a new one, or an earlier session)")
    p.add_argument(
        "--tf",
        metavar="BASE:TOOL",
        help="instead: the flange from /tf (the TOOL frame in the BASE frame) for a robot whose joint states were "
        "not recorded; --out gets what calib handeye takes (images/, poses.csv, camera.yaml from camera info)",
    )
    p.add_argument("--joint-topic", default="/joint_states", help="sensor_msgs/JointState topic (/joint_states)")
    p.add_argument(
        "--image-topic",
        action="append",
        help="an image topic (Image or CompressedImage); twice for a stereo head, left then right "
        "(default: the bag's only image topic; for a stereo head those naming left and right)",
    )
    p.add_argument(
        "--still-deg-s",
        type=float,
        help="still: every joint (with --tf: the tool) at most this fast, deg/s (default 1; 0.5)",
    )
    p.add_argument("--still-mm-s", type=float, help="with --tf: still, the tool at most this fast, mm/s (default 1)")
    p.add_argument("--still-s", type=float, help="still for at least this long, s (default 0.5)")
    p.add_argument("--name", help="the session's name (default: the folder's name)")
    p.add_argument("--calibration", help="the calibration the robot ran with (seeds the detectors; default nominal)")


def _import_bag(args: argparse.Namespace) -> int:
    if args.tf is not None:
        return _import_bag_tf(args)
    if args.robot is None:
        raise InputError("--robot: the robot whose joint states the bag recorded (or --tf BASE:TOOL without them)")
    from calib_core.io import import_bag  # rosbags loads only for this subcommand

    profile = load_robot(args)
    believed = load_calibration(args.calibration, profile).params(profile) if args.calibration else None
    check_writable(args.out, session=True)
    start = time.perf_counter()
    still = {k: v for k, v in (("still_deg_s", args.still_deg_s), ("still_s", args.still_s)) if v is not None}
    made_by = shlex.join(["calib", *sys.argv[1:]]) if sys.argv[0].endswith("calib") else "calib import-bag"
    result = import_bag(
        args.bag,
        profile,
        args.out,
        joint_topic=args.joint_topic,
        image_topics=args.image_topic,
        name=args.name,
        believed=believed,
        made_by=made_by,
        **still,
    )
    print(f"{result.summary()}, in {time.perf_counter() - start:.1f} s: {args.out}")
    return 0


def _import_bag_tf(args: argparse.Namespace) -> int:
    """import-bag --tf: a calib handeye folder from /tf and an image topic."""
    from calib_core.io import handeye_folder_from_bag

    base, sep, tool = args.tf.partition(":")
    if not sep or not base or not tool:
        raise InputError(f"--tf {args.tf!r}: expected BASE:TOOL, the frames' names (e.g. base_link:tool0)")
    if args.robot is not None:
        raise InputError("--robot and --tf: give one (--tf reads the flange's pose, not a robot's joints)")
    out = Path(args.out)
    if out.exists() and (not out.is_dir() or any(out.iterdir())):
        raise InputError("exists and is not an empty folder; give a new folder name", file=args.out)
    still = {
        k: v
        for k, v in (("still_mm_s", args.still_mm_s), ("still_deg_s", args.still_deg_s), ("still_s", args.still_s))
        if v is not None
    }
    topic = args.image_topic[0] if args.image_topic else None
    done = handeye_folder_from_bag(args.bag, out, base.strip(), tool.strip(), topic, **still)
    camera = "camera.yaml from its camera info" if done.camera else "no camera info: give calib handeye your --camera"
    print(
        f"{done.still} still moments of {tool} in {base}, {done.images} images from {done.image_topic} with their "
        f"poses; {camera}: {out}"
    )
    return 0


# This module's subcommands, which app/cli/__init__.py's COMMANDS lists in calib --help's order.
IMPORT_BAG = Command(
    "import-bag",
    "a session folder from a ROS 1 or ROS 2 bag: still poses, images, detections",
    _import_bag_arguments,
    _import_bag,
)
