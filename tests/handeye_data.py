"""Shared by the hand-eye tests and benchmarks/handeye.py: the two set-ups of tests/profiles (a camera on the
sample arm's flange and a board on the table, or a camera in the room and a board on the flange), seeded data
with and without joint offsets, and the figures they are judged by against simulator truth (held-out pixels,
where the camera is)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from calib_core import SimulatedRobot
from calib_core.estimation.problem import Problem
from calib_core.model.kinematics import forward
from calib_core.model.profile import Profile
from calib_core.sim.simulator import Simulation

PROFILES = Path(__file__).resolve().parent / "profiles"
SETUPS = ("handeye-in-hand", "handeye-to-hand")
# Joint offsets of the simulated arm (deg) for the runs "with offsets": 0.2-0.5 deg on every joint.
OFFSETS_DEG = {
    "shoulder_pan": 0.2,
    "shoulder_lift": 0.3,
    "elbow": -0.25,
    "wrist_1": 0.4,
    "wrist_2": -0.3,
    "wrist_3": 0.5,
}
POSE_NAMES = ("x", "y", "z", "yaw", "pitch", "roll")
HELD_OUT = 30  # configurations each calibration is judged on


def truth(profile: Profile, offsets: bool) -> np.ndarray:
    """The simulated arm: the profile's `simulation.truth`, with OFFSETS_DEG on its joints when `offsets`."""
    p = profile.true_params()
    return profile.params_from_display(OFFSETS_DEG, p) if offsets else p


def seeded_data(profile: Profile, seed: int, offsets: bool, poses: int) -> tuple[Simulation, Simulation]:
    """`poses` configurations to calibrate from and HELD_OUT new ones of the same simulated arm."""
    robot = SimulatedRobot.from_profile(profile, seed=seed, truth=truth(profile, offsets))
    return robot.simulate(poses), robot.simulate(HELD_OUT)


def rms_px(profile: Profile, data, p: np.ndarray) -> float:
    """RMS over the corners of the distance (px) between what parameters p predict and what was measured."""
    pred = Problem(profile, data, [], p, noise_model=False).predict(p)
    return float(np.sqrt(np.mean(np.sum((pred[:, :2] - data.measured[:, :2]) ** 2, axis=1))))


def mount_error(profile: Profile, p: np.ndarray, truth: np.ndarray) -> tuple[float, float]:
    """How far the camera's estimated registration (x, y, z, yaw, pitch, roll) is from the truth: mm, deg."""
    idx = [profile.param(f"camera_mount.{k}") for k in POSE_NAMES]

    def rotation(v):
        return Rotation.from_euler("ZYX", v[idx[3:]])

    angle = (rotation(p) * rotation(truth).inv()).magnitude()
    return float(np.linalg.norm(p[idx[:3]] - truth[idx[:3]])), float(np.degrees(angle))


def camera_error(profile: Profile, p: np.ndarray, truth: np.ndarray, q: np.ndarray) -> tuple[float, float]:
    """How far the model puts the camera from where it is, seen from the board, at configurations q: RMS mm, largest
    deg. A joint offset the data cannot see (the first and last axes) moves the registration it is absorbed in, not
    this."""
    sensor, target = profile.sensors[profile.data.sensor].frame, profile.targets[0].frame

    def in_board(v):
        poses = forward(profile, v, q, frames=[sensor, target])
        R = poses.R[target].transpose(0, 2, 1) @ poses.R[sensor]
        return R, (poses.R[target].transpose(0, 2, 1) @ (poses.t[sensor] - poses.t[target])[:, :, None])[:, :, 0]

    (R, t), (R0, t0) = in_board(p), in_board(truth)
    angle = Rotation.from_matrix(R @ R0.transpose(0, 2, 1)).magnitude()
    return float(np.sqrt(np.mean(np.sum((t - t0) ** 2, axis=1)))), float(np.degrees(angle.max()))
