"""The planner's time for Robonaut's full calibration, this checkout and, in the same run, an earlier commit
(issue 37: 300 planned configurations took 27 s before a replay could start).

    .venv/bin/python benchmarks/plan_speed.py [--counts 60 300] [--seeds 3] [--against COMMIT]

For each count and seed, each checkout plans in a process of its own (after a small plan that loads what the
planner imports, as a running desk has), one checkout after the other, alternating, so that both see the same
load. Printed per checkout and count: the plan's own time (`Plan.seconds`, what a replay job reports), its
CPU time, and the predicted RMS error of the plan over the workspace (the same plans, or better, is the point).
"""

from __future__ import annotations

import argparse
import statistics
import tempfile
from pathlib import Path

from checkouts import checkouts, run_in

MEASURE = """
import json, sys, time
from calib_core import load_profile
from calib_core.estimation.planning import plan
profile = load_profile("robonaut-a")
plan(profile, "full", 5, seed=99)
cpu = time.process_time()
made = plan(profile, "full", int(sys.argv[1]), seed=int(sys.argv[2]))
print(json.dumps({"seconds": made.seconds, "cpu": time.process_time() - cpu, "rms": made.predicted.rms}))
"""


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--counts", type=int, nargs="+", default=[60, 300])
    ap.add_argument("--seeds", type=int, default=3)
    ap.add_argument("--against", help="an earlier commit to measure beside this checkout")
    args = ap.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        trees = checkouts(args.against, Path(tmp))
        for n in args.counts:
            got: dict[str, list[dict]] = {name: [] for name in trees}
            for seed in range(args.seeds):
                for name, tree in trees.items():
                    got[name].append(run_in(tree, MEASURE, str(n), str(seed)))
            for name, runs in got.items():
                wall, cpu = [r["seconds"] for r in runs], [r["cpu"] for r in runs]
                rms = ", ".join(f"{r['rms']:.5f}" for r in runs)
                print(
                    f"robonaut-a full {n:4d} {name:14s} plan median {statistics.median(wall):5.2f} s "
                    f"(least {min(wall):5.2f}), CPU median {statistics.median(cpu):5.2f} s; predicted RMS {rms}"
                )


if __name__ == "__main__":
    main()
