"""The solver's own time (`solve_seconds`, what `calib solve` prints) of the papers' full calibrations on the
simulated robots, this checkout and, in the same run, an earlier commit (issue 37: the NAO's per-frame scales
had made its full calibration four times slower).

    .venv/bin/python benchmarks/solve_speed.py [--runs 15] [--against COMMIT]

Each robot's data are simulated once (`calib simulate`'s default plan, seed 0); each checkout calibrates them
in a process of its own, `--runs` times after one warm-up, one checkout after the other, alternating, so that
both see the same load. Printed: the median and the least of the solver's times, and the estimate's largest
difference between the checkouts in standard deviations.
"""

from __future__ import annotations

import statistics
import subprocess
import sys
import tempfile
from pathlib import Path

from checkouts import against_parser, checkouts, run_in

ROBOTS = (("nao", "full"), ("robonaut-a", "full"))

MEASURE = """
import json, sys
from calib_core import calibrate, load_profile, read_dataset
robot, mode, path = sys.argv[1:4]
profile = load_profile(robot)
data = read_dataset(profile, path)
calibrate(profile, data, mode)
times, cal = [], None
for _ in range(int(sys.argv[4])):
    cal = calibrate(profile, data, mode)
    times.append(cal.solver.solve_seconds)
print(json.dumps({"times": times, "values": {p.name: [p.value, p.std] for p in cal.parameters if p.estimated},
                  "iterations": cal.solver.iterations}))
"""


def main() -> None:
    ap = against_parser(__doc__)
    ap.add_argument("--runs", type=int, default=15)
    args = ap.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        trees = checkouts(args.against, Path(tmp))
        for robot, mode in ROBOTS:
            data = Path(tmp) / f"{robot}.csv"
            subprocess.run(
                [str(Path(sys.executable).parent / "calib"), "simulate", "--robot", robot, "--out", str(data)],
                check=True,
                capture_output=True,
            )
            results: dict[str, dict] = {name: {"times": []} for name in trees}
            for _ in range(3):  # alternating thirds: both checkouts under the same load
                for name, tree in trees.items():
                    got = run_in(tree, MEASURE, robot, mode, str(data), str(max(args.runs // 3, 1)))
                    results[name]["times"] += got["times"]
                    results[name].update(values=got["values"], iterations=got["iterations"])
            for name, r in results.items():
                t = [1000 * s for s in r["times"]]
                print(
                    f"{robot} {mode:5s} {name:14s} solver median {statistics.median(t):6.1f} ms, least "
                    f"{min(t):6.1f} ms ({len(t)} runs, {r['iterations']} iterations)"
                )
            if len(results) == 2:
                (a, b) = (r["values"] for r in results.values())
                worst = max(abs(a[n][0] - b[n][0]) / max(a[n][1] or 0, 1e-12) for n in a if n in b)
                print(f"{robot} {mode:5s} estimates differ by at most {worst:.3f} sd")


if __name__ == "__main__":
    main()
