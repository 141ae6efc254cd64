"""FIGAROH's published real data (sample_sessions/figaroh): the desk's plain profiles of TALOS, TIAGo and
the UR10e read every file as published, and on the splits of calib_core.io.figaroh_data (10 random 70/30 splits
by configuration; TIAGo also FIGAROH's two sessions) mode `auto` predicts the held-out data at least as well as
FIGAROH's better level, and each named mode as its counterpart (within 0.5% where it is behind). FIGAROH does
not run here: its figures are those benchmarks/peers.py measured."""

from __future__ import annotations

import hashlib
import math
from pathlib import Path

import numpy as np
import pytest

from calib_core import calibrate, load_profile, read_dataset
from calib_core.errors import InputError
from calib_core.estimation.validation import holdout_split
from calib_core.io.figaroh_data import (
    POSE_AXIS_M,
    POSE_POINTS,
    ROBOTS,
    heldout_errors,
    pose_points,
    rpy_matrix,
    splits,
)

FOLDER = Path(__file__).resolve().parents[1] / "sample_sessions" / "figaroh"

# FIGAROH 1.0.2 (Pinocchio 4.1.0) on the same splits, held-out RMS of the measured point (mm) and, for the
# UR10e's camera poses, of the rotation (deg): `python benchmarks/peers.py`, 2026-11-29 (docs/peers.md). By
# (robot, FIGAROH's two sessions rather than the random splits) and level.
PEER = {
    ("talos", False): {"joint_offset": (1.684, None), "full_params": (0.754, None)},
    ("tiago", False): {"joint_offset": (3.779, None), "full_params": (5.368, None)},
    ("tiago", True): {"joint_offset": (4.229, None), "full_params": (4.035, None)},
    ("ur10e-pose", False): {"joint_offset": (3.951, 0.587), "full_params": (3.941, 0.420)},
}
COUNTERPART = {"offsets": "joint_offset", "origins": "full_params"}

# The published files' sha256: FIGAROH's TIAGo protocol (protocol.yaml) and data inventory
# (docs/data-inventory.md, first 16 digits), SOURCES.md.
PUBLISHED = {
    "qualisys_2021-11-30_static_postures.csv": "b6c0051e20c6a077a6d2cf64ba912996945bbb85d6860cd6cea7d8ff65b1b9af",
    "qualisys_2021-11-26_static_postures.csv": "7c986df711757c4d31d8bb6db34b354f72318a78673dac280fd3a14abc5460a0",
    "talos_left_arm_02_10_contact.csv": "36b7a3b92f468b6e",
    "ur10_calibration.csv": "31d5a3d56cbb5ea3",
}


@pytest.fixture(scope="module")
def profiles():
    return {robot: load_profile(FOLDER / spec.profile) for robot, spec in ROBOTS.items()}


def test_every_profile_loads_plain_and_every_file_imports(profiles) -> None:
    """No note (nothing of the URDF put right, no limit overridden), no refusal: TIAGo's torso lift reads
    0.350184 m against its 0.35 m limit, a length, not an angle. Each profile's nominal agrees with its data
    once the mocap or room frame is fitted (no registration misfit)."""
    sizes = {}
    for robot, spec in ROBOTS.items():
        profile = profiles[robot]
        assert profile.notes == ()
        for name in filter(None, (spec.data, spec.heldout)):
            data = read_dataset(profile, FOLDER / name)
            sizes[name] = (data.n_configurations, data.n_observations)
        cal = calibrate(profile, read_dataset(profile, FOLDER / spec.data), "offsets")
        assert cal.converged and "registration-misfit" not in {d.code for d in cal.diagnostics}
    assert sizes == {
        "talos_left_arm_02_10_contact.csv": (61, 61),
        "qualisys_2021-11-30_static_postures.csv": (37, 37),
        "qualisys_2021-11-26_static_postures.csv": (62, 62),
        "ur10_calibration_points.csv": (23, 23 * 7),
        "ur10_calibration.csv": (23, 23),  # ur10e-pose: the same poses, read as poses
    }
    torso = profiles["tiago"].joint("torso_lift_joint")
    train = read_dataset(profiles["tiago"], FOLDER / ROBOTS["tiago"].data)
    assert np.nanmax(train.joints[:, torso]) == pytest.approx(350.18063257809234)  # mm, over the 350 mm limit


def test_ur10_origins_on_16_configurations_is_not_refused(profiles) -> None:
    """A 70/30 split leaves 16 poses to fit 54 parameters on: 16 x 7 points determine them (what the data
    cannot separate is held and named)."""
    ur10 = profiles["ur10e"]
    data = read_dataset(ur10, FOLDER / ROBOTS["ur10e"].data)
    train, _ = holdout_split(data, 0.3, 0)
    cal = calibrate(ur10, data.select(train), "origins")
    assert len(train) == 16 and cal.converged
    assert any(p.estimated for p in cal.parameters if p.name.endswith(".roll"))
    assert any(not p.estimated and p.note for p in cal.parameters if p.name.startswith("shoulder_pan_joint."))


@pytest.mark.parametrize("name", sorted(PUBLISHED))
def test_shipped_files_are_the_published_ones(name: str) -> None:
    digest = hashlib.sha256((FOLDER / name).read_bytes()).hexdigest()
    assert digest.startswith(PUBLISHED[name])


def test_the_ur10_points_are_its_poses() -> None:
    """The shipped points file is pose_points of the published poses (to round-off), and each pose's 7
    points give back its origin and its rotation."""
    poses = (FOLDER / ROBOTS["ur10e"].pose).read_text()
    made = [line.split(",") for line in pose_points(poses).splitlines()]
    shipped = [line.split(",") for line in (FOLDER / ROBOTS["ur10e"].data).read_text().splitlines()]
    assert len(made) == len(shipped) == 1 + 23 * 7 and made[0] == shipped[0]
    assert [m[:2] + m[5:] for m in made] == [s[:2] + s[5:] for s in shipped]  # frame, point, joints
    xyz = np.array([[float(v) for v in m[2:5]] for m in made[1:]])
    np.testing.assert_allclose(xyz, [[float(v) for v in s[2:5]] for s in shipped[1:]], rtol=0, atol=1e-12)
    x, y, z, roll, pitch, yaw = (float(v) for v in poses.splitlines()[1].split(",")[:6])
    np.testing.assert_allclose(xyz[0], [x, y, z], atol=1e-15)
    axes = np.stack([xyz[2 * k + 1] - xyz[2 * k + 2] for k in range(3)], axis=1) / (2 * POSE_AXIS_M)
    np.testing.assert_allclose(axes, rpy_matrix(roll, pitch, yaw), atol=1e-12)
    with pytest.raises(InputError, match=r"line 2, column 'phiy1': expected a number"):
        pose_points(poses.replace("-0.5109858420062574", "n/a"), "poses.csv")


def test_the_points_weigh_a_pose_as_figaroh_does() -> None:
    """For a small position error dp and rotation error dtheta, the 7 points' squared errors sum to
    7 (|dp|^2 + 0.5^2 |dtheta|^2): FIGAROH's UR10 cost, position 1 per m and orientation 0.5 per rad."""
    rng = np.random.default_rng(3)
    R = rpy_matrix(*rng.uniform(-np.pi, np.pi, 3))
    for _ in range(5):
        dp, dtheta = rng.normal(0, 1e-4, 3), rng.normal(0, 1e-4, 3)
        angle = float(np.linalg.norm(dtheta))
        k = dtheta / angle
        K = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
        dR = np.eye(3) + math.sin(angle) * K + (1 - math.cos(angle)) * K @ K
        before = POSE_AXIS_M * POSE_POINTS @ R.T
        after = dp + POSE_AXIS_M * POSE_POINTS @ (dR @ R).T
        total = float(np.sum((after - before) ** 2))
        assert total == pytest.approx(7 * (dp @ dp + 0.25 * dtheta @ dtheta), rel=1e-3)


def test_splits_are_ten_random_70_30_splits_by_configuration_and_figaroh_s_sessions(profiles) -> None:
    """Every robot: 10 splits (seeds 0-9) of its file's configurations, 30% held out, each a different held-out set
    and none seen in training; TIAGo also by FIGAROH's protocol, one session against the other."""
    sizes = {"talos": (43, 18), "tiago": (26, 11), "ur10e-pose": (16, 7)}
    for robot, size in sizes.items():
        pairs = splits(profiles[robot], FOLDER, robot)
        assert [(len(t.frame_ids), len(h.frame_ids)) for t, h in pairs] == [size] * 10
        assert len({tuple(h.frame_ids) for _, h in pairs}) == 10
        for train, heldout in pairs:
            assert not set(train.frame_ids) & set(heldout.frame_ids)
    tiago = splits(profiles["tiago"], FOLDER, "tiago", sessions=True)
    assert [(len(t.frame_ids), len(h.frame_ids)) for t, h in tiago] == [(37, 62)]
    with pytest.raises(InputError, match="robot 'talos' has no held-out session"):
        splits(profiles["talos"], FOLDER, "talos", sessions=True)


def _held_out(profile, robot: str, sessions: bool, mode: str) -> tuple[float, float | None]:
    """The desk's held-out RMS in mm and, for a pose, deg, rounded as FIGAROH's figures are."""
    errors = heldout_errors(profile, FOLDER, robot, mode, sessions)
    deg = errors.rms_deg()
    return round(errors.rms_mm(), 3), None if deg is None else round(deg, 3)


@pytest.mark.slow
@pytest.mark.parametrize("robot, sessions", [("talos", False), ("tiago", True), ("ur10e-pose", False)])
def test_auto_is_at_least_as_good_as_figaroh_s_better_level(profiles, robot: str, sessions: bool) -> None:
    """Held-out RMS to the micrometre (and the UR10e's rotation to the thousandth of a degree) against the level
    of FIGAROH's that predicts the held-out positions better. Failed before `auto` (no such mode), and with the
    URDF's `origins` priors as they are on TALOS and the UR10e (0.757 mm, 3.952 mm)."""
    mm, deg = _held_out(profiles[robot], robot, sessions, "auto")
    peer_mm, peer_deg = min(PEER[robot, sessions].values())
    assert mm <= peer_mm
    assert deg is None or deg <= peer_deg


@pytest.mark.slow
def test_on_tiago_s_random_splits_auto_is_ahead_of_full_params() -> None:
    """TIAGo's random splits leave 26 postures (78 rows) for the 31 parameters `origins` estimates: the origins'
    priors that cross-validation on 21 of them finds best (mostly x1/2) predict the other 11 worse than the offsets
    alone do, the desk's and FIGAROH's alike (3.779 mm). `auto` is ahead of FIGAROH's full parameters and 10% behind
    its offsets: the one comparison where it is behind (docs/peers.md)."""
    tiago = load_profile(FOLDER / ROBOTS["tiago"].profile)
    mm, _ = _held_out(tiago, "tiago", False, "auto")
    assert mm <= PEER["tiago", False]["full_params"][0]
    assert mm <= 1.11 * PEER["tiago", False]["joint_offset"][0]


@pytest.mark.slow
@pytest.mark.parametrize("robot, sessions", sorted(PEER))
@pytest.mark.parametrize("mode", sorted(COUNTERPART))
def test_each_mode_against_its_counterpart(profiles, robot: str, sessions: bool, mode: str) -> None:
    """`offsets` at least as good as FIGAROH's `joint_offset` on the positions, `origins` as `full_params`, but for
    `origins` on TALOS and the UR10e's positions: within 0.5% there (the URDF's prior of 5 mm, 1 deg is wider than
    the UR10e's data support and narrower than TALOS's: `auto` chooses it). The UR10e's rotations: `origins`
    ahead, `offsets` within 0.5%."""
    mm, deg = _held_out(profiles[robot], robot, sessions, mode)
    peer_mm, peer_deg = PEER[robot, sessions][COUNTERPART[mode]]
    behind = {("talos", "origins"), ("ur10e-pose", "origins")}
    assert mm <= (1.005 * peer_mm if (robot, mode) in behind else peer_mm)
    if deg is not None:
        assert deg <= (peer_deg if mode == "origins" else 1.005 * peer_deg)
