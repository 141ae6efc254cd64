"""The hand-eye equations in closed form (calib_core.estimation.handeye) against exact synthetic poses: the
robot-world/hand-eye AX = ZB (Shah), AX = XB (Park and Martin), the board's pose in an image (PnP), and what
they cannot determine."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from calib_core.estimation.handeye import (
    board_poses,
    hand_eye_candidates,
    inverse,
    pose,
    relative_motions,
    rotation_spread_deg,
    solve_ax_xb,
    solve_ax_zb,
    zyx_angles,
)


def random_pose(rng: np.random.Generator, size: float = 500.0) -> np.ndarray:
    return pose(Rotation.random(random_state=rng).as_matrix(), rng.uniform(-size, size, 3))


def loop(rng: np.random.Generator, n: int) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Poses A_i of a robot and B_i = Z^-1 A_i X of what the camera sees, for random X and Z."""
    X, Z = random_pose(rng, 100.0), random_pose(rng)
    A = np.array([random_pose(rng) for _ in range(n)])
    return A, inverse(Z) @ A @ X, X, Z


@pytest.mark.parametrize("n", [3, 5, 40])
def test_shah_recovers_both_poses_from_exact_data(n: int) -> None:
    A, B, X, Z = loop(np.random.default_rng(n), n)
    X_found, Z_found = solve_ax_zb(A, B)
    np.testing.assert_allclose(X_found, X, atol=1e-8)
    np.testing.assert_allclose(Z_found, Z, atol=1e-8)


def test_park_martin_recovers_the_hand_eye_pose_from_relative_motions() -> None:
    A, B, X, _ = loop(np.random.default_rng(7), 6)
    X_found = solve_ax_xb(relative_motions(A, left=True), relative_motions(B, left=True))
    np.testing.assert_allclose(X_found, X, atol=1e-8)


def test_every_closed_form_agrees_on_exact_data_and_stays_near_on_noisy_data() -> None:
    rng = np.random.default_rng(3)
    A, B, X, Z = loop(rng, 15)
    for label, X_found, Z_found in hand_eye_candidates(A, B):
        np.testing.assert_allclose(X_found, X, atol=1e-7, err_msg=label)
        np.testing.assert_allclose(Z_found, Z, atol=1e-7, err_msg=label)
    # 0.05 deg and 0.1 mm on what the camera sees: every form within a few times that.
    noisy = B @ np.array(
        [pose(Rotation.from_rotvec(rng.normal(0, 1e-3, 3)).as_matrix(), rng.normal(0, 0.1, 3)) for _ in B]
    )
    for label, X_found, _ in hand_eye_candidates(A, noisy):
        angle = np.degrees(Rotation.from_matrix(X_found[:3, :3] @ X[:3, :3].T).magnitude())
        assert angle < 0.1, label
        assert np.linalg.norm(X_found[:3, 3] - X[:3, 3]) < 2.0, label


def test_motions_about_one_axis_have_no_spread() -> None:
    """Turns about one axis leave a hand-eye pose undetermined (a shift along that axis changes nothing)."""
    A = np.array([pose(Rotation.from_rotvec([0, 0, a]).as_matrix(), [a, 0, 0]) for a in np.linspace(0, 2, 6)])
    assert rotation_spread_deg(A) < 1e-6
    assert rotation_spread_deg(loop(np.random.default_rng(0), 6)[0]) > 30


def test_zyx_angles_rebuild_the_rotation() -> None:
    R = Rotation.random(random_state=4).as_matrix()
    yaw, pitch, roll = zyx_angles(R)
    np.testing.assert_allclose(Rotation.from_euler("ZYX", [yaw, pitch, roll]).as_matrix(), R, atol=1e-12)


def board(rows: int = 6, cols: int = 7, spacing: float = 30.0) -> np.ndarray:
    r, k = np.divmod(np.arange(rows * cols), cols)
    return np.stack([spacing * k, spacing * r, np.zeros(rows * cols)], axis=1)


def rays_of(P: np.ndarray, points: np.ndarray) -> np.ndarray:
    x = points @ P[:3, :3].T + P[:3, 3]
    return x / np.linalg.norm(x, axis=1, keepdims=True)


def test_a_planar_boards_pose_and_its_flip() -> None:
    P = pose(Rotation.from_euler("xyz", [170, 10, 30], degrees=True).as_matrix(), [-50.0, 20.0, 600.0])
    first, *rest = board_poses(board(), rays_of(P, board()))
    np.testing.assert_allclose(first, P, atol=1e-6)
    assert len(rest) == 1 and not np.allclose(rest[0], P, atol=1e-3)  # IPPE's second: the flip


def test_points_off_a_plane_give_one_pose() -> None:
    points = np.random.default_rng(2).uniform(-100, 100, (10, 3))
    P = pose(Rotation.from_euler("xyz", [20, -10, 5], degrees=True).as_matrix(), [10.0, -20.0, 800.0])
    (found,) = board_poses(points, rays_of(P, points))
    np.testing.assert_allclose(found, P, atol=1e-6)


def test_too_few_points_or_points_on_a_line_give_no_pose() -> None:
    P = pose(np.eye(3), [0.0, 0.0, 500.0])
    assert board_poses(board()[:3], rays_of(P, board()[:3])) == []
    line = board()[:7]  # the first row
    assert board_poses(line, rays_of(P, line)) == []
