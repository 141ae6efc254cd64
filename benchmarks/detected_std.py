"""Do the reported standard deviations hold for calibrations from detected (image) measurements?

    .venv/bin/python benchmarks/detected_std.py                # 48 runs, 2 processes (about 5 minutes)
    .venv/bin/python benchmarks/detected_std.py --runs 16      # a rough look

The solver weighs observations by the sensor's noise model (Robonaut: the stereo model, 0.3 px
lateral and 0.25 px of disparity, about 5 mm at 1 m) and scales the covariance by the residuals'
own sigma^2. BallFinder centres from the rendered stereo depth are several times more precise than
that model, and not necessarily shaped like it. Each run puts a first-day Robonaut in 67 new
configurations, renders them, detects the sphere (seeded by the nominal model) and calibrates in
mode full; the spread of the estimates over the runs is set beside the mean reported standard
deviation, parameter by parameter (1.0: right). The same is done, much faster, for the simulator's
exact measurements with its nominal noise, as the reference. With 48 runs the spread itself is
known to about 10%.
"""

from __future__ import annotations

import argparse
import multiprocessing as mp

import numpy as np

from calib_core import SimulatedRobot, calibrate, load_profile


def one_run(seed: int) -> tuple[dict[str, tuple[float, float]], dict[str, tuple[float, float]], float, float]:
    """Estimates (value, std) from detections and from exact measurements, and the two fits' sigma."""
    rn = load_profile("robonaut-a")
    robot = SimulatedRobot.from_profile(rn, seed=50_000 + seed)
    images = robot.simulate_images(67)
    cal_detected = calibrate(rn, images.data, "full")
    exact = SimulatedRobot.from_profile(rn, seed=60_000 + seed).simulate(67)
    cal_exact = calibrate(rn, exact.data, "full")
    return (
        _estimates(cal_detected),
        _estimates(cal_exact),
        cal_detected.solver["sigma"],
        cal_exact.solver["sigma"],
    )


def _estimates(cal) -> dict[str, tuple[float, float]]:
    """Value and reported std of every estimated parameter that is not held fixed."""
    return {
        e.name: (e.value, e.std)
        for e in cal.parameters
        if e.estimated and (e.note is None or e.note.startswith("tied"))
    }


def ratios(runs: list[dict[str, tuple[float, float]]]) -> dict[str, float]:
    names = sorted(set.intersection(*(set(r) for r in runs)))
    values = np.array([[r[n][0] for n in names] for r in runs])
    stds = np.array([[r[n][1] for n in names] for r in runs])
    return dict(zip(names, stds.mean(axis=0) / values.std(axis=0, ddof=1), strict=True))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--runs", type=int, default=48)
    ap.add_argument("--processes", type=int, default=2)
    args = ap.parse_args()
    with mp.Pool(args.processes) as pool:
        results = pool.map(one_run, range(args.runs))
    detected = ratios([r[0] for r in results])
    exact = ratios([r[1] for r in results])
    print(f"Robonaut full, 67 configurations, {args.runs} runs: reported std / spread of the estimates")
    print(f"{'parameter':<24} {'detected':>9} {'exact':>9}")
    for name in sorted(detected):
        print(f"{name:<24} {detected[name]:>9.2f} {exact.get(name, float('nan')):>9.2f}")
    d, e = np.array(list(detected.values())), np.array(list(exact.values()))
    print(f"{'median (range)':<24} {np.median(d):>9.2f} {np.median(e):>9.2f}   ({d.min():.2f}-{d.max():.2f} detected)")
    sig_d = np.median([r[2] for r in results])
    sig_e = np.median([r[3] for r in results])
    print(f"fit sigma (residuals in units of the noise model), median: detected {sig_d:.3f}, exact {sig_e:.3f}")


if __name__ == "__main__":
    main()
