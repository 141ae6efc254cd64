"""FIGAROH's published real data (sample_sessions/figaroh): three robots, their profiles, and the
train/held-out splits the desk is compared with FIGAROH on (benchmarks/peers.py, tests/test_peers.py).

- Every robot: SPLITS random splits by configuration (`holdout_split`, seeds 0 to 9, as `calib solve
  --holdout 0.3 --seed k` makes them), HELD_OUT of the configurations of its file held out of each; the
  held-out figure pools the 10 held-out sets. One split's figure differs from another's by up to a half
  (TALOS), far more than the tools differ by.
- `tiago` also has FIGAROH's own held-out protocol (`session_split`): fit on the 2021-11-30 session (37
  postures), judge on the 2021-11-26 session (62).

A 6-D pose (the UR10e's camera: x, y, z and roll, pitch, yaw, FIGAROH's columns) is read by a pose6d
sensor as it is (`ur10e-pose`), or, as before the desk had one, as 7 points of the measured frame
(`ur10e`): its origin and the points POSE_AXIS_M along each axis both ways. For small errors
dp (position) and dtheta (rotation) the 7 point errors sum to 7 |dp|^2 + 4 a^2 |dtheta|^2 =
7 (|dp|^2 + 0.25 |dtheta|^2) with a = POSE_AXIS_M: least squares on the points weighs orientation
against position exactly as FIGAROH's UR10 example does (1 per m, 0.5 per rad), so both tools fit the
same measurements the same way.
"""

from __future__ import annotations

import csv
import io
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..dataset import Dataset
from ..errors import InputError
from ..estimation.calibrate import calibrate
from ..estimation.problem import Problem
from ..estimation.validation import holdout_split
from ..model.profile import Profile
from ..units import length_factor
from .csv_format import read_dataset

POSE_AXIS_M = math.sqrt(7 / 16)  # 4 a^2 / 7 = 0.5^2: FIGAROH's UR10 weighting (see the module doc)
POSE_COLUMNS = ("x1", "y1", "z1", "phix1", "phiy1", "phiz1")  # m, and roll, pitch, yaw in rad
SPLITS = 10  # random train/held-out splits by configuration, seeds 0-9
HELD_OUT = 0.3  # the share of configurations each split holds out


@dataclass(frozen=True)
class PeerData:
    """One robot's profile and data files in the folder, and its held-out session (FIGAROH's protocol; None: none)."""

    profile: str
    data: str
    heldout: str | None = None
    pose: str | None = None  # the verbatim 6-D pose file `data` was made from (pose_points)


ROBOTS: dict[str, PeerData] = {
    "talos": PeerData("talos.yaml", "talos_left_arm_02_10_contact.csv"),
    "tiago": PeerData(
        "tiago.yaml", "qualisys_2021-11-30_static_postures.csv", "qualisys_2021-11-26_static_postures.csv"
    ),
    "ur10e": PeerData("ur10e.yaml", "ur10_calibration_points.csv", pose="ur10_calibration.csv"),
    "ur10e-pose": PeerData("ur10e-pose.yaml", "ur10_calibration.csv"),  # the same poses, read as poses
}


def rpy_matrix(roll: float, pitch: float, yaw: float) -> np.ndarray:
    """R = Rot_z(yaw) Rot_y(pitch) Rot_x(roll), URDF's and FIGAROH's convention."""
    c, s = np.cos([roll, pitch, yaw]), np.sin([roll, pitch, yaw])
    Rx = np.array([[1, 0, 0], [0, c[0], -s[0]], [0, s[0], c[0]]])
    Ry = np.array([[c[1], 0, s[1]], [0, 1, 0], [-s[1], 0, c[1]]])
    Rz = np.array([[c[2], -s[2], 0], [s[2], c[2], 0], [0, 0, 1]])
    return Rz @ Ry @ Rx


# The 7 points of a pose, in its frame, as multiples of POSE_AXIS_M: the origin, then +x, -x, +y, -y, +z, -z.
POSE_POINTS = np.vstack([np.zeros(3), *[s * e for e in np.eye(3) for s in (1.0, -1.0)]])


def pose_points(text: str, name: str = "<poses>") -> str:
    """A CSV of 6-D poses (POSE_COLUMNS, then joint columns) as the desk's points CSV: `frame` (the pose's
    row, from 1), `point` (0-6, POSE_POINTS), x, y, z in m, then the joint columns unchanged."""
    reader = csv.DictReader(io.StringIO(text))
    header = reader.fieldnames or []
    missing = [c for c in POSE_COLUMNS if c not in header]
    if missing:
        raise InputError(f"missing pose column(s) {', '.join(missing)}", file=name)
    joints = [c for c in header if c not in POSE_COLUMNS]
    out = io.StringIO()
    out.write(",".join(["frame", "point", "x", "y", "z", *joints]) + "\n")
    for number, row in enumerate(reader, start=1):
        values = []
        for c in POSE_COLUMNS:
            try:
                values.append(float(row[c]))
            except (TypeError, ValueError):
                raise InputError(f"expected a number, got {row[c]!r}", file=name, line=number + 1, column=c) from None
        x, y, z, roll, pitch, yaw = values
        points = np.array([x, y, z]) + POSE_AXIS_M * POSE_POINTS @ rpy_matrix(roll, pitch, yaw).T
        for k, point in enumerate(points):
            out.write(
                ",".join([str(number), str(k), *(repr(float(v)) for v in point), *(row[j] for j in joints)]) + "\n"
            )
    return out.getvalue()


def splits(profile: Profile, folder: str | Path, robot: str, sessions: bool = False) -> list[tuple[Dataset, Dataset]]:
    """The (train, held-out) datasets the comparison uses for `robot` (a key of ROBOTS): SPLITS random splits of
    its data file, HELD_OUT of the configurations held out of each, seeds 0 to SPLITS - 1 (the same for every tool
    compared); `sessions`: FIGAROH's protocol instead, its data file against its held-out session (TIAGo)."""
    if robot not in ROBOTS:
        raise InputError(f"unknown robot '{robot}' (known: {', '.join(ROBOTS)})")
    spec = ROBOTS[robot]
    data = read_dataset(profile, Path(folder) / spec.data)
    if sessions:
        if spec.heldout is None:
            raise InputError(f"robot '{robot}' has no held-out session")
        return [(data, read_dataset(profile, Path(folder) / spec.heldout))]
    return [
        (data.select(train), data.select(test))
        for train, test in (holdout_split(data, HELD_OUT, seed) for seed in range(SPLITS))
    ]


@dataclass(frozen=True)
class PoseErrors:
    """Per held-out configuration: the measured point's position error (m), and for a 6-D pose the
    measured frame's rotation error (rad; None for a point)."""

    position_m: np.ndarray  # (N,)
    rotation_rad: np.ndarray | None

    def rms_mm(self) -> float:
        return 1000.0 * float(np.sqrt(np.mean(self.position_m**2)))

    def rms_deg(self) -> float | None:
        return None if self.rotation_rad is None else math.degrees(float(np.sqrt(np.mean(self.rotation_rad**2))))


def pose_errors(profile: Profile, data: Dataset, predicted: np.ndarray) -> PoseErrors:
    """The errors of `predicted` (M, 3) points (or (M, 6) poses), the profile's length unit, against `data`:
    per configuration, its point's (or, for a pose, its origin's) distance and the pose's rotation."""
    to_m = length_factor(profile.length_unit, "m")
    diff = (predicted[:, :3] - data.measured[:, :3]) * to_m
    sensor = profile.sensors[profile.data.sensor]
    if sensor.rotation_axes:  # a pose sensor: its own rotation error
        rotation = sensor.error(predicted[:, : sensor.dim], data.measured[:, : sensor.dim])[:, 3:]
        return PoseErrors(np.linalg.norm(diff, axis=1), np.linalg.norm(rotation, axis=1))
    if np.all(data.vertex < 0):  # one point per configuration
        return PoseErrors(np.linalg.norm(diff, axis=1), None)
    position, rotation = np.zeros(data.n_configurations), np.zeros(data.n_configurations)
    for c in range(data.n_configurations):
        rows = np.flatnonzero(data.cfg == c)
        at = {int(data.vertex[r]): r for r in rows}
        if sorted(at) != list(range(len(POSE_POINTS))):
            raise InputError(f"configuration {int(data.frame_ids[c])} does not hold the 7 points of a pose")
        position[c] = np.linalg.norm(diff[at[0]])
        axes = [
            np.stack([m[at[2 * k + 1]] - m[at[2 * k + 2]] for k in range(3)], axis=1)
            for m in (predicted, data.measured)
        ]
        R_pred, R_meas = (a / np.linalg.norm(a, axis=0) for a in axes)
        cos = (np.trace(R_meas.T @ R_pred) - 1.0) / 2.0
        rotation[c] = math.acos(min(1.0, max(-1.0, cos)))
    return PoseErrors(position, rotation)


def pooled(parts: list[PoseErrors]) -> PoseErrors:
    """The errors of several held-out sets as one."""
    rotations = [e.rotation_rad for e in parts if e.rotation_rad is not None]
    return PoseErrors(
        np.concatenate([e.position_m for e in parts]),
        np.concatenate(rotations) if len(rotations) == len(parts) else None,
    )


def heldout_errors(profile: Profile, folder: str | Path, robot: str, mode: str, sessions: bool = False) -> PoseErrors:
    """The desk's held-out errors in `mode`, pooled over the robot's splits (`splits`)."""
    parts = []
    for train, heldout in splits(profile, folder, robot, sessions):
        p = calibrate(profile, train, mode).params(profile)
        parts.append(pose_errors(profile, heldout, Problem(profile, heldout, [], p, noise_model=False).predict(p)))
    return pooled(parts)
