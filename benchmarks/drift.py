"""The History's figures on the simulated NAO itself, calibrations and all (issue 39): not draws from a covariance,
as tests/test_drift.py takes, but each day simulated, measured with noise and calibrated in mode `full`, so the
test leans on the covariances the solver reports as an operator's history would.

- histories of nothing: `--histories` runs of `--days` days of one NAO that does not move (each its own seeds);
  how many show any flag (a change or a trend) at the desk's level (1%) and at 10%;
- a drifting knee: the same runs with LKneePitch drifting `--rate` deg a day; the rate found against the rate put
  in, and whether anything else was named;
- a team: `--teams` teams of five NAOs, nao-4's board 2 mm off (LTransX): how often nao-4 / LTransX alone is named.

    .venv/bin/python benchmarks/drift.py [--histories 20 --days 6 --teams 10]
"""

from __future__ import annotations

import argparse
import time
from datetime import UTC, datetime, timedelta

import numpy as np

from calib_core import calibrate, load_profile
from calib_core.estimation import Epoch, compare_team, find_drift
from calib_core.sim import Law, SimulatedRobot

T0 = datetime(2026, 11, 1, 9, tzinfo=UTC)


def epoch(profile, law: Law, seed: int, day: int, name: str) -> Epoch:
    truth = law.truth(profile, profile.true_params(), day)
    sim = SimulatedRobot.from_profile(profile, seed=seed, truth=truth).simulate(None)
    return Epoch.of(calibrate(profile, sim.data, "full"), name, T0 + timedelta(days=day - 1))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--histories", type=int, default=20)
    ap.add_argument("--days", type=int, default=6)
    ap.add_argument("--rate", type=float, default=0.05, help="the knee's drift, deg a day")
    ap.add_argument("--teams", type=int, default=10)
    args = ap.parse_args()
    nao = load_profile("nao")
    started = time.perf_counter()
    still = Law()
    drifting = Law(drift_per_day={"LKneePitch": args.rate})
    flags = {0.01: 0, 0.1: 0}
    rates, others = [], 0
    for h in range(args.histories):
        quiet = [epoch(nao, still, 10_000 + 100 * h + d, d, f"d{d}") for d in range(1, args.days + 1)]
        for level in flags:
            drift = find_drift(quiet, level)
            flags[level] += bool(drift.trends or drift.flagged)
        moving = [epoch(nao, drifting, 20_000 + 100 * h + d, d, f"d{d}") for d in range(1, args.days + 1)]
        drift = find_drift(moving)
        knee = [t for t in drift.trends if t.parameter == "LKneePitch"]
        rates.append(knee[0].rate_per_day if knee else float("nan"))
        named = {t.parameter for t in drift.trends} | {m.parameter for s in drift.flagged for m in s.moved}
        others += bool(named - {"LKneePitch"})
    took = time.perf_counter() - started
    print(f"NAO, mode full, {args.histories} histories of {args.days} days each ({took:.0f} s)")
    for level, n in flags.items():
        print(f"  nothing moving: {n}/{args.histories} histories flagged at level {level:g}")
    r = np.array(rates)
    found = np.isfinite(r)
    err = np.abs(r[found] - args.rate) / args.rate
    print(
        f"  knee +{args.rate} deg/day: found in {found.sum()}/{args.histories}, rate {np.nanmean(r):.4f} "
        f"(sd {np.nanstd(r):.4f}), error at most {100 * err.max():.1f}%; something else named in {others}"
    )
    started = time.perf_counter()
    named_right = 0
    law4 = Law(shift={"LTransX": 2.0})
    for k in range(args.teams):
        team = {f"nao-{i}": epoch(nao, law4 if i == 4 else still, 30_000 + 10 * k + i, 1, f"c{i}") for i in range(1, 6)}
        odd = [(o.robot, o.parameter) for o in compare_team(team).odd]
        named_right += odd == [("nao-4", "LTransX")]
    print(
        f"  teams of five, nao-4's board 2 mm off: nao-4 / LTransX alone named in {named_right}/{args.teams} "
        f"({time.perf_counter() - started:.0f} s)"
    )


if __name__ == "__main__":
    main()
