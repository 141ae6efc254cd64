"""End to end: simulated capture -> rendered images -> detections -> calibration, judged against the truth.

    .venv/bin/python benchmarks/end_to_end.py           # the sample sessions' sizes (about a minute)
    .venv/bin/python benchmarks/end_to_end.py --quick   # fewer frames

For each experiment the simulated robot is put in the configurations its simulator picks; the
cameras' images are rendered and the detectors (seeded by what the robot believes: the nominal
model on a first day, the first day's calibration later) measure the fixture. Beside the calibration
from those detections stands one from the simulator's exact measurements of the same configurations
with its nominal noise (Robonaut: 0.3 px lateral, 0.25 px disparity; NAO: 0.2 px). The detections
are weighed by the detectors' own noise (the profile's `simulation.detected_noise`); a column shows
the same detections weighed by the sensor's model in the profile, as `calib solve` does.

Both are judged on held-out configurations of the same day against the truth: each calibration
predicts the fixture from the robot's readings (rounded to 0.1 deg) and the prediction is compared
with the simulator's noise-free measurement at the true joint angles. "Floor" is the same error for
the hidden true parameters: what the encoder rounding alone leaves. "Detector error" is the RMS
distance of the detections from the noise-free measurement (Robonaut mm, NAO px), beside that of the
simulated noise.

  Robonaut full:  first day, 67 configurations, mode full from the nominal model.
  Robonaut daily: a later day (joint offsets drifted 4 deg RMS), 150 configurations, mode daily from
                  the first day's full calibration (the detectors seeded by it).
  NAO full:       24 leg stances x 3 head postures per leg, mode full (the paper's 21 parameters).
"""

from __future__ import annotations

import argparse
import os
import time
from dataclasses import dataclass

import numpy as np

from calib_core import Calibration, Problem, Profile, SimulatedRobot, calibrate, load_profile
from calib_core.sim.simulator import ImageSimulation, Simulation


@dataclass
class Result:
    name: str
    frames: str
    unit: str
    detector: float  # RMS distance of the detections from the noise-free measurement
    simulated: float  # the same for the simulator's nominal noise
    detected_after: float  # training RMS of the calibration from detections
    exact_after: float
    detected_heldout: tuple[float, float]  # mean, RMS against the truth on held-out configurations
    model_heldout: tuple[float, float]  # the same, the detections weighed by the sensor's (stereo) model
    exact_heldout: tuple[float, float]
    floor: tuple[float, float]
    seconds: float
    cal_detected: Calibration
    cal_exact: Calibration


def heldout(profile: Profile, held: Simulation, p: np.ndarray) -> tuple[float, float]:
    """Mean and RMS distance between the prediction of p from the readings and the noise-free truth."""
    e = np.linalg.norm(Problem(profile, held.data, [], p).predict(p) - held.exact, axis=1)
    return float(e.mean()), float(np.sqrt(np.mean(e**2)))


def rms(a: np.ndarray, b: np.ndarray) -> float:
    return float(np.sqrt(np.mean(np.sum((a - b) ** 2, axis=1))))


def same_frames(robot: SimulatedRobot, images: ImageSimulation) -> Simulation:
    """The simulator's exact measurement of the frames the detectors measured, with its nominal noise."""
    idx = images.data.frame_ids - 1
    return robot.measure(images.true_joints[idx], images.targets[idx])


def experiment(
    name: str,
    profile: Profile,
    robot: SimulatedRobot,
    n: int | None,
    mode: str,
    held: Simulation,
    base: tuple[Calibration, Calibration] | None = None,
) -> Result:
    """Capture n frames through the images and calibrate, and the same frames with exact measurements;
    `base`: the (detected, exact) calibrations the day starts from."""
    start = time.perf_counter()
    believed = base[0].params(profile) if base else None
    images = robot.simulate_images(n, believed)
    exact = same_frames(robot, images)
    cal_d = calibrate(images.profile_for_data(profile), images.data, mode, base[0] if base else None)
    cal_m = calibrate(profile, images.data, mode, base[0] if base else None)  # weighed as the head's model says
    cal_e = calibrate(profile, exact.data, mode, base[1] if base else None)
    unit = "mm" if profile.length_unit == "cm" else cal_d.figures["after"].unit
    scale = 10.0 if unit == "mm" else 1.0
    return Result(
        name,
        f"{images.data.n_configurations} of {len(images.captures)}",
        unit,
        scale * rms(images.data.measured, exact.exact),
        scale * rms(exact.data.measured, exact.exact),
        cal_d.figures["after"].rms * scale,
        cal_e.figures["after"].rms * scale,
        tuple(scale * v for v in heldout(profile, held, cal_d.params(profile))),  # type: ignore[arg-type]
        tuple(scale * v for v in heldout(profile, held, cal_m.params(profile))),  # type: ignore[arg-type]
        tuple(scale * v for v in heldout(profile, held, cal_e.params(profile))),  # type: ignore[arg-type]
        tuple(scale * v for v in heldout(profile, held, robot.true_params)),  # type: ignore[arg-type]
        time.perf_counter() - start,
        cal_d,
        cal_e,
    )


def twin(robot: SimulatedRobot, seed: int) -> SimulatedRobot:
    """The same robot (same day, same truth) with its own random stream: for held-out configurations."""
    return SimulatedRobot(robot.profile, robot.true_params, robot.pixel_noise, robot.disparity_noise, seed=seed)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--quick", action="store_true", help="30 + 60 Robonaut configurations, 8 NAO stances per leg")
    ap.add_argument("--seed", type=int, default=1)
    args = ap.parse_args()
    n_full, n_daily, n_nao = (30, 60, 48) if args.quick else (67, 150, None)

    rn = load_profile("robonaut-a")
    day1 = SimulatedRobot.from_profile(rn, seed=args.seed)
    full = experiment("Robonaut full", rn, day1, n_full, "full", twin(day1, 1000 + args.seed).simulate(300))
    day2 = day1.drifted(seed=1000 * args.seed + 2)
    daily = experiment(
        "Robonaut daily (later day)",
        rn,
        day2,
        n_daily,
        "daily",
        twin(day2, 2000 + args.seed).simulate(300),
        (full.cal_detected, full.cal_exact),
    )
    nao = load_profile("nao")
    robot = SimulatedRobot.from_profile(nao, seed=args.seed)
    held = twin(robot, 3000 + args.seed).simulate()
    nao_full = experiment("NAO full", nao, robot, n_nao, "full", held)

    print(
        "| experiment | frames measured | detector error (simulated noise) | training RMS: detected / exact "
        "| held-out vs truth, mean / RMS: from detections | (weighed by the head's model) "
        "| from exact + nominal noise | floor (true parameters) | time |"
    )
    print("|---|---|---|---|---|---|---|---|---|")
    for r in (full, daily, nao_full):
        print(
            f"| {r.name} | {r.frames} | {r.detector:.2f} {r.unit} ({r.simulated:.2f}) "
            f"| {r.detected_after:.2f} / {r.exact_after:.2f} {r.unit} "
            f"| {r.detected_heldout[0]:.2f} / {r.detected_heldout[1]:.2f} {r.unit} "
            f"| {r.model_heldout[0]:.2f} / {r.model_heldout[1]:.2f} "
            f"| {r.exact_heldout[0]:.2f} / {r.exact_heldout[1]:.2f} {r.unit} "
            f"| {r.floor[0]:.2f} / {r.floor[1]:.2f} {r.unit} | {r.seconds:.0f} s |"
        )
    print(f"(machine load average at the end: {os.getloadavg()[0]:.1f} on {os.cpu_count()} cores)")


if __name__ == "__main__":
    main()
