"""Where a pose sensor stands (an optical tracker, a camera in the room that sees a board on the robot), from
the poses it measured: the start of every calibration that frees its `registration: true` frame.

Each measured pose T_meas of the target in the sensor frame and the model's pose T_model of the target in the
registration frame's parent give the registration T = T_model T_meas^-1; one pose is enough, and with many
the rotation is their chordal mean (the rotation nearest sum R_model R_meas^T) and the position the mean of
p_model - R p_meas. This is the least-squares registration when the model is right and the noise isotropic.
"""

from __future__ import annotations

import numpy as np

from ..dataset import Dataset
from ..model.profile import Profile
from .problem import Problem


def pose_registration(profile: Profile, own: Dataset, p: np.ndarray, params: list[int]) -> np.ndarray:
    """The registration parameters (x, y, z, yaw, pitch, roll; internal units) that best put the model's
    poses of `own`'s targets on its measured ones (one sensor's observations; `params`: its frame's)."""
    from scipy.spatial.transform import Rotation  # here, not at the top: SciPy slows every start

    q = p.copy()
    q[params] = 0.0  # the sensor at its parent's origin: the predicted poses are in the parent's frame
    model = Problem(profile, own, [], q, noise_model=False).predict(q)[:, :6]
    R_model = Rotation.from_rotvec(model[:, 3:]).as_matrix()
    R_meas = Rotation.from_rotvec(own.measured[:, 3:6]).as_matrix()
    U, _, Vt = np.linalg.svd((R_model @ R_meas.transpose(0, 2, 1)).sum(axis=0))
    R = U @ np.diag([1.0, 1.0, np.sign(np.linalg.det(U @ Vt))]) @ Vt
    t = (model[:, :3] - own.measured[:, :3] @ R.T).mean(axis=0)
    yaw, pitch, roll = Rotation.from_matrix(R).as_euler("ZYX")  # R = Rot_z(yaw) Rot_y(pitch) Rot_x(roll)
    return np.array([*t, yaw, pitch, roll])
