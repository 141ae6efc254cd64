"""The dashboard's store: sessions, frames, observations, calibrations, the apply history and jobs.

    DATA/store.sqlite                  the rows (SQLite, WAL, synchronous=FULL, foreign keys)
    DATA/sessions/<id>/images/*.jpg    frame images (JPEG q90)
    DATA/calibrations/<id>.json        calib-calibration/1 files

Crash safety comes from ordering: every file is written whole (temporary name, fsync, rename) before
the transaction that references it commits, and every multi-row change is one transaction. A crash
therefore leaves at most files no row references; the next Store sweeps them away. One connection
serves every thread, behind a lock.
"""

from __future__ import annotations

import csv
import errno
import io
import json
import logging
import math
import os
import re
import secrets
import shutil
import sqlite3
import tempfile
import threading
import time
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from datetime import UTC, datetime
from functools import cache
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from calib_core import Calibration, Dataset, InputError, Profile, load_profile, parse_dataset, to_csv
from calib_core.io.session import read_session
from calib_core.model.loader import BUILTIN_PROFILES

log = logging.getLogger(__name__)

FRAME_STATUSES = ("measured", "not found", "skipped", "pending")
SESSION_SOURCES = ("sample", "import", "capture")
JOB_ACTIVE_STATES = ("queued", "running")
INTERRUPTED = "interrupted by a server restart"
JPEG_QUALITY = 90
SWEEP_AGE_S = 60.0  # leftovers younger than this may be a write in flight: the sweep leaves them
_ID = re.compile(r"[A-Za-z0-9][A-Za-z0-9_.-]{0,63}")
_ROLE = re.compile(r"[a-z][a-z0-9_]{0,31}")
# Why the disk refused a write: by errno (files) and by SQLite result code (the database).
_WRITE_ERRNOS = {
    errno.ENOSPC: "no space left on device",
    errno.EDQUOT: "disk quota exceeded",
    errno.EFBIG: "file too large",
    errno.EROFS: "read-only file system",
    errno.EACCES: "permission denied",
    errno.EPERM: "permission denied",
    errno.EIO: "input/output error",
}
_SQLITE_WRITE_FAILURES = {
    "SQLITE_FULL": "no space left on device",
    "SQLITE_READONLY": "the database is read-only",
    "SQLITE_IOERR": "input/output error",
    "SQLITE_CANTOPEN": "the database cannot be opened",
}

_SCHEMA = """
CREATE TABLE IF NOT EXISTS meta (key TEXT PRIMARY KEY, value TEXT NOT NULL);
CREATE TABLE IF NOT EXISTS sessions (
    id TEXT PRIMARY KEY, robot TEXT NOT NULL, name TEXT NOT NULL, description TEXT NOT NULL,
    created TEXT NOT NULL, source TEXT NOT NULL, truth TEXT);
CREATE TABLE IF NOT EXISTS frames (
    session_id TEXT NOT NULL REFERENCES sessions(id) ON DELETE CASCADE,
    idx INTEGER NOT NULL, joints_rad TEXT NOT NULL, target INTEGER NOT NULL, status TEXT NOT NULL,
    reason TEXT NOT NULL, images TEXT NOT NULL, detail TEXT NOT NULL, captured TEXT NOT NULL,
    PRIMARY KEY (session_id, idx));
CREATE TABLE IF NOT EXISTS observations (
    session_id TEXT NOT NULL, idx INTEGER NOT NULL, seq INTEGER NOT NULL, target INTEGER NOT NULL,
    vertex INTEGER NOT NULL, px REAL, py REAL, pz REAL, m0 REAL NOT NULL, m1 REAL NOT NULL, m2 REAL,
    PRIMARY KEY (session_id, idx, seq),
    FOREIGN KEY (session_id, idx) REFERENCES frames(session_id, idx) ON DELETE CASCADE);
CREATE TABLE IF NOT EXISTS calibrations (
    id TEXT PRIMARY KEY, session_id TEXT REFERENCES sessions(id) ON DELETE SET NULL,
    robot TEXT NOT NULL, mode TEXT NOT NULL, created TEXT NOT NULL,
    base_id TEXT REFERENCES calibrations(id), holdout REAL NOT NULL, path TEXT NOT NULL, figures TEXT NOT NULL);
CREATE TABLE IF NOT EXISTS applies (
    seq INTEGER PRIMARY KEY AUTOINCREMENT, robot TEXT NOT NULL, time TEXT NOT NULL,
    calibration_id TEXT NOT NULL REFERENCES calibrations(id), previous_id TEXT, note TEXT NOT NULL);
CREATE INDEX IF NOT EXISTS applies_robot ON applies (robot, seq);
CREATE TABLE IF NOT EXISTS jobs (
    id TEXT PRIMARY KEY, kind TEXT NOT NULL, state TEXT NOT NULL, session_id TEXT,
    created TEXT NOT NULL, updated TEXT NOT NULL, snapshot TEXT NOT NULL);
"""


class StoreWriteError(OSError):
    """The data directory refused a write (disk full, read-only, no permission). The change it belonged to
    was rolled back and its files removed, so nothing is half-written; the message names no path."""

    def __init__(self, reason: str) -> None:
        super().__init__(f"the data directory cannot be written ({reason})")
        self.reason = reason


@contextmanager
def _writing() -> Iterator[None]:
    """Report the disk refusing a write (an OSError or SQLite error of that kind) as StoreWriteError."""
    try:
        yield
    except (OSError, sqlite3.OperationalError) as exc:
        if isinstance(exc, StoreWriteError):
            raise
        if isinstance(exc, OSError):
            reason = _WRITE_ERRNOS.get(exc.errno or 0)
        else:
            name = getattr(exc, "sqlite_errorname", "") or ""
            reason = next((why for code, why in _SQLITE_WRITE_FAILURES.items() if name.startswith(code)), None)
        if reason is None:
            raise
        raise StoreWriteError(reason) from exc


@dataclass
class SessionInfo:
    id: str
    robot: str
    name: str
    description: str
    created: str  # ISO 8601 UTC
    source: str  # "sample" | "import" | "capture"
    frames: int
    measured: int
    truth: dict[str, float] | None


@dataclass
class FrameInfo:
    session_id: str
    index: int  # frame number, unique in its session
    joints_rad: np.ndarray  # profile.joint_names order
    target: int
    status: str  # "measured" | "not found" | "skipped" | "pending"
    reason: str
    images: dict[str, str]  # role -> path relative to the data directory
    detail: dict
    captured: str  # ISO 8601 UTC


@dataclass
class CalibrationInfo:
    id: str
    session_id: str | None
    robot: str
    mode: str
    created: str
    base_id: str | None
    holdout: float
    path: str  # relative to the data directory
    figures: dict  # Calibration.figures as JSON


@dataclass
class _Observations:
    """A frame's observations in internal units (rows of the dataset)."""

    target: np.ndarray  # (K,)
    vertex: np.ndarray  # (K,)
    point: np.ndarray  # (K, 3), NaN: the target's own point
    measured: np.ndarray  # (K, dim)


class Store:
    def __init__(self, data_dir: Path) -> None:
        self.data_dir = Path(data_dir)
        self.data_dir.mkdir(parents=True, exist_ok=True)
        (self.data_dir / "sessions").mkdir(exist_ok=True)
        (self.data_dir / "calibrations").mkdir(exist_ok=True)
        self._lock = threading.RLock()
        self._db = sqlite3.connect(
            self.data_dir / "store.sqlite", isolation_level=None, check_same_thread=False, timeout=30.0
        )
        self._db.row_factory = sqlite3.Row
        self._db.execute("PRAGMA journal_mode=WAL")
        self._db.execute("PRAGMA synchronous=FULL")
        self._db.execute("PRAGMA foreign_keys=ON")
        self._db.executescript(_SCHEMA)
        self._sweep()

    def close(self) -> None:
        with self._lock:
            self._db.close()

    # --- sessions -----------------------------------------------------------------------------------
    def create_session(
        self,
        robot: str,
        name: str,
        *,
        source: str,
        description: str = "",
        truth: dict[str, float] | None = None,
        session_id: str | None = None,
    ) -> str:
        _profile(robot)
        if source not in SESSION_SOURCES:
            raise InputError(f"unknown session source '{source}' ({', '.join(SESSION_SOURCES)})")
        sid = self._new_session_id(session_id)
        with self._tx() as db:
            self._insert_session(db, sid, robot, name, description, source, truth)
        return sid

    def sessions(self) -> list[SessionInfo]:
        with self._lock:
            rows = self._db.execute(_SESSION_QUERY + " GROUP BY s.id ORDER BY s.created, s.id").fetchall()
        return [_session_info(r) for r in rows]

    def session(self, session_id: str) -> SessionInfo:
        with self._lock:
            row = self._db.execute(_SESSION_QUERY + " WHERE s.id = ? GROUP BY s.id", (session_id,)).fetchone()
        if row is None:
            raise KeyError(f"unknown session '{session_id}'")
        return _session_info(row)

    def delete_session(self, session_id: str) -> None:
        """Rows first (one transaction), then the images; its calibrations stay, without a session."""
        with self._tx() as db:
            if db.execute("DELETE FROM sessions WHERE id = ?", (session_id,)).rowcount == 0:
                raise KeyError(f"unknown session '{session_id}'")
        shutil.rmtree(self._session_dir(session_id), ignore_errors=True)

    # --- frames -------------------------------------------------------------------------------------
    def add_frame(
        self,
        session_id: str,
        *,
        index: int | None,
        joints_rad: np.ndarray,
        target: int,
        status: str,
        reason: str = "",
        measured: np.ndarray | None = None,
        points: np.ndarray | None = None,
        vertices: np.ndarray | None = None,
        images: dict[str, np.ndarray] | None = None,
        detail: dict | None = None,
    ) -> int:
        """Store a frame and its observations; an existing frame with that index is replaced whole.

        index None takes the next free number. Images (role -> uint8 grey or BGR) are encoded outside
        the lock and written under names no row uses yet, so a re-measure never touches the old frame's
        files before its transaction commits; the old files go afterwards.
        """
        robot = self.session(session_id).robot
        profile = _profile(robot)
        q = _joints(profile, joints_rad)
        target = _target(profile, target)
        if status not in FRAME_STATUSES:
            raise InputError(f"unknown frame status '{status}' ({', '.join(FRAME_STATUSES)})")
        obs = None
        if measured is not None:
            obs = _observations(profile, target, measured, points, vertices)
        if (status == "measured") != (obs is not None and len(obs.measured) > 0):
            raise InputError("a frame has measurements exactly when its status is 'measured'")
        encoded = {_role(role): _encode_jpeg(img) for role, img in (images or {}).items()}
        detail_json = json.dumps(jsonable(detail or {}))
        written: list[Path] = []
        with self._lock:
            try:
                with self._tx() as db:
                    if not self._exists("sessions", session_id):
                        raise KeyError(f"unknown session '{session_id}'")
                    if index is None:
                        row = db.execute("SELECT MAX(idx) FROM frames WHERE session_id = ?", (session_id,)).fetchone()
                        index = 1 if row[0] is None else int(row[0]) + 1
                    index = int(index)
                    old = db.execute(
                        "SELECT images FROM frames WHERE session_id = ? AND idx = ?", (session_id, index)
                    ).fetchone()
                    old_images = set(json.loads(old["images"]).values()) if old else set()
                    paths = {}
                    for role, data in encoded.items():
                        rel = self._free_image_name(session_id, index, role, old_images)
                        _write_bytes(self.data_dir / rel, data)
                        written.append(self.data_dir / rel)
                        paths[role] = rel
                    if written:
                        _fsync_dir(written[0].parent)
                    db.execute("DELETE FROM frames WHERE session_id = ? AND idx = ?", (session_id, index))
                    self._insert_frame(db, session_id, index, q, target, status, reason, paths, detail_json, _now())
                    if obs is not None:
                        self._insert_observations(db, session_id, index, obs)
            except BaseException:
                for path in written:
                    path.unlink(missing_ok=True)
                raise
        for rel in old_images - set(paths.values()):
            (self.data_dir / rel).unlink(missing_ok=True)
        return index

    def frames(self, session_id: str) -> list[FrameInfo]:
        self.session(session_id)
        with self._lock:
            rows = self._db.execute("SELECT * FROM frames WHERE session_id = ? ORDER BY idx", (session_id,)).fetchall()
        return [_frame_info(r) for r in rows]

    def frame(self, session_id: str, index: int) -> FrameInfo:
        with self._lock:
            row = self._db.execute(
                "SELECT * FROM frames WHERE session_id = ? AND idx = ?", (session_id, int(index))
            ).fetchone()
        if row is None:
            self.session(session_id)
            raise KeyError(f"session '{session_id}' has no frame {index}")
        return _frame_info(row)

    def dataset(self, session_id: str, profile: Profile) -> Dataset:
        """The measured frames as a calib_core Dataset, equal to what parse_dataset makes of their CSV.

        Like parse_dataset, a frame's joint readings are NaN where none of its observations' chains
        needs them. `lines` is None (no file); `header` and `rows` are the profile's CSV, so that
        calib_core.to_csv and predictions per row work on it.
        """
        info = self.session(session_id)
        if info.robot != profile.name:
            raise InputError(f"session '{session_id}' is of robot '{info.robot}', not '{profile.name}'")
        with self._lock, self._snapshot() as db:
            frames = db.execute(
                "SELECT idx, joints_rad FROM frames WHERE session_id = ? AND status = 'measured' "
                "AND EXISTS (SELECT 1 FROM observations o WHERE o.session_id = frames.session_id "
                "AND o.idx = frames.idx) ORDER BY idx",
                (session_id,),
            ).fetchall()
            obs = db.execute(
                "SELECT o.idx, o.target, o.vertex, o.px, o.py, o.pz, o.m0, o.m1, o.m2 FROM observations o "
                "JOIN frames f ON f.session_id = o.session_id AND f.idx = o.idx "
                "WHERE o.session_id = ? AND f.status = 'measured' ORDER BY o.idx, o.seq",
                (session_id,),
            ).fetchall()
        dim = profile.sensors[profile.data.sensor].dim
        frame_ids = np.array([r["idx"] for r in frames], dtype=int)
        position = {int(f): k for k, f in enumerate(frame_ids)}
        cfg = np.array([position[r["idx"]] for r in obs], dtype=int)
        target = np.array([r["target"] for r in obs], dtype=int)
        values = np.array([[r["px"], r["py"], r["pz"], r["m0"], r["m1"], r["m2"]] for r in obs], dtype=float).reshape(
            -1, 6
        )
        joints = np.array([json.loads(r["joints_rad"]) for r in frames], dtype=float).reshape(-1, len(profile.joints))
        needed = np.zeros((len(profile.targets), len(profile.joints)), bool)
        for t in range(len(profile.targets)):
            needed[t, sorted(profile.joints_between(t, profile.data.sensor))] = True
        keep = np.zeros(joints.shape, bool)
        np.logical_or.at(keep, cfg, needed[target])
        data = Dataset(
            robot=profile.name,
            frame_ids=frame_ids,
            joints=np.where(keep, joints, np.nan),
            cfg=cfg,
            target=target,
            point=values[:, :3],
            vertex=np.array([r["vertex"] for r in obs], dtype=int),
            measured=values[:, 3 : 3 + dim],
            sensor=np.full(len(obs), profile.data.sensor),
            source=f"session {session_id}",
        )
        table = list(csv.reader(io.StringIO(to_csv(profile, data))))
        data.header, data.rows = table[0], table[1:]
        return data

    # --- imports ------------------------------------------------------------------------------------
    def import_session_folder(self, folder: Path, session_id: str | None = None, *, source: str = "import") -> str:
        """A calib-session/1 folder (frames, observations, images copied) as one new session.

        The images are copied into a staging folder beside the sessions; the folder is renamed into
        place and the rows inserted while the lock is held, so a failure leaves nothing behind.
        """
        folder = Path(folder)
        s = read_session(folder)
        profile = _profile(s.robot)
        sid = self._new_session_id(session_id)
        data = s.data
        by_frame: dict[int, _Observations] = {}
        for c, fid in enumerate(data.frame_ids):
            rows = data.cfg == c
            by_frame[int(fid)] = _Observations(
                data.target[rows], data.vertex[rows], data.point[rows], data.measured[rows]
            )
        records = {fr.frame: fr for fr in s.frames}
        if len(records) != len(s.frames):
            raise InputError("session.json lists a frame number twice", file=str(folder / "session.json"))
        missing = sorted(set(by_frame) - set(records))
        if missing:
            raise InputError(f"data.csv has frame {missing[0]}, which session.json does not list", file=str(folder))
        frame_rows = []
        for fr in s.frames:
            where = f"{folder / 'session.json'}"
            if fr.status not in FRAME_STATUSES:
                raise InputError(f"frame {fr.frame}: unknown status '{fr.status}'", file=where)
            q = np.zeros(len(profile.joints))
            for jname, deg in fr.joints_deg.items():
                if jname not in profile.joint_names:
                    raise InputError(f"frame {fr.frame}: unknown joint '{jname}'", file=where)
                q[profile.joint(jname)] = math.radians(float(deg))
            obs = by_frame.get(fr.frame)
            status = fr.status
            if obs is not None:
                c = int(np.flatnonzero(data.frame_ids == fr.frame)[0])
                known = ~np.isnan(data.joints[c])
                q[known] = data.joints[c, known]  # the CSV's readings are the ones the observations used
                status = "measured"
            elif status == "measured":
                raise InputError(f"frame {fr.frame} is 'measured' but data.csv has no row of it", file=where)
            frame_rows.append((fr, q, status, obs))
        targets = _frame_targets(profile, [(q, obs) for _, q, _, obs in frame_rows])

        staging = Path(tempfile.mkdtemp(dir=self.data_dir / "sessions", prefix=f".{sid}."))
        try:
            image_paths = []
            for fr, *_ in frame_rows:
                paths = {}
                for role, rel in fr.images.items():
                    src = folder / rel
                    if not src.resolve().is_relative_to(folder.resolve()) or not src.is_file():
                        raise InputError(f"frame {fr.frame}: no image '{rel}' in the session folder", file=str(folder))
                    name = f"{fr.frame:04d}_{_role(role)}.jpg"
                    raw = src.read_bytes()
                    if not raw.startswith(b"\xff\xd8"):
                        raise InputError(f"frame {fr.frame}: image '{rel}' is not a JPEG file", file=str(folder))
                    _write_bytes(staging / "images" / name, raw, atomic=False)
                    paths[role] = f"sessions/{sid}/images/{name}"
                image_paths.append(paths)
            (staging / "images").mkdir(exist_ok=True)
            _fsync_dir(staging / "images")
            captured = _now()
            with self._lock:
                final = self._session_dir(sid)
                if final.exists() or self._exists("sessions", sid):
                    raise InputError(f"a session '{sid}' exists already")
                staging.rename(final)
                try:
                    _fsync_dir(final.parent)
                    with self._tx() as db:
                        self._insert_session(db, sid, s.robot, s.name, s.description, source, s.truth)
                        for (fr, q, status, obs), paths, target in zip(frame_rows, image_paths, targets, strict=True):
                            detail = json.dumps(jsonable(fr.detail))
                            self._insert_frame(db, sid, fr.frame, q, target, status, fr.reason, paths, detail, captured)
                            if obs is not None:
                                self._insert_observations(db, sid, fr.frame, obs)
                except BaseException:
                    final.rename(staging)
                    raise
        except BaseException:
            shutil.rmtree(staging, ignore_errors=True)
            raise
        return sid

    def import_csv(self, robot: str, name: str, text: str, filename: str) -> str:
        """A session from a CSV in the robot's pinned format; InputError (naming line and column) leaves
        nothing behind, since the rows are inserted only once the whole file has been read."""
        profile = _profile(robot)
        data = parse_dataset(profile, text, filename)
        sid = self._new_session_id(None)
        captured = _now()
        with self._tx() as db:
            self._insert_session(db, sid, robot, name, f"imported from {filename}", "import", None)
            for c, fid in enumerate(data.frame_ids):
                rows = data.cfg == c
                obs = _Observations(data.target[rows], data.vertex[rows], data.point[rows], data.measured[rows])
                q = np.nan_to_num(data.joints[c])
                self._insert_frame(db, sid, int(fid), q, int(obs.target[0]), "measured", "", {}, "{}", captured)
                self._insert_observations(db, sid, int(fid), obs)
        return sid

    def ensure_samples(self, folder: Path) -> list[str]:
        """On a fresh store, import every session folder under `folder` (id = folder name).

        Runs once per store: a sample the operator deleted does not come back. A sample that cannot
        be read is logged and skipped, so a bad sample never stops the server. Returns the new ids.
        """
        with self._lock:
            if self._meta("samples") is not None:
                return []
        if not Path(folder).is_dir():
            return []
        imported = []
        for sub in sorted(Path(folder).iterdir()):
            if not (sub / "session.json").is_file() or self._exists("sessions", sub.name):
                continue
            try:
                imported.append(self.import_session_folder(sub, sub.name, source="sample"))
            except (InputError, OSError) as exc:
                log.warning("sample session %s not imported: %s", sub.name, exc)
        self._set_meta("samples", _now())
        return imported

    # --- calibrations -------------------------------------------------------------------------------
    def add_calibration(self, cal: Calibration, *, session_id: str | None, base_id: str | None, holdout: float) -> str:
        """The JSON file first (atomic), then its row; a failed insert removes the file."""
        cid = "c-" + secrets.token_hex(4)
        rel = f"calibrations/{cid}.json"
        path = self.data_dir / rel
        figures = json.dumps(jsonable({k: v.to_dict() for k, v in cal.figures.items()}))
        try:
            with _writing():
                cal.save(path)
                _fsync_dir(path.parent)
            with self._tx() as db:
                if session_id is not None and not self._exists("sessions", session_id):
                    raise KeyError(f"unknown session '{session_id}'")
                if base_id is not None and not self._exists("calibrations", base_id):
                    raise KeyError(f"unknown calibration '{base_id}'")
                db.execute(
                    "INSERT INTO calibrations VALUES (?, ?, ?, ?, ?, ?, ?, ?, ?)",
                    (
                        cid,
                        session_id,
                        cal.robot,
                        cal.mode,
                        cal.created or _now(),
                        base_id,
                        float(holdout),
                        rel,
                        figures,
                    ),
                )
        except BaseException:
            path.unlink(missing_ok=True)
            raise
        return cid

    def calibration(self, cal_id: str) -> Calibration:
        return Calibration.load(self.data_dir / self.calibration_info(cal_id).path)

    def calibration_info(self, cal_id: str) -> CalibrationInfo:
        with self._lock:
            row = self._db.execute("SELECT * FROM calibrations WHERE id = ?", (cal_id,)).fetchone()
        if row is None:
            raise KeyError(f"unknown calibration '{cal_id}'")
        return _calibration_info(row)

    def calibrations(self, session_id: str | None = None, robot: str | None = None) -> list[CalibrationInfo]:
        """Newest first."""
        sql, args = "SELECT * FROM calibrations WHERE 1", []
        if session_id is not None:
            sql, args = sql + " AND session_id = ?", [*args, session_id]
        if robot is not None:
            sql, args = sql + " AND robot = ?", [*args, robot]
        with self._lock:
            rows = self._db.execute(sql + " ORDER BY rowid DESC", args).fetchall()
        return [_calibration_info(r) for r in rows]

    # --- apply history ------------------------------------------------------------------------------
    def apply(self, robot: str, cal_id: str, note: str = "") -> tuple[str, str | None]:
        """Make `cal_id` the robot's active calibration; returns (active, previous)."""
        with self._tx() as db:
            row = db.execute("SELECT robot FROM calibrations WHERE id = ?", (cal_id,)).fetchone()
            if row is None:
                raise KeyError(f"unknown calibration '{cal_id}'")
            if row["robot"] != robot:
                raise InputError(f"calibration '{cal_id}' is for robot '{row['robot']}', not '{robot}'")
            previous = self._active(db, robot)
            db.execute(
                "INSERT INTO applies (robot, time, calibration_id, previous_id, note) VALUES (?, ?, ?, ?, ?)",
                (robot, _now(), cal_id, previous, note),
            )
        return cal_id, previous

    def active(self, robot: str) -> str | None:
        with self._lock:
            return self._active(self._db, robot)

    def history(self, robot: str) -> list[dict]:
        """Newest first: {seq, time, calibration, previous, mode, session, figures, note}."""
        with self._lock:
            rows = self._db.execute(
                "SELECT a.*, c.mode, c.session_id, c.figures FROM applies a JOIN calibrations c "
                "ON c.id = a.calibration_id WHERE a.robot = ? ORDER BY a.seq DESC",
                (robot,),
            ).fetchall()
        out = []
        for r in rows:
            figs = json.loads(r["figures"])
            out.append(
                {
                    "seq": r["seq"],
                    "time": r["time"],
                    "calibration": r["calibration_id"],
                    "previous": r["previous_id"],
                    "mode": r["mode"],
                    "session": r["session_id"],
                    "figures": {
                        k: {f: figs[k].get(f) for f in ("mean", "rms", "max", "n", "unit")}
                        for k in ("before", "after", "holdout_after")
                        if k in figs
                    },
                    "note": r["note"],
                }
            )
        return out

    # --- jobs ---------------------------------------------------------------------------------------
    def save_job(self, job: dict) -> None:
        """Upsert a job snapshot by its id."""
        snap = json.dumps(jsonable(job))
        with self._tx() as db:
            db.execute(
                "INSERT INTO jobs VALUES (?, ?, ?, ?, ?, ?, ?) ON CONFLICT(id) DO UPDATE SET "
                "kind = excluded.kind, state = excluded.state, session_id = excluded.session_id, "
                "updated = excluded.updated, snapshot = excluded.snapshot",
                (job["id"], job["kind"], job["state"], job.get("session"), job["created"], job["updated"], snap),
            )

    def jobs(self, session_id: str | None = None) -> list[dict]:
        """Newest first."""
        sql, args = "SELECT snapshot FROM jobs", []
        if session_id is not None:
            sql, args = sql + " WHERE session_id = ?", [session_id]
        with self._lock:
            rows = self._db.execute(sql + " ORDER BY created DESC, rowid DESC", args).fetchall()
        return [json.loads(r["snapshot"]) for r in rows]

    def job(self, job_id: str) -> dict:
        with self._lock:
            row = self._db.execute("SELECT snapshot FROM jobs WHERE id = ?", (job_id,)).fetchone()
        if row is None:
            raise KeyError(f"unknown job '{job_id}'")
        return json.loads(row["snapshot"])

    def fail_interrupted_jobs(self) -> int:
        """Jobs a previous server left queued or running: failed, with the reason. Returns how many."""
        with self._tx() as db:
            marks = ",".join("?" * len(JOB_ACTIVE_STATES))
            rows = db.execute(f"SELECT snapshot FROM jobs WHERE state IN ({marks})", JOB_ACTIVE_STATES).fetchall()
            now = _now()
            for r in rows:
                job = json.loads(r["snapshot"])
                job.update(state="failed", error=INTERRUPTED, updated=now, paused=False)
                job["version"] = job.get("version", 0) + 1
                db.execute(
                    "UPDATE jobs SET state = 'failed', updated = ?, snapshot = ? WHERE id = ?",
                    (now, json.dumps(job), job["id"]),
                )
        return len(rows)

    # --- internals ----------------------------------------------------------------------------------
    @contextmanager
    def _tx(self) -> Iterator[sqlite3.Connection]:
        """One write transaction (BEGIN IMMEDIATE ... COMMIT), rolled back on any exception, a failed COMMIT
        included (the disk full); the disk refusing a write in it raises StoreWriteError."""
        with self._lock, _writing():
            self._db.execute("BEGIN IMMEDIATE")
            try:
                yield self._db
                self._db.execute("COMMIT")
            except BaseException:
                if self._db.in_transaction:
                    self._db.execute("ROLLBACK")
                raise

    @contextmanager
    def _snapshot(self) -> Iterator[sqlite3.Connection]:
        """Several reads that see one state of the database."""
        with self._lock:
            self._db.execute("BEGIN")
            try:
                yield self._db
            finally:
                self._db.execute("COMMIT")

    def _exists(self, table: str, key: str) -> bool:
        with self._lock:
            return self._db.execute(f"SELECT 1 FROM {table} WHERE id = ?", (key,)).fetchone() is not None

    def _meta(self, key: str) -> str | None:
        row = self._db.execute("SELECT value FROM meta WHERE key = ?", (key,)).fetchone()
        return None if row is None else row["value"]

    def _set_meta(self, key: str, value: str) -> None:
        with self._tx() as db:
            db.execute("INSERT OR REPLACE INTO meta VALUES (?, ?)", (key, value))

    @staticmethod
    def _active(db: sqlite3.Connection, robot: str) -> str | None:
        row = db.execute(
            "SELECT calibration_id FROM applies WHERE robot = ? ORDER BY seq DESC LIMIT 1", (robot,)
        ).fetchone()
        return None if row is None else row["calibration_id"]

    def _new_session_id(self, session_id: str | None) -> str:
        if session_id is None:
            return "s-" + secrets.token_hex(4)
        if not _ID.fullmatch(session_id):
            raise InputError(
                f"session id '{session_id}' must be 1-64 letters, digits, '_', '.' or '-' (first a letter or digit)"
            )
        if self._exists("sessions", session_id):
            raise InputError(f"a session '{session_id}' exists already")
        return session_id

    def _session_dir(self, session_id: str) -> Path:
        return self.data_dir / "sessions" / session_id

    def _free_image_name(self, session_id: str, index: int, role: str, taken: set[str]) -> str:
        rel = f"sessions/{session_id}/images/{index:04d}_{role}.jpg"
        while rel in taken or (self.data_dir / rel).exists():
            rel = f"sessions/{session_id}/images/{index:04d}_{role}_{secrets.token_hex(3)}.jpg"
        return rel

    @staticmethod
    def _insert_session(
        db: sqlite3.Connection,
        sid: str,
        robot: str,
        name: str,
        description: str,
        source: str,
        truth: dict[str, float] | None,
    ) -> None:
        db.execute(
            "INSERT INTO sessions VALUES (?, ?, ?, ?, ?, ?, ?)",
            (sid, robot, name, description, _now(), source, None if truth is None else json.dumps(jsonable(truth))),
        )

    @staticmethod
    def _insert_frame(
        db: sqlite3.Connection,
        sid: str,
        index: int,
        q: np.ndarray,
        target: int,
        status: str,
        reason: str,
        images: dict[str, str],
        detail_json: str,
        captured: str,
    ) -> None:
        db.execute(
            "INSERT INTO frames VALUES (?, ?, ?, ?, ?, ?, ?, ?, ?)",
            (sid, index, json.dumps(q.tolist()), target, status, reason, json.dumps(images), detail_json, captured),
        )

    @staticmethod
    def _insert_observations(db: sqlite3.Connection, sid: str, index: int, obs: _Observations) -> None:
        def opt(v: float) -> float | None:
            return None if math.isnan(v) else float(v)

        rows = []
        for k in range(len(obs.measured)):
            m = [float(v) for v in obs.measured[k]] + [None] * (3 - obs.measured.shape[1])
            p = [opt(v) for v in obs.point[k]]
            rows.append((sid, index, k, int(obs.target[k]), int(obs.vertex[k]), *p, *m))
        db.executemany("INSERT INTO observations VALUES (?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?)", rows)

    def _sweep(self) -> None:
        """Remove what a crash can leave: temporary files, and files and folders no row references.

        Only what is older than SWEEP_AGE_S goes: younger ones may belong to a write in flight (of
        another Store on the same folder) whose row is not committed yet.
        """
        with self._lock:
            sessions = {r["id"] for r in self._db.execute("SELECT id FROM sessions")}
            images = {
                p for r in self._db.execute("SELECT images FROM frames") for p in json.loads(r["images"]).values()
            }
            cals = {r["path"] for r in self._db.execute("SELECT path FROM calibrations")}
        for d in (self.data_dir / "sessions").iterdir():
            if d.name not in sessions:
                _remove_stale(d)
            elif (d / "images").is_dir():
                for f in (d / "images").iterdir():
                    if f"sessions/{d.name}/images/{f.name}" not in images:
                        _remove_stale(f)
        for f in (self.data_dir / "calibrations").iterdir():
            if f"calibrations/{f.name}" not in cals:
                _remove_stale(f)


_SESSION_QUERY = (
    "SELECT s.*, COUNT(f.idx) AS n_frames, COALESCE(SUM(f.status = 'measured'), 0) AS n_measured "
    "FROM sessions s LEFT JOIN frames f ON f.session_id = s.id"
)


@cache
def _profile(robot: str) -> Profile:
    if robot not in BUILTIN_PROFILES:
        raise InputError(f"unknown robot '{robot}' (known: {', '.join(BUILTIN_PROFILES)})")
    return load_profile(robot)


def _now() -> str:
    return datetime.now(UTC).isoformat(timespec="milliseconds")


def _session_info(r: sqlite3.Row) -> SessionInfo:
    return SessionInfo(
        id=r["id"],
        robot=r["robot"],
        name=r["name"],
        description=r["description"],
        created=r["created"],
        source=r["source"],
        frames=int(r["n_frames"]),
        measured=int(r["n_measured"]),
        truth=None if r["truth"] is None else json.loads(r["truth"]),
    )


def _frame_info(r: sqlite3.Row) -> FrameInfo:
    return FrameInfo(
        session_id=r["session_id"],
        index=int(r["idx"]),
        joints_rad=np.array(json.loads(r["joints_rad"]), dtype=float),
        target=int(r["target"]),
        status=r["status"],
        reason=r["reason"],
        images=json.loads(r["images"]),
        detail=json.loads(r["detail"]),
        captured=r["captured"],
    )


def _calibration_info(r: sqlite3.Row) -> CalibrationInfo:
    return CalibrationInfo(
        id=r["id"],
        session_id=r["session_id"],
        robot=r["robot"],
        mode=r["mode"],
        created=r["created"],
        base_id=r["base_id"],
        holdout=float(r["holdout"]),
        path=r["path"],
        figures=json.loads(r["figures"]),
    )


def _joints(profile: Profile, joints_rad: np.ndarray) -> np.ndarray:
    q = np.asarray(joints_rad, dtype=float).ravel()
    if q.shape != (len(profile.joints),):
        raise InputError(f"a {profile.name} frame has {len(profile.joints)} joint readings, not {q.size}")
    if not np.all(np.isfinite(q)):
        raise InputError("joint readings must be finite numbers")
    return q


def _target(profile: Profile, target: int) -> int:
    if not 0 <= int(target) < len(profile.targets):
        raise InputError(f"target {target} is not one of the {len(profile.targets)} targets of {profile.name}")
    return int(target)


def _observations(
    profile: Profile, target: int, measured: np.ndarray, points: np.ndarray | None, vertices: np.ndarray | None
) -> _Observations:
    dim = profile.sensors[profile.data.sensor].dim
    m = np.asarray(measured, dtype=float)
    if m.ndim != 2 or m.shape[1] != dim:
        raise InputError(f"{profile.name} measurements are rows of {dim} numbers, not shape {m.shape}")
    if not np.all(np.isfinite(m)):
        raise InputError("measurements must be finite numbers")
    k = len(m)
    p = np.full((k, 3), np.nan) if points is None else np.asarray(points, dtype=float).reshape(k, 3)
    v = np.full(k, -1) if vertices is None else np.asarray(vertices, dtype=int).reshape(k)
    return _Observations(np.full(k, target), v, p, m)


def _frame_targets(profile: Profile, frames: list[tuple[np.ndarray, _Observations | None]]) -> list[int]:
    """Each frame's target: that of its observations; for a frame without any (the detector found
    nothing), that of the measured frame with the nearest joint readings (session folders do not
    record it)."""
    if len(profile.targets) == 1:
        return [0] * len(frames)
    known = [(q, int(obs.target[0])) for q, obs in frames if obs is not None]
    out = []
    for q, obs in frames:
        if obs is not None:
            out.append(int(obs.target[0]))
        elif known:
            out.append(min(known, key=lambda qt: float(np.sum((qt[0] - q) ** 2)))[1])
        else:
            out.append(profile.data.target or 0)
    return out


def _role(role: str) -> str:
    if not _ROLE.fullmatch(role):
        raise InputError(f"image role '{role}' must be a short lower-case name (e.g. left, right, image)")
    return role


def _encode_jpeg(image: np.ndarray) -> bytes:
    img = np.asarray(image)
    if img.dtype != np.uint8 or not (img.ndim == 2 or (img.ndim == 3 and img.shape[2] in (1, 3))):
        raise InputError(f"an image must be uint8 grey (H, W) or BGR (H, W, 3), not {img.dtype} {img.shape}")
    ok, buf = cv2.imencode(".jpg", img, [cv2.IMWRITE_JPEG_QUALITY, JPEG_QUALITY])
    if not ok:
        raise InputError(f"the image ({img.shape}) cannot be encoded as JPEG")
    return buf.tobytes()


def _write_bytes(path: Path, data: bytes, *, atomic: bool = True) -> None:
    """Write and fsync; `atomic` writes a temporary name first and renames it into place."""
    path.parent.mkdir(parents=True, exist_ok=True)
    target = path.with_name(f".{path.name}.{secrets.token_hex(3)}.tmp") if atomic else path
    try:
        with open(target, "wb") as fh:
            fh.write(data)
            fh.flush()
            os.fsync(fh.fileno())
        if atomic:
            os.replace(target, path)
    except BaseException:
        target.unlink(missing_ok=True)
        raise


def _remove_stale(path: Path) -> None:
    try:
        if time.time() - path.stat().st_mtime < SWEEP_AGE_S:
            return
    except FileNotFoundError:
        return
    if path.is_dir():
        shutil.rmtree(path, ignore_errors=True)
    else:
        path.unlink(missing_ok=True)


def _fsync_dir(path: Path) -> None:
    """Make renames and new names in `path` durable."""
    fd = os.open(path, os.O_RDONLY)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)


def jsonable(obj: Any) -> Any:
    """JSON-ready: numpy values as Python ones, NaN and infinities as null."""
    if isinstance(obj, dict):
        return {str(k): jsonable(v) for k, v in obj.items()}
    if isinstance(obj, list | tuple):
        return [jsonable(v) for v in obj]
    if isinstance(obj, np.ndarray):
        return jsonable(obj.tolist())
    if isinstance(obj, np.generic):
        return jsonable(obj.item())
    if isinstance(obj, float) and not math.isfinite(obj):
        return None
    return obj
