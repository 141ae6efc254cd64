"""Intrinsics with the arm: a camera nobody calibrated (tests/profiles/handeye-intrinsics.yaml: the profile says
fx = fy = 600, cx = 320, cy = 240 and no distortion; the simulated lens has fx 615, fy 612, cx 326, cy 236,
k1 = -0.1) calibrated from the same board images as where it sits, by the mode that frees `cam.intrinsics`.
Against simulator truth, and beside cv2.calibrateCamera on the same corners."""

from __future__ import annotations

import cv2
import numpy as np
import pytest
from handeye_data import PROFILES, rms_px, seeded_data
from jacobian_check import check_jacobian, perturbed

from calib_core import InputError, Problem, calibrate, load_profile

LENS = ("fx", "fy", "cx", "cy", "k1", "k2", "p1", "p2", "k3")


@pytest.fixture(scope="module")
def profile():
    return load_profile(PROFILES / "handeye-intrinsics.yaml")


def lens(profile, p: np.ndarray) -> np.ndarray:
    return p[[profile.param(f"cam.{k}") for k in LENS]]


def opencv_lens(profile, data) -> np.ndarray:
    """cv2.calibrateCamera on the same corners (one view per configuration, its own board poses): fx, fy, cx, cy and
    k1, k2, p1, p2, k3."""
    grid = profile.targets[0].grid.astype(np.float32)
    n = data.n_configurations
    corners = data.measured[:, :2].reshape(n, len(grid), 2).astype(np.float32)
    _, K, dist, _, _ = cv2.calibrateCamera([grid] * n, list(corners), (640, 480), None, None)
    return np.array([K[0, 0], K[1, 1], K[0, 2], K[1, 2], *dist.ravel()[:5]])


def test_cam_intrinsics_frees_the_lens_and_gives_an_undistorted_camera_its_coefficients(profile) -> None:
    """`cam.intrinsics` in a mode's `free`: fx, fy, cx, cy and OpenCV's five coefficients, at zero where the
    profile writes none."""
    free = [profile.parameter_names[i] for i in profile.modes["handeye+intrinsics"].free]
    assert free[12:] == [f"cam.{k}" for k in LENS]
    assert not lens(profile, profile.nominal())[4:].any()
    assert list(lens(profile, profile.true_params())[:5]) == [615, 612, 326, 236, -0.1]


def test_a_mode_naming_the_intrinsics_of_no_camera_is_refused(tmp_path) -> None:
    text = (PROFILES / "handeye-intrinsics.yaml").read_text().replace("cam.intrinsics]", "lens.intrinsics]", 1)
    (tmp_path / "arm.urdf").write_text((PROFILES.parent.parent / "docs" / "ros2" / "arm.urdf").read_text())
    path = tmp_path / "p.yaml"
    path.write_text(text.replace("../../docs/ros2/arm.urdf", "arm.urdf"))
    with pytest.raises(InputError, match=r"modes.handeye\+intrinsics.free\[2\]: 'lens.intrinsics' matches no"):
        load_profile(path)


def test_a_point_beyond_the_lens_field_is_not_seen_where_the_distortion_folds_it_into_the_image(profile) -> None:
    """k1 = -0.1 turns back at 61 deg off the axis: a point 72 deg off lands near the image's centre in OpenCV's
    model, but no lens shows it (the simulator drew such boards before)."""
    sensor, p = profile.sensors[0], profile.true_params()
    off_axis = np.array([[3.0, 0.0, 1.0], [0.3, 0.0, 1.0]])  # tan 71.6 deg, tan 16.7 deg
    uv = sensor.project(p, off_axis)
    assert 0 < uv[0, 0] < 640 and 0 < uv[1, 0] < 640  # both inside the image
    assert list(sensor.visible(p, off_axis)) == [False, True]


def test_the_lens_derivatives_are_exact(profile) -> None:
    """The mode's Jacobian, the lens columns with it, against central differences, distortion far from zero."""
    sim, _ = seeded_data(profile, 0, False, 4)
    p = perturbed(profile, np.random.default_rng(0))
    p[[profile.param(f"cam.{k}") for k in ("k1", "k2", "k3")]] = [-0.1, 0.05, -0.02]
    free = list(profile.modes["handeye+intrinsics"].free)
    problem = Problem(profile, sim.data, free, p)
    assert check_jacobian(problem, [profile.parameter_names[i] for i in free]) == len(free)


@pytest.mark.slow
@pytest.mark.parametrize("seed", [0, 1, 2])
def test_the_lens_is_recovered_to_the_floor_and_closer_than_calibrate_camera(profile, seed: int) -> None:
    """40 configurations, no pose and no lens given: the held-out pixels within 5% of the true model's (the
    intrinsics the profile guessed leave them over twice that); fx, fy, cx, cy and k1 each within three of its
    reported standard deviations of the truth, those below 0.6 px and 0.01 (measured: errors fx, fy 0.06-0.38 px,
    cx, cy 0.14-1.17 px, k1 0.008-0.011, at most 2.2 of their deviations of 0.16-0.53 px and 0.005; k2 and k3
    trade against each other within the image). cv2.calibrateCamera on the same corners, knowing nothing of the
    arm, misses fx, fy, cx, cy by 2.9-6.3 px together (measured 2026-11-26): the desk's are nearer the truth on
    every seed."""
    sim, new = seeded_data(profile, seed, False, 40)
    truth, floor = lens(profile, sim.true_params), rms_px(profile, new.data, sim.true_params)
    cal = calibrate(profile, sim.data, "handeye+intrinsics")
    assert cal.converged and cal.solver.fits_noise
    p = cal.params(profile)
    assert rms_px(profile, new.data, p) < 1.05 * floor
    assert rms_px(profile, new.data, calibrate(profile, sim.data, "handeye").params(profile)) > 2 * floor
    desk = np.abs(lens(profile, p) - truth)
    std = np.array([{e.name: e.std for e in cal.parameters}[f"cam.{k}"] for k in LENS[:5]])
    assert (desk[:5] < 3 * std).all() and (std[:4] < 0.6).all() and std[4] < 0.01, (desk, std)
    opencv = np.abs(opencv_lens(profile, sim.data) - truth)
    print(f"seed {seed}: |error| of {LENS}: desk {np.round(desk, 4)}, cv2.calibrateCamera {np.round(opencv, 4)}")
    assert np.linalg.norm(desk[:4]) < np.linalg.norm(opencv[:4])
