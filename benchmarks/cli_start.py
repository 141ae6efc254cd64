"""How long `calib solve` takes to start (issue 25 item 14): from launching the command to the calibration starting,
and the whole run, on a small problem (Robonaut's first sample day, a daily calibration). The command runs as
`python -c` in this checkout around app.cli's main, which notes the wall clock when solve's `calibrate` is called.

    .venv/bin/python benchmarks/cli_start.py [--runs 9]
"""

from __future__ import annotations

import argparse
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
CHILD = """
import sys, time
import app.cli
import app.cli.calibration as solve
calibrate = solve.calibrate
def timed(*a, **k):
    print("calibrate", time.time(), file=sys.stderr)
    return calibrate(*a, **k)
solve.calibrate = timed
sys.argv = sys.argv[1:]
app.cli.main()
"""


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--runs", type=int, default=9)
    args = ap.parse_args()
    data = ROOT / "sample_sessions" / "robonaut-a-day1" / "data.csv"
    starts, totals = [], []
    with tempfile.TemporaryDirectory() as tmp:
        argv = ["calib", "solve", "--robot", "robonaut-a", "--mode", "daily", "--data", str(data)]
        for _ in range(args.runs):
            t0 = time.time()
            proc = subprocess.run(
                [sys.executable, "-c", CHILD, *argv, "--out", f"{tmp}/cal.json"],
                capture_output=True,
                text=True,
                cwd=ROOT,
            )
            totals.append(time.time() - t0)
            if proc.returncode:
                raise SystemExit(proc.stderr[-2000:])
            (line,) = [x for x in proc.stderr.splitlines() if x.startswith("calibrate ")]
            starts.append(float(line.split()[1]) - t0)
    load = Path("/proc/loadavg").read_text().split()[0]
    print(f"calib solve (robonaut-a daily, {args.runs} runs, load average {load}):")
    print(
        f"  start, from launch to the calibration starting: median {np.median(starts):.3f} s, max {max(starts):.3f} s"
    )
    print(f"  whole run: median {np.median(totals):.3f} s, max {max(totals):.3f} s")


if __name__ == "__main__":
    main()
