"""The hand-eye equations in closed form: where a camera and a board stand when nobody measured either.

A camera sees a board in image i: its pose C_i in the camera follows from the image (`board_poses`,
PnP). The robot's kinematics give the rest of the loop, so that for the unknown poses X and Z

    A_i X = Z B_i

the robot-world/hand-eye equation (both poses unknown: a camera on the flange and a board on the table,
or a camera in the room and a board on the flange). Rotations first, then the translations by linear
least squares with the rotations held:

- `solve_ax_zb`: Shah's (2013) Kronecker form, R_A R_X = R_Z R_B as one homogeneous linear system in
  the 18 entries of R_X and R_Z, its null vector projected onto the rotations.
- `solve_ax_xb`: Park and Martin's (1994) for the relative motions A_ij X = X B_ij (the poses of pairs of
  images), which turn about the same axes: R_X maps the axes of B_ij onto those of A_ij (a Kabsch fit of
  their log vectors). With X found, Z is the mean of A_i X B_i^-1.

Poses are 4x4 homogeneous matrices, stacked (n, 4, 4). OpenCV's calibrateHandEye is not used: it is gone
from OpenCV 5's Python package.
"""

from __future__ import annotations

import numpy as np

# A board's points lie on a plane when their thinnest spread is below this share of their widest.
PLANAR_SHARE = 1e-6
MIN_PNP_POINTS = 4  # a board's pose from fewer points is not determined


def pose(R: np.ndarray, t: np.ndarray) -> np.ndarray:
    """The 4x4 (or (n, 4, 4)) homogeneous transforms of rotations R and translations t."""
    R = np.asarray(R, float)
    T = np.zeros((*R.shape[:-2], 4, 4))
    T[..., :3, :3] = R
    T[..., :3, 3] = t
    T[..., 3, 3] = 1.0
    return T


def inverse(T: np.ndarray) -> np.ndarray:
    """The inverse of rigid transforms (4, 4) or (n, 4, 4)."""
    Rt = np.swapaxes(T[..., :3, :3], -1, -2)
    return pose(Rt, -(Rt @ T[..., :3, 3:])[..., 0])


def nearest_rotation(M: np.ndarray) -> np.ndarray:
    """The rotation nearest M in the Frobenius norm (its polar factor, the sign of its determinant fixed)."""
    U, _, Vt = np.linalg.svd(M)
    D = np.diag([1.0, 1.0, np.sign(np.linalg.det(U @ Vt))])
    return U @ D @ Vt


def mean_pose(T: np.ndarray) -> np.ndarray:
    """The mean of poses (n, 4, 4): the rotation nearest the mean rotation matrix (the chordal mean), the mean
    translation."""
    return pose(nearest_rotation(T[:, :3, :3].mean(axis=0)), T[:, :3, 3].mean(axis=0))


def zyx_angles(R: np.ndarray) -> tuple[float, float, float]:
    """yaw, pitch, roll (rad) with R = Rot_z(yaw) Rot_y(pitch) Rot_x(roll)."""
    pitch = float(np.arcsin(np.clip(-R[2, 0], -1.0, 1.0)))
    yaw = float(np.arctan2(R[1, 0], R[0, 0]))
    roll = float(np.arctan2(R[2, 1], R[2, 2]))
    return yaw, pitch, roll


def solve_ax_zb(A: np.ndarray, B: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """X and Z (4, 4) with A_i X = Z B_i for poses A, B (n, 4, 4), n >= 3 with rotations about distinct axes.

    vec(R_A R_X) = (I kron R_A) vec(R_X) and vec(R_Z R_B) = (R_B^T kron I) vec(R_Z) (column-major vec): the
    rotations are the null vector of the stacked system, scaled to determinant 1 and projected onto the
    rotations; then [R_A, -I] [t_X; t_Z] = R_Z t_B - t_A in least squares."""
    I3 = np.eye(3)
    rows = [np.hstack([np.kron(I3, a[:3, :3]), -np.kron(b[:3, :3].T, I3)]) for a, b in zip(A, B, strict=True)]
    v = np.linalg.svd(np.vstack(rows), full_matrices=False)[2][-1]
    Rx, Rz = v[:9].reshape(3, 3, order="F"), v[9:].reshape(3, 3, order="F")
    det = np.linalg.det(Rx)
    scale = np.sign(det) / abs(det) ** (1 / 3)
    Rx, Rz = nearest_rotation(scale * Rx), nearest_rotation(scale * Rz)
    M = np.vstack([np.hstack([a[:3, :3], -I3]) for a in A])
    rhs = (B[:, :3, 3] @ Rz.T - A[:, :3, 3]).ravel()
    t = np.linalg.lstsq(M, rhs, rcond=None)[0]
    return pose(Rx, t[:3]), pose(Rz, t[3:])


def solve_ax_xb(A: np.ndarray, B: np.ndarray) -> np.ndarray:
    """X (4, 4) with A_k X = X B_k for relative motions A, B (k, 4, 4), at least two about distinct axes
    (Park and Martin): R_A = R_X R_B R_X^T, so the rotation vectors a_k = R_X b_k (a Kabsch fit without
    centring); then (R_A - I) t_X = R_X t_B - t_A in least squares."""
    from scipy.spatial.transform import Rotation  # here, not at the top: SciPy slows every start

    a = Rotation.from_matrix(A[:, :3, :3]).as_rotvec()
    b = Rotation.from_matrix(B[:, :3, :3]).as_rotvec()
    R = nearest_rotation(a.T @ b)
    M = np.vstack(A[:, :3, :3] - np.eye(3))
    rhs = (B[:, :3, 3] @ R.T - A[:, :3, 3]).ravel()
    return pose(R, np.linalg.lstsq(M, rhs, rcond=None)[0])


def relative_motions(T: np.ndarray, *, left: bool) -> np.ndarray:
    """The motions between consecutive-ish pairs of poses T (n, 4, 4): every pair (i, j), i < j, as
    T_j^-1 T_i (`left`: for A X = X B with A_i X = Z B_i gives A_j^-1 A_i X = X B_j^-1 B_i) or as
    T_i T_j^-1 (for Z: A_i A_j^-1 Z = Z B_i B_j^-1)."""
    i, j = np.triu_indices(len(T), k=1)
    return inverse(T[j]) @ T[i] if left else T[i] @ inverse(T[j])


def hand_eye_candidates(A: np.ndarray, B: np.ndarray) -> list[tuple[str, np.ndarray, np.ndarray]]:
    """Solutions (label, X, Z) of A_i X = Z B_i by the closed forms above: Shah's, and Park and Martin's for X
    (Z the mean of A_i X B_i^-1) and for Z (X the mean of A_i^-1 Z B_i). They agree on exact data; on noisy
    data with few or small rotations one may be far better than the others."""
    out = [("Shah", *solve_ax_zb(A, B))]
    X = solve_ax_xb(relative_motions(A, left=True), relative_motions(B, left=True))
    out.append(("Park-Martin on X", X, mean_pose(A @ X @ inverse(B))))
    Z = solve_ax_xb(relative_motions(A, left=False), relative_motions(B, left=False))
    out.append(("Park-Martin on Z", mean_pose(inverse(A) @ Z @ B), Z))
    return out


def rotation_spread_deg(T: np.ndarray) -> float:
    """The largest angle (deg) between the rotation axes of the motions between poses T (n, 4, 4), of the
    motions that turn at all: 0 when every motion turns about one axis (the hand-eye equations then leave the
    poses undetermined)."""
    from scipy.spatial.transform import Rotation  # here, not at the top: SciPy slows every start

    axes = Rotation.from_matrix(relative_motions(T, left=True)[:, :3, :3]).as_rotvec()
    angle = np.linalg.norm(axes, axis=1)
    axes = axes[angle > np.radians(1.0)] / angle[angle > np.radians(1.0), None]
    if len(axes) < 2:
        return 0.0
    cos = np.clip(np.abs(axes @ axes.T), 0.0, 1.0)
    return float(np.degrees(np.arccos(cos.min())))


def board_poses(points: np.ndarray, rays: np.ndarray) -> list[np.ndarray]:
    """The board's poses in the camera's optical frame that fit one image: points (K, 3) in the board's frame,
    rays (K, 3) their view rays in the optical frame (distortion undone). A planar board has two (IPPE: the
    best first, then the mirror-like flip); points off a plane one. [] when fewer than MIN_PNP_POINTS points
    or points on a line do not fix a pose."""
    if len(points) < MIN_PNP_POINTS:
        return []
    spread = np.linalg.svd(points - points.mean(axis=0), compute_uv=False)
    if spread[1] <= PLANAR_SHARE * spread[0]:
        return []
    import cv2  # a camera's start only: every other calibration starts without OpenCV

    image = np.ascontiguousarray(rays[:, :2] / rays[:, 2:], dtype=np.float64)
    obj = np.ascontiguousarray(points, dtype=np.float64)
    method = cv2.SOLVEPNP_IPPE if spread[2] <= PLANAR_SHARE * spread[0] else cv2.SOLVEPNP_SQPNP
    try:
        _, rvecs, tvecs, _ = cv2.solvePnPGeneric(obj, image, np.eye(3), None, flags=method)
    except cv2.error:
        return []
    return [pose(cv2.Rodrigues(r)[0], t.ravel()) for r, t in zip(rvecs, tvecs, strict=True)]
