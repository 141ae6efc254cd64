"""Session folders: a capture session on disk, the form the sample sessions ship in.

    <folder>/session.json   robot, name, description, how it was made, when it was measured (optional,
                            ISO 8601), one record per frame (joint readings in deg, status "measured" /
                            "not found" and why, images)
    <folder>/data.csv       the measured observations in the robot's pinned CSV format
    <folder>/truth.json     (simulated sessions) the hidden true parameters, display units
    <folder>/images/        camera images (JPEG; the detections were made before compression), where kept
    <folder>/profile.yaml   (a robot no built-in profile describes) its profile, e.g. a robot known by its
                            reported flange pose (calib_core.io.flange_session)

A prismatic joint's reading (under "joints_deg" as any joint's) is a length in its profile's length unit.

The CSV is the contract other tools read; session.json adds what the CSV cannot hold: frames whose
detector found nothing, and where each frame's images are.
"""

from __future__ import annotations

import json
import math
import shutil
import tempfile
from dataclasses import dataclass
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

import numpy as np

from ..dataset import Dataset
from ..errors import InputError
from ..files import write_atomic
from ..frame_status import FrameStatus
from ..model.loader import BUILTIN_PROFILES, load_profile
from ..model.profile import Profile
from .csv_format import read_dataset, to_csv
from .observations_csv import parse_observations, to_observations_csv

FORMAT = "calib-session/1"
CARRIED_PROFILE = "profile.yaml"  # a session of a robot no built-in profile describes may carry its own


@dataclass
class FrameRecord:
    frame: int
    joints_deg: dict[str, float]
    status: FrameStatus
    reason: str
    images: dict[str, str]  # role ("left", "right", "image") -> path relative to the session folder
    detail: dict[str, Any]


@dataclass
class SessionFolder:
    folder: Path
    robot: str
    name: str
    description: str
    made_by: str
    frames: list[FrameRecord]
    data: Dataset
    truth: dict[str, float] | None
    measured: datetime | None = None  # when its data were measured (None: not said)


def parse_measured(text: object, field: str = "measured") -> datetime:
    """When data were measured, from ISO 8601 (a date, or a date and time; UTC unless it says its zone);
    InputError naming `field` otherwise."""
    try:
        if not isinstance(text, str):
            raise ValueError
        when = datetime.fromisoformat(text.strip())
    except ValueError:
        raise InputError(
            f"{field}: {text!r} is not a date or time in ISO 8601 (2026-11-02 or 2026-11-02T09:30:00Z)"
        ) from None
    return when.replace(tzinfo=UTC) if when.tzinfo is None else when.astimezone(UTC)


def write_session(
    folder: str | Path,
    profile: Profile,
    *,
    name: str,
    description: str,
    made_by: str,
    data: Dataset,
    frames: list[FrameRecord],
    images: dict[int, dict[str, np.ndarray]] | None = None,
    truth: np.ndarray | None = None,
    measured: datetime | None = None,
    extra: dict[str, str] | None = None,
) -> None:
    """Write a session folder whole: it is built beside the target and moved into place, so a
    crash leaves the old folder or the new one, never half of one. `extra`: more text files (name -> text)."""
    target = Path(folder)
    target.parent.mkdir(parents=True, exist_ok=True)
    work = Path(tempfile.mkdtemp(dir=target.parent, prefix=f".{target.name}."))
    try:
        (work / "images").mkdir()
        records = []
        for fr in frames:
            paths = {}
            for role, img in (images or {}).get(fr.frame, {}).items():
                # JPEG keeps sessions small; the detections were made on the uncompressed images.
                rel = f"images/{fr.frame:04d}_{role}.jpg"
                import cv2  # a session with images only: reading and solving sessions start without OpenCV

                if not cv2.imwrite(str(work / rel), img, [cv2.IMWRITE_JPEG_QUALITY, 90]):
                    raise OSError(f"cannot write {rel}")
                paths[role] = rel
            records.append({**fr.__dict__, "images": paths or fr.images})
        pinned = set(data.sensors) <= csv_sensors(profile)
        meta = {
            "format": FORMAT,
            "robot": profile.name,
            "name": name,
            "description": description,
            "made_by": made_by,
            **({"measured": measured.isoformat()} if measured is not None else {}),
            "data": "data.csv" if pinned else "observations.csv",
            "data_format": "profile" if pinned else "observations",
            "truth": "truth.json" if truth is not None else None,
            "frames": records,
        }
        write_atomic(work / "session.json", json.dumps(meta, indent=1) + "\n")
        text = to_csv(profile, data) if pinned else to_observations_csv(profile, data)
        write_atomic(work / meta["data"], text)
        if truth is not None:
            write_atomic(work / "truth.json", json.dumps(profile.params_to_display(truth), indent=1) + "\n")
        for file_name, text in (extra or {}).items():
            write_atomic(work / file_name, text)
        if target.exists():
            old = target.with_name(f".{target.name}.old")
            shutil.rmtree(old, ignore_errors=True)
            target.rename(old)
            work.rename(target)
            shutil.rmtree(old, ignore_errors=True)
        else:
            work.rename(target)
    except BaseException:
        shutil.rmtree(work, ignore_errors=True)
        raise


def read_session(folder: str | Path, profile: Profile | None = None) -> SessionFolder:
    """A session folder; InputError names the file and the field of any problem. `profile`: the robot
    the folder must be of (a robot of one's own); default the profile the folder carries (`profile.yaml`, a
    robot known by its flange pose: calib_core.io.flange_session), else a built-in one, by the folder's robot
    name."""
    folder = Path(folder)
    meta, meta_path = _meta(folder)
    if profile is None and (folder / CARRIED_PROFILE).is_file():
        profile = load_profile(folder / CARRIED_PROFILE)
    try:
        profile = _profile(meta["robot"], profile)
        if not isinstance(meta["frames"], list):
            raise InputError("frames: expected a list")
        frames = [_frame_record(fr, i) for i, fr in enumerate(meta["frames"])]
        data = _read_data(profile, folder / _text(meta, "data", "data.csv"), meta.get("data_format", "profile"))
        truth = None
        if meta.get("truth"):
            truth = json.loads((folder / _text(meta, "truth")).read_text(encoding="utf-8"))
            if not isinstance(truth, dict) or not all(_finite(v) for v in truth.values()):
                raise InputError(f"{meta['truth']}: expected parameter names with finite numbers")
        measured = parse_measured(meta["measured"]) if meta.get("measured") is not None else None
        return SessionFolder(
            folder,
            profile.name,
            str(meta["name"]),
            str(meta.get("description", "")),
            str(meta.get("made_by", "")),
            frames,
            data,
            truth,
            measured,
        )
    except InputError as exc:
        if exc.file:  # the data file's own error (line, column)
            raise
        raise InputError(exc.message, file=str(meta_path)) from None
    except KeyError as exc:
        raise InputError(f"lacks the field {exc}", file=str(meta_path)) from None
    except (TypeError, json.JSONDecodeError, OSError) as exc:
        raise InputError(f"is malformed ({exc})", file=str(meta_path)) from None


def session_robot(folder: str | Path) -> str:
    """The name of the robot a session folder is of (to pick its profile before reading the folder)."""
    meta, meta_path = _meta(Path(folder))
    robot = meta.get("robot")
    if not isinstance(robot, str) or not robot:
        raise InputError(f"robot: expected a robot's name, got {robot!r}", file=str(meta_path))
    return robot


def _meta(folder: Path) -> tuple[dict, Path]:
    """session.json of a folder, checked to be one."""
    meta_path = folder / "session.json"
    try:
        meta = json.loads(meta_path.read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise InputError("session.json is missing: not a session folder", file=str(folder)) from None
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise InputError(f"cannot be read ({exc})", file=str(meta_path)) from None
    if not isinstance(meta, dict) or meta.get("format") != FORMAT:
        raise InputError(f"not a session file (format is not {FORMAT!r})", file=str(meta_path))
    return meta, meta_path


def csv_sensors(profile: Profile) -> set[int]:
    """The sensors the profile's pinned CSV format holds observations of."""
    fmt = profile.data
    return set(fmt.sensor_values.values()) if fmt.sensor_column else {fmt.sensor}


def _profile(robot: Any, profile: Profile | None) -> Profile:
    if profile is not None:
        if robot != profile.name:
            raise InputError(f"robot: the session is of robot {robot!r}, not {profile.name!r}")
        return profile
    if robot not in BUILTIN_PROFILES:  # a name, never a path to read a profile from
        raise InputError(f"robot: unknown robot {robot!r} (known: {', '.join(BUILTIN_PROFILES)})")
    return load_profile(robot)


def _read_data(profile: Profile, path: Path, data_format: Any) -> Dataset:
    """The measured observations: the profile's pinned CSV format, or the observations format."""
    if data_format == "profile":
        return read_dataset(profile, path)
    if data_format != "observations":
        raise InputError(f"data_format: {data_format!r} is not 'profile' or 'observations'")
    try:
        text = path.read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as exc:
        raise InputError(f"cannot be read ({exc.__class__.__name__})", file=str(path)) from None
    return parse_observations(profile, text, str(path))


def _finite(value: Any) -> bool:
    return isinstance(value, int | float) and not isinstance(value, bool) and math.isfinite(value)


def _text(meta: dict, key: str, default: str | None = None) -> str:
    value = meta.get(key, default)
    if not isinstance(value, str) or not value:
        raise InputError(f"{key}: expected a file name, got {value!r}")
    return value


def _frame_record(fr: Any, i: int) -> FrameRecord:
    """One frame of session.json, every field of its type: what the importer relies on."""
    where = f"frames[{i}]"
    if not isinstance(fr, dict):
        raise InputError(f"{where}: expected an object")
    fields = ("frame", "joints_deg", "status", "reason", "images", "detail")
    missing, unknown = [k for k in fields if k not in fr], sorted(set(fr) - set(fields))
    if missing or unknown:
        raise InputError(
            f"{where}: " + (f"lacks the field '{missing[0]}'" if missing else f"unknown field '{unknown[0]}'")
        )
    frame, joints, images = fr["frame"], fr["joints_deg"], fr["images"]
    if not isinstance(frame, int) or isinstance(frame, bool) or not -(2**63) <= frame < 2**63:
        raise InputError(f"{where}.frame: expected a whole number, got {frame!r}")
    if not isinstance(joints, dict) or not all(isinstance(k, str) and _finite(v) for k, v in joints.items()):
        raise InputError(f"{where}.joints_deg: expected joint names with finite angles in deg")
    status = FrameStatus.parse(fr["status"], f"{where}.status")
    if not isinstance(fr["reason"], str):
        raise InputError(f"{where}.reason: expected text, got {fr['reason']!r}")
    if not isinstance(images, dict) or not all(isinstance(k, str) and isinstance(v, str) for k, v in images.items()):
        raise InputError(f"{where}.images: expected image roles with file names")
    if not isinstance(fr["detail"], dict):
        raise InputError(f"{where}.detail: expected an object")
    joints_deg = {k: float(v) for k, v in joints.items()}
    return FrameRecord(frame, joints_deg, status, fr["reason"], images, fr["detail"])
