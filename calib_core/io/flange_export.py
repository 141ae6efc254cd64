"""A desk calibration of a robot known by its flange pose, as `calib handeye` writes its result (specs
handeye-poses.md): so that what the desk estimated goes where a `calib handeye` output goes (`calib export`'s ROS 2
launch file, URDF joint and easy_handeye YAML; calib_core/io/handeye_export.py), with no number copied by hand.

The camera's frame is the profile's pinhole frame, OpenCV's optical frame. The board's frame is the detector's (a
chessboard's first inner corner, x along a row, z out of its face; OpenCV's for a ChArUco board), found as the
rigid transform that carries the board's points from the detector's frame to the profile's grid.
"""

from __future__ import annotations

import math

import numpy as np

from ..errors import InputError
from ..estimation.calibration import Calibration
from ..model.flange_pose import (
    BOARD_FRAME,
    CAMERA_FRAME,
    FLANGE,
    body_rotation_covariance,
    frame_pose,
    is_flange_pose,
    setup_of,
)
from ..model.profile import Profile
from ..sensors.pinhole import Pinhole


def flange_calibration_json(profile: Profile, cal: Calibration) -> dict:
    """The calibration `cal` of a flange-pose robot in `calib handeye`'s output form (lengths mm, the standard
    deviations' angles deg about the frame's own axes), `images` and `heldout` empty (the desk's frames are its
    session's)."""
    if not is_flange_pose(profile):
        raise InputError(f"robot '{profile.name}' is not a robot known by its flange pose: it has no hand-eye form")
    p = cal.params(profile)
    setup = setup_of(profile)
    parents = (FLANGE, "base") if setup == "eye-in-hand" else ("base", FLANGE)
    names = ("camera_in_flange", "board_in_base") if setup == "eye-in-hand" else ("camera_in_base", "board_in_flange")
    cov = None if cal.covariance is None else dict(zip(cal.covariance.parameters, range(10**6), strict=False))
    out: dict = {"setup": setup}
    for name, frame, parent in zip(names, (CAMERA_FRAME, BOARD_FRAME), parents, strict=True):
        T = frame_pose(profile, p, frame, parent)
        if frame == BOARD_FRAME:
            T = T @ _detector_in_grid(profile)
        out[name] = {"matrix": T.tolist(), "unit": "mm", "std": _std(profile, cal, p, frame, cov)}
    sensor = profile.sensors[profile.data.sensor]
    assert isinstance(sensor, Pinhole) and sensor.intrinsics is not None
    fx, fy, cx, cy = (float(p[i]) for i in sensor.intrinsics)
    out["camera"] = {
        "camera_matrix": [[fx, 0.0, cx], [0.0, fy, cy], [0.0, 0.0, 1.0]],
        "distortion": list(sensor.distortion_coefficients(p)[:5]),
    }
    out["images"] = []
    out["heldout"] = {"images": [], "rms_px": None}
    out["desk"] = {"robot": cal.robot, "mode": cal.mode, "created": cal.created}
    return out


def _std(profile: Profile, cal: Calibration, p: np.ndarray, frame: str, cov: dict | None) -> dict[str, float]:
    """x, y, z (mm, along the parent's axes: the registration's own translations) and rx, ry, rz (deg, about the
    frame's own axes) from the calibration's covariance; NaN where it has none."""
    keys = [f"{frame}.{k}" for k in ("x", "y", "z", "yaw", "pitch", "roll")]
    if cov is None or not all(k in cov for k in keys):
        return dict.fromkeys(("x", "y", "z", "rx", "ry", "rz"), math.nan)
    C = np.array(cal.covariance.matrix)[np.ix_([cov[k] for k in keys], [cov[k] for k in keys])]  # display units
    sd = {k: float(math.sqrt(max(C[i, i], 0.0))) for i, k in enumerate("xyz")}
    yaw, pitch, roll = (float(p[profile.param(k)]) for k in keys[3:])
    body = body_rotation_covariance(yaw, pitch, roll, C[3:, 3:] * (math.pi / 180.0) ** 2)
    sd |= {f"r{k}": math.degrees(math.sqrt(max(body[i, i], 0.0))) for i, k in enumerate("xyz")}
    return sd


def _detector_in_grid(profile: Profile) -> np.ndarray:
    """The detector's board frame (4, 4) in the profile's target frame (mm): a ChArUco board's is OpenCV's already;
    a chessboard's inner corners, row by row from the first (x along a row, y down the rows), matched to the
    profile's grid by the rigid transform that carries one onto the other (Kabsch)."""
    target = profile.targets[profile.data.target if profile.data.target is not None else 0]
    grid, shape = target.grid, target.grid_shape
    assert grid is not None and shape is not None
    if target.charuco is not None:
        return np.eye(4)
    rows, cols = shape
    spacing = float(np.linalg.norm(grid[1] - grid[0]))
    row, col = np.divmod(np.arange(rows * cols), cols)
    det = np.stack([col * spacing, row * spacing, np.zeros(rows * cols)], axis=1)
    a, b = det - det.mean(axis=0), grid - grid.mean(axis=0)
    U, _, Vt = np.linalg.svd(a.T @ b)
    R = (U @ np.diag([1.0, 1.0, np.linalg.det(U @ Vt)]) @ Vt).T
    T = np.eye(4)
    T[:3, :3], T[:3, 3] = R, grid.mean(axis=0) - R @ det.mean(axis=0)
    return T
