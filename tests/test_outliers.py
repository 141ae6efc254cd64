"""Outlier rejection tells an isolated gross error (a failed detection) from model error (what the
mode's parameters cannot describe), against the simulator's truth.

The simulated Motoman's truth has errors in every joint origin (a, d, alpha as well as offsets);
mode `offsets` cannot describe them. Its sessions are a small cube of poses with a few anywhere in
the workspace: the wide poses then show residuals far beyond the cube's, which are model error.
The tracker is weighed with the default outlier limit (the profile's declares a wide one)."""

from __future__ import annotations

import numpy as np
import pytest

from calib_core import SimulatedRobot, calibrate
from calib_core.estimation.problem import Problem

GROSS_M = 0.02  # a misread reflector: 20 mm


@pytest.fixture(scope="module")
def tracked(motoman):
    """The Motoman with a tracker of 0.05 mm noise."""
    tracker = [s.name for s in motoman.sensors].index("tracker")
    return motoman.with_noise({"model": "isotropic", "sigma": 0.00005}, tracker)


def session(profile, seed: int, n: int, outlier_rate: float = 0.0):
    robot = SimulatedRobot.from_profile(profile, seed=seed)
    q, targets = robot.clustered(n, spread=0.2, wide_share=0.15)
    return robot.measure(q, targets, outlier_rate=outlier_rate, outlier_size=GROSS_M)


def max_error_mm(profile, data, p) -> float:
    return 1000 * float(np.max(np.linalg.norm(Problem(profile, data, [], p).predict(p) - data.measured, axis=1)))


@pytest.fixture(scope="module")
def fresh(tracked):
    return session(tracked, seed=101, n=400)


def test_model_error_beyond_the_limit_is_kept_and_held_out_is_no_worse(tracked, fresh) -> None:
    sim = session(tracked, seed=2, n=200)
    robust = calibrate(tracked, sim.data, "offsets")
    plain = calibrate(tracked, sim.data, "offsets", robust=False)
    kept = [d for d in robust.diagnostics if d.code == "model-error"]
    assert robust.outliers == []
    assert len(kept) == 1 and int(kept[0].message.split()[0]) >= 10  # far beyond the limit, and kept
    e_robust = max_error_mm(tracked, fresh.data, robust.params(tracked))
    e_plain = max_error_mm(tracked, fresh.data, plain.params(tracked))
    assert e_robust <= 1.01 * e_plain, (e_robust, e_plain)


def test_failed_detections_among_model_error_are_still_rejected(tracked, fresh) -> None:
    sim = session(tracked, seed=3, n=200, outlier_rate=0.05)
    injected = {int(f) for f in sim.data.frame_ids[sim.data.cfg[sim.outliers]]}
    robust = calibrate(tracked, sim.data, "offsets")
    flagged = {o.frame for o in robust.outliers}
    assert len(injected) >= 4
    assert flagged == injected, (sorted(injected), sorted(flagged))
    assert all(o.sigmas is not None and o.sigmas > 4.6 for o in robust.outliers)
    assert any(d.code == "outliers" and "failed detection" in d.message for d in robust.diagnostics)
    plain = calibrate(tracked, sim.data, "offsets", robust=False)
    e_robust = max_error_mm(tracked, fresh.data, robust.params(tracked))
    e_plain = max_error_mm(tracked, fresh.data, plain.params(tracked))
    assert e_robust < e_plain, (e_robust, e_plain)
