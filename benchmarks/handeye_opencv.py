"""OpenCV 4's hand-eye calibrations of benchmarks/handeye.py's cases, run in an environment of their own
(OpenCV 5.0's Python package has no calibrateHandEye): numpy and opencv-python-headless<5 only, never the desk.

Reads an npz (`object_points` (K, 3) of the board in its frame, `camera_matrix` (3, 3), per case k `corners_k`
(N, K, 2) px, `gripper_k` (N, 4, 4) the flange's pose in the robot's base by the believed kinematics, and
`eye_in_hand_k`; images that each see a part of the board, a ChArUco board's, instead give per case `counts_k` (N,)
corners an image, `corners_k` (sum, 2) and `object_points_k` (sum, 3) the board's points they are), writes a JSON
list, per case {method: {"X": 4x4, "Z": 4x4, "seconds": s}} (X and Z null with the `error` OpenCV raised when a
method fails outright): eye-in-hand X is the camera in the flange and Z the board in the base; eye-to-hand X is the
camera in the base and Z the board in the flange. Each board pose per image is cv2.solvePnP's on the corners (no
distortion, as the camera has none); `seconds` is those PnPs' time plus the method's.

    .venv-cv4/bin/python benchmarks/handeye_opencv.py cases.npz out.json
"""

from __future__ import annotations

import json
import sys
import time

import cv2
import numpy as np

HAND_EYE = ("TSAI", "PARK", "HORAUD", "ANDREFF", "DANIILIDIS")
ROBOT_WORLD = ("SHAH", "LI")


def pose(R: np.ndarray, t: np.ndarray) -> np.ndarray:
    T = np.eye(4)
    T[:3, :3], T[:3, 3] = R, np.ravel(t)
    return T


def inverse(T: np.ndarray) -> np.ndarray:
    """Inverse of rigid transforms (..., 4, 4)."""
    out = np.zeros_like(T)
    Rt = np.swapaxes(T[..., :3, :3], -1, -2)
    out[..., :3, :3] = Rt
    out[..., :3, 3] = -(Rt @ T[..., :3, 3:4])[..., 0]
    out[..., 3, 3] = 1.0
    return out


def mean_pose(T: np.ndarray) -> np.ndarray:
    """The chordal mean of rigid transforms (N, 4, 4): the rotation nearest their rotations' sum, the mean shift."""
    U, _, Vt = np.linalg.svd(T[:, :3, :3].sum(axis=0))
    R = U @ np.diag([1.0, 1.0, np.linalg.det(U @ Vt)]) @ Vt
    return pose(R, T[:, :3, 3].mean(axis=0))


def board_in_camera(object_points: list[np.ndarray], corners: list[np.ndarray], K: np.ndarray) -> np.ndarray:
    """Each image's board pose in the camera (N, 4, 4) by cv2.solvePnP on its corners and the board's points."""
    out = []
    for obj, uv in zip(object_points, corners, strict=True):
        ok, rvec, tvec = cv2.solvePnP(obj, uv, K, None)
        if not ok:
            raise RuntimeError("solvePnP found no board pose")
        out.append(pose(cv2.Rodrigues(rvec)[0], tvec))
    return np.array(out)


def solve_case(
    object_points: list[np.ndarray], K: np.ndarray, corners: list[np.ndarray], G: np.ndarray, in_hand: bool
) -> dict:
    """Every method's X and Z (module doc) for one case."""
    t0 = time.perf_counter()
    C = board_in_camera(object_points, corners, K)
    pnp_s = time.perf_counter() - t0
    # Eye-to-hand is eye-in-hand with the base and the flange swapped (OpenCV's documentation).
    moving = G if in_hand else inverse(G)
    out = {}
    for name in HAND_EYE:
        t0 = time.perf_counter()
        try:
            R, t = cv2.calibrateHandEye(
                moving[:, :3, :3],
                moving[:, :3, 3],
                C[:, :3, :3],
                C[:, :3, 3],
                method=getattr(cv2, f"CALIB_HAND_EYE_{name}"),
            )
        except cv2.error as exc:  # a method that fails outright on these poses says why
            out[name] = {"X": None, "Z": None, "error": str(exc.err), "seconds": pnp_s + time.perf_counter() - t0}
            continue
        X = pose(R, t)
        Z = mean_pose(moving @ X @ C)  # the board where each image puts it, averaged
        out[name] = {"X": X.tolist(), "Z": Z.tolist(), "seconds": pnp_s + time.perf_counter() - t0}
    # AX = ZB with A the board in the camera and B the base in the flange (eye-to-hand: the flange in the base).
    B = inverse(G) if in_hand else G
    for name in ROBOT_WORLD:
        t0 = time.perf_counter()
        try:
            R_bw, t_bw, R_gc, t_gc = cv2.calibrateRobotWorldHandEye(
                C[:, :3, :3],
                C[:, :3, 3],
                B[:, :3, :3],
                B[:, :3, 3],
                method=getattr(cv2, f"CALIB_ROBOT_WORLD_HAND_EYE_{name}"),
            )
        except cv2.error as exc:
            out[name] = {"X": None, "Z": None, "error": str(exc.err), "seconds": pnp_s + time.perf_counter() - t0}
            continue
        X, Z = inverse(pose(R_gc, t_gc)), inverse(pose(R_bw, t_bw))
        out[name] = {"X": X.tolist(), "Z": Z.tolist(), "seconds": pnp_s + time.perf_counter() - t0}
    return out


def main() -> None:
    src, dst = sys.argv[1:3]
    with np.load(src) as f:
        obj, K = f["object_points"].astype(np.float64), f["camera_matrix"]
        cases = []
        k = 0
        while f"corners_{k}" in f:
            corners = f[f"corners_{k}"].astype(np.float64)
            if f"counts_{k}" in f:  # each image its own corners of the board
                split = np.cumsum(f[f"counts_{k}"])[:-1]
                points = np.split(f[f"object_points_{k}"].astype(np.float64), split)
                corners = np.split(corners, split)
            else:
                points = [obj] * len(corners)
            cases.append(solve_case(points, K, list(corners), f[f"gripper_{k}"], bool(f[f"eye_in_hand_{k}"])))
            k += 1
    with open(dst, "w") as out:
        json.dump({"opencv": cv2.__version__, "cases": cases}, out)


if __name__ == "__main__":
    main()
