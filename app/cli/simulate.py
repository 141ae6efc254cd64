"""calib simulate: a dataset, a session folder with images, or a run of days, measured on the simulated robot."""

from __future__ import annotations

import argparse
import json
import shlex
import sys
import time
from datetime import UTC, datetime, timedelta
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from calib_core import InputError, to_csv, write_atomic
from calib_core.io import FrameRecord, parse_measured, write_session
from calib_core.model import Profile
from calib_core.sim import Law, measured_on
from calib_core.units import length_factor

from .common import Command, check_writable, load_calibration, load_robot, save

if TYPE_CHECKING:
    from calib_core.sim import ImageSimulation


def _simulate_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--robot", required=True)
    p.add_argument("--configurations", type=int, help="how many (default: the profile's plan)")
    p.add_argument("--day", type=int, default=1, help="2, 3, ...: a later day with drifted offsets")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--outliers", type=float, default=0.0, help="share of failed detections")
    p.add_argument("--out", help="the dataset CSV (points measured with the sensor's noise model)")
    p.add_argument("--truth", help="also write the hidden true parameters (JSON)")
    p.add_argument(
        "--session",
        help="instead: render camera images, run the detectors and write a session folder "
        "(session.json, data.csv from the detections, truth.json, images/)",
    )
    p.add_argument("--name", help="the session's name (with --session)")
    p.add_argument("--keep-images", type=int, help="with --session: keep the images of the first N frames")
    p.add_argument("--calibration", help="with --session: the calibration the robot runs with (seeds the detectors)")
    p.add_argument(
        "--days",
        type=int,
        help="a run of days: --out and --session name a folder that gets one dataset (day-01.csv ...) or one "
        "session folder (day-01/ ...) per day, and days.json saying when each was measured and its truth; the "
        "robot moves only as --drift and --shift say",
    )
    p.add_argument(
        "--drift",
        action="append",
        default=[],
        metavar="PARAMETER:RATE",
        help="with --days: the parameter moves RATE a day (deg, the profile's length unit), e.g. LKneePitch:0.05",
    )
    p.add_argument(
        "--shift",
        action="append",
        default=[],
        metavar="PARAMETER:CHANGE",
        help="the true robot's parameter off its profile's truth by CHANGE (deg, length unit), e.g. LTransX:2",
    )
    p.add_argument("--start", help="with --days: the first day, ISO 8601 (default: the last day is today)")


def _simulate(args: argparse.Namespace) -> int:
    profile = load_robot(args)
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
    believed = load_calibration(args.calibration, profile).params(profile) if args.calibration else None
    if args.days is not None:
        return _simulate_days(args, profile, law, believed)
    check_writable(args.out or args.session, session=args.session is not None)
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
    save(args.out, lambda: write_atomic(Path(args.out), to_csv(profile, sim.data)))
    if args.truth:
        truth = {
            "robot": profile.name,
            "day": args.day,
            "seed": args.seed,
            "parameters": profile.params_to_display(sim.true_params),
        }
        save(args.truth, lambda: write_atomic(Path(args.truth), json.dumps(truth, indent=2) + "\n"))
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
    check_writable(str(folder / "days.json") if folder.is_dir() else str(folder))
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
            save(str(folder / data), lambda sim=sim, data=data: write_atomic(folder / data, to_csv(profile, sim.data)))
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
    save(str(folder / "days.json"), lambda: write_atomic(folder / "days.json", json.dumps(index, indent=1) + "\n"))
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
    save(
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


def _gross_error(profile: Profile) -> float:
    """A failed detection's size: 20 cm for a 3-D point, 40 px for a pixel."""
    if profile.sensors[profile.data.sensor].unit == "px":
        return 40.0
    return 0.2 * length_factor("m", profile.length_unit)


# This module's subcommands, which app/cli/__init__.py's COMMANDS lists in calib --help's order.
SIMULATE = Command("simulate", "write a dataset measured on the simulated robot", _simulate_arguments, _simulate)
