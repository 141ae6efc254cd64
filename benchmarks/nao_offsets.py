"""The NAO's 12 leg offsets from a planned replay, as the desk does it: N configurations planned for the mode
`full` (its `plan`, or --criterion), rendered at the simulator's truth, found by the sandal-board detector,
their joint readings rounded to the encoder's 0.1 deg, calibrated in mode `full`. Prints each offset's error
against the hidden truth and its reported standard deviation, per seed, and the pooled figures.

    .venv/bin/python benchmarks/nao_offsets.py [--configurations 60] [--seeds 0,1,2] [--criterion task]
    .venv/bin/python benchmarks/nao_offsets.py --no-images   # the detectors' noise drawn, no rendering
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from calib_core import SimulatedRobot, calibrate, load_profile
from calib_core.estimation.planning import CRITERIA, plan
from calib_core.vision.sighting import dataset_from_captures

LEGS = [f"{s}{j}" for s in "LR" for j in ("HipYawPitch", "HipRoll", "HipPitch", "KneePitch", "AnklePitch", "AnkleRoll")]
CAMERA = ("CamYaw", "CamPitch", "CamRoll")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--configurations", type=int, default=60)
    ap.add_argument("--seeds", default="0,1,2", help="plan seeds; the robot's noise seed is the plan's + 1")
    ap.add_argument("--criterion", choices=CRITERIA, help="default: the mode's plan")
    ap.add_argument("--no-images", action="store_true", help="draw the detectors' noise instead of rendering")
    args = ap.parse_args()
    profile = load_profile("nao")
    criterion = args.criterion or profile.mode("full").plan
    errors, stds = [], []
    for seed in [int(s) for s in args.seeds.split(",")]:
        robot = SimulatedRobot.from_profile(profile, seed=seed + 1)
        truth = profile.params_to_display(robot.true_params)
        started = time.perf_counter()
        planned = plan(profile, "full", args.configurations, seed=seed, criterion=criterion)
        plan_s = time.perf_counter() - started
        if args.no_images:
            robot.pixel_noise = float(profile.simulation["detected_noise"]["sigma"])
            data = robot.measure(planned.q, planned.targets).data
        else:
            captures = [
                robot.capture(k + 1, planned.q[k], int(planned.targets[k]), profile.nominal())
                for k in range(len(planned.q))
            ]
            data = dataset_from_captures(profile, captures, "benchmark")
        started = time.perf_counter()
        cal = calibrate(profile, data, "full")
        solve_s = time.perf_counter() - started
        found = {p.name: p for p in cal.parameters if p.estimated}
        e = np.array([found[n].value - truth[n] for n in LEGS])
        s = np.array([found[n].std for n in LEGS])
        errors.append(e)
        stds.append(s)
        camera = max(abs(found[n].value - truth[n]) for n in CAMERA)
        print(
            f"seed {seed}: {data.n_configurations} of {len(planned.q)} frames measured, plan {plan_s:.1f} s, "
            f"calibration {solve_s:.1f} s; leg offsets max |error| {np.abs(e).max():.3f} deg, max |error|/std "
            f"{np.abs(e / s).max():.2f}; camera max |error| {camera:.3f} deg"
        )
        print("  error deg ", " ".join(f"{x:+.3f}" for x in e))
        print("  std deg   ", " ".join(f"{x:.3f}" for x in s))
    E, S = np.array(errors), np.array(stds)
    print("offsets    ", " ".join(f"{n:>6.6}" for n in LEGS))
    print("RMS error  ", " ".join(f"{x:6.3f}" for x in np.sqrt(np.mean(E**2, axis=0))))
    print("mean std   ", " ".join(f"{x:6.3f}" for x in S.mean(axis=0)))
    print(
        f"{args.configurations} configurations, {criterion}: RMS error {np.sqrt(np.mean(E**2)):.3f} deg, max "
        f"{np.abs(E).max():.3f} deg, RMS error/std {np.sqrt(np.mean((E / S) ** 2)):.2f}"
    )


if __name__ == "__main__":
    main()
