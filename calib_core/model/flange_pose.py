"""A robot that is its flange pose: the profile of an arm known only by the pose its controller reports.

Most people who calibrate a camera against an arm hold images and, for each, the flange's pose in the base as the
controller (a UR's TCP pose, a KUKA's $POS_ACT) or ROS TF reported it: no URDF, no joint angles. Here that pose is
the robot's reading, six joints a profile can hold, so that the desk's estimation, identifiability, standard
deviations, noise test, review and apply serve it as any other robot:

    base -> x, y, z (prismatic along the base's axes, mm) -> a fixed reference rotation -> yaw, pitch, roll
    (about z, y, x, deg) -> flange

The reference rotation is the poses' mean orientation, so the three angles (the ZYX Euler angles of the
orientation relative to it) stay far from the pitch of +-90 deg where yaw and roll turn about one axis. The camera
and the board hang from registration frames (no pose given: the desk computes them from the images): eye-in-hand
the camera on the flange and the board on the base, eye-to-hand the other way round.

A controller's pose is not exact: each joint declares its reading's noise (`Joint.noise`, mm and deg), which the
estimation treats as a per-image error shared by that image's corners (calib_core.estimation.readings), so the
corners are not asked to absorb it.
"""

from __future__ import annotations

import math

import numpy as np

from .kinematics import axis_angle
from .profile import Profile

JOINTS = ("x", "y", "z", "yaw", "pitch", "roll")  # the reading: mm, mm, mm, deg, deg, deg
TRANSLATION_JOINTS = JOINTS[:3]
ROTATION_JOINTS = JOINTS[3:]
FLANGE = "flange"
CAMERA_FRAME, BOARD_FRAME = "camera_mount", "board_frame"
SETUPS = ("eye-in-hand", "eye-to-hand")
REACH_MM = 10000.0  # the translations' limits: a reading is where the controller says, not a move we command
VELOCITY = {"mm": 250.0, "deg": 30.0}  # per second: never used to move (nothing drives this robot), as declared


def reference_rotation(rotations: np.ndarray) -> np.ndarray:
    """The mean orientation (3, 3) of rotations (N, 3, 3): the rotation nearest their sum (chordal L2 mean)."""
    U, _, Vt = np.linalg.svd(np.sum(rotations, axis=0))
    return U @ np.diag([1.0, 1.0, np.linalg.det(U @ Vt)]) @ Vt


def profile_reference(profile: Profile) -> np.ndarray:
    """The reference orientation (3, 3) a flange-pose profile reads its angles from (its `reference` frame)."""
    p = profile.nominal()
    yaw, pitch, roll = (float(p[profile.param(f"reference.{k}")]) for k in ("yaw", "pitch", "roll"))
    return axis_angle(np.eye(3)[2], yaw) @ axis_angle(np.eye(3)[1], pitch) @ axis_angle(np.eye(3)[0], roll)


def is_flange_pose(profile: Profile) -> bool:
    """Whether a profile is one `flange_pose_profile` wrote (its joints are the pose's six readings)."""
    names = {f.name for f in profile.frames}
    return tuple(profile.joint_names) == JOINTS and {"reference", FLANGE, CAMERA_FRAME, BOARD_FRAME} <= names


def setup_of(profile: Profile) -> str:
    """eye-in-hand or eye-to-hand: where a flange-pose profile's camera hangs."""
    parent = profile.frames[profile.frame(CAMERA_FRAME)].parent
    return "eye-in-hand" if parent >= 0 and profile.frames[parent].name == FLANGE else "eye-to-hand"


def zyx_angles(R: np.ndarray) -> np.ndarray:
    """(yaw, pitch, roll) rad with R = Rz(yaw) Ry(pitch) Rx(roll), for R (N, 3, 3): (N, 3)."""
    pitch = np.arcsin(np.clip(-R[:, 2, 0], -1.0, 1.0))
    yaw = np.arctan2(R[:, 1, 0], R[:, 0, 0])
    roll = np.arctan2(R[:, 2, 1], R[:, 2, 2])
    return np.stack([yaw, pitch, roll], axis=1)


def readings(flange_in_base: np.ndarray, reference: np.ndarray, length_unit_m: float = 1e-3) -> np.ndarray:
    """The six joints' readings (N, 6) of flange poses (N, 4, 4) m: x, y, z in the profile's length unit
    (`length_unit_m` m each, default mm), then yaw, pitch, roll in deg relative to `reference` (3, 3)."""
    t = flange_in_base[:, :3, 3] / length_unit_m
    angles = np.degrees(zyx_angles(reference.T @ flange_in_base[:, :3, :3]))
    return np.concatenate([t, angles], axis=1)


def flange_pose_profile(
    name: str,
    setup: str,
    *,
    camera_matrix: np.ndarray,
    distortion: np.ndarray,
    image_size: tuple[int, int] | None,
    board: dict,
    reference: np.ndarray,
    pixel_sd: float,
    flange_sd_mm: float,
    flange_sd_deg: float,
    title: str = "",
) -> dict:
    """The profile document (what a profile YAML holds; `compile_profile` reads it) of a robot whose reading is its
    flange pose. `board`: the target's form, `{"grid": {...}, "pattern": "checkerboard"}` or `{"charuco": {...}}`,
    lengths in mm; `reference` (3, 3): the orientation the angles are read from (`reference_rotation`);
    `pixel_sd`: the corners' noise px; `flange_sd_mm`, `flange_sd_deg`: the reported pose's, per axis."""
    if setup not in SETUPS:
        raise ValueError(f"setup {setup!r}: expected eye-in-hand or eye-to-hand")
    yaw, pitch, roll = np.degrees(zyx_angles(reference[None]))[0]
    joints = {
        j: {"type": "prismatic", "lower": -REACH_MM, "upper": REACH_MM, "velocity": VELOCITY["mm"]}
        | {"noise": _sd(flange_sd_mm)}
        for j in TRANSLATION_JOINTS
    }
    joints |= {
        j: {"lower": -90.0 if j == "pitch" else -180.0, "upper": 90.0 if j == "pitch" else 180.0}
        | {"velocity": VELOCITY["deg"], "noise": _sd(flange_sd_deg)}
        for j in ROTATION_JOINTS
    }
    chain = [("base", "flange_x", "x", "tx"), ("flange_x", "flange_y", "y", "ty"), ("flange_y", "flange_z", "z", "tz")]
    frames: list[dict] = [
        {"name": frame, "parent": parent, "joint": joint, "ops": [{op: 0.0, "joint": True, "param": joint}]}
        for parent, frame, joint, op in chain
    ]
    frames.append(
        {
            "name": "reference",
            "parent": "flange_z",
            "ops": [
                {"rz": _deg(yaw), "param": "reference.yaw"},
                {"ry": _deg(pitch), "param": "reference.pitch"},
                {"rx": _deg(roll), "param": "reference.roll"},
            ],
        }
    )
    chain = [("reference", "flange_yaw", "yaw", "rz"), ("flange_yaw", "flange_pitch", "pitch", "ry")]
    chain.append(("flange_pitch", FLANGE, "roll", "rx"))
    frames += [
        {"name": frame, "parent": parent, "joint": joint, "ops": [{op: 0.0, "joint": True, "param": joint}]}
        for parent, frame, joint, op in chain
    ]
    camera_parent, board_parent = (FLANGE, "base") if setup == "eye-in-hand" else ("base", FLANGE)
    frames.append({"name": CAMERA_FRAME, "parent": camera_parent, "registration": True})
    frames.append({"name": BOARD_FRAME, "parent": board_parent, "registration": True})
    K = np.asarray(camera_matrix, float)
    sensor: dict = {
        "name": "cam",
        "frame": CAMERA_FRAME,
        "model": "pinhole",
        "convention": "z-forward",
        "intrinsics": {"fx": float(K[0, 0]), "fy": float(K[1, 1]), "cx": float(K[0, 2]), "cy": float(K[1, 2])},
        "distortion": dict(zip(("k1", "k2", "p1", "p2", "k3"), (float(v) for v in distortion), strict=False)),
        "noise": {"model": "isotropic", "sigma": _sd(pixel_sd)},
    }
    if image_size is not None:
        sensor["image"] = [int(image_size[0]), int(image_size[1])]
    registration = [f"{CAMERA_FRAME}.*", f"{BOARD_FRAME}.*"]
    return {
        "profile": 1,
        "name": name,
        "title": title or f"an arm known by its reported flange pose, {setup}",
        "units": {"length": "mm", "angle": "deg"},
        "base": "base",
        "joints": joints,
        "frames": frames,
        "targets": [{"name": "board", "frame": BOARD_FRAME, **board}],
        "sensors": [sensor],
        "data": {
            "frame_column": "frame",
            "sensor": "cam",
            "target": "board",
            "vertex_column": "vertex",
            "joints": {j: f"{j}_{'mm' if j in TRANSLATION_JOINTS else 'deg'}" for j in JOINTS},
            "measurement": {"columns": ["u", "v"], "unit": "px"},
            "prediction_columns": ["pred_u", "pred_v"],
            "joint_unit": "deg",
            "joint_length_unit": "mm",
        },
        "modes": {
            "handeye": {
                "description": "where the camera and the board are (the reported poses and the lens as given)",
                "free": registration,
            },
            "handeye-lens": {
                "description": "the same, and the camera's intrinsics and distortion with them",
                "free": [*registration, "cam.intrinsics"],
            },
        },
    }


def _sd(value: float) -> float:
    """A standard deviation as the profile states it: 4 significant digits; zero only where asked (readings taken
    as exact), never from an estimate that came out at zero."""
    return 0.0 if value == 0.0 else float(f"{max(value, 1e-6):.4g}")


def _deg(value: float) -> float:
    return float(f"{value:.10g}") if math.isfinite(value) else 0.0


def frame_pose(profile: Profile, p: np.ndarray, frame: str, parent: str) -> np.ndarray:
    """The pose (4, 4) of `frame` in `parent` (its parent frame, or the base), in the profile's length unit, at
    parameters p and zero readings: a registration frame's own pose."""
    from .kinematics import forward

    poses = forward(profile, p, np.zeros((1, len(profile.joints))))
    out = []
    for name in (frame, parent):
        T = np.eye(4)
        if name != "base":
            k = profile.frame(name)
            T[:3, :3], T[:3, 3] = poses.R[k][0], poses.t[k][0]
        out.append(T)
    return np.linalg.inv(out[1]) @ out[0]


def body_rotation_covariance(yaw: float, pitch: float, roll: float, cov_ypr: np.ndarray) -> np.ndarray:
    """The covariance (3, 3) of a small rotation about the frame's own axes (x, y, z), from that of its ZYX angles
    R = Rz(yaw) Ry(pitch) Rx(roll) (rad): the body angular velocity is E d(yaw, pitch, roll)."""
    Rx = axis_angle(np.eye(3)[0], roll)
    Ry = axis_angle(np.eye(3)[1], pitch)
    E = np.column_stack([Rx.T @ Ry.T @ np.eye(3)[2], Rx.T @ np.eye(3)[1], np.eye(3)[0]])
    return E @ cov_ypr @ E.T
