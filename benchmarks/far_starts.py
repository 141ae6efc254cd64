"""Far starts of a hand-eye calibration: how many reach the noise floor with one start and with the
turned starts of calib_core.estimation.starts.

The set-up of tests/profiles/wrist-camera.yaml (a camera on the sample arm's tool, a board on the
table, 0.3 px corner noise), mode `handeye+offsets`. Each start puts the camera mount 300 mm away from
the simulated truth in a random direction and turns it by 90 deg about a random axis; the board and
the joint offsets start at the profile's values. A start reaches the floor when the fit's RMS is within
5% of the truth's on the same data.

    python benchmarks/far_starts.py [--starts 10] [--configurations 15] [--seed 0]
"""

from __future__ import annotations

import argparse
import time
from dataclasses import replace
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from calib_core import SimulatedRobot, calibrate, load_profile
from calib_core.estimation import calibrate as calibrate_module
from calib_core.estimation.problem import Problem
from calib_core.estimation.registration import zyx_angles
from calib_core.model.profile import Profile

PROFILE = Path(__file__).resolve().parents[1] / "tests" / "profiles" / "wrist-camera.yaml"
MOUNT = [f"camera_mount.{k}" for k in ("x", "y", "z", "yaw", "pitch", "roll")]


def far_start(profile: Profile, k: int) -> Profile:
    """The profile with its camera mount 300 mm and 90 deg from the truth (direction and axis drawn from k)."""
    rng = np.random.default_rng(100 + k)
    truth = profile.true_params()
    idx = [profile.param(n) for n in MOUNT]
    shift = rng.normal(size=3)
    turn = rng.normal(size=3)
    R = (
        Rotation.from_euler("ZYX", truth[idx[3:]]).as_matrix()
        @ Rotation.from_rotvec(turn / np.linalg.norm(turn) * np.pi / 2).as_matrix()
    )
    values = dict(zip(idx, [*(truth[idx[:3]] + 300.0 * shift / np.linalg.norm(shift)), *zyx_angles(R)], strict=True))
    params = [replace(p, nominal=float(values[i])) if i in values else p for i, p in enumerate(profile.parameters)]
    return replace(profile, parameters=params)


def rms_px(profile: Profile, data, p: np.ndarray) -> float:
    pred = Problem(profile, data, [], p, noise_model=False).predict(p)
    return float(np.sqrt(np.mean(np.sum((pred[:, :2] - data.measured[:, :2]) ** 2, axis=1))))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--starts", type=int, default=10)
    parser.add_argument("--configurations", type=int, default=15)
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args()
    profile = load_profile(PROFILE)
    sim = SimulatedRobot.from_profile(profile, seed=args.seed).simulate(args.configurations)
    floor = rms_px(profile, sim.data, sim.true_params)
    print(f"{args.configurations} configurations, floor {floor:.3f} px (the truth's RMS)")
    turn = calibrate_module.far_above_noise
    for label, multi in (("one start", False), ("turned starts", True)):
        calibrate_module.far_above_noise = turn if multi else (lambda *a: False)
        reached, seconds, finals = 0, [], []
        for k in range(args.starts):
            t0 = time.perf_counter()
            cal = calibrate(far_start(profile, k), sim.data, "handeye+offsets")
            seconds.append(time.perf_counter() - t0)
            finals.append(cal.figures["after"].rms)
            reached += finals[-1] < 1.05 * floor
            warned = "noise-excess" in [d.code for d in cal.diagnostics]
            print(
                f"  {label:13s} start {k}: {finals[-1]:9.2f} px, converged {cal.converged}, warned {warned}, "
                f"{cal.solver.starts} starts, {seconds[-1]:.2f} s"
            )
        print(f"{label}: {reached} of {args.starts} reach the floor; median {np.median(seconds):.2f} s per calibration")
    calibrate_module.far_above_noise = turn


if __name__ == "__main__":
    main()
