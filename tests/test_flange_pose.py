"""A robot that is its flange pose (calib_core.model.flange_pose, calib_core.io.flange_session): the desk's own
estimation on images and reported poses, its standard deviations against the spread of its estimates, and ViSP's
real images against `calib handeye`."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from calib_core.estimation import calibrate_flange, find_views
from calib_core.estimation.calibrate import calibrate
from calib_core.io import parse_board, read_camera, read_flange_poses
from calib_core.io.flange_session import board_target, flange_pose_session, write_flange_session
from calib_core.io.session import read_session
from calib_core.model.flange_pose import (
    flange_pose_profile,
    profile_reference,
    readings,
    reference_rotation,
    zyx_angles,
)
from calib_core.model.kinematics import axis_angle
from calib_core.model.loader import compile_profile
from calib_core.sim.simulator import SimulatedRobot

VISP = Path(__file__).resolve().parents[1] / "sample_sessions" / "handeye-visp"


def _pose(R: np.ndarray, t: np.ndarray) -> np.ndarray:
    T = np.eye(4)
    T[:3, :3], T[:3, 3] = R, t
    return T


def _rot(rng: np.random.Generator, deg: float) -> np.ndarray:
    axis = rng.normal(size=3)
    return axis_angle(axis / np.linalg.norm(axis), np.radians(deg))


def test_the_readings_are_the_pose_the_profile_composes_again() -> None:
    """x, y, z and the ZYX angles relative to the reference, through the profile's chain, give back each pose."""
    rng = np.random.default_rng(3)
    T = np.array([_pose(_rot(rng, rng.uniform(0, 170)), rng.uniform(-800, 800, 3) / 1000) for _ in range(20)])
    ref = reference_rotation(T[:, :3, :3])
    assert np.allclose(ref @ ref.T, np.eye(3)) and np.linalg.det(ref) > 0
    q = readings(T, ref)
    profile = compile_profile(_synthetic_doc(ref), "<test>")
    from calib_core.model.kinematics import forward

    qi = q.copy()
    qi[:, 3:] = np.radians(q[:, 3:])
    poses = forward(profile, profile.nominal(), qi)
    flange = profile.frame("flange")
    assert np.allclose(poses.t[flange], T[:, :3, 3] * 1000, atol=1e-9)
    assert np.allclose(poses.R[flange], T[:, :3, :3], atol=1e-12)
    assert np.allclose(zyx_angles(poses.R[flange]), zyx_angles(T[:, :3, :3]), atol=1e-9)


def _synthetic_doc(reference: np.ndarray, setup: str = "eye-in-hand") -> dict:
    board = parse_board("chessboard:9x6:25")
    return flange_pose_profile(
        "sim-flange",
        setup,
        camera_matrix=np.array([[600.0, 0, 320], [0, 600, 240], [0, 0, 1]]),
        distortion=np.zeros(5),
        image_size=(640, 480),
        board=board_target(board),
        reference=reference,
        pixel_sd=0.3,
        flange_sd_mm=0.1,
        flange_sd_deg=0.02,
    )


def _looking_at_the_board(n: int, rng: np.random.Generator, X: np.ndarray, Z: np.ndarray) -> np.ndarray:
    """Flange poses (n, 4, 4) m whose camera (X in the flange) looks at the board (Z in the base) from 0.4-0.6 m,
    tilted up to 30 deg, turned about its axis up to 90 deg: eye-in-hand."""
    out = []
    for _ in range(n):
        tilt = _rot(rng, rng.uniform(0, 30))
        turn = axis_angle(np.array([0, 0, 1.0]), np.radians(rng.uniform(-90, 90)))
        R_board_cam = tilt @ turn @ np.diag([1.0, -1.0, -1.0])  # optical axis down onto the board's face
        t_board_cam = -R_board_cam @ np.array([0, 0, rng.uniform(0.4, 0.6)])
        cam_in_base = Z @ _pose(R_board_cam, t_board_cam)
        out.append(cam_in_base @ np.linalg.inv(X))
    return np.array(out)


@pytest.fixture(scope="module")
def simulated():
    """The profile, the true camera-in-flange and board-in-base poses, and 15 configurations looking at it."""
    rng = np.random.default_rng(7)
    X = _pose(_rot(rng, 5) @ axis_angle(np.array([0, 0, 1.0]), np.pi / 2), np.array([0.03, -0.05, 0.04]))
    Z = _pose(axis_angle(np.array([0, 0, 1.0]), 0.3), np.array([0.6, 0.1, -0.2]))
    T = _looking_at_the_board(15, rng, X, Z)
    ref = reference_rotation(T[:, :3, :3])
    profile = compile_profile(_synthetic_doc(ref), "<test>")
    q = readings(T, ref)
    q[:, 3:] = np.radians(q[:, 3:])
    return profile, X, Z, q


def _truth(profile, X: np.ndarray, Z: np.ndarray) -> np.ndarray:
    """The profile's parameters with the camera and board frames at X and Z (its grid is centred, y up, z out of
    the face: the detector's chessboard frame turned half about x and moved to the board's centre)."""
    board = profile.targets[0].grid
    centre = np.array([4 * 25.0, 2.5 * 25.0, 0.0]) / 1000
    Z_grid = Z @ _pose(np.diag([1.0, -1.0, -1.0]), centre)
    assert board is not None
    values = {}
    for frame, T in (("camera_mount", X), ("board_frame", Z_grid)):
        yaw, pitch, roll = np.degrees(zyx_angles(T[None, :3, :3]))[0]
        values |= {f"{frame}.{k}": v * 1000 for k, v in zip("xyz", T[:3, 3], strict=True)}
        values |= {f"{frame}.yaw": yaw, f"{frame}.pitch": pitch, f"{frame}.roll": roll}
    return profile.params_from_display(values)


def test_the_desk_finds_the_camera_with_the_poses_noise_modelled(simulated) -> None:
    """Reported poses 0.1 mm / 0.02 deg off, corners 0.3 px: the desk's handeye mode finds the camera on the flange
    within 3 standard deviations, from no pose given (the registration frames start at zero)."""
    profile, X, Z, q = simulated
    truth = _truth(profile, X, Z)
    sim = SimulatedRobot(profile, truth, pixel_noise=0.3, seed=1).measure(q, np.zeros(len(q), int))
    cal = calibrate(profile, sim.data, "handeye")
    est = {e.name: e for e in cal.parameters if e.estimated}
    for k, axis in enumerate("xyz"):
        e = est[f"camera_mount.{axis}"]
        assert abs(e.value - X[k, 3] * 1000) < 3 * e.std, (axis, e.value, X[k, 3] * 1000, e.std)
    assert not [d for d in cal.diagnostics if d.severity == "warning"], cal.diagnostics


@pytest.mark.slow
def test_its_standard_deviations_are_the_spread_of_its_estimates(simulated) -> None:
    """Monte Carlo, as for the other set-ups: 120 data sets (new pose errors and corner noise each), the reported
    standard deviation of every estimated parameter within 0.8-1.25 of the estimates' spread."""
    profile, X, Z, q = simulated
    truth = _truth(profile, X, Z)
    values, stds = [], []
    for seed in range(120):
        sim = SimulatedRobot(profile, truth, pixel_noise=0.3, seed=100 + seed).measure(q, np.zeros(len(q), int))
        cal = calibrate(profile, sim.data, "handeye")
        est = [e for e in cal.parameters if e.estimated]
        values.append([e.value for e in est])
        stds.append([e.std for e in est])
    names = [e.name for e in est]
    v = np.array(values)
    angle = np.array([e.unit == "deg" for e in est])
    v[:, angle] = v[0, angle] + (v[:, angle] - v[0, angle] + 180.0) % 360.0 - 180.0  # a roll of 180 is one of -180
    ratio = np.mean(stds, axis=0) / np.std(v, axis=0, ddof=1)
    bad = {n: round(float(r), 3) for n, r in zip(names, ratio, strict=True) if not 0.8 <= r <= 1.25}
    assert len(names) == 12 and not bad, bad


@pytest.mark.slow
def test_modelling_the_poses_noise_finds_the_camera_better_than_taking_them_as_exact(simulated) -> None:
    """What the pose noise model buys: the same data (poses 0.1 mm / 0.02 deg off, corners 0.1 px) calibrated by a
    profile that declares its readings exact put the camera on the flange at least 1.5 times further from the
    truth (RMS over 40 data sets: the corners absorb the poses' errors; measured 0.39-0.52 against 0.07-0.20 mm
    at 0.05 px), while each reports standard deviations that cover its own error (per-frame scales)."""
    profile, X, Z, q = simulated
    truth = _truth(profile, X, Z)
    doc = _synthetic_doc(profile_reference(profile))
    doc["joints"] = {k: v | {"noise": 0.0} for k, v in doc["joints"].items()}
    exact = compile_profile(doc, "<exact>")
    errors: dict[str, list] = {"model": [], "exact": []}
    for seed in range(40):
        sim = SimulatedRobot(profile, truth, pixel_noise=0.1, seed=500 + seed).measure(q, np.zeros(len(q), int))
        for name, prof in (("model", profile), ("exact", exact)):
            est = {e.name: e.value for e in calibrate(prof, sim.data, "handeye").parameters if e.estimated}
            errors[name].append([est[f"camera_mount.{a}"] - X[k, 3] * 1000 for k, a in enumerate("xyz")])
    rms = {name: np.sqrt(np.mean(np.square(e), axis=0)) for name, e in errors.items()}
    assert np.linalg.norm(rms["exact"]) > 1.5 * np.linalg.norm(rms["model"]), rms


def test_visp_s_real_images_as_a_desk_session_agree_with_calib_handeye(tmp_path) -> None:
    """ViSP's 8 real images and poses as a desk robot and session: written, read back through its own profile,
    calibrated by the desk in mode handeye: the camera where `calib handeye`'s fit puts it (within its standard
    deviation), with standard deviations of the same size, and no warning."""
    names = sorted(p.name for p in (VISP / "images").iterdir())
    board = parse_board((VISP / "board.txt").read_text().strip())
    camera = read_camera(VISP / "camera.yaml")
    poses = read_flange_poses(VISP / "poses.csv", names, "m", "rad")
    import cv2

    images = {n: cv2.imread(str(VISP / "images" / n)) for n in names}
    views = find_views({n: cv2.cvtColor(im, cv2.COLOR_BGR2GRAY) for n, im in images.items()}, board, camera)
    session = flange_pose_session("visp-arm", views, poses, camera, board, "eye-in-hand")
    write_flange_session(tmp_path / "visp", session, images, name="ViSP's tutorial", made_by="test")
    folder = read_session(tmp_path / "visp")  # the folder carries its robot's profile
    assert folder.robot == "visp-arm" and folder.data.n_configurations == 8
    assert (tmp_path / "visp" / "profile.yaml").is_file() and len(list((tmp_path / "visp" / "images").iterdir())) == 8
    cal = calibrate(session.profile, folder.data, "handeye")
    reference = calibrate_flange(find_views(_grey(images), board, camera), poses, camera, board, "eye-in-hand")
    est = {e.name: e for e in cal.parameters if e.estimated}
    for k, axis in enumerate("xyz"):
        e = est[f"camera_mount.{axis}"]
        mm = reference.X[k, 3] * 1000
        sd = reference.X_std[k] * 1000
        assert abs(e.value - mm) < max(e.std, sd), (axis, e.value, mm)
        assert 0.5 < e.std / sd < 2.0, (axis, e.std, sd)
    assert not [d.code for d in cal.diagnostics if d.severity == "warning"]


def _grey(images: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
    import cv2

    return {n: cv2.cvtColor(im, cv2.COLOR_BGR2GRAY) for n, im in images.items()}
