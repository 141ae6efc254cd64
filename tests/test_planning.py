"""Planning configurations (calib_core.estimation.planning, `calib plan`): every planned configuration
inside the joint limits less the margin and predicted visible; NAO plans within the paper's stance
structure; the Woodbury updates match the criterion computed afresh; the predicted error matches the
error calibrations from those configurations actually have against the simulator's truth; and a plan
beats random configurations from the same candidates on held-out accuracy against the truth.
"""

from __future__ import annotations

import csv
import itertools
import math
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from calib_core import SimulatedRobot, calibrate, load_profile, plan, predict_accuracy
from calib_core.errors import Cancelled
from calib_core.estimation import planning
from calib_core.estimation.planning import (
    JOINT_MARGIN_DEG,
    SequentialPlan,
    candidates,
    design,
    plan_margins,
    within_margin,
    workspace,
)
from calib_core.estimation.selection import Selection, largest, trace_solve
from calib_core.vision.visibility import MIN_SPHERE_SHARE, Visibility

ROOT = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def rn_pool(rn):
    """Candidates planned with the nominal model (a robot never calibrated)."""
    return candidates(rn, rn.nominal(), seed=3, count=400)


@pytest.fixture(scope="module")
def rn_heldout(rn):
    """Held-out configurations the true robot shows, and the true model's predictions there."""
    truth = rn.true_params()
    q, t = candidates(rn, truth, seed=99, count=150)
    return q, t, SimulatedRobot(rn, truth, quantise=False).measure(q, t).data.measured


def _error_against_truth(profile, p, heldout) -> float:
    q, t, true_pred = heldout
    e = SimulatedRobot(profile, p, quantise=False).measure(q, t).data.measured - true_pred
    return float(np.sqrt(np.mean(np.sum(e**2, axis=1))))


def _calibrated_error(profile, q, targets, seed, heldout, mode="full") -> float:
    """Measure q on the true robot (losing what it does not show), calibrate, and judge on held-out."""
    robot = SimulatedRobot.from_profile(profile, seed=seed)
    seen = Visibility(profile, robot.true_params).sees(q, targets)
    cal = calibrate(profile, robot.measure(q[seen], targets[seen]).data, mode)
    return _error_against_truth(profile, cal.params(profile), heldout)


@pytest.mark.slow
def test_plan_within_limits_less_margin_and_predicted_visible(rn) -> None:
    planned = plan(rn, "full", 12, seed=1)
    assert planned.q.shape == (12, len(rn.joints))
    lo, hi = rn.joint_limits()
    m = np.minimum(math.radians(JOINT_MARGIN_DEG), (hi - lo) / 2)
    assert np.all(planned.q >= lo + m - 1e-12) and np.all(planned.q <= hi - m + 1e-12)
    assert within_margin(rn, planned.q).all()
    margin_px, share, _ = plan_margins(rn)  # a stereo head's plan keeps more clear than its detector needs
    assert margin_px > 10.0 and share > MIN_SPHERE_SHARE
    believer = Visibility(rn, rn.nominal(), margin_px=margin_px, sphere_share=share)
    assert believer.sees(planned.q, planned.targets).all()
    assert len({tuple(r) for r in np.round(planned.q, 9)}) == 12  # no configuration twice
    pred = planned.predicted
    assert pred.unit == "cm" and 0 < pred.mean <= pred.rms <= pred.max
    # The greedy picks lower the predicted error at every step.
    assert all(b <= a + 1e-12 for a, b in itertools.pairwise(planned.history))


def test_woodbury_updates_match_the_criterion_recomputed(rn, rn_pool) -> None:
    q, t = rn_pool
    d = design(rn, "full", rn.nominal(), q[:120], t[:120])
    for criterion in ("task", "d"):
        sel = Selection(d, criterion)
        chosen = list(range(0, 100, 4))
        for c in chosen:
            sel.add(c)
        gains = sel.gains()
        before = sel.value()
        fresh = np.linalg.inv(d.start() + d.information(np.array([*chosen, 61])))
        assert sel.value(fresh) == pytest.approx(before - gains[61], rel=1e-7, abs=1e-9)
        sel.exchange()
        after = np.linalg.inv(d.start() + d.information(np.array(sel.chosen)))
        assert sel.value(after) == pytest.approx(sel.value(), rel=1e-7)
        assert sel.value() <= before + 1e-12


def test_gains_kept_by_low_rank_updates_match_them_computed_afresh(rn, rn_pool) -> None:
    """Each candidate's gain, kept up to date through greedy choices from a regularised start (C falls a
    millionfold), an exchange and a pool that grew, is the gain computed from the covariance afresh."""
    q, t = rn_pool
    d = design(rn, "full", rn.nominal(), q[:150], t[:150])

    def afresh(sel: Selection) -> np.ndarray:
        C = np.linalg.inv(d.start() + d.information(np.array(sel.chosen, int)))
        B = d.L @ C
        S = np.eye(d.L.shape[1]) + B @ d.L.transpose(0, 2, 1)
        return np.trace(np.linalg.solve(S, B @ d.A @ B.transpose(0, 2, 1)), axis1=1, axis2=2)

    sel = Selection(d, "task")
    for _ in range(40):
        sel.add(sel.best())
        np.testing.assert_allclose(sel.gains(), afresh(sel), rtol=1e-6, atol=1e-9 * afresh(sel).max())
    swaps = sel.exchange(1)
    d.extend(q[150:200], t[150:200])
    sel.add(sel.best())
    np.testing.assert_allclose(sel.gains(), afresh(sel), rtol=1e-6, atol=1e-9 * afresh(sel).max())
    assert len(sel.gains()) == 200 and swaps >= 0


def test_refinement_candidates_carry_the_information_the_design_gives_them(rn, rn_pool) -> None:
    """Candidates added to a design (a plan's local refinement) get the same whitened information as if
    they had been in its pool from the start."""
    q, t = rn_pool
    workspace = (q[:60], t[:60])
    d = design(rn, "full", rn.nominal(), q[:100], t[:100], workspace=workspace)
    d.extend(q[100:140], t[100:140])
    whole = design(rn, "full", rn.nominal(), q[:140], t[:140], workspace=workspace)
    assert d.free == whole.free and len(d.q) == 140
    rows = np.arange(90, 140)
    assert np.allclose(d.information(rows), whole.information(rows), rtol=1e-9, atol=1e-12 * whole.scale.max())


def test_predicted_error_matches_calibrations_against_the_truth(rn, rn_pool, rn_heldout) -> None:
    """With the true model as the base, the prediction is the linearised truth: the RMS error of
    calibrations from the same configurations over noise seeds must match it (within 35 %)."""
    truth = rn.true_params()
    q, t = rn_pool
    q, t = q[Visibility(rn, truth).sees(q, t)][:30], t[:30]
    pred = predict_accuracy(rn, "full", q, t, truth, seed=5)
    errors = []
    for seed in range(6):
        data = SimulatedRobot.from_profile(rn, seed=200 + seed).measure(q, t).data
        errors.append(_error_against_truth(rn, calibrate(rn, data, "full").params(rn), rn_heldout))
    actual = float(np.sqrt(np.mean(np.square(errors))))
    assert pred.rms == pytest.approx(actual, rel=0.35), (pred.rms, errors)
    names = {p.name for p in pred.parameters}
    assert "shoulder_roll.theta" in names and not names & set(pred.held)


def test_plan_beats_random_configurations_against_the_truth(rn, rn_pool, rn_heldout) -> None:
    """From the same candidates (nominal model), 20 planned configurations give a smaller held-out
    error against the truth than 20 random ones, over noise seeds and random draws."""
    planned = plan(rn, "full", 20, pool=rn_pool)
    ours = [_calibrated_error(rn, planned.q, planned.targets, 300 + s, rn_heldout) for s in range(4)]
    q, t = rn_pool
    visible = np.flatnonzero(Visibility(rn, rn.nominal(), margin_px=40.0).sees(q, t))
    drawn = []
    for s in range(4):
        pick = np.random.default_rng(s).choice(visible, 20, replace=False)
        drawn.append(_calibrated_error(rn, q[pick], t[pick], 300 + s, rn_heldout))
    assert np.mean(ours) < 0.8 * np.mean(drawn), (ours, drawn)


@pytest.mark.slow
def test_nao_plan_stays_within_the_stance_structure() -> None:
    nao = load_profile("nao")
    planned = plan(nao, "full", 10, seed=2)
    sampling = nao.simulation["sampling"]
    pitch = np.degrees(planned.q[:, nao.joint(sampling["posture_joint"])])
    lo, hi = sampling["posture_range"]
    assert np.all((pitch >= lo - 1.2) & (pitch <= hi + 1.2))  # the postures, jittered by 0.02 rad
    for qk, target in zip(planned.q, planned.targets, strict=True):
        ranges = sampling["stance"][nao.targets[target].name]
        for name, (a, b) in ranges.items():
            assert a - 1e-9 <= math.degrees(qk[nao.joint(name)]) <= b + 1e-9
        lifted = {nao.joint(n) for n in ranges} | {nao.joint("HeadYaw"), nao.joint("HeadPitch")}
        assert all(qk[j] == 0.0 for j in range(len(qk)) if j not in lifted)  # the other leg lies still
    assert Visibility(nao, nao.nominal(), margin_px=10.0).sees(planned.q, planned.targets).all()
    assert set(planned.targets.tolist()) == {0, 1}  # both boards: each foot's mounting is a parameter
    assert planned.predicted.unit == "px"


@pytest.mark.subprocess
def test_cli_plan_writes_the_configurations(tmp_path) -> None:
    out = tmp_path / "plan.csv"
    env = {"PYTHONPATH": str(ROOT), "PATH": "/usr/bin:/bin"}
    args = [sys.executable, "-m", "app.cli", "plan", "--robot", "nao", "--mode", "full"]
    proc = subprocess.run(
        [*args, "--configurations", "6", "--seed", "4", "--out", str(out)],
        capture_output=True,
        text=True,
        env=env,
        timeout=120,
    )
    assert proc.returncode == 0, proc.stderr
    assert "predicted error over the workspace" in proc.stdout
    rows = list(csv.DictReader(out.open()))
    assert len(rows) == 6 and [r["frame"] for r in rows] == [str(k) for k in range(1, 7)]
    assert {r["leg"] for r in rows} <= {"left", "right"}
    assert "u" not in rows[0] and -38.5 <= float(rows[0]["HeadPitch"]) <= 29.5  # degrees, no measurements
    bad = subprocess.run(
        [*args[:-1], "weekly", "--configurations", "6", "--out", str(tmp_path / "x.csv")],
        capture_output=True,
        text=True,
        env=env,
        timeout=120,
    )
    assert bad.returncode == 2 and "unknown mode 'weekly'" in bad.stderr and "Traceback" not in bad.stderr
    assert not (tmp_path / "x.csv").exists()


def test_a_stop_is_heard_while_a_plan_draws_before_any_design(rn, monkeypatch) -> None:
    """Esc while a capture-until plan starts (its candidates, its workspace) ends it there, before the linearised
    calibration is built: SequentialPlan and workspace() ask should_stop as plan() does."""

    def no_design(*args: object, **kwargs: object) -> None:
        raise AssertionError("the design was built after the stop")

    monkeypatch.setattr(planning, "design", no_design)
    with pytest.raises(Cancelled):
        SequentialPlan(rn, "full", should_stop=lambda: True)
    with pytest.raises(Cancelled):
        workspace(rn, rn.nominal(), should_stop=lambda: True)


def test_candidates_a_camera_sees_rarely_are_drawn_near_those_seen_too() -> None:
    """A wrist camera and a board on the table, their poses registered from 8 frames: uniform draws see the board
    in about 1 of 400 configurations (50 draws of 2000 found 137). Later draws also look near what was seen: all
    2000 asked for, each seen, spread over the workspace and not one neighbourhood; Robonaut's sphere, seen in 1
    of 10, is drawn uniformly as ever (the same candidates as plain uniform draws)."""
    from calib_core.estimation import register

    profile = load_profile("arm-handeye")
    robot = SimulatedRobot.from_profile(profile, seed=3)
    q8, t8 = robot.configurations(8)
    p = register(profile, robot.measure(q8, t8).data, profile.nominal())
    lo, hi = profile.limits_less_margin(planning.JOINT_MARGIN_DEG, planning.JOINT_MARGIN_M)
    uniform = np.random.default_rng(0).uniform(lo, hi, (4000, len(lo)))
    assert Visibility(profile, p).sees(uniform, np.zeros(4000, int)).mean() < planning.SPARSE_SHARE
    q, targets = candidates(profile, p, count=2000)
    assert len(q) == 2000 and Visibility(profile, p).sees(q, targets).all()
    assert np.all((q >= lo) & (q <= hi))
    assert np.degrees(q.std(axis=0)).min() > 15  # every joint turns over a range, not about one seen configuration

    rn = load_profile("robonaut-a")
    q_rn, _ = candidates(rn, rn.nominal(), seed=4, count=300)
    rng = np.random.default_rng(4)
    lo, hi = planning._limits_less_margin(rn, planning.JOINT_MARGIN_DEG)
    draws = []
    while sum(len(d) for d in draws) < 300:
        draw = rng.uniform(lo, hi, (300, len(lo)))
        draws.append(draw[Visibility(rn, rn.nominal(), planning.VIEW_MARGIN_PX).sees(draw, np.zeros(300, int))])
    np.testing.assert_array_equal(q_rn, np.concatenate(draws)[:300])


@pytest.mark.parametrize("robot", ["nao", "arm-handeye", "robonaut-a"])
def test_each_configurations_information_is_its_rows_weighed_by_their_whole_covariance(robot: str) -> None:
    """The planner's information per configuration against the dense formula written out here: J^T C^-1 J, C the
    noise model's per observation plus the readings' rounding (step^2 / 12 per quantised joint) that all of a
    configuration's observations share. A board's 48 or 84 rows (Woodbury's identity) and a sphere's 3 alike."""
    from calib_core.estimation.problem import Problem

    profile = load_profile(robot)
    robot_sim = SimulatedRobot.from_profile(profile, seed=1)
    q, targets = robot_sim.configurations(5)
    p = robot_sim.true_params
    data = planning._dataset(profile, p, q[:5], targets[:5])
    mode = profile.mode("full" if robot != "arm-handeye" else "offsets")
    problem = Problem(profile, data, list(mode.free), p, noise_model=False)
    _, J = problem.residuals_jacobian(problem.x0)
    J = J[: problem.n_data_rows]
    B = planning._whitened(problem, J, p, isotropic=False)

    rows_of = np.concatenate([np.repeat(data.cfg[b.obs], b.dim) for b in problem.blocks])
    noise = np.zeros((len(J), len(J)))
    for b in problem.blocks:
        cov = b.sensor.covariance(p, data.measured[b.obs, : b.dim])
        for k, start in enumerate(range(b.rows.start, b.rows.stop, b.dim)):
            noise[start : start + b.dim, start : start + b.dim] = cov[k]
    quantised = [
        (op.param, profile.joints[op.joint].resolution)
        for f in profile.frames
        for op in f.ops
        if op.joint >= 0 and profile.joints[op.joint].resolution > 0
    ]
    Jq = np.zeros((len(J), 0))  # the sample arm's readings are not rounded
    if quantised:
        probe = Problem(profile, data, [i for i, _ in quantised], p, noise_model=False)
        Jq = probe.residuals_jacobian(probe.x0)[1][: probe.n_data_rows] * [s / np.sqrt(12.0) for _, s in quantised]
    for c in range(data.n_configurations):
        mine = rows_of == c
        C = noise[np.ix_(mine, mine)] + Jq[mine] @ Jq[mine].T
        want = J[mine].T @ np.linalg.solve(C, J[mine])
        np.testing.assert_allclose(B[c].T @ B[c], want, rtol=1e-7, atol=1e-9 * np.abs(want).max())


@pytest.mark.parametrize("k", [1, 2, 3, 4])
def test_a_candidates_gain_solves_as_lapack_does(k: int) -> None:
    """trace(S^-1 T) by the adjugate up to 3 x 3 (the planner's gain per candidate) against LAPACK's solve, on
    symmetric positive definite S as the planner makes them (I + L C L^T), far from and near singular."""
    rng = np.random.default_rng(k)
    X = rng.normal(size=(500, k, 7)) * np.logspace(-4, 2, 500)[:, None, None]
    S = np.eye(k) + X @ X.transpose(0, 2, 1)
    T = rng.normal(size=(500, k, k))
    T = T + T.transpose(0, 2, 1)
    expected = np.trace(np.linalg.solve(S, T), axis1=1, axis2=2)
    np.testing.assert_allclose(trace_solve(S.transpose(1, 2, 0), T.transpose(1, 2, 0)), expected, rtol=1e-9, atol=1e-12)


@pytest.mark.parametrize("seed", range(4))
def test_the_largest_gains_are_those_a_full_sort_ranks_first(seed: int) -> None:
    """`largest` (the window of best candidates, bounded by block maxima) against a full sort of the gains, with
    candidates refused or chosen (-inf) and NaN among them, for pools and windows of the sizes a plan has."""
    rng = np.random.default_rng(seed)
    for n, size in [(16000, 64), (16916, 1024), (20759, 64), (300, 64), (50, 64), (16000, 16384)]:
        g = rng.normal(size=n) ** 3
        g[rng.integers(0, n, n // (2 + seed))] = -np.inf
        if seed == 3:
            g[rng.integers(0, n, 5)] = np.nan
        got = largest(g, size)
        got = got[np.isfinite(g[got])]
        finite = np.flatnonzero(np.isfinite(g))
        want = finite[np.argsort(-g[finite], kind="stable")][:size]
        np.testing.assert_array_equal(got, want)
