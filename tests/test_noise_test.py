"""A fit's residuals against each sensor's declared noise (a chi-square test per sensor), and several
starts for a pose nobody measured. Against simulator truth: a session measured with the declared noise
is warned about at the test's level (0.1%) and its p-values are uniform; one measured far noisier than
declared is warned about, with the factor; a camera mount started 300 mm and 90 deg off reaches the
noise floor, and a fit left far above the noise says so."""

from __future__ import annotations

import re
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
from scipy.stats import kstest

from calib_core import SimulatedRobot, calibrate, load_profile
from calib_core.estimation import calibrate as calibrate_module
from calib_core.estimation.problem import Problem

PROFILES = Path(__file__).resolve().parent / "profiles"


@pytest.fixture(scope="module")
def wrist():
    """A camera on the tool sees a board on the table; the profile's camera mount is 300 mm and 90 deg off."""
    return load_profile(PROFILES / "wrist-camera.yaml")


@pytest.fixture(scope="module")
def wrist_known(wrist):
    """The same set-up with the camera mount where the simulated truth puts it."""
    truth = wrist.true_params()
    return replace(
        wrist,
        parameters=[
            replace(q, nominal=float(truth[i])) if q.name.startswith("camera_mount.") else q
            for i, q in enumerate(wrist.parameters)
        ],
    )


def floor_px(profile, data, p: np.ndarray) -> float:
    """RMS pixel error (2-D) of parameters `p` on `data`."""
    pred = Problem(profile, data, [], p, noise_model=False).predict(p)
    return float(np.sqrt(np.mean(np.sum((pred[:, :2] - data.measured[:, :2]) ** 2, axis=1))))


@pytest.mark.slow
def test_fits_with_the_declared_noise_are_warned_about_at_the_tests_level() -> None:
    """150 simulated sessions of a tracker arm measured with exactly the noise its profile declares, in a
    mode that holds the simulated errors: the test's p-values are uniform (the degrees of freedom are
    right: counting the rows without the parameters' share pushes them towards 1, KS p ~1e-60), so at
    most a warning or two at the 0.1% level (0.15 expected)."""
    iiwa = load_profile(PROFILES / "iiwa-tracker.yaml")
    p_values, warned = [], 0
    for seed in range(150):
        cal = calibrate(iiwa, SimulatedRobot.from_profile(iiwa, seed=seed).simulate(20).data, "offsets")
        (test,) = cal.solver.noise_tests
        # 20 points, 3 rows each (less any rejected as outliers), less the 11 parameters that stay free
        assert test.sensor == "tracker" and test.rows >= 54 and test.dof == pytest.approx(test.rows - 11)
        p_values.append(test.p_value)
        warned += [d.code for d in cal.diagnostics].count("noise-excess")
    assert kstest(p_values, "uniform").pvalue > 0.001
    assert warned <= 2


@pytest.mark.slow
def test_residuals_clearly_above_the_declared_noise_are_warned_about_with_the_factor(wrist_known) -> None:
    """5 px of corner noise where the camera declares 0.3 px: the old rule (100 times the noise) said
    nothing. The warning names the sensor, the factor and the test; `converged` stays the solver's own
    criterion, `fits_noise` says the residuals are above the noise."""
    robot = SimulatedRobot.from_profile(wrist_known, seed=3)
    robot.pixel_noise = 5.0
    cal = calibrate(wrist_known, robot.simulate(12).data, "handeye+offsets")
    (warning,) = [d for d in cal.diagnostics if d.code == "noise-excess"]
    factor = float(re.search(r"'cam' are ([\d.]+) times the noise it declares", warning.message)[1])
    assert factor == pytest.approx(5.0 / 0.3, rel=0.1)
    assert "chi-square test" in warning.message and "0.1% level" in warning.message
    assert cal.converged and cal.solver.fits_noise is False
    (test,) = cal.solver.noise_tests
    assert test.rejected and test.factor == pytest.approx(factor, rel=1e-2)
    assert cal.to_dict()["fits_noise"] is False and cal.to_dict()["solver"]["noise_tests"][0]["rejected"] is True
    # The same session measured with the declared noise: no warning.
    quiet = calibrate(
        wrist_known, SimulatedRobot.from_profile(wrist_known, seed=3).simulate(12).data, "handeye+offsets"
    )
    assert "noise-excess" not in [d.code for d in quiet.diagnostics] and quiet.solver.fits_noise is True


@pytest.mark.parametrize(("times", "warned"), [(1.1, False), (1.3, True)])
def test_the_words_follow_the_size_of_the_excess_and_the_test_keeps_its_verdict(wrist_known, times, warned) -> None:
    """3360 corner rows measured 1.1 and 1.3 times noisier than the camera declares: the test rejects both (p
    1e-15 and 1e-121), but 1.1 times, what a real robot's close model leaves, is a line of the report saying how
    much, and 1.3 times a warning with what to do."""
    robot = SimulatedRobot.from_profile(wrist_known, seed=4)
    robot.pixel_noise = 0.3 * times
    cal = calibrate(wrist_known, robot.simulate(40).data, "handeye+offsets")
    (test,) = cal.solver.noise_tests
    assert test.rows == 3360 and test.rejected and test.factor == pytest.approx(times, rel=0.03)
    assert cal.solver.fits_noise is False
    codes = {d.code: d for d in cal.diagnostics}
    summary = cal.summary()
    if warned:
        assert "noise-scatter" not in codes and codes["noise-excess"].severity.value == "warning"
        assert f"residuals {test.factor:.3g} times the noise 'cam' declares" in summary
    else:
        assert "noise-excess" not in codes and codes["noise-scatter"].severity.value == "info"
        line = f"the data scatter {test.factor:.2g} times what 'cam' declares (a chi-square test of its 3360 "
        assert codes["noise-scatter"].message.startswith(line) and f"info: {line}" in summary
        assert "times the noise 'cam' declares" not in summary and not any("scatter" in w for w in cal.warnings)


@pytest.mark.slow
def test_a_camera_mount_started_300_mm_and_90_deg_off_reaches_the_noise_floor(wrist) -> None:
    """From the profile's guess alone the solver settles hundreds of pixels off and calls it converged
    (11 of 30 such far starts reached the floor); turned through the cube's rotations with the translation
    re-fitted, the mount is found (30 of 30: benchmarks/far_starts.py)."""
    sim = SimulatedRobot.from_profile(wrist, seed=0).simulate(15)
    cal = calibrate(wrist, sim.data, "handeye+offsets")
    floor = floor_px(wrist, sim.data, sim.true_params)
    assert cal.figures["after"].rms < 1.02 * floor  # 0.42 px; from the guess alone: 224 px
    p = cal.params(wrist)
    mount = [wrist.param(f"camera_mount.{k}") for k in ("x", "y", "z", "yaw", "pitch", "roll")]
    np.testing.assert_allclose(p[mount[:3]], sim.true_params[mount[:3]], atol=2.0)  # mm
    np.testing.assert_allclose(p[mount[3:]], sim.true_params[mount[3:]], atol=np.radians(0.5))
    assert cal.converged and cal.solver.fits_noise is True and not cal.warnings[1:]  # one held-fixed only
    assert cal.solver.starts == 47 and cal.solver.start.startswith("camera_mount turned ")
    assert f"47 starts (kept: {cal.solver.start})" in cal.summary()


def test_a_fit_left_far_above_the_noise_is_not_a_plain_converged(wrist, monkeypatch) -> None:
    """Without the turned starts the far start ends in a wrong minimum that the solver's criteria call
    converged: the result says it is far above the noise and may be a wrong minimum."""
    monkeypatch.setattr(calibrate_module, "far_above_noise", lambda *args: False)
    sim = SimulatedRobot.from_profile(wrist, seed=0).simulate(15)
    cal = calibrate(wrist, sim.data, "handeye+offsets")
    assert cal.figures["after"].rms > 30 * floor_px(wrist, sim.data, sim.true_params)
    assert cal.converged and cal.solver.fits_noise is False and cal.to_dict()["fits_noise"] is False
    (warning,) = [d for d in cal.diagnostics if d.code == "noise-excess"]
    assert "may be a wrong minimum (only the start values were tried" in warning.message
    assert "times the noise 'cam' declares" in cal.summary()


def test_a_mode_that_cannot_model_the_error_names_the_mode_that_estimates_more() -> None:
    """The ChArUco hand-eye set-up whose joints carry offsets, fitted by the poses-only mode `handeye` (as OpenCV's
    closed forms are): the residuals stay about 10 times the noise and the warning names mode 'offsets' and the
    joint offsets it adds; that mode fits to the noise."""
    profile = load_profile(PROFILES / "handeye-charuco.yaml")
    data = SimulatedRobot.from_profile(profile, seed=2).simulate(15).data
    poses_only = calibrate(profile, data, "handeye")
    (warning,) = [d for d in poses_only.diagnostics if d.code == "noise-excess"]
    assert poses_only.solver.noise_tests[0].factor > 5
    assert (
        "; mode 'offsets' also estimates shoulder_pan, shoulder_lift, elbow, wrist_1, wrist_2, wrist_3,"
        in warning.message
    )
    with_offsets = calibrate(profile, data, "offsets")
    assert "noise-excess" not in [d.code for d in with_offsets.diagnostics] and with_offsets.solver.fits_noise


def test_a_registration_fitted_in_closed_form_is_not_turned() -> None:
    """A tracker's registration starts from its least-squares fit (Kabsch): a mode that leaves the model far
    above the noise (offsets where the arm's origins are off: 60 times) solves once."""
    arm = load_profile(Path(__file__).resolve().parents[1] / "sample_sessions" / "arm" / "arm.yaml")
    cal = calibrate(arm, SimulatedRobot.from_profile(arm, seed=1).simulate(30).data, "offsets")
    (test,) = cal.solver.noise_tests
    assert test.factor > 30 and cal.solver.starts == 1 and cal.solver.start == "the start values"
    (warning,) = [d for d in cal.diagnostics if d.code == "noise-excess"]
    assert "only the start values were tried" in warning.message


def test_a_solver_report_without_noise_tests_still_loads() -> None:
    """Files written before the test have no noise_tests, starts or start: fits_noise is unknown (None)."""
    iiwa = load_profile(PROFILES / "iiwa-tracker.yaml")
    cal = calibrate(iiwa, SimulatedRobot.from_profile(iiwa, seed=0).simulate(20).data, "offsets")
    d = cal.to_dict()
    assert d["solver"]["fits_noise"] is True and d["solver"]["starts"] == 1
    assert type(cal).from_dict(d).solver.noise_tests == cal.solver.noise_tests
    for key in ("noise_tests", "fits_noise", "starts", "start"):
        del d["solver"][key]
    back = type(cal).from_dict(d)
    assert back.solver.fits_noise is None and back.solver.starts == 1


def _arm_within_a_fifth(offset_share: float, noise: float, seed: int):
    """The hand-eye sample's arm fitted in mode handeye (no joint offsets), 30% held out: its joints
    carry `offset_share` of the sample's true offsets, its pixels `noise` times the declared noise."""
    profile = load_profile("arm-handeye")
    truth, nominal = profile.true_params(), profile.nominal()
    joints = [profile.param(j.name) for j in profile.joints]
    truth[joints] = nominal[joints] + offset_share * (truth[joints] - nominal[joints])
    robot = SimulatedRobot.from_profile(profile, seed=seed, truth=truth)
    robot.pixel_noise *= noise
    return calibrate(profile, robot.simulate(None).data, "handeye", holdout=0.3)


@pytest.mark.slow
def test_a_fit_within_a_fifth_of_the_noise_warns_only_where_a_richer_mode_predicts_held_out_data_better() -> None:
    """Issue 37: within 1.2 times the declared noise the test's verdict is a line of the report, and a warning only
    where the profile's richer mode, fitted on the same training data, predicts the held-out data better. Joint
    offsets the mode cannot fit (5% of the sample's): the test rejects at 1.08 times the noise, and mode 'offsets'
    is named with its figures, one click away (Diagnostic.mode). Pixels 1.15 times noisier than declared and no
    offsets: the test rejects as much, but nothing predicts better, and the noise warns of nothing."""
    cal = _arm_within_a_fifth(0.05, 1.0, 3)
    test = cal.solver.noise_tests[0]
    assert test.rejected and not test.warns
    richer = [d for d in cal.diagnostics if d.code == "richer-predicts"]
    assert len(richer) == 1 and richer[0].severity.value == "warning" and richer[0].mode == "offsets"
    assert re.search(r"mode 'offsets' predicts the held-out data better: [0-9.]+ against [0-9.]+ px", richer[0].message)
    assert "noise-scatter" in [d.code for d in cal.diagnostics]
    for seed in (10, 11):
        cal = _arm_within_a_fifth(0.0, 1.15, seed)
        assert cal.solver.noise_tests[0].rejected and not cal.solver.noise_tests[0].warns
        codes = [d.code for d in cal.diagnostics]
        assert "noise-scatter" in codes and "richer-predicts" not in codes and "noise-excess" not in codes, codes
