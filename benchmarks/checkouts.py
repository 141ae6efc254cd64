"""This checkout and an earlier commit side by side, for the benchmarks that measure a change in one run
(`solve_speed.py`, `plan_speed.py`): the commit extracted with `git archive`, code run in each by a process of
its own with one BLAS thread."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent


def checkouts(against: str | None, tmp: Path) -> dict[str, Path]:
    """{"this checkout": ROOT} and, when `against` names a commit, that commit's tree under `tmp`."""
    trees = {"this checkout": ROOT}
    if against:
        old = tmp / "against"
        old.mkdir()
        archive = subprocess.run(["git", "archive", against], cwd=ROOT, capture_output=True, check=True)
        subprocess.run(["tar", "-x", "-C", str(old)], input=archive.stdout, check=True)
        trees[against] = old
    return trees


def run_in(tree: Path, code: str, *args: str) -> dict:
    """The JSON that `code` prints, run with `args` by Python in `tree` (its calib_core and app)."""
    done = subprocess.run(
        [sys.executable, "-c", code, *args],
        cwd=tree,
        env={"PYTHONPATH": str(tree), "OPENBLAS_NUM_THREADS": "1", "PATH": "/usr/bin:/bin"},
        capture_output=True,
        text=True,
        check=True,
    )
    return json.loads(done.stdout)
