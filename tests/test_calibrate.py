"""Calibration against the simulator's ground truth.

Every accuracy figure here is measured against the hidden true robot of the simulator: the error the
true parameters give on the same (noisy, quantised) data is the floor no calibration can beat, and a
calibration is good when its error on fresh configurations is close to that floor, and its estimates
are within a few of their own reported standard deviations of the truth.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from calib_core import Calibration, Dataset, InputError, Problem, SimulatedRobot, calibrate, load_profile
from calib_core.estimation.validation import configuration_groups, kfold_splits


def rms_error(profile, data: Dataset, p: np.ndarray) -> float:
    """RMS Euclidean distance between prediction (parameters p) and measurement, data units."""
    pred = Problem(profile, data, [], p, noise_model=False).predict(p)
    return float(np.sqrt(np.mean(np.sum((pred - data.measured) ** 2, axis=1))))


def concat(a: Dataset, b: Dataset) -> Dataset:
    """Two datasets of one robot as one, b's frames renumbered after a's."""
    return Dataset(
        robot=a.robot,
        frame_ids=np.concatenate([a.frame_ids, b.frame_ids + a.frame_ids.max()]),
        joints=np.concatenate([a.joints, b.joints]),
        cfg=np.concatenate([a.cfg, b.cfg + a.n_configurations]),
        target=np.concatenate([a.target, b.target]),
        point=np.concatenate([a.point, b.point]),
        vertex=np.concatenate([a.vertex, b.vertex]),
        measured=np.concatenate([a.measured, b.measured]),
        sensor=np.concatenate([a.sensor, b.sensor]),
        source="concatenated",
    )


# Structural dependencies of the Robonaut model (specs/robonaut-a.md): a held parameter h with its
# partner q and coefficient c such that +1 on h and c on q changes no prediction.
ROBONAUT_GAUGE = {
    "neck_yaw.d": ("shoulder_roll.d", -1.0),  # both translate the chains along the same chest axis
    "neck_roll.theta": ("neck_pitch.theta", -1.0),  # alpha = a = 0 between them: Rot_z then Rot_z
    "fixture.z": ("wrist_yaw.d", -1.0),  # both along the hand's z axis
}


def gauge_equivalent_truth(profile, cal: Calibration, truth: np.ndarray, data: Dataset) -> np.ndarray:
    """The truth moved, without changing any prediction, so that held-fixed parameters sit at the
    calibration's base value: the values an unbiased calibration should find for the others."""
    p = truth.copy()
    base = {e.name: profile.from_display(profile.param(e.name), e.base) for e in cal.parameters}
    for held in cal.identifiability.held_fixed:
        name = held.parameter
        i = profile.param(name)
        delta = base[name] - p[i]
        if delta == 0.0:
            continue
        assert name in ROBONAUT_GAUGE, f"{name} held fixed away from the truth, with no known exact partner"
        partner, coefficient = ROBONAUT_GAUGE[name]
        p[i] += delta
        p[profile.param(partner)] += coefficient * delta
    # The move is a true symmetry of the model: the same predictions to round-off.
    np.testing.assert_allclose(
        Problem(profile, data, [], p, noise_model=False).predict(p),
        Problem(profile, data, [], truth, noise_model=False).predict(truth),
        rtol=0,
        atol=1e-9,
    )
    return p


# --- Robonaut -------------------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def rn_robot(rn):
    return SimulatedRobot.from_profile(rn, seed=11)


@pytest.fixture(scope="module")
def rn_sim(rn_robot):
    return rn_robot.simulate(67)  # the paper's 67 configurations


@pytest.fixture(scope="module")
def rn_fresh(rn_robot):
    return rn_robot.simulate(150)  # 150 new configurations of the same robot


@pytest.fixture(scope="module")
def rn_full(rn, rn_sim):
    return calibrate(rn, rn_sim.data, "full")


def test_robonaut_full_generalises_to_the_truth_floor(rn, rn_sim, rn_fresh, rn_full) -> None:
    floor = rms_error(rn, rn_fresh.data, rn_fresh.true_params)
    nominal = rms_error(rn, rn_fresh.data, rn.nominal())
    after = rms_error(rn, rn_fresh.data, rn_full.params(rn))
    assert nominal > 10 * floor  # the nominal model is far off: there is something to calibrate
    assert after <= 1.08 * floor, (after, floor)
    # The figures the calibration reports describe its own training data.
    assert rn_full.figures["after"].rms == pytest.approx(rms_error(rn, rn_sim.data, rn_full.params(rn)))
    assert rn_full.figures["before"].rms == pytest.approx(rms_error(rn, rn_sim.data, rn.nominal()))


def test_robonaut_full_estimates_within_4_sigma(rn, rn_sim, rn_full) -> None:
    truth = gauge_equivalent_truth(rn, rn_full, rn_sim.true_params, rn_sim.data)
    checked = []
    for est in rn_full.parameters:
        if not est.estimated or not (est.note is None or est.note.startswith("tied")):
            continue
        i = rn.param(est.name)
        assert est.std is not None and 0 < est.std < np.inf, est
        z = (est.value - rn.to_display(i, truth[i])) / est.std
        checked.append((est.name, z))
    # 10 theta + 7 non-zero d and a (2 followers among them carry their leader's value) + P_e
    # minus what the data cannot determine.
    assert len(checked) >= 18
    assert max(abs(z) for _, z in checked) < 4.0, checked


def test_robonaut_full_keeps_the_pinned_ties(rn, rn_full) -> None:
    v = rn_full.values()
    assert v["shoulder_pitch.a"] == pytest.approx(-v["shoulder_roll.a"], abs=1e-12)
    assert v["elbow_pitch.a"] == pytest.approx(-v["elbow_roll.a"], abs=1e-12)
    assert v["wrist_roll.d"] == pytest.approx(v["elbow_roll.d"], abs=1e-12)
    # alpha is never estimated.
    for est in rn_full.parameters:
        if est.name.endswith(".alpha"):
            assert not est.estimated and est.value == est.nominal


@pytest.fixture(scope="module")
def day2(rn_robot):
    robot = rn_robot.drifted(seed=21)
    return robot, robot.simulate(75), robot.simulate(150)


@pytest.fixture(scope="module")
def day2_daily(rn, rn_full, day2):
    return calibrate(rn, day2[1].data, "daily", base=rn_full)


def test_daily_calibration_on_a_later_day(rn, rn_full, day2, day2_daily) -> None:
    _, _, fresh = day2
    floor = rms_error(rn, fresh.data, fresh.true_params)
    stale = rms_error(rn, fresh.data, rn_full.params(rn))
    after = rms_error(rn, fresh.data, day2_daily.params(rn))
    assert stale > 4 * floor  # the drift matters
    assert after <= 1.10 * floor, (after, floor, stale)
    # Daily mode moves only the joint offsets; everything else comes from the base calibration.
    base = rn_full.values()
    for est in day2_daily.parameters:
        if est.name.endswith(".theta") and est.name != "neck_roll.theta":
            assert est.estimated, est.name
        elif not est.name.endswith(".theta"):
            assert not est.estimated and est.value == base[est.name], est.name


@pytest.mark.slow
def test_nelder_mead_reaches_nearly_the_lm_error(rn, rn_full, day2, day2_daily) -> None:
    _, train, fresh = day2
    nm = calibrate(rn, train.data, "daily", base=rn_full, method="nelder-mead")
    assert nm.method == "nelder-mead"
    lm_err = rms_error(rn, fresh.data, day2_daily.params(rn))
    nm_err = rms_error(rn, fresh.data, nm.params(rn))
    stale = rms_error(rn, fresh.data, rn_full.params(rn))
    assert nm_err <= 1.05 * lm_err, (nm_err, lm_err)
    assert nm_err < 0.2 * stale


@pytest.fixture(scope="module")
def outlier_case(rn):
    robot = SimulatedRobot.from_profile(rn, seed=31)
    sim = robot.simulate(150, outlier_rate=0.05, outlier_size=20.0)
    robust = calibrate(rn, sim.data, "full")
    plain = calibrate(rn, sim.data, "full", robust=False)
    bad_cfgs = np.unique(sim.data.cfg[sim.outliers])
    clean = calibrate(rn, sim.data.select(np.setdiff1d(np.arange(sim.data.n_configurations), bad_cfgs)), "full")
    return sim, robust, plain, clean


def test_robust_solve_flags_the_injected_outliers(outlier_case) -> None:
    sim, robust, _, _ = outlier_case
    injected = {int(f) for f in sim.data.frame_ids[sim.data.cfg[sim.outliers]]}
    flagged = {o.frame for o in robust.outliers}
    assert len(injected) >= 4  # 5% of 150
    assert len(injected ^ flagged) <= 1, (sorted(injected), sorted(flagged))
    assert robust.figures["after"].excluded == len(robust.outliers)
    assert any("outliers" in w for w in robust.warnings)


def test_robust_solve_is_as_good_as_without_outliers(rn, rn_fresh, outlier_case) -> None:
    _, robust, plain, clean = outlier_case
    # The simulated robots share the truth, so rn_fresh tests all of them.
    floor = rms_error(rn, rn_fresh.data, rn_fresh.true_params)
    e_robust = rms_error(rn, rn_fresh.data, robust.params(rn))
    e_clean = rms_error(rn, rn_fresh.data, clean.params(rn))
    e_plain = rms_error(rn, rn_fresh.data, plain.params(rn))
    assert e_robust <= 1.03 * e_clean, (e_robust, e_clean)
    assert e_robust <= 1.08 * floor, (e_robust, floor)
    assert e_plain > 1.5 * e_robust, (e_plain, e_robust)  # least squares is dragged by the outliers
    assert plain.outliers == []


@pytest.fixture(scope="module")
def duplicated(rn):
    """30 configurations, the first 15 of them measured a second time (same readings, new noise)."""
    robot = SimulatedRobot.from_profile(rn, seed=41)
    q, targets = robot.configurations(30)
    first = robot.measure(q, targets)
    again = robot.measure(q[:15], targets[:15])
    return concat(first.data, again.data), first


@pytest.fixture(scope="module")
def split_cal(rn, duplicated):
    data, _ = duplicated
    return calibrate(rn, data, "full", holdout=0.3, folds=4, seed=3)


def test_holdout_keeps_repeated_configurations_together(rn, duplicated, split_cal) -> None:
    data, _ = duplicated
    train, held = split_cal.frames["train"], split_cal.frames["holdout"]
    assert sorted(train + held) == sorted(data.frame_ids.tolist())
    assert not set(train) & set(held)
    # The configuration of each frame, from its readings (duplicates read exactly the same).
    key = {int(f): tuple(np.round(np.degrees(data.joints[k]), 6)) for k, f in enumerate(data.frame_ids)}
    assert len(set(key.values())) == 30
    assert not {key[f] for f in train} & {key[f] for f in held}
    assert len({key[f] for f in held}) == round(0.3 * 30)


def test_holdout_and_cv_figures_are_consistent(rn, duplicated, split_cal) -> None:
    data, first = duplicated
    f = split_cal.figures
    assert {"before", "after", "holdout_before", "holdout_after", "cv_after"} <= set(f)
    n_train, n_held = len(split_cal.frames["train"]), len(split_cal.frames["holdout"])  # one point per frame
    for name in ("before", "after", "cv_after"):
        assert f[name].n + f[name].excluded == n_train, name
    for name in ("holdout_before", "holdout_after"):
        assert f[name].n + f[name].excluded == n_held, name
    assert n_train + n_held == data.n_observations
    # The held-out figure is the calibration's error on the held-out frames, recomputed here.
    index = {int(fid): k for k, fid in enumerate(data.frame_ids)}
    held = data.select(np.array([index[fid] for fid in split_cal.frames["holdout"]]))
    assert f["holdout_after"].excluded == 0
    assert f["holdout_after"].rms == pytest.approx(rms_error(rn, held, split_cal.params(rn)), rel=1e-9)
    assert f["holdout_before"].rms == pytest.approx(rms_error(rn, held, rn.nominal()), rel=1e-9)
    # Held-out and cross-validated errors are near the truth floor, far below the nominal model.
    floor = rms_error(rn, data, first.true_params)
    assert f["holdout_after"].rms < 2.0 * floor
    assert f["cv_after"].rms < 2.0 * floor
    assert f["cv_after"].rms > 0.8 * f["after"].rms
    assert split_cal.solver.folds == 4


def test_kfold_splits_keep_repeated_configurations_together(duplicated) -> None:
    data, _ = duplicated
    groups = configuration_groups(data)
    splits = kfold_splits(data, 4, seed=3)
    seen = np.concatenate([test for _, test in splits])
    assert sorted(seen.tolist()) == list(range(data.n_configurations))  # each configuration tested once
    for train, test in splits:
        assert len(test) > 0
        assert not set(groups[train]) & set(groups[test])


def test_a_calibration_file_of_the_previous_format_loads(rn_full, tmp_path) -> None:
    """Files written before the solver status and the diagnostics were typed: a free-text status and
    a list of warning sentences."""
    d = rn_full.to_dict()
    d["solver"] = {k: v for k, v in d["solver"].items() if k not in ("converged", "message")}
    d["solver"]["status"] = "converged (no step can reduce the cost further)"
    for key in ("diagnostics", "converged", "sensor_figures"):
        d.pop(key)
    d["identifiability"]["held_fixed"] = [h["parameter"] for h in d["identifiability"]["held_fixed"]]
    path = tmp_path / "old.json"
    path.write_text(json.dumps(d))
    back = Calibration.load(path)
    assert back.converged and back.solver.status.code == "no_further_decrease"
    assert back.warnings == rn_full.warnings
    assert [h.parameter for h in back.identifiability.held_fixed] == [
        h.parameter for h in rn_full.identifiability.held_fixed
    ]
    d["solver"]["status"] = "maximum iterations reached"
    path.write_text(json.dumps(d))
    assert not Calibration.load(path).converged
    d["solver"]["folds"] = float("inf")  # found by fuzzing: int(inf) overflowed past the file's checks
    path.write_text(json.dumps(d))
    with pytest.raises(InputError, match="calibration file is malformed"):
        Calibration.load(path)


def test_calibration_save_load_round_trip(rn, rn_sim, rn_full, tmp_path) -> None:
    path = tmp_path / "full.json"
    rn_full.save(path)
    back = Calibration.load(path)
    assert back.parameters == rn_full.parameters
    np.testing.assert_array_equal(back.params(rn), rn_full.params(rn))
    assert back.figures == rn_full.figures
    assert back.identifiability.held_fixed == rn_full.identifiability.held_fixed
    assert back.outliers == rn_full.outliers
    assert back.warnings == rn_full.warnings
    assert back.frames == rn_full.frames
    assert (back.robot, back.mode, back.method) == (rn_full.robot, rn_full.mode, rn_full.method)
    # A loaded calibration is a valid base for the next one: it starts from the saved values.
    daily = calibrate(rn, rn_sim.data, "daily", base=back)
    assert [e.base for e in daily.parameters] == [e.value for e in rn_full.parameters]


# --- NAO ------------------------------------------------------------------------------------------------

NAO_21 = [
    "CamYaw",
    "CamPitch",
    "CamRoll",
    *(s + j for s in "LR" for j in ("HipYawPitch", "HipRoll", "HipPitch", "KneePitch", "AnklePitch", "AnkleRoll")),
    *(s + k for s in "LR" for k in ("RotZ", "TransX", "TransY")),
]


@pytest.fixture(scope="module")
def nao_sims(nao):
    robot = SimulatedRobot.from_profile(nao, seed=3)
    return robot.simulate(), robot.simulate()


@pytest.fixture(scope="module")
def nao_full(nao, nao_sims):
    return calibrate(nao, nao_sims[0].data, "full")


def test_nao_full_recovers_the_21_parameters(nao, nao_sims, nao_full) -> None:
    sim = nao_sims[0]
    estimated = {e.name: e for e in nao_full.parameters if e.estimated}
    assert sorted(estimated) == sorted(NAO_21)
    assert nao_full.identifiability.held_fixed == []
    z = {}
    for name, est in estimated.items():
        i = nao.param(name)
        assert est.std is not None and 0 < est.std < 1.0, (name, est.std)
        z[name] = (est.value - nao.to_display(i, sim.true_params[i])) / est.std
    assert max(abs(v) for v in z.values()) < 4.0, z
    # The truth is far from the nominal start (all zero): recovering it is not trivial.
    assert max(abs(nao.to_display(nao.param(n), sim.true_params[nao.param(n)])) for n in NAO_21) > 4.0


def test_nao_full_reaches_the_floor(nao, nao_sims, nao_full) -> None:
    train, fresh = nao_sims
    floor = rms_error(nao, fresh.data, fresh.true_params)
    after = rms_error(nao, fresh.data, nao_full.params(nao))
    assert rms_error(nao, fresh.data, nao.nominal()) > 20 * floor
    assert after <= 1.08 * floor, (after, floor)
    # On its own training data a least-squares fit is at (or just below) the truth.
    train_floor = rms_error(nao, train.data, train.true_params)
    assert 0.9 * train_floor <= nao_full.figures["after"].rms <= train_floor


ARM = Path(__file__).resolve().parents[1] / "sample_sessions" / "arm" / "arm.yaml"


@pytest.fixture(scope="module")
def arm():
    """The sample arm (a UR5-like URDF, a tracker at an unknown pose): its mode `origins` frees 51 parameters."""
    return load_profile(ARM)


def test_a_mode_of_more_parameters_than_rows_is_fitted_holding_what_the_rows_cannot_tell_apart(arm) -> None:
    """12 configurations of one reflector are 36 rows for the 51 parameters of `origins`: refused before,
    although no data of this kind determine more than 25 of them. Now the rest are held, each named, and
    the calibration predicts fresh configurations at the truth's floor, far better than `offsets` (whose 13
    parameters cannot take the arm's origin errors)."""
    train = SimulatedRobot.from_profile(arm, seed=1).simulate(12)
    fresh = SimulatedRobot.from_profile(arm, seed=99).simulate(200)
    cal = calibrate(arm, train.data, "origins")
    held = [d for d in cal.diagnostics if d.code == "held-fixed"]
    assert len(arm.modes["origins"].free) == 51 and len(cal.identifiability.free) == 25 and len(held) == 26
    assert {h.parameter for h in cal.identifiability.held_fixed} >= {"shoulder_pan", "wrist_3", "shoulder_pan.x"}
    floor = rms_error(arm, fresh.data, fresh.true_params)  # 0.035 mm
    after = rms_error(arm, fresh.data, cal.params(arm))  # 0.051 mm
    offsets = rms_error(arm, fresh.data, calibrate(arm, train.data, "offsets").params(arm))  # 2.4 mm
    assert after < 1.6 * floor and after < offsets / 20


def test_rows_no_more_than_what_they_determine_are_refused_saying_how_many_stay_free(arm) -> None:
    """8 configurations are 24 rows: they would fix 24 of the 51 parameters exactly, with nothing left to
    check the fit; 9 (27 rows for the 25 they determine) are calibrated."""
    robot = SimulatedRobot.from_profile(arm, seed=1)
    data = robot.simulate(9).data
    with pytest.raises(
        InputError,
        match=r"8 observations \(24 rows\) cannot calibrate mode 'origins': they would fix "
        r"24 of its 51 parameters exactly \(27 more held",
    ):
        calibrate(arm, data.select(np.arange(8)), "origins")
    assert len(calibrate(arm, data, "origins").identifiability.free) == 25
