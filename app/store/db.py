"""The store's SQLite layer: one connection, its transactions, the schema and its migrations, write errors.

One connection serves every thread, behind a lock (WAL, synchronous=FULL, foreign keys). Every multi-row
change is one transaction (`tx`), and a disk that refuses a write (full, read-only, no permission) raises
StoreWriteError with the reason and no path, after the transaction was rolled back.

The schema has a version (`meta.schema`). A store made before versions were recorded is version 1;
`migrate` brings an older store up to SCHEMA_VERSION in place, one step per version, each in one
transaction, so the rows already there stay as they are.
"""

from __future__ import annotations

import errno
import math
import sqlite3
import threading
from collections.abc import Iterator
from contextlib import contextmanager
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

import numpy as np

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

# Version 1: what the first dashboard made (no version recorded).
_SCHEMA_V1 = """
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

# Version 2: the robots on the desk as instances (name, profile, driver), so that a robot added while the
# desk runs is there after a restart. Sessions, calibrations and applies name the instance, as they did
# the built-in robot (whose instance is named after its profile), so their rows need no change.
_SCHEMA_V2 = """
CREATE TABLE IF NOT EXISTS robots (
    name TEXT PRIMARY KEY, profile TEXT NOT NULL, driver TEXT, options TEXT NOT NULL,
    origin TEXT NOT NULL, added TEXT NOT NULL);
"""

# Version 3: observations of several sensors in one session (the Motoman's tracker and two cameras looking at
# one pose): each row says its sensor (NULL in rows of before: the robot's data-format sensor, the only one
# sessions had), and a measurement of one number (a plane's distance) leaves m1 empty. SQLite cannot drop a
# NOT NULL, so the table is rebuilt, its rows copied as they are.
_SCHEMA_V3 = """
CREATE TABLE observations_v3 (
    session_id TEXT NOT NULL, idx INTEGER NOT NULL, seq INTEGER NOT NULL, target INTEGER NOT NULL,
    vertex INTEGER NOT NULL, px REAL, py REAL, pz REAL, m0 REAL NOT NULL, m1 REAL, m2 REAL, sensor INTEGER,
    PRIMARY KEY (session_id, idx, seq),
    FOREIGN KEY (session_id, idx) REFERENCES frames(session_id, idx) ON DELETE CASCADE);
INSERT INTO observations_v3 SELECT session_id, idx, seq, target, vertex, px, py, pz, m0, m1, m2, NULL FROM observations;
DROP TABLE observations;
ALTER TABLE observations_v3 RENAME TO observations;
"""

# Version 4: a measurement of six numbers (a 6-D pose: position, rotation vector in rad) fills m3, m4, m5 too;
# the rows of before measured at most three and keep them NULL.
_SCHEMA_V4 = """
ALTER TABLE observations ADD COLUMN m3 REAL;
ALTER TABLE observations ADD COLUMN m4 REAL;
ALTER TABLE observations ADD COLUMN m5 REAL;
"""

MIGRATIONS = {
    1: _SCHEMA_V1,
    2: _SCHEMA_V2,
    3: _SCHEMA_V3,
    4: _SCHEMA_V4,
}  # version -> what brings the version before it there
SCHEMA_VERSION = max(MIGRATIONS)


class StoreWriteError(OSError):
    """The data directory refused a write (disk full, read-only, no permission). The change it belonged to
    was rolled back and its files removed, so nothing is half-written; the message names no path."""

    def __init__(self, reason: str) -> None:
        super().__init__(f"the data directory cannot be written ({reason})")
        self.reason = reason


@contextmanager
def writing() -> Iterator[None]:
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


class Database:
    """The connection, its lock and its transactions."""

    def __init__(self, path: Path) -> None:
        self.lock = threading.RLock()
        self._db = sqlite3.connect(path, isolation_level=None, check_same_thread=False, timeout=30.0)
        self._db.row_factory = sqlite3.Row
        self._db.execute("PRAGMA journal_mode=WAL")
        self._db.execute("PRAGMA synchronous=FULL")
        self._db.execute("PRAGMA foreign_keys=ON")
        self.migrate()

    def close(self) -> None:
        with self.lock:
            self._db.close()

    @property
    def version(self) -> int:
        with self.lock:
            if not self._db.execute("SELECT 1 FROM sqlite_master WHERE name = 'meta'").fetchone():
                return 0
            row = self._db.execute("SELECT value FROM meta WHERE key = 'schema'").fetchone()
            if row is not None:
                return int(row["value"])
            has_sessions = self._db.execute("SELECT 1 FROM sqlite_master WHERE name = 'sessions'").fetchone()
            return 1 if has_sessions else 0

    def migrate(self) -> None:
        """Bring the schema to SCHEMA_VERSION, each step one transaction that also records its version."""
        with self.lock:
            for version in range(self.version + 1, SCHEMA_VERSION + 1):
                with self.tx() as db:
                    for statement in MIGRATIONS[version].split(";"):
                        if statement.strip():
                            db.execute(statement)
                    db.execute("INSERT OR REPLACE INTO meta VALUES ('schema', ?)", (str(version),))

    @contextmanager
    def tx(self) -> Iterator[sqlite3.Connection]:
        """One write transaction (BEGIN IMMEDIATE ... COMMIT), rolled back on any exception, a failed COMMIT
        included (the disk full); the disk refusing a write in it raises StoreWriteError."""
        with self.lock, writing():
            self._db.execute("BEGIN IMMEDIATE")
            try:
                yield self._db
                self._db.execute("COMMIT")
            except BaseException:
                if self._db.in_transaction:
                    self._db.execute("ROLLBACK")
                raise

    @contextmanager
    def snapshot(self) -> Iterator[sqlite3.Connection]:
        """Several reads that see one state of the database."""
        with self.lock:
            self._db.execute("BEGIN")
            try:
                yield self._db
            finally:
                self._db.execute("COMMIT")

    def all(self, sql: str, args: tuple | list = ()) -> list[sqlite3.Row]:
        with self.lock:
            return self._db.execute(sql, args).fetchall()

    def one(self, sql: str, args: tuple | list = ()) -> sqlite3.Row | None:
        with self.lock:
            return self._db.execute(sql, args).fetchone()

    def exists(self, table: str, key: str, column: str = "id") -> bool:
        return self.one(f"SELECT 1 FROM {table} WHERE {column} = ?", (key,)) is not None

    def meta(self, key: str) -> str | None:
        row = self.one("SELECT value FROM meta WHERE key = ?", (key,))
        return None if row is None else row["value"]

    def set_meta(self, key: str, value: str) -> None:
        with self.tx() as db:
            db.execute("INSERT OR REPLACE INTO meta VALUES (?, ?)", (key, value))


def now() -> str:
    """ISO 8601 UTC, milliseconds: the store's timestamps."""
    return datetime.now(UTC).isoformat(timespec="milliseconds")


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
