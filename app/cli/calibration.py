"""The commands on a calibration's way from data to a driver: solve (and self-observe, from what the robot's
cameras see of its markers), predict, evaluate, export.
"""

from __future__ import annotations

import argparse
import csv
import io
import sys
from pathlib import Path

from calib_core import Calibration, InputError, Problem, calibrate, evaluate, load_profile, read_dataset, write_atomic
from calib_core.dataset import Dataset
from calib_core.estimation import check_share, register, registration_params
from calib_core.io import measurement_values, readings_beyond_limits, select_rows
from calib_core.model import Profile

from .common import Command, check_writable, load_calibration, load_robot, print_json, save

WHERE_HELP = "use only the rows with this value in this column (repeatable; e.g. leica_frame_group=A)"
VERBOSE_HELP = "list each diagnostic of a kind that has several (by default: one line per kind, its parameters named)"


def _solve_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--robot", required=True, help="built-in profile (robonaut-a, nao) or a profile YAML file")
    p.add_argument(
        "--mode",
        required=True,
        help="the profile's mode (robonaut-a: daily, full; nao: full, full+head; profiles may define more), or auto: "
        "the data choose among the profile's modes, and their priors' width, by k-fold cross-validation on the "
        "training configurations (the summary says what was chosen and why)",
    )
    p.add_argument("--data", required=True, help="the dataset CSV")
    p.add_argument("--where", action="append", default=[], metavar="COLUMN=VALUE", help=WHERE_HELP)
    p.add_argument("--base", help="calibration JSON to start from; keeps its non-estimated parameters")
    p.add_argument("--out", required=True, help="where to write the calibration JSON")
    p.add_argument("--holdout", type=float, default=0.0, help="share of configurations held out (0..0.9)")
    p.add_argument("--folds", type=int, default=0, help="k-fold cross-validation on the training part")
    p.add_argument("--method", default="lm", choices=["lm", "nelder-mead"], help="solver (default lm)")
    p.add_argument("--no-robust", action="store_true", help="plain least squares (no outlier rejection)")
    p.add_argument("--seed", type=int, default=0, help="seed of the held-out split")
    p.add_argument(
        "--minimal",
        action="store_true",
        help="estimate a minimal identifiable parameter set (QR of the data, no priors); hold and name the rest",
    )
    p.add_argument("--verbose", action="store_true", help=VERBOSE_HELP)


def _predict_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--robot", required=True)
    p.add_argument("--calibration", help="calibration JSON (default: the nominal model)")
    p.add_argument("--data", required=True)
    p.add_argument("--where", action="append", default=[], metavar="COLUMN=VALUE", help=WHERE_HELP)
    p.add_argument("--out", required=True, help="CSV: the input rows plus prediction columns")


def _evaluate_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--robot", required=True)
    p.add_argument("--calibration", required=True, help="calibration JSON")
    p.add_argument("--data", required=True, help="CSV in the robot's format, with measurements")
    p.add_argument("--where", action="append", default=[], metavar="COLUMN=VALUE", help=WHERE_HELP)
    p.add_argument(
        "--register",
        action="store_true",
        help="fit the tracker's pose to these data first (another tracker set-up); the robot's parameters stay",
    )
    p.add_argument("--json", action="store_true", help='one JSON object {"mean", "rms", "max", "n", "unit"}')


def _self_observe_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--robot", required=True, help="a profile with camera1, camera2 and markers1, markers2 (motoman)")
    p.add_argument(
        "--mode",
        default="cameras",
        help="the profile's mode (default cameras), or auto: the data choose among the profile's modes, and their "
        "priors' width, by k-fold cross-validation on the training poses",
    )
    p.add_argument("--data", required=True, help="folder with camera_observations.csv and camera_poses.csv")
    p.add_argument("--source", action="append", default=[], help="use only this source_file (repeatable)")
    p.add_argument("--holdout", type=float, default=0.3, help="share of poses held out (default 0.3)")
    p.add_argument("--seed", type=int, default=0, help="seed of the held-out split")
    p.add_argument("--out", required=True, help="where to write the calibration JSON")
    p.add_argument("--verbose", action="store_true", help=VERBOSE_HELP)


def _export_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--robot", help="built-in profile or a profile YAML file (not for a calib handeye output)")
    p.add_argument("--calibration", required=True, help="calibration JSON (from solve, or from handeye)")
    p.add_argument(
        "--format",
        required=True,
        choices=["urdf", "yaml", "bhuman", "ros2-static-tf", "urdf-joint", "easy-handeye"],
        help="urdf: corrected joint origins; yaml: offsets; bhuman: a NAO's jointCalibration.cfg (B-Human's form); "
        "of a calib handeye output: ros2-static-tf (a launch file publishing the camera on /tf_static), urdf-joint "
        "(a fixed joint to paste), easy-handeye (its calibration YAML)",
    )
    p.add_argument("--parent", help="handeye: the camera's parent frame (default tool0 eye-in-hand, base_link)")
    p.add_argument("--child", default="camera_optical_frame", help="handeye: the camera's (optical) frame")
    p.add_argument("--out", required=True, help="the file to write")


def _where(data: Dataset, items: list[str]) -> Dataset:
    where = {}
    for item in items:
        column, sep, value = item.partition("=")
        if not sep or not column:
            raise InputError(f"--where {item!r} must be COLUMN=VALUE")
        where[column.strip()] = value.strip()
    return select_rows(data, where) if where else data


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
    profile = load_robot(args)
    profile.mode(args.mode)
    base = load_calibration(args.base, profile) if args.base else None
    data = _read_data(args, profile)
    check_writable(args.out)
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
    save(args.out, lambda: cal.save(args.out))
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
    profile = load_robot(args)
    cal = load_calibration(args.calibration, profile) if args.calibration else None
    p = cal.params(profile) if cal else profile.nominal()
    data = _read_data(args, profile)
    check_writable(args.out)
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
    save(args.out, lambda: write_atomic(Path(args.out), out.getvalue()))
    print(
        f"{len(data.rows)} rows predicted with "
        f"{'calibration ' + args.calibration if cal else 'the nominal model'}"
        f"{' (registration fitted to these rows)' if cal is None and registration_params(profile) else ''}: {args.out}"
    )
    return 0


def _evaluate(args: argparse.Namespace) -> int:
    profile = load_profile(args.robot)
    cal = load_calibration(args.calibration, profile)
    data = _read_data(args, profile)
    result = evaluate(profile, cal, data, reregister=args.register)
    if args.json:
        print_json(result.to_dict(), one_line=True)
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
    profile = load_robot(args)
    profile.mode(args.mode)
    data = camera_dataset(profile, args.data, set(args.source) or None)
    check_writable(args.out)
    cal = calibrate(profile, data, args.mode, holdout=args.holdout, seed=args.seed)
    save(args.out, lambda: cal.save(args.out))
    _print_summary(cal, args.verbose)
    print(f"  written: {args.out}")
    return 0


def _export(args: argparse.Namespace) -> int:
    from calib_core.io import HANDEYE_FORMATS, bhuman_joint_calibration, calibrated_urdf, offsets_yaml

    if args.format in HANDEYE_FORMATS:
        return _export_handeye(args)
    if args.robot is None:
        raise InputError(f"--format {args.format} needs --robot (the profile the calibration is of)")
    profile = load_robot(args)
    cal = load_calibration(args.calibration, profile)
    check_writable(args.out)
    write, what = {
        "urdf": (calibrated_urdf, "URDF with corrected joint origins"),
        "yaml": (offsets_yaml, "joint offsets"),
        "bhuman": (bhuman_joint_calibration, "joint offsets as B-Human's jointCalibration.cfg"),
    }[args.format]
    text = write(profile, cal)
    save(args.out, lambda: write_atomic(Path(args.out), text))
    print(f"{what}: {args.out}")
    return 0


def _export_handeye(args: argparse.Namespace) -> int:
    """A calib handeye output's camera pose where a ROS robot takes it (calib_core/io/handeye_export.py)."""
    from calib_core.io import export_handeye, read_handeye

    setup, T = read_handeye(args.calibration)
    parent = args.parent or ("tool0" if setup == "eye-in-hand" else "base_link")
    text = export_handeye(setup, T, args.format, parent, args.child)
    check_writable(args.out)
    save(args.out, lambda: write_atomic(Path(args.out), text))
    print(f"the camera {args.child} in {parent} as {args.format}: {args.out}")
    return 0


# This module's subcommands, which app/cli/__init__.py's COMMANDS lists in calib --help's order.
SOLVE = Command("solve", "calibrate from a dataset (CSV) and write a calibration (JSON)", _solve_arguments, _solve)
PREDICT = Command("predict", "add the model's predictions to each row of a dataset", _predict_arguments, _predict)
EVALUATE = Command(
    "evaluate", "the error figures of a calibration on data it was not fitted on", _evaluate_arguments, _evaluate
)
SELF_OBSERVE = Command(
    "self-observe",
    "calibrate from what the robot's cameras see of its markers (the CTU camera format)",
    _self_observe_arguments,
    _self_observe,
)
EXPORT = Command(
    "export", "what a driver takes: the calibrated URDF or the joint offsets (YAML)", _export_arguments, _export
)
