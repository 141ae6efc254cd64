"""Sessions, their frames and each frame's observations; frame images under DATA/sessions/<id>/images/.

A session belongs to one robot on the desk (its instance name); a frame is checked against that robot's
profile (`profiles`: name -> Profile) before anything is written. Unknown ids raise NotFound.
"""

from __future__ import annotations

import itertools
import json
import math
import secrets
import shutil
import sqlite3
from collections.abc import Callable
from dataclasses import dataclass
from datetime import UTC, datetime
from pathlib import Path

import numpy as np

from calib_core import Dataset, FrameStatus, InputError, Profile

from ..errors import NotFound
from .db import Database, jsonable, now
from .files import encode_jpeg, fsync_dir, write_bytes
from .validation import check_id, check_joints_rad, check_role, check_target

SESSION_SOURCES = ("sample", "import", "capture")

_MEASURED = f"'{FrameStatus.MEASURED}'"  # the status as an SQL literal
MEASURED = ("m0", "m1", "m2", "m3", "m4", "m5")  # an observation's measurement columns (a pose fills six)
_SESSION_QUERY = (
    f"SELECT s.*, COUNT(f.idx) AS n_frames, COALESCE(SUM(f.status = {_MEASURED}), 0) AS n_measured "
    "FROM sessions s LEFT JOIN frames f ON f.session_id = s.id"
)


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
    status: FrameStatus
    reason: str
    images: dict[str, str]  # role -> path relative to the data directory
    detail: dict
    captured: str  # ISO 8601 UTC


@dataclass
class Observations:
    """A frame's observations in internal units (rows of the dataset), of one sensor or several."""

    target: np.ndarray  # (K,)
    vertex: np.ndarray  # (K,)
    point: np.ndarray  # (K, 3), NaN: the target's own point
    measured: np.ndarray  # (K, width): NaN beyond what an observation's sensor measures
    sensor: np.ndarray  # (K,) the sensor of each (its index in the profile)

    @classmethod
    def of(
        cls,
        profile: Profile,
        target: int,
        measured: np.ndarray,
        points: np.ndarray | None = None,
        vertices: np.ndarray | None = None,
        sensor: int | None = None,
    ) -> Observations:
        """One sensor's measurements (default: the data format's) of one target, checked: rows of the sensor's
        measurement size, finite (InputError otherwise). `points` NaN and `vertices` -1 by default."""
        s = profile.data.sensor if sensor is None else sensor
        if not 0 <= s < len(profile.sensors):
            raise InputError(f"sensor {s} is not one of the {len(profile.sensors)} sensors of {profile.name}")
        dim = profile.sensors[s].dim
        m = np.asarray(measured, dtype=float)
        if m.ndim != 2 or m.shape[1] != dim:
            raise InputError(f"{profile.name} measurements are rows of {dim} numbers, not shape {m.shape}")
        if not np.all(np.isfinite(m)):
            raise InputError("measurements must be finite numbers")
        k = len(m)
        p = np.full((k, 3), np.nan) if points is None else np.asarray(points, dtype=float).reshape(k, 3)
        v = np.full(k, -1) if vertices is None else np.asarray(vertices, dtype=int).reshape(k)
        return cls(np.full(k, target), v, p, m, np.full(k, s))

    @classmethod
    def joined(cls, parts: list[Observations]) -> Observations:
        """Several sensors' observations of one frame as one, rows in order; measurements NaN-padded to the
        widest."""
        width = max(o.measured.shape[1] for o in parts)
        measured = [
            np.pad(o.measured, ((0, 0), (0, width - o.measured.shape[1])), constant_values=np.nan) for o in parts
        ]
        return cls(
            np.concatenate([o.target for o in parts]),
            np.concatenate([o.vertex for o in parts]),
            np.concatenate([o.point for o in parts]),
            np.concatenate(measured),
            np.concatenate([o.sensor for o in parts]),
        )

    @classmethod
    def each(cls, data: Dataset) -> list[Observations]:
        """The observations of each configuration of a dataset, in its order (one pass, not one per
        configuration)."""
        order = np.argsort(data.cfg, kind="stable")
        bounds = np.searchsorted(data.cfg[order], np.arange(data.n_configurations + 1))
        runs = [order[a:b] for a, b in itertools.pairwise(bounds)]
        return [cls(data.target[r], data.vertex[r], data.point[r], data.measured[r], data.sensor[r]) for r in runs]


@dataclass
class NewFrame:
    """A frame an importer hands over whole, checked already; `images` are stored files (role -> path)."""

    index: int
    joints_rad: np.ndarray
    target: int
    status: FrameStatus
    reason: str
    images: dict[str, str]
    detail: dict
    observations: Observations | None


class SessionRepository:
    def __init__(self, db: Database, data_dir: Path, profiles: Callable[[str], Profile]) -> None:
        self.db = db
        self.data_dir = data_dir
        self.profile = profiles
        (data_dir / "sessions").mkdir(exist_ok=True)

    # --- sessions -----------------------------------------------------------------------------------
    def create(
        self,
        robot: str,
        name: str,
        *,
        source: str,
        description: str = "",
        truth: dict[str, float] | None = None,
        session_id: str | None = None,
    ) -> str:
        self.profile(robot)
        if source not in SESSION_SOURCES:
            raise InputError(f"unknown session source '{source}' ({', '.join(SESSION_SOURCES)})")
        sid = self.new_id(session_id)
        with self.db.tx() as db:
            _insert_session(db, sid, robot, name, description, source, truth)
        return sid

    def list(self) -> list[SessionInfo]:
        rows = self.db.all(_SESSION_QUERY + " GROUP BY s.id ORDER BY s.created, s.id")
        return [_session_info(r) for r in rows]

    def get(self, session_id: str) -> SessionInfo:
        row = self.db.one(_SESSION_QUERY + " WHERE s.id = ? GROUP BY s.id", (session_id,))
        if row is None:
            raise NotFound.unknown("session", session_id)
        return _session_info(row)

    def exists(self, session_id: str) -> bool:
        return self.db.exists("sessions", session_id)

    def measured(self, session_ids: list[str]) -> dict[str, datetime]:
        """When each session's data were measured: its first frame's capture (sessions without a frame left
        out)."""
        marks = ",".join("?" * len(session_ids))
        rows = self.db.all(
            f"SELECT session_id, MIN(captured) AS t FROM frames WHERE session_id IN ({marks}) GROUP BY session_id",
            list(session_ids),
        )
        return {r["session_id"]: datetime.fromisoformat(r["t"]) for r in rows}

    def delete(self, session_id: str) -> None:
        """Rows first (one transaction), then the images; its calibrations stay, without a session."""
        with self.db.tx() as db:
            if db.execute("DELETE FROM sessions WHERE id = ?", (session_id,)).rowcount == 0:
                raise NotFound.unknown("session", session_id)
        shutil.rmtree(self.folder(session_id), ignore_errors=True)

    def new_id(self, session_id: str | None) -> str:
        """A new random id, or `session_id` checked and free."""
        if session_id is None:
            return "s-" + secrets.token_hex(4)
        check_id("session id", session_id)
        if self.exists(session_id):
            raise InputError(f"a session '{session_id}' exists already")
        return session_id

    def folder(self, session_id: str) -> Path:
        return self.data_dir / "sessions" / session_id

    def add_whole(
        self,
        session_id: str,
        robot: str,
        name: str,
        *,
        description: str,
        source: str,
        truth: dict[str, float] | None,
        frames: list[NewFrame],
        staged: Path | None = None,
        measured: datetime | None = None,
    ) -> None:
        """A whole session in one transaction. `staged`: a folder beside the sessions holding its images,
        renamed into place under the lock before the rows go in (and back, should they fail). `measured`: when
        its frames were captured (None: now)."""
        with self.db.lock:
            final = self.folder(session_id)
            if final.exists() or self.exists(session_id):
                raise InputError(f"a session '{session_id}' exists already")
            if staged is not None:
                staged.rename(final)
            try:
                if staged is not None:
                    fsync_dir(final.parent)
                captured = now() if measured is None else measured.astimezone(UTC).isoformat(timespec="milliseconds")
                with self.db.tx() as db:
                    _insert_session(db, session_id, robot, name, description, source, truth)
                    for f in frames:
                        detail = json.dumps(jsonable(f.detail))
                        q = np.asarray(f.joints_rad, float)
                        _insert_frame(
                            db, session_id, f.index, q, f.target, f.status, f.reason, f.images, detail, captured
                        )
                        if f.observations is not None:
                            _insert_observations(db, session_id, f.index, f.observations)
            except BaseException:
                if staged is not None:
                    final.rename(staged)
                raise

    # --- frames -------------------------------------------------------------------------------------
    def add_frame(
        self,
        session_id: str,
        *,
        index: int | None,
        joints_rad: np.ndarray,
        target: int,
        status: FrameStatus,
        reason: str = "",
        observations: Observations | None = None,
        images: dict[str, np.ndarray] | None = None,
        detail: dict | None = None,
    ) -> int:
        """Store a frame and its observations (`Observations.of`: one sensor's, checked; `Observations.joined`:
        several sensors'); an existing frame with that index is replaced whole.

        index None takes the next free number. Images (role -> uint8 grey or BGR) are encoded outside
        the lock and written under names no row uses yet, so a re-measure never touches the old frame's
        files before its transaction commits; the old files go afterwards.
        """
        profile = self.profile(self.get(session_id).robot)
        q = check_joints_rad(profile, joints_rad)
        target = check_target(profile, target)
        status = FrameStatus.parse(status)
        obs = observations
        if (status == FrameStatus.MEASURED) != (obs is not None and len(obs.measured) > 0):
            raise InputError(f"a frame has measurements exactly when its status is '{FrameStatus.MEASURED}'")
        encoded = {check_role(role): encode_jpeg(img) for role, img in (images or {}).items()}
        detail_json = json.dumps(jsonable(detail or {}))
        written: list[Path] = []
        with self.db.lock:
            try:
                with self.db.tx() as db:
                    if not self.exists(session_id):
                        raise NotFound.unknown("session", session_id)
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
                        write_bytes(self.data_dir / rel, data)
                        written.append(self.data_dir / rel)
                        paths[role] = rel
                    if written:
                        fsync_dir(written[0].parent)
                    db.execute("DELETE FROM frames WHERE session_id = ? AND idx = ?", (session_id, index))
                    _insert_frame(db, session_id, index, q, target, status, reason, paths, detail_json, now())
                    if obs is not None:
                        _insert_observations(db, session_id, index, obs)
            except BaseException:
                for path in written:
                    path.unlink(missing_ok=True)
                raise
        for rel in old_images - set(paths.values()):
            (self.data_dir / rel).unlink(missing_ok=True)
        return index

    def frames(self, session_id: str) -> list[FrameInfo]:
        self.get(session_id)
        rows = self.db.all("SELECT * FROM frames WHERE session_id = ? ORDER BY idx", (session_id,))
        return [_frame_info(r) for r in rows]

    def frame(self, session_id: str, index: int) -> FrameInfo:
        row = self.db.one("SELECT * FROM frames WHERE session_id = ? AND idx = ?", (session_id, int(index)))
        if row is None:
            self.get(session_id)
            raise NotFound(f"session '{session_id}' has no frame {index}")
        return _frame_info(row)

    def dataset(self, session_id: str, profile: Profile) -> Dataset:
        """The measured frames as a calib_core Dataset, equal to what parse_dataset makes of their CSV.

        Like parse_dataset, a frame's joint readings are NaN where none of its observations' chains
        needs them. `lines` is None, `header` and `rows` are empty (no file: calib_core.to_csv writes the
        profile's CSV of it, where every observation is of a sensor that format holds; writing and parsing it at
        every calibration, review and apply took five sixths of reading NAO's sample session: 121 -> 20 ms,
        benchmarks/session_dataset.py). `measured` has the columns of the largest
        sensor's measurement.
        """
        info = self.get(session_id)
        if info.robot != profile.name:
            raise InputError(f"session '{session_id}' is of robot '{info.robot}', not '{profile.name}'")
        with self.db.snapshot() as db:
            frames = db.execute(
                f"SELECT idx, joints_rad FROM frames WHERE session_id = ? AND status = {_MEASURED} "
                "AND EXISTS (SELECT 1 FROM observations o WHERE o.session_id = frames.session_id "
                "AND o.idx = frames.idx) ORDER BY idx",
                (session_id,),
            ).fetchall()
            obs = db.execute(
                "SELECT o.idx, o.target, o.vertex, o.px, o.py, o.pz, o.m0, o.m1, o.m2, o.m3, o.m4, o.m5, o.sensor "
                "FROM observations o "
                "JOIN frames f ON f.session_id = o.session_id AND f.idx = o.idx "
                f"WHERE o.session_id = ? AND f.status = {_MEASURED} ORDER BY o.idx, o.seq",
                (session_id,),
            ).fetchall()
        frame_ids = np.array([r["idx"] for r in frames], dtype=int)
        position = {int(f): k for k, f in enumerate(frame_ids)}
        cfg = np.array([position[r["idx"]] for r in obs], dtype=int)
        target = np.array([r["target"] for r in obs], dtype=int)
        sensor = np.array([profile.data.sensor if r["sensor"] is None else r["sensor"] for r in obs], dtype=int)
        columns = ("px", "py", "pz", *MEASURED)
        values = np.array([[r[c] for c in columns] for r in obs], dtype=float).reshape(-1, len(columns))
        width = max(
            (profile.sensors[s].dim for s in set(sensor.tolist())), default=profile.sensors[profile.data.sensor].dim
        )
        joints = np.array([json.loads(r["joints_rad"]) for r in frames], dtype=float).reshape(-1, len(profile.joints))
        keep = np.zeros(joints.shape, bool)
        for t, s in {(int(t), int(s)) for t, s in zip(target, sensor, strict=True)}:
            rows = cfg[(target == t) & (sensor == s)]
            keep[np.ix_(rows, sorted(profile.joints_between(t, s)))] = True
        return Dataset(
            robot=profile.name,
            frame_ids=frame_ids,
            joints=np.where(keep, joints, np.nan),
            cfg=cfg,
            target=target,
            point=values[:, :3],
            vertex=np.array([r["vertex"] for r in obs], dtype=int),
            measured=values[:, 3 : 3 + width],
            sensor=sensor,
            source=f"session {session_id}",
        )

    def sensor_counts(self, session_id: str) -> dict[int, dict[int, int]]:
        """Per frame index, how many observations each sensor (profile index; None: the data sensor) made."""
        self.get(session_id)
        rows = self.db.all(
            "SELECT idx, sensor, COUNT(*) AS n FROM observations WHERE session_id = ? GROUP BY idx, sensor",
            (session_id,),
        )
        out: dict[int, dict[int, int]] = {}
        for r in rows:
            out.setdefault(int(r["idx"]), {})[r["sensor"]] = int(r["n"])
        return out

    def observation_counts(self, session_id: str) -> dict[int | None, int]:
        """How many observations the session's measured frames hold, per sensor (profile index; None: the
        data sensor): what a calibration of it would read, counted without reading it."""
        self.get(session_id)
        rows = self.db.all(
            "SELECT o.sensor, COUNT(*) AS n FROM observations o JOIN frames f ON f.session_id = o.session_id "
            f"AND f.idx = o.idx WHERE o.session_id = ? AND f.status = {_MEASURED} GROUP BY o.sensor",
            (session_id,),
        )
        return {r["sensor"]: int(r["n"]) for r in rows}

    # --- what the sweep keeps -----------------------------------------------------------------------
    def ids(self) -> set[str]:
        return {r["id"] for r in self.db.all("SELECT id FROM sessions")}

    def image_paths(self) -> set[str]:
        return {p for r in self.db.all("SELECT images FROM frames") for p in json.loads(r["images"]).values()}

    def _free_image_name(self, session_id: str, index: int, role: str, taken: set[str]) -> str:
        rel = f"sessions/{session_id}/images/{index:04d}_{role}.jpg"
        while rel in taken or (self.data_dir / rel).exists():
            rel = f"sessions/{session_id}/images/{index:04d}_{role}_{secrets.token_hex(3)}.jpg"
        return rel


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
        (sid, robot, name, description, now(), source, None if truth is None else json.dumps(jsonable(truth))),
    )


def _insert_frame(
    db: sqlite3.Connection,
    sid: str,
    index: int,
    q: np.ndarray,
    target: int,
    status: FrameStatus,
    reason: str,
    images: dict[str, str],
    detail_json: str,
    captured: str,
) -> None:
    db.execute(
        "INSERT INTO frames VALUES (?, ?, ?, ?, ?, ?, ?, ?, ?)",
        (sid, index, json.dumps(q.tolist()), target, status, reason, json.dumps(images), detail_json, captured),
    )


def _insert_observations(db: sqlite3.Connection, sid: str, index: int, obs: Observations) -> None:
    def opt(v: float) -> float | None:
        return None if math.isnan(v) else float(v)

    rows = []
    for k in range(len(obs.measured)):
        m = [opt(v) for v in obs.measured[k]] + [None] * (len(MEASURED) - obs.measured.shape[1])
        p = [opt(v) for v in obs.point[k]]
        rows.append((sid, index, k, int(obs.target[k]), int(obs.vertex[k]), *p, *m[:3], int(obs.sensor[k]), *m[3:]))
    db.executemany("INSERT INTO observations VALUES (?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?)", rows)


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
        status=FrameStatus(r["status"]),
        reason=r["reason"],
        images=json.loads(r["images"]),
        detail=json.loads(r["detail"]),
        captured=r["captured"],
    )
