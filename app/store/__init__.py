"""The dashboard's store: sessions, frames, observations, calibrations, the apply history, jobs and robots.

    DATA/store.sqlite                  the rows (SQLite, WAL, synchronous=FULL, foreign keys): db.py
    DATA/sessions/<id>/images/*.jpg    frame images (JPEG q90): sessions.py
    DATA/calibrations/<id>.json        calib-calibration/1 files: calibrations.py
    DATA/robots/<name>/                profiles (and their URDF) of robots added while the desk ran: robots.py

A robot's profile is a built-in one by name or a profile file, named after the robot (profiles.py). Sessions
from outside the desk come in whole through importers.py; validation.py holds the checks every door of the desk
shares (ids, image roles, frame numbers, joints, targets), the store's first of all.

Crash safety comes from ordering: every file is written whole (temporary name, fsync, rename) before
the transaction that references it commits, and every multi-row change is one transaction. A crash
therefore leaves at most files no row references; opening the store sweeps them away.
"""

from __future__ import annotations

from pathlib import Path

from .calibrations import CalibrationInfo, CalibrationRepository
from .db import Database, StoreWriteError
from .files import remove_stale
from .jobs import INTERRUPTED, JobRepository
from .robots import ProfileFiles, RobotRecord, RobotRepository
from .sessions import FrameInfo, NewFrame, Observations, SessionInfo, SessionRepository

__all__ = [
    "INTERRUPTED",
    "CalibrationInfo",
    "FrameInfo",
    "NewFrame",
    "Observations",
    "ProfileFiles",
    "RobotRecord",
    "SessionInfo",
    "Store",
    "StoreWriteError",
]


class Store:
    """The repositories over one database in one data directory."""

    def __init__(self, data_dir: Path) -> None:
        self.data_dir = Path(data_dir)
        self.data_dir.mkdir(parents=True, exist_ok=True)
        self.db = Database(self.data_dir / "store.sqlite")
        self.robots = RobotRepository(self.db, self.data_dir)
        self.sessions = SessionRepository(self.db, self.data_dir, self.robots.profile)
        self.calibrations = CalibrationRepository(self.db, self.data_dir)
        self.jobs = JobRepository(self.db)
        self._sweep()

    def close(self) -> None:
        self.db.close()

    def _sweep(self) -> None:
        """Remove what a crash can leave: temporary files, and files and folders no row references.

        Only what is older than files.SWEEP_AGE_S goes: younger ones may belong to a write in flight (of
        another Store on the same folder) whose row is not committed yet.
        """
        with self.db.lock:
            sessions = self.sessions.ids()
            images = self.sessions.image_paths()
            cals = self.calibrations.paths()
            robots = {r.name for r in self.robots.list()}
        for d in (self.data_dir / "sessions").iterdir():
            if d.name not in sessions:
                remove_stale(d)
            elif (d / "images").is_dir():
                for f in (d / "images").iterdir():
                    if f"sessions/{d.name}/images/{f.name}" not in images:
                        remove_stale(f)
        for f in (self.data_dir / "calibrations").iterdir():
            if f"calibrations/{f.name}" not in cals:
                remove_stale(f)
        if (self.data_dir / "robots").is_dir():
            for d in (self.data_dir / "robots").iterdir():
                if d.name not in robots:
                    remove_stale(d)
