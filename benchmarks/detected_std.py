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

WEIGHTINGS = {
    "stereo model": None,
    "stereo 0.28/0.023": {"model": "stereo", "pixel": 0.28, "disparity": 0.023},
    "isotropic z^2": {"model": "isotropic", "sigma": 0.052, "reference_distance": 100.0},
}


def one_run(seed: int) -> dict[str, tuple[dict[str, tuple[float, float]], float]]:
    """Estimates (value, std) and the fit's sigma: from detections under each weighting, and from
    the simulator's exact measurements with its nominal noise."""
    rn = load_profile("robonaut-a")
    robot = SimulatedRobot.from_profile(rn, seed=50_000 + seed)
    images = robot.simulate_images(67)
    out = {}
    for name, noise in WEIGHTINGS.items():
        cal = calibrate(rn if noise is None else rn.with_noise(noise), images.data, "full")
        out[name] = (_estimates(cal), cal.solver.sigma)
    exact = SimulatedRobot.from_profile(rn, seed=60_000 + seed).simulate(67)
    cal = calibrate(rn, exact.data, "full")
    out["exact, stereo model"] = (_estimates(cal), cal.solver.sigma)
    return out


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
    columns = list(results[0])
    table = {c: ratios([r[c][0] for r in results]) for c in columns}
    print(f"Robonaut full, 67 configurations, {args.runs} runs: reported std / spread of the estimates")
    print(f"{'parameter':<22}" + "".join(f"{c:>22}" for c in columns))
    for name in sorted(table[columns[0]]):
        print(f"{name:<22}" + "".join(f"{table[c].get(name, float('nan')):>22.2f}" for c in columns))
    for label, f in (("median", np.median), ("min", np.min), ("max", np.max)):
        print(f"{label:<22}" + "".join(f"{f(list(table[c].values())):>22.2f}" for c in columns))
    sigmas = [np.median([r[c][1] for r in results]) for c in columns]
    print(f"{'fit sigma (median)':<22}" + "".join(f"{v:>22.3f}" for v in sigmas))


if __name__ == "__main__":
    main()
