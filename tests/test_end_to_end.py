"""Simulated capture -> rendered images -> detections -> calibration, judged against the simulator's truth:
the predictions of the calibrated model on held-out configurations against the noise-free measurement."""

from __future__ import annotations

import numpy as np
import pytest

from calib_core import InputError, Problem, SimulatedRobot, calibrate, load_profile
from calib_core.sim.simulator import Simulation


def _heldout_rms(profile, held: Simulation, p: np.ndarray) -> float:
    """RMS distance between what p predicts from the readings and the noise-free truth."""
    e = Problem(profile, held.data, [], p).predict(p) - held.exact
    return float(np.sqrt(np.mean(np.sum(e**2, axis=1))))


def _twin(robot: SimulatedRobot, seed: int) -> SimulatedRobot:
    return SimulatedRobot(robot.profile, robot.true_params, robot.pixel_noise, robot.disparity_noise, seed=seed)


@pytest.mark.slow
def test_nao_calibrated_from_its_own_images() -> None:
    """4 stances x 3 head postures per leg, every board found; the 21 parameters from the detected
    vertices predict held-out stances as well as those from the simulator's exact vertices with its
    0.2 px of noise. With 24 frames both stay a quarter above the floor the encoders' rounding sets."""
    nao = load_profile("nao")
    robot = SimulatedRobot.from_profile(nao, seed=4)
    images = robot.simulate_images(24)
    assert images.data.n_configurations == 24  # the simulator picks only boards the detector can measure
    idx = images.data.frame_ids - 1
    exact = robot.measure(images.true_joints[idx], images.targets[idx]).exact
    detector_px = np.sqrt(np.mean((images.data.measured - exact) ** 2))  # per axis
    assert detector_px < 0.1  # below the simulator's 0.2 px
    assert detector_px == pytest.approx(images.noise["sigma"], rel=0.4)  # the declared detector noise
    held = _twin(robot, 40).simulate(48)
    floor = _heldout_rms(nao, held, robot.true_params)  # the encoders' rounding alone
    detected = _heldout_rms(nao, held, calibrate(nao, images.data, "full").params(nao))
    simulated = robot.measure(images.true_joints[idx], images.targets[idx]).data
    assert detected < 1.35 * floor
    assert detected < 1.1 * _heldout_rms(nao, held, calibrate(nao, simulated, "full").params(nao))
    assert _heldout_rms(nao, held, nao.nominal()) > 20 * floor


@pytest.mark.slow
def test_robonaut_daily_calibration_from_rendered_stereo() -> None:
    """A later day: joint offsets drifted; the detectors seeded by the first day's calibration find the
    sphere in the stereo depth of nearly every configuration, to about a millimetre, and the daily
    calibration from them brings the held-out error from centimetres to within a millimetre of the
    floor the encoders' rounding sets."""
    rn = load_profile("robonaut-a")
    day1 = SimulatedRobot.from_profile(rn, seed=5)
    base = calibrate(rn, day1.simulate(67).data, "full")
    day2 = day1.drifted(seed=6)
    images = day2.simulate_images(16, base.params(rn))
    assert images.data.n_configurations >= 14
    idx = images.data.frame_ids - 1
    exact = day2.measure(images.true_joints[idx], images.targets[idx]).exact
    error_mm = 10 * np.linalg.norm(images.data.measured - exact, axis=1)
    assert np.median(error_mm) < 1.5 and error_mm.max() < 4.0
    # Along the view ray the errors are what the detectors' declared noise says; the stereo head's
    # model, meant for one triangulated point, expects ten times more.
    sensor = rn.sensors[rn.data.sensor]
    X = exact @ sensor.R_frame_optical  # cm, optical frame
    ray_cm = np.einsum("ni,ni->n", (images.data.measured - exact) @ sensor.R_frame_optical, X) / np.linalg.norm(
        X, axis=1
    )
    f_px = day2.true_params[sensor.intrinsics[0]]
    for noise, lo, hi in ((images.noise, 0.6, 1.6), (sensor.noise, 0.0, 0.2)):
        sigma_cm = X[:, 2] * np.linalg.norm(X, axis=1) * noise["disparity"] / (f_px * sensor.baseline)
        assert lo < np.sqrt(np.mean((ray_cm / sigma_cm) ** 2)) < hi
    cal = calibrate(images.profile_for_data(rn), images.data, "daily", base)
    held = _twin(day2, 60).simulate(100)
    before = _heldout_rms(rn, held, base.params(rn))
    after = _heldout_rms(rn, held, cal.params(rn))
    assert before > 2.0  # cm: the drift
    assert after < 0.2  # cm
    assert after == pytest.approx(_heldout_rms(rn, held, day2.true_params), abs=0.1)  # the floor: 0.06 cm


def test_a_declared_noise_model_is_checked() -> None:
    rn = load_profile("robonaut-a")
    assert rn.with_noise({"model": "isotropic", "sigma": 0.05}).sensors[rn.data.sensor].noise["sigma"] == 0.05
    assert rn.sensors[rn.data.sensor].noise["model"] == "stereo"  # the profile itself is unchanged
    for noise, field in (
        ({"model": "gaussian", "sigma": 1}, "model"),
        ({"model": "stereo", "pixel": 0.3}, "disparity"),
        ({"model": "isotropic", "sigma": -1.0}, "sigma"),
        ({"model": "isotropic", "sigma": 1.0, "pixel": 0.3}, "pixel"),
    ):
        with pytest.raises(InputError, match=field):
            rn.with_noise(noise)
    with pytest.raises(InputError, match="a pinhole sensor takes the isotropic noise model"):
        load_profile("nao").with_noise({"model": "stereo", "pixel": 0.3, "disparity": 0.02})
