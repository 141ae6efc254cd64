"""The `calib` command (specs/cli.md): solve, predict, plan, evaluate, simulate, detect-sphere, detect-board.

Bad input ends with exit status 2 and a message naming file, line and column; an internal failure
(a bug) with exit status 1 and one line (set CALIB_DEBUG=1 for the traceback); never a traceback
for the user's mistakes.
"""

from __future__ import annotations

import argparse
import contextlib
import csv
import importlib
import io
import json
import os
import shlex
import sys
import threading
import time
import traceback
from collections.abc import Callable, Sequence
from datetime import UTC, datetime, timedelta
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
import yaml

from calib_core import (
    Calibration,
    InputError,
    Problem,
    calibrate,
    evaluate,
    load_profile,
    read_dataset,
    to_csv,
    write_atomic,
)
from calib_core.dataset import Dataset
from calib_core.estimation import check_share, register, registration_params
from calib_core.io import (
    FrameRecord,
    measurement_values,
    parse_measured,
    plan_csv,
    readings_beyond_limits,
    select_rows,
    write_session,
)
from calib_core.model import BUILTIN_PROFILES, Profile
from calib_core.sim import Law, measured_on
from calib_core.units import length_factor

from .web.limits import DEFAULT_MAX_ROWS, DEFAULT_MAX_UPLOAD_BYTES, Limits

if TYPE_CHECKING:
    from calib_core.sim import ImageSimulation

    from .robots.desk_config import DeskConfig

SIGPIPE_STATUS = 141  # 128 + SIGPIPE: how a shell reports a command that wrote to a closed pipe


class _Parser(argparse.ArgumentParser):
    """argparse, but usage errors name the subcommand and exit 2 without a traceback."""

    def error(self, message: str) -> None:  # type: ignore[override]
        self.print_usage(sys.stderr)
        self.exit(2, f"{self.prog}: error: {message}\n")


WHERE_HELP = "use only the rows with this value in this column (repeatable; e.g. leica_frame_group=A)"
VERBOSE_HELP = "list each diagnostic of a kind that has several (by default: one line per kind, its parameters named)"


def _where(data: Dataset, items: list[str]) -> Dataset:
    where = {}
    for item in items:
        column, sep, value = item.partition("=")
        if not sep or not column:
            raise InputError(f"--where {item!r} must be COLUMN=VALUE")
        where[column.strip()] = value.strip()
    return select_rows(data, where) if where else data


def _parser() -> argparse.ArgumentParser:
    p = _Parser(prog="calib", description="Kinematic self-calibration of robots that see themselves.")
    sub = p.add_subparsers(dest="command", required=True, parser_class=_Parser)

    s = sub.add_parser("solve", help="calibrate from a dataset (CSV) and write a calibration (JSON)")
    s.add_argument("--robot", required=True, help="built-in profile (robonaut-a, nao) or a profile YAML file")
    s.add_argument(
        "--mode",
        required=True,
        help="robonaut-a: daily, full; nao: full (profiles may define more)",
    )
    s.add_argument("--data", required=True, help="the dataset CSV")
    s.add_argument("--where", action="append", default=[], metavar="COLUMN=VALUE", help=WHERE_HELP)
    s.add_argument("--base", help="calibration JSON to start from; keeps its non-estimated parameters")
    s.add_argument("--out", required=True, help="where to write the calibration JSON")
    s.add_argument("--holdout", type=float, default=0.0, help="share of configurations held out (0..0.9)")
    s.add_argument("--folds", type=int, default=0, help="k-fold cross-validation on the training part")
    s.add_argument("--method", default="lm", choices=["lm", "nelder-mead"], help="solver (default lm)")
    s.add_argument("--no-robust", action="store_true", help="plain least squares (no outlier rejection)")
    s.add_argument("--seed", type=int, default=0, help="seed of the held-out split")
    s.add_argument(
        "--minimal",
        action="store_true",
        help="estimate a minimal identifiable parameter set (QR of the data, no priors); hold and name the rest",
    )
    s.add_argument("--verbose", action="store_true", help=VERBOSE_HELP)

    pr = sub.add_parser("predict", help="add the model's predictions to each row of a dataset")
    pr.add_argument("--robot", required=True)
    pr.add_argument("--calibration", help="calibration JSON (default: the nominal model)")
    pr.add_argument("--data", required=True)
    pr.add_argument("--where", action="append", default=[], metavar="COLUMN=VALUE", help=WHERE_HELP)
    pr.add_argument("--out", required=True, help="CSV: the input rows plus prediction columns")

    pl = sub.add_parser(
        "plan", help="choose N configurations that make a calibration as accurate as it can be (before moving)"
    )
    pl.add_argument("--robot", required=True, help="built-in profile (robonaut-a, nao, motoman) or a profile YAML")
    pl.add_argument("--mode", required=True, help="the calibration mode the configurations are for")
    pl.add_argument("--configurations", required=True, type=int, metavar="N", help="how many to plan")
    pl.add_argument(
        "--base", help="calibration JSON the robot runs with (visibility and linearisation; default nominal)"
    )
    pl.add_argument("--seed", type=int, default=0, help="seed of the candidate configurations")
    pl.add_argument(
        "--criterion",
        choices=["task", "offsets", "d", "random"],
        help="task: least predicted error over the workspace; offsets: least variance of the joint offsets; "
        "d: D-optimal; random: a random draw (default: what the mode's `plan` says, else task)",
    )
    pl.add_argument("--out", required=True, help="the plan CSV (joint columns, no measurements)")

    ev = sub.add_parser("evaluate", help="the error figures of a calibration on data it was not fitted on")
    ev.add_argument("--robot", required=True)
    ev.add_argument("--calibration", required=True, help="calibration JSON")
    ev.add_argument("--data", required=True, help="CSV in the robot's format, with measurements")
    ev.add_argument("--where", action="append", default=[], metavar="COLUMN=VALUE", help=WHERE_HELP)
    ev.add_argument(
        "--register",
        action="store_true",
        help="fit the tracker's pose to these data first (another tracker set-up); the robot's parameters stay",
    )
    ev.add_argument("--json", action="store_true", help='one JSON object {"mean", "rms", "max", "n", "unit"}')

    so = sub.add_parser(
        "self-observe", help="calibrate from what the robot's cameras see of its markers (the CTU camera format)"
    )
    so.add_argument("--robot", required=True, help="a profile with camera1, camera2 and markers1, markers2 (motoman)")
    so.add_argument("--mode", default="cameras", help="the profile's mode (default cameras)")
    so.add_argument("--data", required=True, help="folder with camera_observations.csv and camera_poses.csv")
    so.add_argument("--source", action="append", default=[], help="use only this source_file (repeatable)")
    so.add_argument("--holdout", type=float, default=0.3, help="share of poses held out (default 0.3)")
    so.add_argument("--seed", type=int, default=0, help="seed of the held-out split")
    so.add_argument("--out", required=True, help="where to write the calibration JSON")
    so.add_argument("--verbose", action="store_true", help=VERBOSE_HELP)

    ex = sub.add_parser("export", help="what a driver takes: the calibrated URDF or the joint offsets (YAML)")
    ex.add_argument("--robot", help="built-in profile or a profile YAML file (not for a calib handeye output)")
    ex.add_argument("--calibration", required=True, help="calibration JSON (from solve, or from handeye)")
    ex.add_argument(
        "--format",
        required=True,
        choices=["urdf", "yaml", "bhuman", "ros2-static-tf", "urdf-joint", "easy-handeye"],
        help="urdf: corrected joint origins; yaml: offsets; bhuman: a NAO's jointCalibration.cfg (B-Human's form); "
        "of a calib handeye output: ros2-static-tf (a launch file publishing the camera on /tf_static), urdf-joint "
        "(a fixed joint to paste), easy-handeye (its calibration YAML)",
    )
    ex.add_argument("--parent", help="handeye: the camera's parent frame (default tool0 eye-in-hand, base_link)")
    ex.add_argument("--child", default="camera_optical_frame", help="handeye: the camera's (optical) frame")
    ex.add_argument("--out", required=True, help="the file to write")

    sim = sub.add_parser("simulate", help="write a dataset measured on the simulated robot")
    sim.add_argument("--robot", required=True)
    sim.add_argument("--configurations", type=int, help="how many (default: the profile's plan)")
    sim.add_argument("--day", type=int, default=1, help="2, 3, ...: a later day with drifted offsets")
    sim.add_argument("--seed", type=int, default=0)
    sim.add_argument("--outliers", type=float, default=0.0, help="share of failed detections")
    sim.add_argument("--out", help="the dataset CSV (points measured with the sensor's noise model)")
    sim.add_argument("--truth", help="also write the hidden true parameters (JSON)")
    sim.add_argument(
        "--session",
        help="instead: render camera images, run the detectors and write a session folder "
        "(session.json, data.csv from the detections, truth.json, images/)",
    )
    sim.add_argument("--name", help="the session's name (with --session)")
    sim.add_argument("--keep-images", type=int, help="with --session: keep the images of the first N frames")
    sim.add_argument("--calibration", help="with --session: the calibration the robot runs with (seeds the detectors)")
    sim.add_argument(
        "--days",
        type=int,
        help="a run of days: --out and --session name a folder that gets one dataset (day-01.csv ...) or one "
        "session folder (day-01/ ...) per day, and days.json saying when each was measured and its truth; the "
        "robot moves only as --drift and --shift say",
    )
    sim.add_argument(
        "--drift",
        action="append",
        default=[],
        metavar="PARAMETER:RATE",
        help="with --days: the parameter moves RATE a day (deg, the profile's length unit), e.g. LKneePitch:0.05",
    )
    sim.add_argument(
        "--shift",
        action="append",
        default=[],
        metavar="PARAMETER:CHANGE",
        help="the true robot's parameter off its profile's truth by CHANGE (deg, length unit), e.g. LTransX:2",
    )
    sim.add_argument("--start", help="with --days: the first day, ISO 8601 (default: the last day is today)")

    ds = sub.add_parser("detect-sphere", help="find the calibration sphere's centre in a depth map (BallFinder)")
    ds.add_argument("--depth", required=True, help="float32 depth in metres (.npy), 0 or NaN for no data")
    for name in ("fx", "fy", "cx", "cy"):
        ds.add_argument(f"--{name}", required=True, type=float, help=f"intrinsic {name}, px")
    ds.add_argument("--radius", required=True, type=float, help="sphere radius, m")
    ds.add_argument("--seed", help="predicted centre X,Y,Z in m, camera frame (write --seed=-0.1,0.2,0.8)")
    ds.add_argument("--json", action="store_true", help="one line of JSON (default: indented JSON)")

    db = sub.add_parser("detect-board", help="find a checkerboard's inner corners in an image")
    db.add_argument("--image", required=True, help="the camera image (PNG, JPEG, ...)")
    db.add_argument("--cols", required=True, type=int, help="inner corners per row (6 for the NAO sandals)")
    db.add_argument("--rows", required=True, type=int, help="inner corners per column (4 for the NAO sandals)")
    db.add_argument("--json", action="store_true", help="one line of JSON (default: indented JSON)")

    he = sub.add_parser(
        "handeye",
        help="a camera against an arm from images of a board and the flange poses the controller reported (no URDF)",
    )
    he.add_argument(
        "--poses", required=True, help="CSV (image, x, y, z, rx, ry, rz or qx, qy, qz, qw), or a 4 x 4 matrix a line"
    )
    he.add_argument("--images", required=True, help="the folder of the board's images")
    he.add_argument(
        "--camera", required=True, help="the camera's calibration: ROS camera_info YAML or OpenCV's FileStorage"
    )
    he.add_argument(
        "--board",
        required=True,
        help="chessboard:COLSxROWS:SQUARE_MM or charuco:SQUARES_XxSQUARES_Y:SQUARE_MM:MARKER_MM:DICT",
    )
    he.add_argument("--setup", required=True, choices=["eye-in-hand", "eye-to-hand"])
    he.add_argument("--out", required=True, help="the calibration (JSON, specs handeye-poses.md)")
    he.add_argument("--holdout-images", help="images never fitted, comma-separated; the output gives their error")
    he.add_argument("--intrinsics", choices=["fixed", "free"], default="fixed", help="free: estimated with the poses")
    he.add_argument("--length-unit", choices=["m", "mm"], default="m", help="the poses' positions (default m)")
    he.add_argument("--angle-unit", choices=["rad", "deg"], default="rad", help="a rotation vector's (default rad)")

    ib = sub.add_parser(
        "import-bag", help="a session folder from a ROS 1 or ROS 2 bag: still poses, images, detections"
    )
    ib.add_argument("bag", help="the ROS 1 .bag file, or the ROS 2 bag folder (or its .db3 / .mcap file)")
    ib.add_argument("--robot", help="built-in profile (robonaut-a, nao) or a profile YAML file (not with --tf)")
    ib.add_argument("--out", required=True, help="the session folder to write (a new one, or an earlier session)")
    ib.add_argument(
        "--tf",
        metavar="BASE:TOOL",
        help="instead: the flange from /tf (the TOOL frame in the BASE frame) for a robot whose joint states were "
        "not recorded; --out gets what calib handeye takes (images/, poses.csv, camera.yaml from camera info)",
    )
    ib.add_argument("--joint-topic", default="/joint_states", help="sensor_msgs/JointState topic (/joint_states)")
    ib.add_argument(
        "--image-topic",
        action="append",
        help="an image topic (Image or CompressedImage); twice for a stereo head, left then right "
        "(default: the bag's only image topic; for a stereo head those naming left and right)",
    )
    ib.add_argument(
        "--still-deg-s",
        type=float,
        help="still: every joint (with --tf: the tool) at most this fast, deg/s (default 1; 0.5)",
    )
    ib.add_argument("--still-mm-s", type=float, help="with --tf: still, the tool at most this fast, mm/s (default 1)")
    ib.add_argument("--still-s", type=float, help="still for at least this long, s (default 0.5)")
    ib.add_argument("--name", help="the session's name (default: the folder's name)")
    ib.add_argument("--calibration", help="the calibration the robot ran with (seeds the detectors; default nominal)")

    sv = sub.add_parser("serve", help="start the dashboard (simulated robots, sample sessions) in a browser")
    sv.add_argument("--host", default="127.0.0.1", help="address to bind (default 127.0.0.1: this machine only)")
    sv.add_argument("--port", type=int, default=8000, help="the page and the API (default 8000)")
    sv.add_argument(
        "--viser-port",
        type=int,
        default=0,
        help="the 3-D scene server's port, on 127.0.0.1 only: browsers reach the scene through --port "
        "(default: any free one)",
    )
    sv.add_argument("--data-dir", default="data", help="where sessions, calibrations and history live (default data/)")
    sv.add_argument(
        "--sim-speed", type=float, default=1.0, help="the simulated robots' speed, times their joint velocity limits"
    )
    sv.add_argument(
        "--desk",
        metavar="CONFIG.yaml",
        help="the desk configuration: which robots (name, profile, driver); default: the built-in robots, simulated",
    )
    sv.add_argument(
        "--ros2",
        action="append",
        default=[],
        metavar="CONNECTION.yaml",
        help="a robot on its ROS 2 graph (specs ros2.md; the ros2 extra); may be given more than once",
    )
    sv.add_argument(
        "--naoqi",
        action="append",
        default=[],
        metavar="CONNECTION.yaml",
        help="a NAO through NAOqi (specs naoqi.md; the naoqi extra); may be given more than once",
    )
    sv.add_argument(
        "--max-upload-mb",
        type=float,
        default=DEFAULT_MAX_UPLOAD_BYTES / (1024 * 1024),
        help="the largest file an import or a robot's upload may be, MB (default %(default)g)",
    )
    sv.add_argument(
        "--max-rows",
        type=int,
        default=DEFAULT_MAX_ROWS,
        help="the most rows a CSV import, and observations a calibration, may have (default %(default)d)",
    )
    sv.add_argument(
        "--new-token",
        action="store_true",
        help="bound off loopback: replace the access token (printed once) with a new one",
    )
    r2 = sub.add_parser("sim-ros2", help="a simulated robot as a ROS 2 node (the ros2 extra), until interrupted")
    r2.add_argument("--robot", required=True, help="a built-in robot (nao, motoman) or a profile file")
    r2.add_argument("--urdf", help="the robot's URDF, for a profile that says urdf: ros2")
    r2.add_argument("--seed", type=int, default=1, help="the hidden truth's and the noise's seed (default 1)")
    r2.add_argument("--day", type=int, default=1, help="a later day: the joint offsets drifted (default 1)")
    r2.add_argument("--speed", type=float, default=1.0, help="times the trajectories' timing (default 1)")
    r2.add_argument("--rate", type=float, default=100.0, help="joint states per second (default 100)")
    r2.add_argument("--namespace", default="", help="every topic and the node under this (/nao: robots side by side)")
    r2.add_argument("--name", help="the robot's name in --connection-out (default: the profile's)")
    r2.add_argument("--connection-out", metavar="FILE", help="write the desk's connection file for this node")
    r2.add_argument("--refuse-apply", action="store_true", help="refuse every new robot_description (tests)")
    r2.add_argument(
        "--stall-apply", action="store_true", help="never answer a new robot_description while running (tests)"
    )
    r2.add_argument("--fault", help="what it does wrong (the fault harness: hang, slow:S, drop, nan:JOINT, ...)")
    r2.add_argument("--fault-after", type=int, default=0, metavar="N", help="the fault strikes after N trajectories")
    nq = sub.add_parser("sim-naoqi", help="the simulated NAO served over libqi (the naoqi extra), until interrupted")
    nq.add_argument("--robot", default="nao", help="the built-in nao (default) or a NAO profile file")
    nq.add_argument("--url", default="tcp://127.0.0.1:9559", help="where it listens (default tcp://127.0.0.1:9559)")
    nq.add_argument("--seed", type=int, default=1, help="the hidden truth's and the noise's seed (default 1)")
    nq.add_argument("--day", type=int, default=1, help="a later day: the joint offsets drifted (default 1)")
    nq.add_argument("--speed", type=float, default=1.0, help="times the moves' speed (default 1)")
    nq.add_argument("--name", help="the robot's name in --connection-out (default: the profile's)")
    nq.add_argument("--connection-out", metavar="FILE", help="write the desk's connection file for this robot")
    nq.add_argument(
        "--stiffness-off",
        action="append",
        default=[],
        metavar="JOINT",
        help="a joint whose stiffness stays off (tests)",
    )
    nq.add_argument("--image-size", metavar="WxH", help="serve images of this size whatever is asked (tests)")
    nq.add_argument(
        "--lacks", action="append", default=[], metavar="SERVICE.METHOD", help="a call it does not offer (tests)"
    )
    nq.add_argument("--fault", help="what it does wrong (the fault harness: hang, slow:S, drop, nan:JOINT, ...)")
    nq.add_argument("--fault-after", type=int, default=0, metavar="N", help="the fault strikes after N moves")
    return p


def main(argv: Sequence[str] | None = None) -> int:
    """Run one command; its exit status. A reader that closes our output early (`calib ... | head -1`) ends
    the command quietly with 141, the status of a command a shell sees killed by SIGPIPE (Python ignores the
    signal, so the write raises BrokenPipeError instead: never a traceback or an "internal error")."""
    try:
        try:
            status = _run(argv)
        except SystemExit as exc:  # argparse: --help, a usage error
            status = exc.code if isinstance(exc.code, int) else 0 if exc.code is None else 2
        sys.stdout.flush()  # a closed pipe shows here rather than at the interpreter's exit
    except BrokenPipeError:
        # Whatever is left in the buffer can never be written: point stdout at /dev/null so that the
        # interpreter's own flush at exit does not report the broken pipe once more.
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, sys.stdout.fileno())
        os.close(devnull)
        return SIGPIPE_STATUS
    return status


def _run(argv: Sequence[str] | None) -> int:
    args = _parser().parse_args(argv)
    try:
        commands = {
            "solve": _solve,
            "predict": _predict,
            "evaluate": _evaluate,
            "plan": _plan,
            "export": _export,
            "self-observe": _self_observe,
            "simulate": _simulate,
            "detect-sphere": _detect_sphere,
            "detect-board": _detect_board,
            "handeye": _handeye,
            "import-bag": _import_bag,
            "serve": _serve,
            "sim-ros2": _sim_ros2,
            "sim-naoqi": _sim_naoqi,
        }
        return commands[args.command](args)
    except InputError as exc:
        print(f"calib {args.command}: error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print(f"calib {args.command}: interrupted", file=sys.stderr)
        return 130
    except BrokenPipeError:  # our output's reader went away: main ends quietly
        raise
    except Exception as exc:  # a bug: one line, the traceback only on request
        if os.environ.get("CALIB_DEBUG"):
            traceback.print_exc()
        print(
            f"calib {args.command}: internal error ({exc.__class__.__name__}: {exc}); please report it",
            file=sys.stderr,
        )
        return 1


def _load_robot(args: argparse.Namespace) -> Profile:
    """The --robot profile; what loading it tolerated (a URDF's quirks) goes to stderr as notes."""
    profile = load_profile(args.robot)
    for note in profile.notes:
        print(f"calib {args.command}: note: {note}", file=sys.stderr)
    return profile


def _read_data(args: argparse.Namespace, profile: Profile) -> Dataset:
    """--data (its --where rows); readings beyond a joint's limits go to stderr as notes."""
    data = read_dataset(profile, args.data)
    for note in readings_beyond_limits(profile, data):
        print(f"calib {args.command}: note: {note}", file=sys.stderr)
    return _where(data, args.where)


def _solve(args: argparse.Namespace) -> int:
    check_share(args.holdout, "--holdout")
    if args.folds < 0 or args.folds == 1:
        raise InputError(f"--folds {args.folds} must be 0 (none) or at least 2")
    profile = _load_robot(args)
    profile.mode(args.mode)
    base = _load_calibration(args.base, profile) if args.base else None
    data = _read_data(args, profile)
    _check_writable(args.out)
    cal = calibrate(
        profile,
        data,
        args.mode,
        base,
        holdout=args.holdout,
        folds=args.folds,
        method=args.method,
        robust=not args.no_robust,
        seed=args.seed,
        minimal=args.minimal,
    )
    _save(args.out, lambda: cal.save(args.out))
    _print_summary(cal, args.verbose)
    print(f"  written: {args.out}")
    return 0


def _print_summary(cal: Calibration, verbose: bool) -> None:
    """The calibration's summary, its diagnostics one line per kind; how to see each when some were grouped."""
    print(cal.summary(verbose))
    grouped = sum(len(g.messages) for g in cal.diagnostic_groups() if len(g.messages) > 1)
    if grouped and not verbose:
        print(f"  ({grouped} findings grouped above: --verbose lists each)")


def _predict(args: argparse.Namespace) -> int:
    profile = _load_robot(args)
    cal = _load_calibration(args.calibration, profile) if args.calibration else None
    p = cal.params(profile) if cal else profile.nominal()
    data = _read_data(args, profile)
    _check_writable(args.out)
    if cal is None and registration_params(profile):
        p = register(profile, data, p)  # the nominal model, seen from where the tracker stands
    pred = Problem(profile, data, [], p, noise_model=False).predict(p)
    fmt = profile.data
    pred = measurement_values(profile, pred[:, : profile.sensors[fmt.sensor].dim])
    out = io.StringIO()
    w = csv.writer(out, lineterminator="\n")
    w.writerow([*data.header, *fmt.prediction_columns])
    for row, values in zip(data.rows, pred, strict=True):
        w.writerow([*row, *(f"{v:.6f}" for v in values)])
    _save(args.out, lambda: write_atomic(Path(args.out), out.getvalue()))
    print(
        f"{len(data.rows)} rows predicted with "
        f"{'calibration ' + args.calibration if cal else 'the nominal model'}"
        f"{' (registration fitted to these rows)' if cal is None and registration_params(profile) else ''}: {args.out}"
    )
    return 0


def _plan(args: argparse.Namespace) -> int:
    from calib_core.estimation import plan

    profile = _load_robot(args)
    profile.mode(args.mode)
    if args.configurations < 1:
        raise InputError(f"--configurations must be at least 1, got {args.configurations}")
    p_base = _load_calibration(args.base, profile).params(profile) if args.base else None
    _check_writable(args.out)
    criterion = args.criterion or profile.mode(args.mode).plan
    result = plan(profile, args.mode, args.configurations, p_base, seed=args.seed, criterion=criterion)
    _save(args.out, lambda: write_atomic(Path(args.out), plan_csv(profile, result.q, result.targets)))
    pred = result.predicted
    print(
        f"{profile.name} {args.mode}: {len(result.q)} configurations planned ({result.criterion}) from "
        f"{result.candidates} candidates within the joint limits less the margin and predicted visible, "
        f"in {result.seconds:.1f} s"
    )
    print(f"  {pred}")
    worst = sorted(pred.parameters, key=lambda p: -p.std)[:3]
    print("  largest predicted standard deviations: " + ", ".join(f"{p.name} {p.std:.3g} {p.unit}" for p in worst))
    if pred.held:
        print(f"  held at their base values (not identifiable): {', '.join(pred.held)}")
    print(f"  written: {args.out}")
    return 0


def _evaluate(args: argparse.Namespace) -> int:
    profile = load_profile(args.robot)
    cal = _load_calibration(args.calibration, profile)
    data = _read_data(args, profile)
    result = evaluate(profile, cal, data, reregister=args.register)
    if args.json:
        _print_json(result.to_dict(), one_line=True)
        return 0
    seen = " (the tracker's pose fitted to these rows)" if result.registered else ""
    print(f"{profile.name} {cal.mode} calibration {args.calibration} on {args.data}{seen}")
    print(f"  {result.figures}")
    if len(result.sensors) > 1:
        for name, f in result.sensors.items():
            print(f"  {name}: {f}")
    return 0


def _self_observe(args: argparse.Namespace) -> int:
    from calib_core.io import camera_dataset

    check_share(args.holdout, "--holdout")
    profile = _load_robot(args)
    profile.mode(args.mode)
    data = camera_dataset(profile, args.data, set(args.source) or None)
    _check_writable(args.out)
    cal = calibrate(profile, data, args.mode, holdout=args.holdout, seed=args.seed)
    _save(args.out, lambda: cal.save(args.out))
    _print_summary(cal, args.verbose)
    print(f"  written: {args.out}")
    return 0


def _export(args: argparse.Namespace) -> int:
    from calib_core.io import HANDEYE_FORMATS, bhuman_joint_calibration, calibrated_urdf, offsets_yaml

    if args.format in HANDEYE_FORMATS:
        return _export_handeye(args)
    if args.robot is None:
        raise InputError(f"--format {args.format} needs --robot (the profile the calibration is of)")
    profile = _load_robot(args)
    cal = _load_calibration(args.calibration, profile)
    _check_writable(args.out)
    write, what = {
        "urdf": (calibrated_urdf, "URDF with corrected joint origins"),
        "yaml": (offsets_yaml, "joint offsets"),
        "bhuman": (bhuman_joint_calibration, "joint offsets as B-Human's jointCalibration.cfg"),
    }[args.format]
    text = write(profile, cal)
    _save(args.out, lambda: write_atomic(Path(args.out), text))
    print(f"{what}: {args.out}")
    return 0


def _export_handeye(args: argparse.Namespace) -> int:
    """A calib handeye output's camera pose where a ROS robot takes it (calib_core/io/handeye_export.py)."""
    from calib_core.io import export_handeye, read_handeye

    setup, T = read_handeye(args.calibration)
    parent = args.parent or ("tool0" if setup == "eye-in-hand" else "base_link")
    text = export_handeye(setup, T, args.format, parent, args.child)
    _check_writable(args.out)
    _save(args.out, lambda: write_atomic(Path(args.out), text))
    print(f"the camera {args.child} in {parent} as {args.format}: {args.out}")
    return 0


def _simulate(args: argparse.Namespace) -> int:
    profile = _load_robot(args)
    if (args.out is None) == (args.session is None):
        raise InputError("give either --out (a dataset CSV) or --session (a session folder with images)")
    if args.configurations is not None and args.configurations < 1:
        raise InputError("--configurations must be at least 1")
    if not 0.0 <= args.outliers < 0.5:
        raise InputError("--outliers must be in [0, 0.5)")
    if args.session and args.outliers:
        raise InputError("--outliers applies to --out; with --session the detectors make their own failures")
    law = Law(_changes(args.drift, "--drift"), _changes(args.shift, "--shift")).check(profile)
    if args.days is None and (law.drift_per_day or args.start):
        raise InputError(f"{'--drift' if law.drift_per_day else '--start'} needs --days (a run of days)")
    believed = _load_calibration(args.calibration, profile).params(profile) if args.calibration else None
    if args.days is not None:
        return _simulate_days(args, profile, law, believed)
    _check_writable(args.out or args.session, session=args.session is not None)
    perfect = _perfect_simulation(profile, args.day, images=args.session is not None)
    for note in perfect.values():
        print(f"calib simulate: note: {note}", file=sys.stderr)
    from calib_core import SimulatedRobot  # the simulator, its finders and OpenCV: only for the commands using them

    truth = law.truth(profile, profile.true_params(), 1)
    robot = SimulatedRobot.from_profile(profile, seed=args.seed, truth=truth).on_day(args.day)
    start = time.perf_counter()
    if args.session:
        sim = robot.simulate_images(args.configurations, believed)
        day = f"day {args.day}" if args.day > 1 else "first day"
        _write_simulated_session(args, profile, sim, Path(args.session), args.name, day)
        missed = len(sim.captures) - sim.data.n_configurations
        print(
            f"{len(sim.captures)} configurations rendered, {sim.data.n_configurations} measured, {missed} not "
            f"found, in {time.perf_counter() - start:.1f} s: {args.session}"
        )
        return 0
    sim = robot.simulate(args.configurations, outlier_rate=args.outliers, outlier_size=_gross_error(profile))
    _save(args.out, lambda: write_atomic(Path(args.out), to_csv(profile, sim.data)))
    if args.truth:
        truth = {
            "robot": profile.name,
            "day": args.day,
            "seed": args.seed,
            "parameters": profile.params_to_display(sim.true_params),
        }
        _save(args.truth, lambda: write_atomic(Path(args.truth), json.dumps(truth, indent=2) + "\n"))
    print(
        f"{sim.data.n_configurations} configurations, {sim.data.n_observations} observations "
        f"({int(np.sum(sim.outliers))} gross errors) in {time.perf_counter() - start:.1f} s: {args.out}"
        + (f" ({', '.join(perfect)}: see the notes)" if perfect else "")
    )
    return 0


def _changes(items: list[str], option: str) -> dict[str, float]:
    """--drift / --shift PARAMETER:VALUE options as parameter -> value."""
    out = {}
    for item in items:
        name, sep, value = item.rpartition(":")
        try:
            if not sep or not name:
                raise ValueError
            out[name] = float(value)
        except ValueError:
            raise InputError(f"{option} {item!r}: expected PARAMETER:NUMBER (e.g. LKneePitch:0.05)") from None
    return out


def _simulate_days(args: argparse.Namespace, profile: Profile, law: Law, believed: np.ndarray | None) -> int:
    """--days: a folder of one dataset (or session folder) a day, the robot moving by `law`, and days.json."""
    if not 1 <= args.days <= 366:
        raise InputError(f"--days {args.days}: give 1 to 366 days")
    if args.day != 1:
        raise InputError("--day and --days: give one (--days numbers its days 1, 2, ...)")
    if args.truth:
        raise InputError("--truth: with --days each day's truth is in the folder's days.json")
    folder = Path(args.out or args.session)
    if folder.exists() and (not folder.is_dir() or any(folder.iterdir())):
        raise InputError("exists and is not an empty folder; give a new folder name", file=str(folder))
    _check_writable(str(folder / "days.json") if folder.is_dir() else str(folder))
    first = parse_measured(args.start, "--start") if args.start else _days_before_today(args.days - 1)
    from calib_core import SimulatedRobot

    started = time.perf_counter()
    folder.mkdir(exist_ok=True)
    days = []
    for day in range(1, args.days + 1):
        truth = law.truth(profile, profile.true_params(), day)
        robot = SimulatedRobot.from_profile(profile, seed=1000 * args.seed + day, truth=truth)
        when = measured_on(first, day)
        name = f"day-{day:02d}"
        if args.session:
            sim = robot.simulate_images(args.configurations, believed)
            label = f"day {day} of {args.days}, measured {when:%Y-%m-%d}"
            _write_simulated_session(
                args, profile, sim, folder / name, f"{args.name or folder.name} {name}", label, when
            )
            data = name
        else:
            sim = robot.simulate(args.configurations, outlier_rate=args.outliers, outlier_size=_gross_error(profile))
            data = f"{name}.csv"
            _save(str(folder / data), lambda sim=sim, data=data: write_atomic(folder / data, to_csv(profile, sim.data)))
        days.append(
            {
                "day": day,
                "measured": when.isoformat(),
                "data": data,
                "configurations": sim.data.n_configurations,
                "truth": profile.params_to_display(sim.true_params),
            }
        )
    index = {
        "robot": profile.name,
        "seed": args.seed,
        "drift_per_day": law.drift_per_day,
        "shift": law.shift,
        "days": days,
    }
    _save(str(folder / "days.json"), lambda: write_atomic(folder / "days.json", json.dumps(index, indent=1) + "\n"))
    moves = ", ".join(
        [f"{n} {v:+g} a day" for n, v in law.drift_per_day.items()] + [f"{n} {v:+g}" for n, v in law.shift.items()]
    )
    print(
        f"{args.days} days from {first:%Y-%m-%d} ({moves or 'nothing moves'}) in "
        f"{time.perf_counter() - started:.1f} s: {folder}"
    )
    return 0


def _days_before_today(days: int) -> datetime:
    """09:00 UTC `days` days before today."""
    today = datetime.now(UTC).replace(hour=9, minute=0, second=0, microsecond=0)
    return today - timedelta(days=days)


def _perfect_simulation(profile: Profile, day: int, *, images: bool) -> dict[str, str]:
    """What a profile without (part of) a `simulation` section makes the simulator do silently: measure the
    nominal model itself (on the first day: later days drift the offsets) and, for a dataset CSV, without
    noise (images go through the detectors, which make their own errors). The data are valid but perfect:
    a calibration of them finds nothing to correct, which a user must know before reading one. A short
    phrase for the summary line -> the note that says what to add."""
    sim = profile.simulation
    add = f"add to the profile ({profile.source})"
    notes = {}
    if not sim.get("truth") and day == 1:
        notes["the nominal robot itself"] = (
            f"robot '{profile.name}' has no simulation.truth: the simulated robot is the nominal model itself, "
            f"so a calibration of these data finds nothing to correct; {add} `simulation: {{truth: {{PARAMETER: "
            "VALUE, ...}}` (the hidden robot's parameter values, nominal plus error, in the profile's units; "
            "docs/urdf-robots.md)"
        )
    if not images and not any(float(v) > 0 for v in (sim.get("noise") or {}).values()):
        notes["no measurement noise"] = (
            f"robot '{profile.name}' has no simulation.noise: the measurements are exact; {add} `simulation: "
            "{noise: {point: SIGMA}}` (a 3-D sensor, the profile's length unit) or `{noise: {pixel: SIGMA}}` "
            "(a camera, px)"
        )
    return notes


def _write_simulated_session(
    args: argparse.Namespace,
    profile: Profile,
    sim: ImageSimulation,
    folder: Path,
    name: str | None,
    day: str,
    measured: datetime | None = None,
) -> None:
    keep = len(sim.captures) if args.keep_images is None else args.keep_images
    frames = [
        FrameRecord(
            c.frame,
            {j.name: round(float(np.degrees(v)), 6) for j, v in zip(profile.joints, c.readings, strict=True)},
            c.sighting.status,
            c.sighting.reason,
            {},
            c.sighting.detail,
        )
        for c in sim.captures
    ]
    images = {c.frame: c.images for c in sim.captures[:keep]}
    description = (
        f"Simulated {profile.title}, {day} (seed {args.seed}): {len(frames)} configurations rendered and seen "
        f"through the detectors; {sim.data.n_configurations} measured."
    )
    made_by = shlex.join(["calib", *sys.argv[1:]]) if sys.argv[0].endswith("calib") else "calib simulate --session"
    _save(
        str(folder),
        lambda: write_session(
            folder,
            profile,
            name=name or folder.name,
            description=description,
            made_by=made_by,
            data=sim.data,
            frames=frames,
            images=images,
            truth=sim.true_params,
            measured=measured,
        ),
    )


def _detect_sphere(args: argparse.Namespace) -> int:
    depth = _load_depth(args.depth)
    for name in ("fx", "fy", "radius"):
        if not getattr(args, name) > 0:
            raise InputError(f"--{name} must be positive, got {getattr(args, name)}")
    seed = None
    if args.seed is not None:
        try:
            seed = np.array([float(v) for v in args.seed.split(",")])
        except ValueError:
            raise InputError(f"--seed '{args.seed}' is not three numbers X,Y,Z") from None
        if seed.shape != (3,) or not np.all(np.isfinite(seed)):
            raise InputError(f"--seed '{args.seed}' is not three finite numbers X,Y,Z")
    if seed is not None and seed[2] <= 0:
        raise InputError(f"--seed '{args.seed}' lies behind the camera (Z must be positive)")
    from calib_core.vision import find_sphere

    try:
        found = find_sphere(depth, args.fx, args.fy, args.cx, args.cy, args.radius, seed)
    except ValueError as exc:  # the finder's own checks of its arguments
        raise InputError(str(exc), file=args.depth) from None
    _print_json(found.to_json(), args.json)
    return 0


def _detect_board(args: argparse.Namespace) -> int:
    if args.cols < 3 or args.rows < 3:
        raise InputError("--cols and --rows must be at least 3 (inner corners)")
    if not Path(args.image).is_file():
        raise InputError("image file does not exist", file=args.image)
    import cv2

    from calib_core.vision import MAX_IMAGE_PX, detect_board, too_large

    try:
        image = cv2.imread(args.image, cv2.IMREAD_GRAYSCALE)
    except cv2.error as exc:  # a damaged header: more pixels than OpenCV reads, say
        raise InputError(f"is not an image OpenCV can read ({exc.err})", file=args.image) from None
    if image is None:
        raise InputError("is not an image OpenCV can read", file=args.image)
    if image.size > MAX_IMAGE_PX:
        raise InputError(too_large(image.shape[1], image.shape[0]), file=args.image)
    _print_json(detect_board(image, args.cols, args.rows).to_json(), args.json)
    return 0


IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg", ".bmp", ".tif", ".tiff")


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


def _handeye(args: argparse.Namespace) -> int:
    """specs handeye-poses.md: images, flange poses, the camera and the board; no pose guessed anywhere."""
    import cv2

    from calib_core.estimation import calibrate_flange, find_views
    from calib_core.io import parse_board, read_camera, read_flange_poses

    folder = Path(args.images)
    if not folder.is_dir():
        raise InputError("is not a folder of images", file=args.images)
    names = sorted(p.name for p in folder.iterdir() if p.suffix.lower() in IMAGE_SUFFIXES)
    if not names:
        raise InputError(f"holds no image ({', '.join(IMAGE_SUFFIXES)})", file=args.images)
    board = parse_board(args.board)
    camera = read_camera(args.camera)
    poses = read_flange_poses(args.poses, names, args.length_unit, args.angle_unit)
    heldout = {n.strip() for n in (args.holdout_images or "").split(",") if n.strip()}
    unknown = sorted(heldout - set(names))
    if unknown:
        raise InputError(f"--holdout-images: {unknown[0]} is not an image of {args.images}")
    _check_writable(args.out)
    images = {}
    for name in names:
        grey = cv2.imread(str(folder / name), cv2.IMREAD_GRAYSCALE)
        if grey is None:
            raise InputError("is not an image OpenCV can read", file=str(folder / name))
        images[name] = grey
    views = find_views(images, board, camera)
    for v in views.values():
        if v.corners is None:
            print(f"calib handeye: note: {v.image}: board {v.reason}; left out", file=sys.stderr)
    start = time.perf_counter()
    cal = calibrate_flange(
        views, poses, camera, board, args.setup, heldout=heldout, intrinsics_free=args.intrinsics == "free"
    )
    out = cal.to_json()
    _save(args.out, lambda: write_atomic(Path(args.out), json.dumps(out, indent=2) + "\n"))
    for warning in out["warnings"]:
        print(f"calib handeye: warning: {warning}", file=sys.stderr)
    name = "camera_in_flange" if args.setup == "eye-in-hand" else "camera_in_base"
    t, sd = np.array(out[name]["matrix"])[:3, 3], out[name]["std"]
    used = sum(i["used"] for i in cal.images)
    print(
        f"{len(names)} images, {used} fitted ({cal.start} start, {cal.iterations} iterations, "
        f"{time.perf_counter() - start:.2f} s): {name} at ({t[0]:.2f}, {t[1]:.2f}, {t[2]:.2f}) mm "
        f"+/- ({sd['x']:.2f}, {sd['y']:.2f}, {sd['z']:.2f}); corners fitted to {cal.fitted_rms_px:.3f} px RMS"
        + (f", held out {cal.heldout_rms_px:.3f} px" if cal.heldout_rms_px is not None else "")
        + f": {args.out}"
    )
    return 0


def _import_bag(args: argparse.Namespace) -> int:
    if args.tf is not None:
        return _import_bag_tf(args)
    if args.robot is None:
        raise InputError("--robot: the robot whose joint states the bag recorded (or --tf BASE:TOOL without them)")
    from calib_core.io import import_bag  # rosbags loads only for this subcommand

    profile = _load_robot(args)
    believed = _load_calibration(args.calibration, profile).params(profile) if args.calibration else None
    _check_writable(args.out, session=True)
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


def _load_depth(path: str) -> np.ndarray:
    try:
        depth = np.load(path, allow_pickle=False)
    except FileNotFoundError:
        raise InputError("depth file does not exist", file=path) from None
    except (OSError, ValueError, EOFError) as exc:  # EOFError: an empty or cut-off file
        raise InputError(f"is not a NumPy .npy array ({exc})", file=path) from None
    if not isinstance(depth, np.ndarray) or depth.ndim != 2 or not np.issubdtype(depth.dtype, np.floating):
        raise InputError("must hold a 2-D float array of depths in metres", file=path)
    if depth.size == 0:
        raise InputError(f"holds an empty depth map ({depth.shape[0]} x {depth.shape[1]})", file=path)
    return depth.astype(np.float32, copy=False)


def _print_json(obj: dict, one_line: bool) -> None:
    print(json.dumps(obj) if one_line else json.dumps(obj, indent=2))


def _gross_error(profile: Profile) -> float:
    """A failed detection's size: 20 cm for a 3-D point, 40 px for a pixel."""
    if profile.sensors[profile.data.sensor].unit == "px":
        return 40.0
    return 0.2 * length_factor("m", profile.length_unit)


def _load_calibration(path: str, profile: Profile) -> Calibration:
    """A calibration file that fits the profile: its robot and every parameter name."""
    cal = Calibration.load(path)
    try:
        cal.params(profile)
    except InputError as exc:
        raise InputError(exc.message, file=path) from None
    return cal


def _check_writable(path: str, session: bool = False) -> None:
    """Fail before the work, not after it, when the output cannot be written. A session folder may
    replace an earlier session folder, never any other folder."""
    target = Path(path)
    if session and target.is_dir() and not (target / "session.json").is_file():
        raise InputError("exists and is not a session folder; give a new folder name", file=path)
    if not session and target.is_dir():
        raise InputError("is a directory; give a file name", file=path)
    parent = target.parent if str(target.parent) else Path(".")
    if not parent.is_dir():
        raise InputError("its folder does not exist", file=path)
    if not os.access(parent, os.W_OK):
        raise InputError("its folder is not writable", file=path)


def _save(path: str, write) -> None:
    try:
        write()
    except OSError as exc:
        raise InputError(f"cannot be written ({exc.strerror})", file=path) from None


def _serve(args: argparse.Namespace) -> int:
    if not 0 < args.port < 65536:
        raise InputError(f"--port {args.port} is not a TCP port")
    if not 0 <= args.viser_port < 65536:
        raise InputError(f"--viser-port {args.viser_port} is not a TCP port")
    if not 0.1 <= args.sim_speed <= 100:
        raise InputError(f"--sim-speed {args.sim_speed} must be between 0.1 and 100")
    if not 0.001 <= args.max_upload_mb <= 10_000:
        raise InputError(f"--max-upload-mb {args.max_upload_mb:g} must be between 0.001 and 10000")
    if args.max_rows < 1:
        raise InputError(f"--max-rows {args.max_rows} must be at least 1")
    limits = Limits(upload_bytes=int(args.max_upload_mb * 1024 * 1024), rows=args.max_rows)
    # Meeting a robot mostly waits for it to answer (a ROS 2 robot's latched description: up to 3 s), so the
    # ROS 2 robots are listened to first and everything else is done meanwhile: the desk file read (before
    # anything starts: nothing is written until the robots are checked), the web stack imported (loaded only for
    # this subcommand; for NAOqi, in a thread while its sessions open).
    meetings = _meet_ros2(args.ros2) if args.ros2 else []
    web = threading.Thread(target=_import_quietly, args=(f"{__package__}.server",), daemon=True)
    try:
        from .robots.desk_config import load_desk_config

        config = None if args.desk is None else load_desk_config(Path(args.desk))
        if meetings:
            _import_quietly(f"{__package__}.server")
            config = _with_ros2(config, meetings, Path(args.data_dir))
        if args.naoqi:
            web.start()
            config = _with_naoqi(config, args.naoqi)
    finally:
        for meeting in meetings:  # not reached: the desk file or a robot before it was refused
            meeting.close()
        if web.is_alive():
            web.join()
    from .web.server import serve

    serve(
        args.host,
        args.port,
        Path(args.data_dir),
        viser_port=args.viser_port,
        config=config,
        time_scale=args.sim_speed,
        new_token=args.new_token,
        limits=limits,
    )
    return 0


def _import_quietly(module: str) -> None:
    """Import ahead in a thread; a failure is left to the import that needs the module (said as the command's
    error, not as a thread's traceback)."""
    with contextlib.suppress(Exception):  # the main thread's import raises it again
        importlib.import_module(module)


def _meet_ros2(files: list[str]) -> list[Any]:
    """Every ROS 2 connection file checked, then each robot listened to at once
    (app/drivers/ros2/connection.Meeting)."""
    from .drivers.ros2 import require

    require()
    from .drivers.ros2.connection import Meeting, load_connection

    conns = [load_connection(Path(f)) for f in files]  # every file checked before any robot is met
    meetings: list[Any] = []
    try:
        for conn in conns:
            meetings.append(Meeting(conn))
    except BaseException:
        for meeting in meetings:
            meeting.close()
        raise
    return meetings


def _with_ros2(config: DeskConfig | None, meetings: list[Any], data_dir: Path) -> DeskConfig:
    """The desk's robots and those on ROS 2 graphs, each checked on its graph before the desk starts; a robot's
    meeting is taken from `meetings` (in order) as it is connected."""
    from .drivers.ros2.connection import connect

    conns = [meeting.conn for meeting in meetings]
    return _with_robots(config, conns, lambda _conn: connect(meetings.pop(0), data_dir), "ros2")


def _with_robots(
    config: DeskConfig | None, conns: list, connect: Callable[[Any], tuple[str, dict]], kind: str
) -> DeskConfig:
    """The desk's robots (its configuration's, else the defaults) and one more of driver `kind` per connection,
    `connect(conn)` giving its profile reference and driver options; the first is the one the page shows."""
    from dataclasses import replace

    from .drivers.registry import DriverSpec
    from .robots.desk_config import RobotConfig, default_config

    config = config or default_config()
    robots = list(config.robots)
    for conn in conns:
        if conn.robot in {r.name for r in robots}:
            raise InputError(f"robot: '{conn.robot}' is on the desk already", file=str(conn.path))
        ref, options = connect(conn)
        robots.append(RobotConfig(conn.robot, ref, DriverSpec(kind, options), "config"))
    return replace(config, robots=tuple(robots), connected=config.connected or conns[0].robot)


def _with_naoqi(config: DeskConfig | None, files: list[str]) -> DeskConfig:
    """The desk's robots and the NAOs reached through NAOqi. A robot that does not answer yet is said so; the desk
    starts all the same and connects to it once it answers."""
    from .drivers.naoqi import open_session, require

    require()
    from .drivers.naoqi.connection import load_connection

    def connect(conn: Any) -> tuple[str, dict]:
        url = conn.options["url"]
        try:
            open_session(url).close()
        except RuntimeError as exc:
            print(
                f"calib serve: {conn.robot}: NAOqi does not answer at {url} ({exc}); the desk starts and connects "
                "to it once it answers",
                file=sys.stderr,
                flush=True,
            )
        return conn.profile, conn.options

    conns = [load_connection(Path(f)) for f in files]  # every file checked before any robot is asked
    return _with_robots(config, conns, connect, "naoqi")


def _sim_naoqi(args: argparse.Namespace) -> int:

    from .drivers.naoqi import require

    require()
    from .drivers.faults import parse_fault
    from .drivers.naoqi.sim import SimNao, serve

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
    profile = _load_robot(args)
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
        from .drivers.core import DEFAULT_SETTLE_S

        doc = {"robot": args.name or profile.name, "profile": ref, "url": args.url, "camera": 1}
        doc["settle_s"] = round(DEFAULT_SETTLE_S / args.speed, 6)  # the robot's time: it moves --speed times as fast
        write_atomic(Path(args.connection_out), yaml.safe_dump(doc, sort_keys=False))
    return _until_stopped(f"calib sim-naoqi: {profile.name} at {args.url} (Ctrl-C ends it)", session.close)


def _sim_ros2(args: argparse.Namespace) -> int:

    from .drivers.ros2 import require

    require()
    from .drivers.faults import parse_fault
    from .drivers.ros2.sim_node import SimNode, Topics, connection_doc, load_sim_profile

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


if __name__ == "__main__":
    sys.exit(main())
