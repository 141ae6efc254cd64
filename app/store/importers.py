"""Sessions from outside the desk: a calib-session/1 folder, a CSV in the robot's pinned format, the samples.

Each import is read and checked whole before anything is written; the images go to a staging folder
that is renamed into place with the rows inserted in one transaction (SessionRepository.add_whole), so a
failure leaves nothing behind and bad input is an InputError naming file, line and field.
"""

from __future__ import annotations

import logging
import math
import shutil
import tempfile
from collections.abc import Collection
from datetime import UTC, datetime, timedelta
from pathlib import Path
from typing import NamedTuple

import numpy as np

from calib_core import FrameStatus, InputError, Profile, parse_dataset
from calib_core.io import parse_measured, read_session, readings_beyond_limits, session_robot

from ..errors import TooLarge
from . import NewFrame, Observations, Store
from .db import StoreWriteError, now, writing
from .files import fsync_dir, write_bytes
from .validation import check_role

log = logging.getLogger(__name__)


def import_session_folder(
    store: Store,
    folder: Path,
    session_id: str | None = None,
    *,
    source: str = "import",
    robots: Collection[str] | None = None,
) -> str:
    """A calib-session/1 folder (frames, observations, images copied) as one new session; its robot is
    the one the folder names (a built-in profile), which must be one of `robots` (None: any)."""
    folder = Path(folder)
    robot = session_robot(folder)
    if robots is not None and robot not in robots:
        raise InputError(f"robot '{robot}' is not on the desk", file=str(folder / "session.json"))
    try:
        profile = store.sessions.profile(robot)
    except InputError as exc:  # the robot field names no robot of the desk (and never a path to read)
        raise InputError(f"robot: {exc.message}", file=str(folder / "session.json")) from None
    s = read_session(folder, profile)
    sid = store.sessions.new_id(session_id)
    data = s.data
    by_frame = {int(fid): obs for fid, obs in zip(data.frame_ids, Observations.each(data), strict=True)}
    records = {fr.frame: fr for fr in s.frames}
    if len(records) != len(s.frames):
        raise InputError("session.json lists a frame number twice", file=str(folder / "session.json"))
    missing = sorted(set(by_frame) - set(records))
    if missing:
        raise InputError(f"data.csv has frame {missing[0]}, which session.json does not list", file=str(folder))
    frames = []
    for fr in s.frames:
        where = f"{folder / 'session.json'}"
        q = np.zeros(len(profile.joints))
        for jname, value in fr.joints_deg.items():
            if jname not in profile.joint_names:
                raise InputError(f"frame {fr.frame}: unknown joint '{jname}'", file=where)
            j = profile.joint(jname)  # a prismatic joint's reading is a length in the profile's unit
            q[j] = float(value) if profile.joints[j].prismatic else math.radians(float(value))
        obs = by_frame.get(fr.frame)
        status = fr.status
        if obs is not None:
            c = int(np.flatnonzero(data.frame_ids == fr.frame)[0])
            known = ~np.isnan(data.joints[c])
            q[known] = data.joints[c, known]  # the CSV's readings are the ones the observations used
            status = FrameStatus.MEASURED
        elif status == FrameStatus.MEASURED:
            raise InputError(f"frame {fr.frame} is '{status}' but data.csv has no row of it", file=where)
        frames.append(NewFrame(fr.frame, q, 0, status, fr.reason, {}, fr.detail, obs))
    for frame, target in zip(frames, _frame_targets(profile, frames), strict=True):
        frame.target = target

    staging = Path(tempfile.mkdtemp(dir=store.data_dir / "sessions", prefix=f".{sid}."))
    try:
        for fr, frame in zip(s.frames, frames, strict=True):
            for role, rel in fr.images.items():
                src = folder / rel
                if not src.resolve().is_relative_to(folder.resolve()) or not src.is_file():
                    raise InputError(f"frame {fr.frame}: no image '{rel}' in the session folder", file=str(folder))
                name = f"{fr.frame:04d}_{check_role(role)}.jpg"
                raw = src.read_bytes()
                if not raw.startswith(b"\xff\xd8"):
                    raise InputError(f"frame {fr.frame}: image '{rel}' is not a JPEG file", file=str(folder))
                write_bytes(staging / "images" / name, raw, atomic=False)
                frame.images[role] = f"sessions/{sid}/images/{name}"
        (staging / "images").mkdir(exist_ok=True)
        fsync_dir(staging / "images")
        store.sessions.add_whole(
            sid,
            s.robot,
            s.name,
            description=s.description,
            source=source,
            truth=s.truth,
            frames=frames,
            staged=staging,
            measured=s.measured,
        )
    except BaseException:
        shutil.rmtree(staging, ignore_errors=True)
        raise
    return sid


class Imported(NamedTuple):
    id: str
    notes: list[str]  # what the data say that the operator should know (readings beyond a joint's limits)


def csv_text(raw: bytes, filename: str, max_rows: int) -> str:
    """An uploaded CSV as text: UTF-8 (a byte order mark allowed), refused (TooLarge) beyond `max_rows` rows
    before any is parsed."""
    try:
        text = raw.decode("utf-8-sig")
    except UnicodeDecodeError as exc:
        raise InputError(f"{filename}: not UTF-8 text (byte {exc.start})") from None
    rows = text.count("\n") - 1 + (not text.endswith("\n"))  # less the header: at least the rows a parse would read
    if rows > max_rows:
        raise TooLarge(
            f"{filename}: {rows:,} rows; an import takes at most {max_rows:,} (the desk's row limit, --max-rows)"
        )
    return text


def measured_time(text: str | None) -> datetime | None:
    """An import's `measured` field: ISO 8601, not in the future (InputError naming the field); None: not given."""
    if text is None or not text.strip():
        return None
    when = parse_measured(text)
    if when > datetime.now(UTC) + timedelta(hours=1):
        raise InputError(f"measured: {text!r} is in the future")
    return when


def import_csv(
    store: Store, robot: str, name: str, text: str, filename: str, measured: datetime | None = None
) -> Imported:
    """A session from a CSV in the robot's pinned format, measured at `measured` (None: now); InputError (naming
    line and column) leaves nothing behind, since the rows are inserted only once the whole file has been read."""
    profile = store.sessions.profile(robot)
    data = parse_dataset(profile, text, filename)
    sid = store.sessions.new_id(None)
    frames = []
    joints = np.nan_to_num(data.joints)  # joints a row did not need: 0
    for fid, q, obs in zip(data.frame_ids, joints, Observations.each(data), strict=True):
        frames.append(NewFrame(int(fid), q, int(obs.target[0]), FrameStatus.MEASURED, "", {}, {}, obs))
    store.sessions.add_whole(
        sid,
        robot,
        name,
        description=f"imported from {filename}",
        source="import",
        truth=None,
        frames=frames,
        measured=measured,
    )
    return Imported(sid, readings_beyond_limits(profile, data))


def ensure_samples(store: Store, folder: Path, robots: Collection[str] | None = None) -> list[str]:
    """On a fresh store, import every session folder under `folder` (id = folder name) of one of `robots`
    (None: any).

    Runs once per store: a sample the operator deleted does not come back. A sample that cannot
    be read, or of a robot not on the desk, is logged and skipped, so a bad sample never stops the
    server. One the data directory had no room for (disk full, read-only) is tried again at the next
    start: the samples count as done only once none was refused for want of room. Returns the new ids.
    """
    if store.db.meta("samples") is not None or not Path(folder).is_dir():
        return []
    imported = []
    retry = False
    for sub in sorted(Path(folder).iterdir()):
        if not (sub / "session.json").is_file() or store.sessions.exists(sub.name):
            continue
        try:
            with writing():
                imported.append(import_session_folder(store, sub, sub.name, source="sample", robots=robots))
        except StoreWriteError as exc:
            retry = True
            log.warning("sample session %s not imported, tried again at the next start: %s", sub.name, exc)
        except (InputError, OSError) as exc:
            log.warning("sample session %s not imported: %s", sub.name, exc)
    if not retry:
        store.db.set_meta("samples", now())
    return imported


def _frame_targets(profile: Profile, frames: list[NewFrame]) -> list[int]:
    """Each frame's target: that of its observations; for a frame without any (the detector found
    nothing), that of the measured frame with the nearest joint readings (session folders do not
    record it)."""
    if len(profile.targets) == 1:
        return [0] * len(frames)
    known = [(f.joints_rad, int(f.observations.target[0])) for f in frames if f.observations is not None]
    out = []
    for f in frames:
        if f.observations is not None:
            out.append(int(f.observations.target[0]))
        elif known:
            out.append(min(known, key=lambda qt: float(np.sum((qt[0] - f.joints_rad) ** 2)))[1])
        else:
            out.append(profile.data.target or 0)
    return out
