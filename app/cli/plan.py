"""calib plan: the configurations to measure, chosen before the robot moves."""

from __future__ import annotations

import argparse
from pathlib import Path

from calib_core import InputError, write_atomic
from calib_core.io import plan_csv

from .common import Command, check_writable, load_calibration, load_robot, save


def _plan_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--robot", required=True, help="built-in profile (robonaut-a, nao, motoman) or a profile YAML")
    p.add_argument(
        "--mode",
        required=True,
        help="the calibration mode the configurations are for (auto: the profile's richest mode, the most a "
        "calibration in mode auto may choose to estimate)",
    )
    p.add_argument("--configurations", required=True, type=int, metavar="N", help="how many to plan")
    p.add_argument(
        "--base", help="calibration JSON the robot runs with (visibility and linearisation; default nominal)"
    )
    p.add_argument("--seed", type=int, default=0, help="seed of the candidate configurations")
    p.add_argument(
        "--criterion",
        choices=["task", "offsets", "d", "random"],
        help="task: least predicted error over the workspace; offsets: least variance of the joint offsets; "
        "d: D-optimal; random: a random draw (default: what the mode's `plan` says, else task)",
    )
    p.add_argument("--out", required=True, help="the plan CSV (joint columns, no measurements)")


def _plan(args: argparse.Namespace) -> int:
    from calib_core.estimation import plan

    profile = load_robot(args)
    profile.mode(args.mode)
    if args.configurations < 1:
        raise InputError(f"--configurations must be at least 1, got {args.configurations}")
    p_base = load_calibration(args.base, profile).params(profile) if args.base else None
    check_writable(args.out)
    criterion = args.criterion or profile.mode(args.mode).plan
    result = plan(profile, args.mode, args.configurations, p_base, seed=args.seed, criterion=criterion)
    save(args.out, lambda: write_atomic(Path(args.out), plan_csv(profile, result.q, result.targets)))
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


# This module's subcommands, which app/cli/__init__.py's COMMANDS lists in calib --help's order.
PLAN = Command(
    "plan",
    "choose N configurations that make a calibration as accurate as it can be (before moving)",
    _plan_arguments,
    _plan,
)
