"""Outlier rejection on data with model error: the old rule (every observation beyond the limit
rejected), the new one (only those nothing else in the data predicts: estimation/outliers.py
`sort_outliers`) and no rejection (`--no-robust`), by their held-out error.

1. Simulated Motoman: its truth has errors in every joint origin (a, d, alpha, offsets), fitted in
   mode `offsets`, which cannot describe them. Sessions of 200 poses, 85% within 0.2 rad of one
   pose on every joint and 15% anywhere (the wide ones show model error far beyond the cube's
   spread); with no gross errors and with 5% misread reflectors (20 mm). Held out: 400 fresh poses
   of the same kind; "rejected" counts the configurations left out, "hits" how many of them were
   the injected gross errors.
2. The CTU Motoman tracker data (sample_sessions/motoman-ctu), mode `offsets`, 10 random 70/30
   splits; every held-out pose counted.
Both with the tracker's default outlier limit (99.99% quantile), not the wide one the profile
declares, so that the rule and not the limit decides.

    python benchmarks/outliers.py [--seeds 5] [--splits 10]
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np

from calib_core import Dataset, Profile, SimulatedRobot, calibrate, load_profile
from calib_core.estimation import calibrate as calibrate_module
from calib_core.estimation.outliers import OutlierVerdict, sort_outliers
from calib_core.estimation.problem import Problem
from calib_core.estimation.validation import holdout_split
from calib_core.io.ctu_motoman import LEICA_SUBSETS, leica_subset


def old_rule(problem: Problem, x: np.ndarray, flagged: np.ndarray) -> OutlierVerdict:
    """Before: every observation beyond its sensor's limit is a gross error."""
    return OutlierVerdict(flagged.copy(), np.zeros_like(flagged), np.full(len(flagged), np.nan))


RULES = {"old rule": (old_rule, True), "new rule": (sort_outliers, True), "no rejection": (sort_outliers, False)}


def errors_mm(profile: Profile, data: Dataset, p: np.ndarray) -> np.ndarray:
    return 1000.0 * np.linalg.norm(Problem(profile, data, [], p).predict(p) - data.measured, axis=1)


def solve(profile: Profile, data: Dataset, rule: str, **kwargs):
    calibrate_module.sort_outliers, robust = RULES[rule]
    try:
        return calibrate(profile, data, "offsets", robust=robust, **kwargs)
    finally:
        calibrate_module.sort_outliers = sort_outliers


def simulated(profile: Profile, seeds: int) -> None:
    print("## 1. Simulated Motoman, joint-origin errors, mode offsets (held-out mm, mean ± std over seeds)\n")
    print("| gross errors | rule | held-out mean | held-out max | rejected | hits |")
    print("|---|---|---|---|---|---|")
    for rate in (0.0, 0.05):
        rows: dict[str, list[tuple[float, float, int, int]]] = {r: [] for r in RULES}
        for seed in range(seeds):
            robot = SimulatedRobot.from_profile(profile, seed=seed)
            sim = robot.measure(*robot.clustered(200, 0.2, 0.15), outlier_rate=rate, outlier_size=0.02)
            fresh = robot.measure(*robot.clustered(400, 0.2, 0.15))
            injected = {int(f) for f in sim.data.frame_ids[sim.data.cfg[sim.outliers]]}
            for rule in RULES:
                cal = solve(profile, sim.data, rule)
                e = errors_mm(profile, fresh.data, cal.params(profile))
                frames = {o.frame for o in cal.outliers}
                rows[rule].append((e.mean(), e.max(), len(frames), len(frames & injected)))
        for rule, r in rows.items():
            a = np.array(r)
            print(
                f"| {rate:.0%} | {rule} | {a[:, 0].mean():.3f} ± {a[:, 0].std():.3f} | {a[:, 1].mean():.3f} ± "
                f"{a[:, 1].std():.3f} | {a[:, 2].mean():.1f} | {a[:, 3].mean():.1f} |"
            )


def real(profile: Profile, folder: Path, splits: int) -> None:
    print(f"\n## 2. CTU Motoman tracker data, mode offsets, {splits} 70/30 splits (held-out mm, mean ± std)\n")
    print("| subset (poses) | rule | held-out mean | held-out max | rejected per split | solve |")
    print("|---|---|---|---|---|---|")
    for name in LEICA_SUBSETS:
        data = leica_subset(profile, folder, name)
        for rule in RULES:
            r, seconds = [], []
            for seed in range(splits):
                start = time.perf_counter()
                cal = solve(profile, data, rule, holdout=0.3, seed=seed)
                seconds.append(time.perf_counter() - start)
                e = errors_mm(profile, data.select(holdout_split(data, 0.3, seed)[1]), cal.params(profile))
                r.append((e.mean(), e.max(), len(cal.outliers)))
            a = np.array(r)
            print(
                f"| {name} ({data.n_observations}) | {rule} | {a[:, 0].mean():.3f} ± {a[:, 0].std():.3f} | "
                f"{a[:, 1].mean():.3f} ± {a[:, 1].std():.3f} | {a[:, 2].mean():.1f} | "
                f"{1000 * np.median(seconds):.0f} ms |"
            )


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--data", type=Path, default=Path("sample_sessions/motoman-ctu"))
    ap.add_argument("--seeds", type=int, default=5)
    ap.add_argument("--splits", type=int, default=10)
    args = ap.parse_args()
    profile = load_profile("motoman")
    tracker = [s.name for s in profile.sensors].index("tracker")
    profile = profile.with_noise({"model": "isotropic", "sigma": 0.00005}, tracker)  # the default limit
    simulated(profile, args.seeds)
    real(profile, args.data, args.splits)


if __name__ == "__main__":
    main()
