"""Re-run the shape of the papers' experiments on the simulated robots and print one table.

    .venv/bin/python benchmarks/papers.py            # all, with the Nelder-Mead baseline (a few minutes)
    .venv/bin/python benchmarks/papers.py --quick    # without Nelder-Mead

Robonaut (Nickels & Huber, section IV): A, a full calibration on 67 configurations; B, a later day
with drifted joint offsets, 150 new configurations, daily calibration from A's result; C, the daily
calibration on 75 of them, judged on the other 75. NAO (Kastner et al., 3.1/3.2): 24 leg stances x
3 head postures per leg, the 21 parameters. Every held-out figure is set beside the floor: the error
the hidden true parameters give on the same joint readings and measurements.
"""

from __future__ import annotations

import argparse
import statistics
import time
from dataclasses import dataclass

import numpy as np

from calib_core import Calibration, Dataset, Problem, Profile, SimulatedRobot, calibrate, load_profile


@dataclass
class Row:
    name: str
    data: str
    before: str
    after: str
    heldout: str
    floor: str
    ratio: float
    solve_ms: float
    iterations: int
    param_error: str
    nm: str = "-"


def rms(profile: Profile, data: Dataset, p: np.ndarray) -> float:
    e = Problem(profile, data, [], p, noise_model=False).predict(p) - data.measured
    return float(np.sqrt(np.mean(np.sum(e**2, axis=1))))


def mean_dist(profile: Profile, data: Dataset, p: np.ndarray) -> float:
    e = Problem(profile, data, [], p, noise_model=False).predict(p) - data.measured
    return float(np.mean(np.linalg.norm(e, axis=1)))


def solve_ms(profile: Profile, data: Dataset, mode: str, base: Calibration | None, repeats: int = 7) -> float:
    """Median solver time over repeats (the first run warms caches up and is dropped)."""
    times = [calibrate(profile, data, mode, base).solver.solve_seconds for _ in range(repeats + 1)]
    return 1e3 * statistics.median(times[1:])


def parameter_errors(profile: Profile, cal: Calibration, truth: np.ndarray) -> str:
    """Largest |estimate - truth| over estimated parameters that no held-fixed one is entangled with,
    in deg and in the length unit, and the largest error in reported standard deviations."""
    entangled = set()
    for h in cal.identifiability.held_fixed:
        entangled.add(h.parameter)
        entangled |= {p.name for p in cal.parameters if p.label in h.message}
    worst = {"deg": 0.0, profile.length_unit: 0.0}
    worst_sigma = 0.0
    for p in cal.parameters:
        if not p.estimated or p.name in entangled:
            continue
        i = profile.param(p.name)
        err = abs(p.value - profile.to_display(i, truth[i]))
        worst[p.unit] = max(worst.get(p.unit, 0.0), err)
        if p.std:
            worst_sigma = max(worst_sigma, err / p.std)
    parts = [f"{v:.3g} {u}" for u, v in worst.items() if v > 0]
    return ", ".join(parts) + f" ({worst_sigma:.1f} sd)"


def nelder_mead(profile: Profile, data: Dataset, mode: str, base: Calibration | None, lm_ms: float) -> str:
    start = time.perf_counter()
    nm = calibrate(profile, data, mode, base, method="nelder-mead")
    seconds = time.perf_counter() - start
    unit = nm.figures["after"].unit
    return (
        f"{nm.figures['after'].mean:.3g} {unit} mean in {seconds:.1f} s, {nm.solver.evaluations} evaluations "
        f"({seconds * 1e3 / lm_ms:.0f}x LM)"
    )


def robonaut(with_nm: bool) -> list[Row]:
    prof = load_profile("robonaut-a")
    unit = prof.length_unit
    day1 = SimulatedRobot.from_profile(prof, seed=1)
    s67 = day1.simulate(67)
    fresh = day1.simulate(150)  # the same day, configurations the calibration never saw
    full = calibrate(prof, s67.data, "full")
    truth1 = s67.true_params
    rows = []
    f = full.figures
    ms = solve_ms(prof, s67.data, "full", None)
    ho = rms(prof, fresh.data, full.params(prof))
    floor = rms(prof, fresh.data, truth1)
    rows.append(
        Row(
            "Robonaut IV-A full",
            "67 configs (+150 held out)",
            f"{f['before'].mean:.2f} mean / {f['before'].rms:.2f} RMS {unit}",
            f"{f['after'].mean:.2f} / {f['after'].rms:.2f} {unit}",
            f"{mean_dist(prof, fresh.data, full.params(prof)):.3f} / {ho:.3f} {unit}",
            f"{floor:.3f} {unit}",
            ho / floor,
            ms,
            full.solver.iterations,
            parameter_errors(prof, full, truth1),
            nelder_mead(prof, s67.data, "full", None, ms) if with_nm else "-",
        )
    )
    day2 = day1.drifted(seed=2)
    s150 = day2.simulate(150)
    truth2 = s150.true_params
    daily = calibrate(prof, s150.data, "daily", full)
    d = daily.figures
    ms = solve_ms(prof, s150.data, "daily", full)
    rows.append(
        Row(
            "Robonaut IV-B daily",
            "later day, 150 configs",
            f"{d['before'].mean:.2f} / {d['before'].rms:.2f} {unit}",
            f"{d['after'].mean:.2f} / {d['after'].rms:.2f} {unit}",
            "-",
            f"{rms(prof, s150.data, truth2):.3f} {unit} (on the 150)",
            d["after"].rms / rms(prof, s150.data, truth2),
            ms,
            daily.solver.iterations,
            parameter_errors(prof, daily, truth2),
            nelder_mead(prof, s150.data, "daily", full, ms) if with_nm else "-",
        )
    )
    half = calibrate(prof, s150.data, "daily", full, holdout=0.5, seed=3)
    h = half.figures
    test = s150.data.select(np.isin(s150.data.frame_ids, half.frames["holdout"]))
    floor_c = rms(prof, test, truth2)
    rows.append(
        Row(
            "Robonaut IV-C daily",
            "75 configs, other 75 held out",
            f"{h['holdout_before'].mean:.2f} / {h['holdout_before'].rms:.2f} {unit} (held out)",
            f"{h['after'].mean:.2f} / {h['after'].rms:.2f} {unit}",
            f"{h['holdout_after'].mean:.3f} / {h['holdout_after'].rms:.3f} {unit}",
            f"{floor_c:.3f} {unit}",
            h["holdout_after"].rms / floor_c,
            solve_ms(prof, s150.data.select(np.isin(s150.data.frame_ids, half.frames["train"])), "daily", full),
            half.solver.iterations,
            parameter_errors(prof, half, truth2),
        )
    )
    return rows


def nao(with_nm: bool) -> list[Row]:
    prof = load_profile("nao")
    robot = SimulatedRobot.from_profile(prof, seed=1)
    sim = robot.simulate()  # 24 stances x 3 head postures per leg
    fresh = robot.simulate()
    cal = calibrate(prof, sim.data, "full")
    f = cal.figures
    ms = solve_ms(prof, sim.data, "full", None)
    ho = rms(prof, fresh.data, cal.params(prof))
    floor = rms(prof, fresh.data, sim.true_params)
    ax = f["after"].rms_axes
    return [
        Row(
            "NAO 3.1/3.2 full (21)",
            f"{sim.data.n_configurations} frames, {sim.data.n_observations} vertices",
            f"{f['before'].mean:.1f} / {f['before'].rms:.1f} px",
            f"{f['after'].mean:.3f} / {f['after'].rms:.3f} px (x {ax[0]:.3f}, y {ax[1]:.3f})",
            f"{mean_dist(prof, fresh.data, cal.params(prof)):.3f} / {ho:.3f} px",
            f"{floor:.3f} px",
            ho / floor,
            ms,
            cal.solver.iterations,
            parameter_errors(prof, cal, sim.true_params),
            nelder_mead(prof, sim.data, "full", None, ms) if with_nm else "-",
        )
    ]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="skip the (slow) Nelder-Mead baseline")
    args = ap.parse_args()
    rows = robonaut(not args.quick) + nao(not args.quick)
    head = [
        "experiment",
        "data",
        "before (mean / RMS)",
        "after, training",
        "after, held out",
        "truth floor (RMS)",
        "held-out / floor",
        "solver ms",
        "iter.",
        "max parameter error",
        "Nelder-Mead (paper's method)",
    ]
    print("| " + " | ".join(head) + " |")
    print("|" + "---|" * len(head))
    for r in rows:
        cells = [r.name, r.data, r.before, r.after, r.heldout, r.floor, f"{r.ratio:.3f}", f"{r.solve_ms:.1f}"]
        cells += [str(r.iterations), r.param_error, r.nm]
        print("| " + " | ".join(cells) + " |")


if __name__ == "__main__":
    main()
