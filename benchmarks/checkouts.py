"""This checkout and an earlier commit side by side, for the benchmarks that measure a change in one run
(`solve_speed.py`, `plan_speed.py`): the commit extracted with `git archive`, code run in each by a process of
its own with one BLAS thread."""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
from collections.abc import Iterator
from contextlib import contextmanager
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


@contextmanager
def compared(against: str | None) -> Iterator[dict[str, Path]]:
    """`checkouts` in a temporary folder of their own, removed after the block."""
    with tempfile.TemporaryDirectory() as tmp:
        yield checkouts(against, Path(tmp))


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


def against_parser(doc: str) -> argparse.ArgumentParser:
    """A benchmark's options (its description the doc's first line), with --against."""
    ap = argparse.ArgumentParser(description=doc.splitlines()[0])
    ap.add_argument("--against", help="an earlier commit to measure beside this checkout")
    return ap


def alternating(trees: dict[str, Path], runs: int, code: str, *args: str) -> dict[str, list[dict]]:
    """Each checkout's `run_in` results, `runs` times, one checkout after the other, alternating, so that both see
    the same load; an argument "{tree}" is the checkout's folder."""
    got: dict[str, list[dict]] = {name: [] for name in trees}
    for _ in range(runs):
        for name, tree in trees.items():
            got[name].append(run_in(tree, code, *(str(tree) if a == "{tree}" else a for a in args)))
    return got
