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

from ..dataset import Dataset
from ..errors import InputError
from ..model.profile import Profile
from .csv_format import read_dataset, select_rows

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

    `sources` keeps only those source files (e.g. the poses a tracker also measured). Every problem
    in the files is an InputError naming the file, line and column."""
    folder = Path(folder)
    names = {s.name for s in profile.sensors} | {t.name for t in profile.targets}
    missing = {"camera1", "camera2", "markers1", "markers2"} - names
    if missing:
        raise InputError(f"robot '{profile.name}' has no {', '.join(sorted(missing))}: the camera format needs them")
    joint_cols = {profile.joint(j): c for j, c in profile.data.joint_columns.items()}
    poses: dict[tuple[str, str], np.ndarray] = {}
    for row, number in _rows(folder / "camera_poses.csv", ["source_file", "pose_id", *joint_cols.values()]):
        q = np.zeros(len(profile.joints))
        for j, c in joint_cols.items():
            q[j] = math.radians(number(c))
        poses[(row["source_file"], row["pose_id"])] = q
    per_camera: dict[str, list[tuple[int, int, int, float, float]]] = {"1": [], "2": []}
    pose_index: dict[tuple[str, str], int] = {}
    path = folder / "camera_observations.csv"
    columns = ["source_file", "pose_id", "face_id", "arm", "camera", "u_px", "v_px"]
    for row, number in _rows(path, columns):
        key = (row["source_file"], row["pose_id"])
        if sources is not None and key[0] not in sources:
            continue
        if key not in poses:
            raise number.fail(f"pose {key[1]} of {key[0]} is not in camera_poses.csv", "pose_id")
        camera, arm, face = int(number("camera")), int(number("arm")), int(number("face_id"))
        if str(camera) not in per_camera:
            raise number.fail(f"camera {camera} is not 1 or 2", "camera")
        if arm not in (1, 2):
            raise number.fail(f"arm {arm} is not 1 or 2", "arm")
        if not 1 <= face <= len(profile.targets[profile.target(f"markers{arm}")].points):
            raise number.fail(f"face {face} is not a marker face of the profile", "face_id")
        k = pose_index.setdefault(key, len(pose_index))
        per_camera[str(camera)].append((k, arm, face - 1, number("u_px"), number("v_px")))
    if not pose_index:
        raise InputError("has no observation to calibrate from", file=str(path))
    keys = list(pose_index)
    joints = np.array([poses[k] for k in keys])
    out = {}
    for cam, obs in per_camera.items():
        if not obs:
            continue
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
            source=str(path),
        )
    return out


class _Numbers:
    """Reads a row's numbers; a bad one is an InputError naming the file, the line and the column."""

    def __init__(self, path: Path) -> None:
        self.path, self.row, self.line = path, {}, 0

    def fail(self, message: str, column: str | None = None) -> InputError:
        return InputError(message, file=str(self.path), line=self.line, column=column)

    def __call__(self, column: str) -> float:
        text = (self.row.get(column) or "").strip()
        try:
            value = float(text)
        except ValueError:
            raise self.fail(f"'{text}' is not a number" if text else "is empty", column) from None
        if not math.isfinite(value):
            raise self.fail(f"'{text}' is not a finite number", column)
        return value


def _rows(path: Path, columns: list[str]):
    """(row, number reader) for each data line of a CSV that must have `columns`."""
    if not path.is_file():
        raise InputError("is missing from the data set's folder", file=str(path))
    number = _Numbers(path)
    try:
        with open(path, newline="", encoding="utf-8") as fh:
            reader = csv.DictReader(fh)
            header = reader.fieldnames or []
            for c in columns:
                if c not in header:
                    raise InputError(f"missing column '{c}' in the header", file=str(path), line=1, column=c)
            for row in reader:
                number.row, number.line = row, reader.line_num
                yield row, number
    except (UnicodeDecodeError, csv.Error) as exc:
        raise InputError(f"is not a readable CSV file ({exc.__class__.__name__})", file=str(path)) from None
    except OSError as exc:
        raise InputError(f"cannot be read ({exc.strerror})", file=str(path)) from None
