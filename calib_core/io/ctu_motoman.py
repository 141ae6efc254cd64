"""Readers for the CTU Prague Motoman data set (README in the data set's folder): the Leica tracker
files, split into the subsets that share one tracker set-up and one arm, and the camera pixels
joined with their poses, one dataset of both cameras.

The folder is the data set as published (ctu-vras/multirobot-calibration, converted to CSV); nothing
here is copied from it. The tracker files are also plain `calib solve --robot motoman` input.
"""

from __future__ import annotations

import csv
import math
from dataclasses import replace
from pathlib import Path

import numpy as np

from ..dataset import Dataset, merge
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


def camera_dataset(profile: Profile, folder: str | Path, sources: set[str] | None = None) -> Dataset:
    """Every ArUco face centre each camera ("camera1", "camera2") saw, with the pose's joints: one
    configuration per pose (frame id = the pose's row in camera_poses.csv, from 1).

    `sources` keeps only those source files (e.g. the poses a tracker also measured). Every problem
    in the files is an InputError naming the file, line and column."""
    folder = Path(folder)
    names = {s.name for s in profile.sensors} | {t.name for t in profile.targets}
    missing = {"camera1", "camera2", "markers1", "markers2"} - names
    if missing:
        raise InputError(f"robot '{profile.name}' has no {', '.join(sorted(missing))}: the camera format needs them")
    sensor_of = {str(k): [s.name for s in profile.sensors].index(f"camera{k}") for k in (1, 2)}
    poses = _poses(profile, folder / "camera_poses.csv")
    pose_index: dict[tuple[str, str], int] = {}
    obs: list[tuple[int, int, int, int, float, float]] = []  # pose, sensor, target, vertex, u, v
    path = folder / "camera_observations.csv"
    columns = ["source_file", "pose_id", "face_id", "arm", "camera", "u_px", "v_px"]
    for row, number in _rows(path, columns):
        key = (row["source_file"], row["pose_id"])
        if sources is not None and key[0] not in sources:
            continue
        if key not in poses:
            raise number.fail(f"pose {key[1]} of {key[0]} is not in camera_poses.csv", "pose_id")
        camera, arm, face = int(number("camera")), int(number("arm")), int(number("face_id"))
        if str(camera) not in sensor_of:
            raise number.fail(f"camera {camera} is not 1 or 2", "camera")
        if arm not in (1, 2):
            raise number.fail(f"arm {arm} is not 1 or 2", "arm")
        target = profile.target(f"markers{arm}")
        if not 1 <= face <= len(profile.targets[target].points):
            raise number.fail(f"face {face} is not a marker face of the profile", "face_id")
        k = pose_index.setdefault(key, len(pose_index))
        obs.append((k, sensor_of[str(camera)], target, face - 1, number("u_px"), number("v_px")))
    if not pose_index:
        raise InputError("has no observation to calibrate from", file=str(path))
    arr = np.array(obs)
    order = np.argsort(arr[:, 0], kind="stable")  # a pose's observations together
    arr = arr[order]
    target, vertex = arr[:, 2].astype(int), arr[:, 3].astype(int)
    return Dataset(
        robot=profile.name,
        frame_ids=np.array([poses[k][0] for k in pose_index]),
        joints=np.array([poses[k][1] for k in pose_index]),
        cfg=arr[:, 0].astype(int),
        target=target,
        point=np.array([profile.targets[t].points[v] for t, v in zip(target, vertex, strict=True)]),
        vertex=vertex,
        measured=arr[:, 4:6],
        sensor=arr[:, 1].astype(int),
        source=str(path),
    )


def _poses(profile: Profile, path: Path) -> dict[tuple[str, str], tuple[int, np.ndarray]]:
    """(source file, pose id) -> the pose's row in camera_poses.csv (from 1) and its joint readings (rad)."""
    joint_cols = {profile.joint(j): c for j, c in profile.data.joint_columns.items()}
    poses = {}
    for row, number in _rows(path, ["source_file", "pose_id", *joint_cols.values()]):
        q = np.zeros(len(profile.joints))
        for j, c in joint_cols.items():
            q[j] = math.radians(number(c))
        poses[(row["source_file"], row["pose_id"])] = (len(poses) + 1, q)
    return poses


def recording(profile: Profile, folder: str | Path, source: str) -> Dataset:
    """One recording of the Feb 2019 session (a source file: one tracker set-up, one arm) as one
    dataset of three sensors: per pose, the tracker's reading of the reflector (where it has one)
    and both cameras' face centres; frame id = the pose's row in camera_poses.csv."""
    folder = Path(folder)
    poses = _poses(profile, folder / "camera_poses.csv")
    tracker = read_dataset(profile, folder / "leica_feb2019.csv")
    column = {h: i for i, h in enumerate(tracker.header)}
    if "pose_id" not in column or "source_file" not in column:
        raise InputError("needs the columns source_file and pose_id", file=str(folder / "leica_feb2019.csv"))
    tracker = select_rows(tracker, {"source_file": source})
    frame_of = []
    for c in range(tracker.n_configurations):
        row = tracker.rows[int(np.flatnonzero(tracker.cfg == c)[0])]
        key = (source, row[column["pose_id"]].strip())
        if key not in poses:
            raise InputError(f"pose {key[1]} of {source} is not in camera_poses.csv", file=tracker.source)
        frame_of.append(poses[key][0])
    tracker = replace(tracker, frame_ids=np.array(frame_of), header=[], rows=[], lines=None)
    return merge([tracker, camera_dataset(profile, folder, {source})])


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
