"""The registration of an external measuring device: where a laser tracker stands in the robot's
base frame, a pose nobody knows before the calibration.

A profile declares it as a frame with `registration: true` (six parameters: x, y, z, yaw, pitch,
roll) carrying a point sensor. Every calibration estimates it with the kinematic parameters, one per
tracker set-up; this module gives the solver its starting point (and the "before" figures their
meaning: the nominal model with only the registration fitted) by the closed-form rigid fit of the
predicted points to the measured ones (Kabsch), which for a point sensor with isotropic noise is
the least-squares registration itself.
"""

from __future__ import annotations

import numpy as np

from ..dataset import Dataset
from ..errors import InputError
from ..model.profile import Profile
from .pose_registration import pose_registration
from .problem import Problem


def registration_params(profile: Profile, sensors: list[int] | None = None) -> list[int]:
    """The parameters of the registration frames the given sensors (default: the data format's)
    hang from, or [] when none does."""
    out: list[int] = []
    for s in [profile.data.sensor] if sensors is None else sensors:
        frame = profile.frames[profile.sensors[s].frame]
        if frame.registration:
            out += [op.param for op in frame.ops if op.param not in out]
    return out


def register(profile: Profile, data: Dataset, p: np.ndarray) -> np.ndarray:
    """p with each registration the data's sensors hang from set to the least-squares rigid fit of
    the model to that sensor's observations."""
    q = p.copy()
    for s in data.sensors:
        params = registration_params(profile, [s])
        if not params:
            continue
        sensor = profile.sensors[s]
        if sensor.rotation_axes:  # a pose sensor: the registration from its poses themselves
            q[params] = pose_registration(profile, data.of_sensor(s), q, params)
            continue
        if sensor.dim != 3:
            raise InputError(f"sensor '{sensor.name}' is on a registration frame but does not measure 3-D points")
        own = data.of_sensor(s)
        q[params] = 0.0  # the device at the base: its "sensor points" are base-frame points
        base_points = Problem(profile, own, [], q).sensor_points(q)
        R, t = rigid_fit(own.measured[:, :3], base_points)
        yaw, pitch, roll = zyx_angles(R)
        q[params] = [*t, yaw, pitch, roll]
    return q


def rigid_fit(a: np.ndarray, b: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """R, t minimising sum |R a_i + t - b_i|^2 over rotations (Kabsch, without reflection)."""
    if len(a) < 3 or np.linalg.matrix_rank(a - a.mean(axis=0), tol=1e-9) < 2:
        raise InputError(f"{len(a)} measured points do not fix a registration (at least 3 not on one line are needed)")
    ca, cb = a.mean(axis=0), b.mean(axis=0)
    U, _, Vt = np.linalg.svd((a - ca).T @ (b - cb))
    D = np.diag([1.0, 1.0, np.sign(np.linalg.det(Vt.T @ U.T))])
    R = Vt.T @ D @ U.T
    return R, cb - R @ ca


def zyx_angles(R: np.ndarray) -> tuple[float, float, float]:
    """yaw, pitch, roll (rad) with R = Rot_z(yaw) Rot_y(pitch) Rot_x(roll)."""
    pitch = float(np.arcsin(np.clip(-R[2, 0], -1.0, 1.0)))
    yaw = float(np.arctan2(R[1, 0], R[0, 0]))
    roll = float(np.arctan2(R[2, 1], R[2, 2]))
    return yaw, pitch, roll
