"""benchmarks/handeye.py keeps running: its desk side in a quick mode, and its OpenCV 4 side (where the benchmark's
own environment, .venv-cv4, is installed: it needs a network install, so CI may not have it) reproducing the truth
from noise-free corners, which shows the poses it hands OpenCV and reads back are the right way round."""

from __future__ import annotations

import os
import subprocess
import sys
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
from handeye_data import PROFILES, SETUPS, rms_px, seeded_data

from calib_core import load_profile

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "benchmarks"))

import handeye as benchmark  # noqa: E402


@pytest.mark.subprocess
@pytest.mark.slow
def test_the_quick_desk_run_prints_every_cell_at_the_floor_in_the_offsets_mode() -> None:
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    run = subprocess.run(
        [sys.executable, str(ROOT / "benchmarks" / "handeye.py"), "--quick", "--desk-only"],
        capture_output=True,
        text=True,
        env=env,
        timeout=300,
    )
    assert run.returncode == 0, run.stderr
    rows = [line.split("|")[1:-1] for line in run.stdout.splitlines() if "| desk " in line]
    assert len(rows) == 2 * 2 * 2  # set-ups x joints x desk modes
    for setup, joints, _poses, method, heldout, *_, at_floor in (map(str.strip, r) for r in rows):
        px, floor = (float(v) for v in heldout.replace("(", "").replace(")", "").split())
        if method == "desk offsets" or joints == "exact":
            assert at_floor == "1/1" and px < 1.05 * floor, (setup, joints, method)
        else:  # the joint offsets leave the poses alone pixels off
            assert at_floor == "0/1" and px > 2 * floor, (setup, joints, method)


@pytest.mark.subprocess
@pytest.mark.skipif(not benchmark.CV4_PYTHON.exists(), reason="no .venv-cv4 (OpenCV 4) installed")
@pytest.mark.parametrize("setup", SETUPS)
def test_opencv_from_noise_free_corners_predicts_the_truth(setup: str) -> None:
    """Exact corners and exact joints: every OpenCV method's camera and board predict new corners to 1e-3 px."""
    profile = load_profile(PROFILES / f"{setup}.yaml")
    sim, new = seeded_data(profile, 0, False, 10)
    exact = replace(sim, data=replace(sim.data, measured=sim.exact))
    out = benchmark.run_opencv(benchmark.CV4_PYTHON, benchmark.opencv_inputs(profile, [exact]))
    assert out["opencv"].startswith("4.")
    (solved,) = out["cases"]
    assert sorted(solved) == sorted(benchmark.OPENCV_METHODS)
    for method, r in solved.items():
        p = benchmark.opencv_params(profile, np.array(r["X"]), np.array(r["Z"]))
        assert rms_px(profile, replace(new.data, measured=new.exact), p) < 1e-3, method
