"""The CPU time of the fits the test suite spends most on, this checkout and, in the same run, an earlier commit:
mode `auto` on FIGAROH's real data (TALOS, TIAGo's random splits, the UR10e's poses: the first `--splits` of the
10 splits of calib_core.io.figaroh_data, what tests/test_peers.py calibrates) and `calib handeye` on ViSP's real
images (sample_sessions/handeye-visp, docs/handeye.md's example).

    .venv/bin/python benchmarks/fit_speed.py [--splits 3] [--runs 3] [--against COMMIT]

Each checkout runs in a process of its own with one BLAS thread, `--runs` times, one checkout after the other,
alternating, so that both see the same load. Printed: per robot the median of the runs' CPU seconds (all its
splits) and whether both checkouts chose the same candidates and predict the held-out configurations alike
(the pooled held-out RMS, as docs/peers.md gives it); for calib handeye the median CPU seconds and the camera's
position in the flange.
"""

from __future__ import annotations

import statistics

from checkouts import against_parser, alternating, compared

ROBOTS = ("talos", "tiago", "ur10e-pose")

AUTO = """
import json, sys, time
from pathlib import Path
import numpy as np
from calib_core import calibrate, load_profile
from calib_core.estimation.problem import Problem
from calib_core.io.figaroh_data import ROBOTS, pooled, pose_errors, splits
folder = Path(sys.argv[1]) / "sample_sessions" / "figaroh"
robot, n = sys.argv[2], int(sys.argv[3])
profile = load_profile(folder / ROBOTS[robot].profile)
parts, chosen, cpu = [], [], 0.0
for train, heldout in splits(profile, folder, robot)[:n]:
    start = time.process_time()
    cal = calibrate(profile, train, "auto")
    cpu += time.process_time() - start
    p = cal.params(profile)
    parts.append(pose_errors(profile, heldout, Problem(profile, heldout, [], p, noise_model=False).predict(p)))
    chosen.append(cal.choice.picked.name)
print(json.dumps({"cpu": cpu, "chosen": chosen, "mm": pooled(parts).rms_mm()}))
"""

HANDEYE = """
import contextlib, io, json, sys, tempfile, time
from pathlib import Path
from app.cli import main
d = Path(sys.argv[1]) / "sample_sessions" / "handeye-visp"
out = Path(tempfile.mkdtemp()) / "cal.json"
args = ["handeye", "--poses", str(d / "poses.csv"), "--images", str(d / "images"), "--camera", str(d / "camera.yaml"),
        "--board", (d / "board.txt").read_text().strip(), "--setup", "eye-in-hand", "--out", str(out)]
start = time.process_time()
with contextlib.redirect_stdout(io.StringIO()):  # its summary: this prints JSON only
    assert main(args) == 0
cpu = time.process_time() - start
X = json.loads(out.read_text())["camera_in_flange"]["matrix"]
print(json.dumps({"cpu": cpu, "t": [round(X[k][3], 3) for k in range(3)]}))
"""


def main() -> None:
    ap = against_parser(__doc__)
    ap.add_argument("--splits", type=int, default=3)
    ap.add_argument("--runs", type=int, default=3)
    args = ap.parse_args()
    with compared(args.against) as trees:
        for robot in ROBOTS:
            got = alternating(trees, args.runs, AUTO, "{tree}", robot, str(args.splits))
            for name, runs in got.items():
                print(
                    f"auto {robot:10s} {name:14s} {statistics.median(r['cpu'] for r in runs):6.2f} s CPU for "
                    f"{args.splits} splits, held out {runs[0]['mm']:.3f} mm, chose {', '.join(runs[0]['chosen'])}",
                    flush=True,
                )
            if len(got) == 2:
                a, b = (runs[0] for runs in got.values())
                print(f"auto {robot:10s} same choices: {a['chosen'] == b['chosen']}, held out differs by "
                      f"{abs(a['mm'] - b['mm']) * 1000:.2f} um")  # fmt: skip
        got = alternating(trees, args.runs, HANDEYE, "{tree}")
        for name, runs in got.items():
            print(
                f"calib handeye (ViSP) {name:14s} {statistics.median(r['cpu'] for r in runs):6.2f} s CPU, camera "
                f"in flange at {runs[0]['t']} mm"
            )


if __name__ == "__main__":
    main()
