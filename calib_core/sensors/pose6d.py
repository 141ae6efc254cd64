"""A measured 6-D pose: where a tracked rigid body (an optical tracker's marker body on the flange) or a
board (its pose in a camera, from PnP) is, position and orientation, in the sensor's frame.

The measured body is the target's frame, its position the target's point (the frame's origin unless
the target says otherwise). One observation is six numbers: the position x, y, z in the profile's
length unit and the orientation as a rotation vector rx, ry, rz in rad (internally; a CSV may give a
rotation vector in rad or deg, a quaternion or roll, pitch, yaw: `pose_from_columns`).

The residual is the position difference and the rotation vector of R_meas^T R_pred, the rotation that
takes the measured orientation to the predicted one, weighed by the `pose` noise model: `position` (the
length unit, per axis) and `rotation_deg` (deg, per axis of the rotation vector). Its derivatives are
exact: the prediction's by a small rotation of the target frame about the sensor frame's axes (what
the kinematics give), then the right Jacobian of SO(3)'s logarithm at the residual (`error_jacobian`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, ClassVar

import numpy as np
from scipy.spatial.transform import Rotation

from ..errors import InputError
from .base import Sensor, SpecReader

# How a CSV gives a pose's orientation, and how many columns each takes after x, y, z.
ROTATIONS = {"rotvec": 3, "quaternion": 4, "rpy": 3}


@dataclass(frozen=True)
class Pose6D(Sensor):
    kind: ClassVar[str] = "pose6d"
    dim: ClassVar[int] = 6
    axes: ClassVar[tuple[str, ...]] = ("x", "y", "z", "rx", "ry", "rz")
    noise_models: ClassVar[tuple[str, ...]] = ("pose",)
    rotation_axes: ClassVar[int] = 3

    def predict(
        self, p: np.ndarray, x: np.ndarray, *, derivatives: bool = False
    ) -> tuple[np.ndarray, np.ndarray | None, np.ndarray | None]:
        raise InputError(
            f"sensor '{self.name}' measures a pose: its prediction needs the target's orientation, which only "
            "a calibration's problem and a review give (a pose6d sensor is not simulated or planned for)"
        )

    def predict_pose(
        self, p: np.ndarray, x: np.ndarray, rotation: np.ndarray | None, *, derivatives: bool = False
    ) -> tuple[np.ndarray, np.ndarray | None, np.ndarray | None, np.ndarray | None]:
        assert rotation is not None  # rotation_axes asks the problem for it
        h = np.hstack([x, Rotation.from_matrix(rotation).as_rotvec()])
        if not derivatives:
            return h, None, None, None
        n = len(x)
        dh_dx = np.zeros((n, 6, 3))
        dh_dx[:, :3] = np.eye(3)
        dh_drot = np.zeros((n, 6, 3))
        dh_drot[:, 3:] = np.eye(3)  # by the small rotation itself: error_jacobian takes it to the residual
        return h, dh_dx, np.zeros((n, 6, 0)), dh_drot

    def error(self, predicted: np.ndarray, measured: np.ndarray) -> np.ndarray:
        """The position difference and the rotation vector of R_meas^T R_pred (rad); NaN rows where
        nothing was measured."""
        out = predicted[:, :6] - measured[:, :6]
        ok = np.isfinite(out).all(axis=1)
        if ok.any():
            R_pred = Rotation.from_rotvec(predicted[ok, 3:6])
            R_meas = Rotation.from_rotvec(measured[ok, 3:6])
            out[ok, 3:] = (R_meas.inv() * R_pred).as_rotvec()
        return out

    def error_jacobian(self, predicted: np.ndarray, measured: np.ndarray) -> np.ndarray:
        """d(error)/d(prediction): the identity on the position; on the rotation, with R_pred moved to
        exp(d) R_pred, d(log(R_meas^T R_pred)) = Jr^-1(e) R_pred^T d."""
        e = self.error(predicted, measured)[:, 3:]
        R_pred = Rotation.from_rotvec(predicted[:, 3:6]).as_matrix()
        out = np.zeros((len(e), 6, 6))
        out[:, :3, :3] = np.eye(3)
        out[:, 3:, 3:] = right_jacobian_inverse(e) @ R_pred.transpose(0, 2, 1)
        return out

    def covariance(self, p: np.ndarray, measured: np.ndarray) -> np.ndarray:
        rotation_rad = math.radians(self.noise["rotation_deg"])
        diagonal = np.array([self.noise["position"]] * 3 + [rotation_rad] * 3) ** 2
        return np.broadcast_to(np.diag(diagonal), (len(measured), 6, 6))

    def checked_noise(self, noise: Any, where: str) -> dict[str, Any]:
        """The `pose` noise model, the only one a pose takes (its name may be left out)."""
        if isinstance(noise, dict) and "model" not in noise:
            noise = {"model": "pose", **noise}
        elif noise is None:
            noise = {"model": "pose"}
        return super().checked_noise(noise, where)

    def place(self, p: np.ndarray, measured: np.ndarray, x: np.ndarray, normal: np.ndarray) -> np.ndarray:
        """The measured position."""
        return np.array(measured[:, :3], dtype=float)

    @classmethod
    def from_spec(cls, spec: dict, reader: SpecReader, name: str, frame: int, where: str) -> Pose6D:
        sensor = cls(name, frame, reader.length_unit, {})
        return sensor.with_noise(spec.get("noise"), f"{where}.noise")


def right_jacobian_inverse(phi: np.ndarray) -> np.ndarray:
    """Jr^-1 (M, 3, 3) of rotation vectors phi (M, 3): log(exp(phi) exp(d)) = phi + Jr^-1(phi) d + O(d^2)."""
    theta = np.linalg.norm(phi, axis=1)
    K = np.zeros((len(phi), 3, 3))
    K[:, 0, 1], K[:, 0, 2], K[:, 1, 2] = -phi[:, 2], phi[:, 1], -phi[:, 0]
    K[:, 1, 0], K[:, 2, 0], K[:, 2, 1] = phi[:, 2], -phi[:, 1], phi[:, 0]
    small = theta < 1e-4
    t = np.where(small, 1.0, theta)
    with np.errstate(invalid="ignore", divide="ignore"):
        c = np.where(small, 1.0 / 12.0 + theta**2 / 720.0, 1.0 / t**2 - (1 + np.cos(t)) / (2 * t * np.sin(t)))
    return np.eye(3) + 0.5 * K + c[:, None, None] * (K @ K)


def pose_from_columns(values: np.ndarray, rotation: str, angle_factor: float) -> np.ndarray:
    """Poses (M, 6) with a rotation vector in rad from a CSV's columns (M, 3 + ROTATIONS[rotation]):
    x, y, z, then rx, ry, rz (`rotvec`, times `angle_factor` to rad), qx, qy, qz, qw (`quaternion`, any
    norm but zero) or roll, pitch, yaw (`rpy`: R = Rot_z(yaw) Rot_y(pitch) Rot_x(roll), URDF's convention,
    times `angle_factor`). Raises ValueError for a quaternion of norm zero."""
    r = values[:, 3:]
    if rotation == "rotvec":
        rotvec = r * angle_factor
    elif rotation == "quaternion":
        if np.any(np.linalg.norm(r, axis=1) < 1e-12):
            raise ValueError("a quaternion of norm zero is no rotation")
        rotvec = Rotation.from_quat(r).as_rotvec()  # scalar last: qx, qy, qz, qw
    else:
        rotvec = Rotation.from_euler("xyz", r * angle_factor).as_rotvec()  # extrinsic x, y, z: Rz Ry Rx
    return np.hstack([values[:, :3], rotvec])


def pose_to_columns(pose: np.ndarray, rotation: str, angle_factor: float) -> np.ndarray:
    """The CSV's columns of poses (M, 6) with a rotation vector in rad: pose_from_columns undone."""
    R = Rotation.from_rotvec(pose[:, 3:6])
    if rotation == "rotvec":
        r = pose[:, 3:6] / angle_factor
    elif rotation == "quaternion":
        r = R.as_quat()
    else:
        r = R.as_euler("xyz") / angle_factor
    return np.hstack([pose[:, :3], r])
