"""Readers for the CTU Prague Motoman data set (README in the data set's folder): the Leica tracker
files, split into the subsets that share one tracker set-up and one arm, and the camera pixels
joined with their poses, one dataset per camera.

The folder is the data set as published (ctu-vras/multirobot-calibration, converted to CSV); nothing
here is copied from it. The tracker files are also plain `calib solve --robot motoman` input.
"""

from __future__ import annotations

import csv
import math
from dataclasses import replace
from pathlib import Path

import numpy as np

from .dataset import Dataset, read_dataset, select_rows
from .errors import InputError
from .profile import Profile

# The tracker subsets of the data set's README: (file, filter on its columns) per set-up and arm.
LEICA_SUBSETS: dict[str, tuple[str, dict[str, str]]] = {
    "aug2019-right": ("leica_aug2019_right.csv", {"toolbox_excluded": "0"}),
    "feb2019-A-right": ("leica_feb2019.csv", {"leica_frame_group": "A", "reflector_arm": "right"}),
    "feb2019-left-cube": ("leica_feb2019.csv", {"source_file": "leica_left_hand_6x6x6_dataset.mat"}),
    "feb2019-B-right-cube": ("leica_feb2019.csv", {"leica_frame_group": "B"}),
}


def leica_subset(profile: Profile, folder: str | Path, name: str) -> Dataset:
    """One tracker subset (a key of LEICA_SUBSETS): one set-up, one arm."""
    if name not in LEICA_SUBSETS:
        raise InputError(f"unknown subset '{name}' (known: {', '.join(LEICA_SUBSETS)})")
    file, where = LEICA_SUBSETS[name]
    path = Path(folder) / file
    return replace(select_rows(read_dataset(profile, path), where), source=f"{path} [{name}]")


def camera_profile(profile: Profile, camera: str) -> Profile:
    """The profile with `camera`'s pixels as its data: marker faces (vertex = face - 1) per arm."""
    index = {s.name: i for i, s in enumerate(profile.sensors)}
    if camera not in index:
        raise InputError(f"unknown sensor '{camera}'")
    data = replace(
        profile.data,
        sensor=index[camera],
        target=None,
        target_column="arm",
        target_values={"1": profile.target("markers1"), "2": profile.target("markers2")},
        target_default=None,
        vertex_column="face",
        measurement_columns=("u_px", "v_px"),
        measurement_unit="px",
        prediction_columns=("pred_u_px", "pred_v_px"),
    )
    return replace(profile, data=data)


def camera_datasets(profile: Profile, folder: str | Path, sources: set[str] | None = None) -> dict[str, Dataset]:
    """Per camera ("camera1", "camera2"): every ArUco face centre it saw, with the pose's joints.

    `sources` keeps only those source files (e.g. the poses a tracker also measured)."""
    folder = Path(folder)
    for name in ("camera_poses.csv", "camera_observations.csv"):
        if not (folder / name).is_file():
            raise InputError("is missing from the data set's folder", file=str(folder / name))
    poses: dict[tuple[str, str], np.ndarray] = {}
    joint_cols = {profile.joint(j): c for j, c in profile.data.joint_columns.items()}
    with open(folder / "camera_poses.csv", newline="", encoding="utf-8") as fh:
        for row in csv.DictReader(fh):
            q = np.zeros(len(profile.joints))
            for j, c in joint_cols.items():
                q[j] = math.radians(float(row[c]))
            poses[(row["source_file"], row["pose_id"])] = q
    per_camera: dict[str, list[tuple[int, int, int, float, float]]] = {"1": [], "2": []}
    pose_index: dict[tuple[str, str], int] = {}
    with open(folder / "camera_observations.csv", newline="", encoding="utf-8") as fh:
        for row in csv.DictReader(fh):
            key = (row["source_file"], row["pose_id"])
            if sources is not None and key[0] not in sources:
                continue
            k = pose_index.setdefault(key, len(pose_index))
            per_camera[row["camera"]].append(
                (k, int(row["arm"]), int(row["face_id"]) - 1, float(row["u_px"]), float(row["v_px"]))
            )
    keys = list(pose_index)
    joints = np.array([poses[k] for k in keys])
    out = {}
    for cam, obs in per_camera.items():
        prof = camera_profile(profile, f"camera{cam}")
        arr = np.array(obs)
        used = np.unique(arr[:, 0].astype(int))
        remap = np.full(len(keys), -1)
        remap[used] = np.arange(len(used))
        targets = np.array([prof.target(f"markers{int(a)}") for a in arr[:, 1]])
        vertex = arr[:, 2].astype(int)
        points = np.array([prof.targets[t].points[v] for t, v in zip(targets, vertex, strict=True)])
        out[f"camera{cam}"] = Dataset(
            robot=profile.name,
            frame_ids=used + 1,
            joints=joints[used],
            cfg=remap[arr[:, 0].astype(int)],
            target=targets,
            point=points,
            vertex=vertex,
            measured=arr[:, 3:5],
            source=str(folder / "camera_observations.csv"),
        )
    return out
