"""Real data: the CTU Motoman laser-tracker and camera sets (sample_sessions/motoman-ctu).

1. Held-out error of `calib solve --robot motoman` on the tracker data: 10 random 70/30 splits
   (repeats of a configuration on one side), each subset (one tracker set-up, one arm), modes
   registration (the "before": nominal model, registration fitted), offsets and full, next to the
   plain least-squares figures of the data set's README; and how far the parameters moved.
2. Self-observation: calibrate from the camera pixels alone (mode `cameras`), then judge the result
   with the tracker it never saw (only the registration fitted; and, since no camera sees the
   reflector, the registration plus the reflector's row), next to the tracker-trained calibration.
3. Identifiability on real data: free S, T and the torso row as well, and name what the data cannot
   separate.

    python benchmarks/motoman.py [--data sample_sessions/motoman-ctu] [--splits 10]
"""

from __future__ import annotations

import argparse
import math
import time
from pathlib import Path

import numpy as np

from calib_core import calibrate, load_profile
from calib_core.dataset import Dataset
from calib_core.estimation.calibrate import observed_mode
from calib_core.estimation.identifiability import find_dependencies
from calib_core.estimation.problem import Problem
from calib_core.estimation.registration import register
from calib_core.estimation.solver import levenberg_marquardt
from calib_core.estimation.validation import holdout_split
from calib_core.io.ctu_motoman import LEICA_SUBSETS, camera_dataset, leica_subset, recording
from calib_core.model.profile import Profile

# The data set README's held-out figures (mm): M0, M1, M2 as mean / RMS / max, and M2r RMS.
README = {
    "aug2019-right": ((2.58, 3.03, 9.7), (2.28, 2.63, 8.1), (2.16, 2.52, 7.5), 2.52),
    "feb2019-A-right": ((6.14, 6.54, 10.8), (0.53, 0.58, 1.20), (0.36, 0.42, 0.93), 0.41),
    "feb2019-left-cube": ((0.35, 0.38, 0.74), (0.10, 0.11, 0.26), (0.072, 0.077, 0.15), 0.077),
    "feb2019-B-right-cube": ((0.32, 0.34, 0.58), (0.11, 0.13, 0.31), (0.068, 0.073, 0.14), 0.077),
}
MODES = {"registration": 0, "offsets": 1, "full": 2}


def errors_mm(profile: Profile, data: Dataset, p: np.ndarray) -> np.ndarray:
    return 1000.0 * np.linalg.norm(Problem(profile, data, [], p).predict(p) - data.measured, axis=1)


def stats(e: np.ndarray) -> tuple[float, float, float]:
    return float(e.mean()), float(np.sqrt(np.mean(e**2))), float(e.max())


def moved(profile: Profile, p: np.ndarray) -> tuple[float, float]:
    """Largest change from nominal of the robot's own parameters (not the registration): mm, deg."""
    nominal = profile.nominal()
    length, angle = 0.0, 0.0
    for i, prm in enumerate(profile.parameters):
        if prm.name.startswith("tracker."):
            continue
        d = abs(p[i] - nominal[i])
        if prm.kind == "length":
            length = max(length, 1000.0 * d)
        elif prm.kind == "angle":
            angle = max(angle, math.degrees(d))
    return length, angle


def tracker_holdout(profile: Profile, folder: Path, splits: int) -> None:
    print(f"## 1. Tracker data, held-out error over {splits} random 70/30 splits (mm, mean ± std over splits)\n")
    print("| subset (poses) | mode | mean | RMS | max | README mean / RMS / max | largest change | solve |")
    print("|---|---|---|---|---|---|---|---|")
    for name in LEICA_SUBSETS:
        data = leica_subset(profile, folder, name)
        for mode, k in MODES.items():
            rows, changes, seconds = [], [], []
            for seed in range(splits):
                start = time.perf_counter()
                cal = calibrate(profile, data, mode, holdout=0.3, seed=seed)
                seconds.append(time.perf_counter() - start)
                _, test = holdout_split(data, 0.3, seed)
                p = cal.params(profile)
                rows.append(stats(errors_mm(profile, data.select(test), p)))
                changes.append(moved(profile, p))
            r = np.array(rows)
            ref = README[name][k]
            cell = " | ".join(f"{m:.3f} ± {s:.3f}" for m, s in zip(r.mean(0), r.std(0), strict=True))
            ch = np.max(np.array(changes), axis=0)
            change = "-" if mode == "registration" else f"{ch[0]:.1f} mm, {ch[1]:.2f}°"
            print(
                f"| {name} ({data.n_observations}) | {mode} | {cell} | {ref[0]} / {ref[1]} / {ref[2]} | "
                f"{change} | {1000 * np.median(seconds):.0f} ms |"
            )
    print("\nREADME M2r (with a weak prior) RMS: " + ", ".join(f"{n} {v[3]}" for n, v in README.items()))


def self_observation(profile: Profile, folder: Path) -> None:
    print("\n## 2. Self-observation: calibrated from the camera pixels alone, judged by the tracker\n")
    data = camera_dataset(profile, folder)
    names = profile.parameter_names
    start = time.perf_counter()
    cal = calibrate(profile, data, "cameras", holdout=0.3)
    seconds = time.perf_counter() - start
    fitted = cal.params(profile)
    for s, f in cal.sensor_figures.items():
        n_obs = int(np.sum(data.sensor == names_of(profile).index(s)))
        print(
            f"- {s}: {n_obs} face centres, 30% of the {data.n_configurations} poses held out; training before "
            f"{f['before']}; after {f['after']}; held out before {f['holdout_before']}; after {f['holdout_after']}"
        )
    offsets = [f"{j}{a}.offset" for a in (1, 2) for j in "LURB"]
    estimate = {e.name: e for e in cal.parameters}
    print(
        "- joint offsets found (deg, ± standard deviation): "
        + ", ".join(f"{n} {estimate[n].value - estimate[n].nominal:+.3f} ± {estimate[n].std:.3f}" for n in offsets)
    )
    held = ", ".join(h.parameter for h in cal.identifiability.held_fixed) or "none"
    free = len(cal.identifiability.free)
    print(f"- {free} parameters in {seconds:.1f} s ({cal.solver.iterations} iterations); held: {held}")
    intrinsics = [f"camera{c}.{k}" for c in (1, 2) for k in ("fx", "fy", "cx", "cy")]
    print(
        "- intrinsics (px), nominal -> fitted: "
        + ", ".join(f"{n} {profile.nominal()[names.index(n)]:.0f} -> {fitted[names.index(n)]:.0f}" for n in intrinsics)
    )
    registration = list(profile.mode("registration").free)
    print("\n| subset | model | registration only: mean / RMS / max | registration + reflector row |")
    print("|---|---|---|---|")
    for name in ("feb2019-A-right", "feb2019-left-cube", "feb2019-B-right-cube"):
        data = leica_subset(profile, folder, name)
        for label, p in (("nominal", profile.nominal()), ("cameras", fitted)):
            q = register(profile, data, p)
            only = stats(errors_mm(profile, data, q))
            arm = data.target[0] + 1  # LR1 or LR2
            reflector = [names.index(f"LR{arm}.{k}") for k in ("a", "d", "offset")]
            problem = Problem(profile, data, registration + reflector, q)
            q2 = problem.params(levenberg_marquardt(problem.residuals_jacobian, problem.x0).x)
            both = stats(errors_mm(profile, data, q2))
            print(f"| {name} | {label} | {_fmt(only)} | {_fmt(both)} |")
        for mode in ("offsets", "full"):
            p = calibrate(profile, data, mode).params(profile)
            print(f"| {name} | tracker-trained {mode} (in-sample) | {_fmt(stats(errors_mm(profile, data, p)))} | - |")


def identifiability(profile: Profile, folder: Path) -> None:
    print("\n## 3. Identifiability on real data: mode `full` plus S, T and the torso row freed\n")
    names = profile.parameter_names
    for name in ("aug2019-right", "feb2019-A-right", "feb2019-left-cube"):
        data = leica_subset(profile, folder, name)
        arm = "2" if "left" in name else "1"
        extra = [i for i, n in enumerate(names) if n.split(".")[0] in (f"TT{arm}", f"S{arm}", f"T{arm}")]
        free = list(observed_mode(profile, data, profile.mode("full")).free) + extra
        p0 = register(profile, data, profile.nominal())
        problem = Problem(profile, data, free, p0)
        J = problem.residuals_jacobian(problem.x0)[1][: problem.n_data_rows]
        deps = find_dependencies(profile, J, free)
        print(f"- {name}: {len(free)} parameters, {len(deps)} the data cannot separate from the others:")
        for d in deps:
            print(f"  - {d.describe(profile)}")
        warnings = calibrate(profile, data, "full").warnings
        held = [w.split(" cannot")[0] for w in warnings if "held at its base value" in w]
        weak = [w.split(":")[0] for w in warnings if "weakly determined" in w]
        print(
            f"  - mode `full` itself: held: {'; '.join(held) or 'none'}; "
            f"weakly determined (only in combination): {'; '.join(weak) or 'none'}"
        )


def one_session(profile: Profile, folder: Path, splits: int) -> None:
    print("\n## 4. One session of three sensors: the left cube's tracker readings and both cameras' pixels\n")
    data = recording(profile, folder, "leica_left_hand_6x6x6_dataset.mat")
    counts = ", ".join(f"{s.name} {int(np.sum(data.sensor == i))}" for i, s in enumerate(profile.sensors))
    print(f"{data.n_configurations} poses; observations: {counts}. Held out: 30% of the poses, {splits} splits.\n")
    print("| mode | sensor | held out before: RMS | held out after: RMS | solve |")
    print("|---|---|---|---|---|")
    for mode in ("offsets", "cameras", "tracker-cameras"):
        rows: dict[str, list[tuple[float, float]]] = {}
        seconds = []
        for seed in range(splits):
            cal = calibrate(profile, data, mode, holdout=0.3, seed=seed)
            seconds.append(cal.solver.solve_seconds)
            each = cal.sensor_figures or {profile.sensors[data.sensors[0]].name: cal.figures}
            for name, f in each.items():
                rows.setdefault(name, []).append((f["holdout_before"].rms, f["holdout_after"].rms))
        for name, values in rows.items():
            before, after = np.array(values).T
            scale, unit = (1000.0, "mm") if name == "tracker" else (1.0, "px")
            print(
                f"| {mode} | {name} | {scale * before.mean():.3f} {unit} | {scale * after.mean():.3f} ± "
                f"{scale * after.std():.3f} {unit} | {1000 * np.median(seconds):.0f} ms |"
            )


def names_of(profile: Profile) -> list[str]:
    return [s.name for s in profile.sensors]


def _fmt(s: tuple[float, float, float]) -> str:
    return f"{s[0]:.2f} / {s[1]:.2f} / {s[2]:.2f}"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--data", type=Path, default=Path(__file__).resolve().parents[1] / "sample_sessions/motoman-ctu")
    ap.add_argument("--splits", type=int, default=10)
    args = ap.parse_args()
    profile = load_profile("motoman")
    tracker_holdout(profile, args.data, args.splits)
    self_observation(profile, args.data)
    identifiability(profile, args.data)
    one_session(profile, args.data, args.splits)


if __name__ == "__main__":
    main()
