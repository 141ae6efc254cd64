"""The simulator: configurations within limits and in view, readings as a robot reports them, the paper's
NAO protocol, day-to-day drift, and noise with the right statistics."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest

from calib_core import Problem, SimulatedRobot, Visibility
from calib_core.model.kinematics import forward
from calib_core.vision import Sampler
from calib_core.vision.stereo import SPHERE, StereoHead, no_depth_band_px, render_pair, sphere_views

# specs/nao.md joint limits (deg).
NAO_LIMITS = {
    "LHipYawPitch": (-65.62, 42.44),
    "RHipYawPitch": (-65.62, 42.44),
    "LHipRoll": (-21.74, 45.29),
    "RHipRoll": (-45.29, 21.74),
    "LHipPitch": (-88, 27.73),
    "RHipPitch": (-88, 27.73),
    "LKneePitch": (-5.29, 121.04),
    "RKneePitch": (-5.90, 121.47),
    "LAnklePitch": (-68.15, 52.86),
    "RAnklePitch": (-67.97, 53.40),
    "LAnkleRoll": (-22.79, 44.06),
    "RAnkleRoll": (-44.06, 22.80),
    "HeadYaw": (-119.5, 119.5),
    "HeadPitch": (-38.5, 29.5),
}
LEG = ["HipYawPitch", "HipRoll", "HipPitch", "KneePitch", "AnklePitch", "AnkleRoll"]


@pytest.fixture(scope="module")
def rn_robot(rn):
    return SimulatedRobot.from_profile(rn, seed=17)


@pytest.fixture(scope="module")
def rn_sim(rn_robot):
    return rn_robot.simulate(600)


@pytest.fixture(scope="module")
def nao_sim(nao):
    return SimulatedRobot.from_profile(nao, seed=19).simulate()


def _with_true_joints(sim):
    """The dataset with the unquantised readings: what the robot really did."""
    return replace(sim.data, joints=sim.true_joints)


# --- configurations -----------------------------------------------------------------------------------


def test_nao_profile_limits_are_the_spec_limits(nao) -> None:
    lo, hi = nao.joint_limits()
    for name, (a, b) in NAO_LIMITS.items():
        j = nao.joint(name)
        assert math.degrees(lo[j]) == pytest.approx(a) and math.degrees(hi[j]) == pytest.approx(b), name


@pytest.mark.parametrize("which", ["rn", "nao"])
def test_configurations_within_joint_limits(request, which: str) -> None:
    profile = request.getfixturevalue(which)
    sim = request.getfixturevalue(f"{which}_sim")
    lo, hi = profile.joint_limits()
    assert np.all(sim.true_joints >= lo - 1e-12) and np.all(sim.true_joints <= hi + 1e-12)
    # Readings are rounded to 0.1 deg, which may cross a limit by at most half a step.
    half = math.radians(0.05) + 1e-12
    assert np.all(sim.data.joints >= lo - half) and np.all(sim.data.joints <= hi + half)
    # The configurations vary (not one pose repeated).
    assert np.ptp(sim.true_joints, axis=0).max() > math.radians(10)


def test_robonaut_neck_roll_reads_zero(rn, rn_sim) -> None:
    assert np.all(rn_sim.data.joints[:, rn.joint("neck_roll")] == 0.0)


@pytest.mark.parametrize("which", ["rn", "nao"])
def test_readings_are_quantised_to_a_tenth_degree(request, which: str) -> None:
    sim = request.getfixturevalue(f"{which}_sim")
    tenths = np.degrees(sim.data.joints) * 10
    np.testing.assert_allclose(tenths, np.round(tenths), rtol=0, atol=1e-6)
    err = np.degrees(sim.data.joints - sim.true_joints)
    assert np.abs(err).max() <= 0.05 + 1e-9
    moving = np.ptp(sim.true_joints, axis=0) > 0
    assert np.abs(err[:, moving]).max() > 0.04  # really rounded, not exact


def test_quantise_off_reports_the_true_readings(rn) -> None:
    robot = SimulatedRobot.from_profile(rn, seed=23)
    robot.quantise = False
    sim = robot.simulate(20)
    np.testing.assert_array_equal(sim.data.joints, sim.true_joints)


def test_robonaut_exact_measurement_is_the_true_model(rn, rn_sim) -> None:
    """`exact` is the true robot's fixture centre in the eye frame, at the true (unquantised) readings."""
    truth = rn_sim.true_params
    pred = Problem(rn, _with_true_joints(rn_sim), [], truth, noise_model=False).predict(truth)
    np.testing.assert_allclose(rn_sim.exact, pred, rtol=0, atol=1e-9)


def test_robonaut_fixture_in_front_of_the_eye_and_in_the_image(rn, rn_sim) -> None:
    sensor = rn.sensors[rn.data.sensor]
    X = rn_sim.exact @ sensor.R_frame_optical  # optical frame: x right, y down, z forward
    fx, fy, cx, cy = (rn_sim.true_params[i] for i in sensor.intrinsics)
    assert np.all(X[:, 2] > 0)
    lo, hi = sensor.range
    assert np.all((X[:, 2] >= lo) & (X[:, 2] <= hi))
    u = fx * X[:, 0] / X[:, 2] + cx
    v = fy * X[:, 1] / X[:, 2] + cy
    w, h = sensor.image
    assert np.all((u >= 0) & (u <= w - 1) & (v >= 0) & (v <= h - 1))


def test_nao_boards_in_front_of_the_camera_and_in_the_image(nao, nao_sim) -> None:
    truth = nao_sim.true_params
    problem = Problem(nao, _with_true_joints(nao_sim), [], truth, noise_model=False)
    np.testing.assert_allclose(nao_sim.exact, problem.predict(truth), rtol=0, atol=1e-9)
    x = problem.sensor_points(truth)  # camera frame: x forward
    assert np.all(x[:, 0] > 0)
    u, v = nao_sim.exact[:, 0], nao_sim.exact[:, 1]
    assert np.all((u >= 0) & (u <= 639) & (v >= 0) & (v <= 479))
    # The board's patterned face (its -z side, under the sole) looks at the camera.
    pts = x.reshape(144, 24, 3)
    ex = pts[:, 1] - pts[:, 0]  # +x of the board: the next column
    ey = pts[:, 0] - pts[:, 6]  # +y of the board: the previous row
    normal = np.cross(ex, ey)  # +z of the board
    centre = pts.mean(axis=1)
    assert np.all(np.einsum("ni,ni->n", normal, centre) > 0)  # the camera (origin) is on the -z side


def test_nao_protocol_24_stances_by_3_head_postures_per_leg(nao, nao_sim) -> None:
    data = nao_sim.data
    assert data.n_configurations == 144
    assert data.n_observations == 3456
    head = [nao.joint("HeadYaw"), nao.joint("HeadPitch")]
    for side, target in (("L", nao.target("left_board")), ("R", nao.target("right_board"))):
        cfgs = np.unique(data.cfg[data.target == target])
        assert len(cfgs) == 72
        legs = [nao.joint(side + j) for j in LEG]
        stances, counts = np.unique(np.round(data.joints[np.ix_(cfgs, legs)], 9), axis=0, return_counts=True)
        assert len(stances) == 24 and np.all(counts == 3), side
        for stance in stances:
            rows = cfgs[np.all(np.round(data.joints[np.ix_(cfgs, legs)], 9) == stance, axis=1)]
            pitches = np.degrees(data.joints[rows, head[1]])
            assert len(np.unique(pitches)) == 3  # three head postures
            assert pitches.min() < 15 and pitches.max() > 24  # spread over the 10..29 deg range
    # Every configuration shows all 24 vertices of one board, once each.
    for c in range(data.n_configurations):
        obs = data.cfg == c
        assert sorted(data.vertex[obs].tolist()) == list(range(24))
        assert len(np.unique(data.target[obs])) == 1


@pytest.mark.parametrize("believed", ["nominal", "true"])
def test_a_stance_is_aimed_as_trying_every_head_angle_would(nao, believed: str) -> None:
    """The head yaw that centres the board: every tenth of the 121 angles first, then the neighbours of the best of
    them, picks the angle that trying all 121 picks (on the nominal and a drifted model, both boards)."""
    robot = SimulatedRobot.from_profile(nao, seed=4)
    p = nao.nominal() if believed == "nominal" else robot.true_params
    sampler = Sampler(Visibility(nao, p), np.random.default_rng(4))
    sampling = nao.simulation["sampling"]
    look = nao.joint(sampling["look_at"])
    lo, hi = nao.joint_limits()
    every = np.linspace(max(lo[look], -1.2), min(hi[look], 1.2), 121)
    for name, ranges in sampling["stance"].items():
        target = nao.target(name)
        stances, _ = sampler._stance_batch(sampling, ranges, target, 200, 3)
        cost = sampler._off_centre(stances, look, target, np.broadcast_to(every, (len(stances), len(every))))
        assert cost is not None and np.isfinite(cost).any(axis=1).all()
        np.testing.assert_array_equal(sampler._aim(stances, look, target), every[np.argmin(cost, axis=1)])


def test_robonaut_configurations_show_the_sphere_to_both_cameras(rn, rn_robot) -> None:
    """Rendered, the sphere of every configuration the simulator picks is mostly in view of both cameras
    (the arm hides at most a small part) and clear of the left band where the matcher gives no depth."""
    q, _ = rn_robot.configurations(8)
    p = rn_robot.true_params
    head = StereoHead.from_profile(rn, p)
    band = no_depth_band_px(head)
    x = rn_robot.measure(q, np.zeros(len(q), int)).exact @ rn.sensors[rn.data.sensor].R_frame_optical * 0.01
    for n in range(len(q)):
        f = render_pair(rn, p, q[n], head, np.random.default_rng(n))
        for ids, centre_m in ((f.object_id, x[n]), (f.object_id_right, x[n] - [head.baseline_m, 0.0, 0.0])):
            r_px = head.fx_px * 0.04 / np.sqrt(centre_m @ centre_m - 0.04**2)  # the outline's radius, about
            shown = (ids == SPHERE).sum() / (np.pi * r_px**2)
            assert shown > 0.8, (n, shown)
        columns = np.flatnonzero((f.object_id == SPHERE).any(axis=0))
        assert columns.min() > band


def test_robonaut_sphere_hidden_by_the_arm_is_not_picked(rn) -> None:
    """Among random poses within the limits with the fixture's centre in the image, the arm hides the
    sphere in many; the simulator's own picks are the ones the check lets through."""
    robot = SimulatedRobot.from_profile(rn, seed=3)
    lo, hi = rn.joint_limits()
    q = robot.rng.uniform(lo, hi, (4000, len(lo)))
    head = StereoHead.from_profile(rn, robot.true_params)
    views = sphere_views(rn, robot.true_params, q, head)
    u, v = views.centre_px.T
    in_image = (u > 150) & (u < 600) & (v > 30) & (v < 450)
    hidden = in_image & (views.visible.min(axis=1) < 0.5)
    assert hidden.sum() > 0.1 * in_image.sum()  # the check matters
    assert not Visibility(rn, robot.true_params).sees(q[hidden], np.zeros(hidden.sum(), int)).any()


def test_nao_boards_are_seen_well_enough_to_be_measured(nao, nao_sim) -> None:
    """Every picked frame's board is seen at most 86 deg from its normal, its closest vertices at
    least 2.5 px apart in the image: computed here from the board's and the camera's poses."""
    truth = nao_sim.true_params
    camera = nao.sensors[nao.data.sensor].frame
    for n in range(nao_sim.data.n_configurations):
        rows = nao_sim.data.cfg == n
        target = int(nao_sim.data.target[rows][0])
        board = nao.targets[target].frame
        poses = forward(nao, truth, nao_sim.true_joints[n][None], frames=[board, camera])
        normal = poses.R[board][0][:, 2]
        centre = poses.R[board][0] @ nao.targets[target].grid.mean(axis=0) + poses.t[board][0]
        ray = centre - poses.t[camera][0]
        obliquity = np.degrees(np.arccos(abs(normal @ ray) / np.linalg.norm(ray)))
        assert obliquity <= 86.0 + 1e-9
        g = nao_sim.exact[rows].reshape(4, 6, 2)
        spacing = min(
            np.linalg.norm(np.diff(g, axis=0), axis=2).min(), np.linalg.norm(np.diff(g, axis=1), axis=2).min()
        )
        assert spacing >= 2.5


# --- drift ----------------------------------------------------------------------------------------------


def test_drifted_robot_differs_only_in_joint_offsets(rn, rn_robot) -> None:
    later = rn_robot.drifted(seed=5)
    changed = {rn.parameters[i].name for i in np.flatnonzero(later.true_params != rn_robot.true_params)}
    thetas = {f"{j}.theta" for j in rn.joint_names}
    assert changed == thetas  # every joint offset, nothing else
    assert (later.pixel_noise, later.disparity_noise, later.quantise) == (
        rn_robot.pixel_noise,
        rn_robot.disparity_noise,
        rn_robot.quantise,
    )
    drift = np.degrees(later.true_params - rn_robot.true_params)
    assert np.abs(drift).max() > 0.5  # a drift that matters
    # Another day, another drift; the day-1 robot is unchanged.
    assert not np.array_equal(rn_robot.drifted(seed=6).true_params, later.true_params)
    np.testing.assert_array_equal(rn_robot.true_params, rn.true_params())


def test_nao_drift_moves_only_joint_offsets(nao) -> None:
    robot = SimulatedRobot.from_profile(nao, seed=1)
    later = robot.drifted(seed=2)
    changed = {nao.parameters[i].name for i in np.flatnonzero(later.true_params != robot.true_params)}
    assert changed and changed <= set(nao.joint_names)  # NAO's joint offsets carry the joint's name


# --- noise ----------------------------------------------------------------------------------------------


def test_robonaut_error_grows_with_distance(rn) -> None:
    """Stereo depth noise grows with the square of the distance: far points are measured worse, and
    worse by more than their distance ratio (the lateral part alone would grow only linearly)."""
    sim = SimulatedRobot.from_profile(rn, seed=43).simulate(1500)
    err = np.linalg.norm(sim.data.measured - sim.exact, axis=1)
    dist = np.linalg.norm(sim.exact, axis=1)
    order = np.argsort(dist)
    third = len(order) // 3
    near, far = order[:third], order[-third:]
    e_near, e_far = np.sqrt(np.mean(err[near] ** 2)), np.sqrt(np.mean(err[far] ** 2))
    d_near, d_far = dist[near].mean(), dist[far].mean()
    assert np.all(err > 0)
    assert e_far > 1.5 * e_near, (e_near, e_far)
    assert e_far / e_near > 1.1 * d_far / d_near, (e_far / e_near, d_far / d_near)


def test_nao_pixel_noise_is_about_0_2_px(nao_sim) -> None:
    e = nao_sim.data.measured - nao_sim.exact
    assert e.std() == pytest.approx(0.2, rel=0.05)
    assert abs(e.mean()) < 0.02
    # Independent in u and v.
    assert abs(np.corrcoef(e[:, 0], e[:, 1])[0, 1]) < 0.1


def test_noise_off_measures_exactly(rn, nao) -> None:
    for profile, n in ((rn, 20), (nao, None)):
        robot = SimulatedRobot.from_profile(profile, seed=29)
        robot.pixel_noise = 0
        robot.disparity_noise = 0
        sim = robot.measure(*robot.configurations(n)) if n else robot.measure(*_few_stances(robot))
        np.testing.assert_allclose(sim.data.measured, sim.exact, rtol=0, atol=1e-9)


def _few_stances(robot):
    return robot.configurations(6)  # 1 stance per leg, 3 postures each


def test_outliers_are_where_the_simulation_says(rn) -> None:
    robot = SimulatedRobot.from_profile(rn, seed=37)
    sim = robot.simulate(400, outlier_rate=0.05, outlier_size=20.0)
    err = np.linalg.norm(sim.data.measured - sim.exact, axis=1)
    assert 5 <= sim.outliers.sum() <= 40
    assert err[sim.outliers].min() > 15.0  # 20 cm in a random direction, plus the ordinary noise
    assert err[~sim.outliers].max() < 5.0
