"""The registration of an external device: where a laser tracker stands in the robot's base frame, where
a camera sits on the flange or stands in the room, where its board lies: poses nobody knows before the
calibration.

A profile declares one as a frame with `registration: true` (six parameters: x, y, z, yaw, pitch,
roll) carrying a sensor or a target. Every calibration estimates it with the kinematic parameters, one
per set-up; this module gives the solver its starting point (and the "before" figures their meaning: the
nominal model with only the registration fitted). For a point sensor, the closed-form rigid fit of the
predicted points to the measured ones (Kabsch), which for isotropic noise is the least-squares
registration itself; for a pose sensor, the mean of the registrations its poses give (`pose_registration`);
for a camera and its board, the hand-eye equations in closed form refined by least squares
(`camera_registration`).
"""

from __future__ import annotations

import numpy as np

from ..dataset import Dataset
from ..errors import InputError
from ..model.profile import Profile
from .camera_registration import camera_starts, is_camera
from .handeye import zyx_angles
from .pose_registration import pose_registration
from .problem import Problem


def registration_params(
    profile: Profile, sensors: list[int] | None = None, targets: list[int] | None = None
) -> list[int]:
    """The parameters of the registration frames the given sensors (default: the data format's) and targets
    (default: every one) hang from, or [] when none does."""
    frames = [profile.sensors[s].frame for s in ([profile.data.sensor] if sensors is None else sensors)]
    frames += [profile.targets[t].frame for t in (range(len(profile.targets)) if targets is None else targets)]
    out: list[int] = []
    for f in frames:
        for a in profile.chain(f):
            if profile.frames[a].registration:
                out += [op.param for op in profile.frames[a].ops if op.param not in out]
    return out


def register(profile: Profile, data: Dataset, p: np.ndarray) -> np.ndarray:
    """p with each registration the data's sensors and targets hang from set to its least-squares fit to that
    sensor's observations, every other parameter as in p."""
    q = p.copy()
    for s in data.sensors:
        own = data.of_sensor(s)
        targets = np.unique(own.target).tolist()
        if not registration_params(profile, [s], targets):
            continue
        sensor = profile.sensors[s]
        if is_camera(profile, s):
            q = camera_starts(profile, own, q)[0].p
            continue
        params = registration_params(profile, [s], [])
        if sensor.rotation_axes and params and not registration_params(profile, [], targets):
            q[params] = pose_registration(profile, own, q, params)  # a pose sensor: from its poses themselves
            continue
        if sensor.dim != 3 or registration_params(profile, [], targets):
            raise InputError(
                f"sensor '{sensor.name}' or what it sees is on a registration frame, but it measures neither 3-D "
                "points (a tracker), poses nor a board's pixels (a camera)"
            )
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
