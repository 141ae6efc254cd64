"""Calibrations (DATA/calibrations/<id>.json and a row each) and the apply history of each robot.

A calibration belongs to the robot (instance) whose session it was made from; the robot's active
calibration is the last one applied to it. Every apply is a row of its own, never changed or removed,
so the history is the whole story (a rollback is an apply of an earlier calibration).
"""

from __future__ import annotations

import builtins
import json
import secrets
import sqlite3
from dataclasses import dataclass
from pathlib import Path
from typing import TypedDict

from calib_core import Calibration, InputError

from ..errors import NotFound
from .db import Database, jsonable, now, writing
from .files import fsync_dir


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


class AppliedFigures(TypedDict):
    """A calibration's figure as the apply history gives it (of Calibration.figures; None: NaN, not determined)."""

    mean: float | None
    rms: float | None
    max: float | None
    n: int
    unit: str


class Applied(TypedDict):
    """One apply of the history (`CalibrationRepository.history`)."""

    seq: int
    time: str
    calibration: str
    previous: str | None  # the robot's active calibration before (None: it ran the nominal model)
    mode: str
    session: str | None  # the session the calibration was made from (None: gone, or none)
    figures: dict[str, AppliedFigures]  # before, after and held-out after (holdout_after), those it has
    note: str


class CalibrationRepository:
    def __init__(self, db: Database, data_dir: Path) -> None:
        self.db = db
        self.data_dir = data_dir
        (data_dir / "calibrations").mkdir(exist_ok=True)

    def add(self, cal: Calibration, *, session_id: str | None, base_id: str | None, holdout: float) -> str:
        """The JSON file first (atomic), then its row; a failed insert removes the file."""
        cid = "c-" + secrets.token_hex(4)
        rel = f"calibrations/{cid}.json"
        path = self.data_dir / rel
        figures = json.dumps(jsonable({k: v.to_dict() for k, v in cal.figures.items()}))
        try:
            with writing():
                cal.save(path)
                fsync_dir(path.parent)
            with self.db.tx() as db:
                if session_id is not None and not self.db.exists("sessions", session_id):
                    raise NotFound.unknown("session", session_id)
                if base_id is not None and not self.db.exists("calibrations", base_id):
                    raise NotFound.unknown("calibration", base_id)
                db.execute(
                    "INSERT INTO calibrations VALUES (?, ?, ?, ?, ?, ?, ?, ?, ?)",
                    (cid, session_id, cal.robot, cal.mode, cal.created or now(), base_id, float(holdout), rel, figures),
                )
        except BaseException:
            path.unlink(missing_ok=True)
            raise
        return cid

    def load(self, cal_id: str) -> Calibration:
        """The calibration itself, from its file."""
        return Calibration.load(self.data_dir / self.info(cal_id).path)

    def info(self, cal_id: str) -> CalibrationInfo:
        row = self.db.one("SELECT * FROM calibrations WHERE id = ?", (cal_id,))
        if row is None:
            raise NotFound.unknown("calibration", cal_id)
        return _calibration_info(row)

    def list(self, session_id: str | None = None, robot: str | None = None) -> list[CalibrationInfo]:
        """Newest first."""
        sql, args = "SELECT * FROM calibrations WHERE 1", []
        if session_id is not None:
            sql, args = sql + " AND session_id = ?", [*args, session_id]
        if robot is not None:
            sql, args = sql + " AND robot = ?", [*args, robot]
        return [_calibration_info(r) for r in self.db.all(sql + " ORDER BY rowid DESC", args)]

    def paths(self) -> set[str]:
        """Every calibration file a row refers to (what the sweep keeps)."""
        return {r["path"] for r in self.db.all("SELECT path FROM calibrations")}

    # --- apply history ------------------------------------------------------------------------------
    def apply(self, robot: str, cal_id: str, note: str = "") -> tuple[str, str | None]:
        """Make `cal_id` the robot's active calibration; returns (active, previous)."""
        with self.db.tx() as db:
            row = db.execute("SELECT robot FROM calibrations WHERE id = ?", (cal_id,)).fetchone()
            if row is None:
                raise NotFound.unknown("calibration", cal_id)
            if row["robot"] != robot:
                raise InputError(f"calibration '{cal_id}' is for robot '{row['robot']}', not '{robot}'")
            row = db.execute(_ACTIVE, (robot,)).fetchone()
            previous = None if row is None else row["calibration_id"]
            db.execute(
                "INSERT INTO applies (robot, time, calibration_id, previous_id, note) VALUES (?, ?, ?, ?, ?)",
                (robot, now(), cal_id, previous, note),
            )
        return cal_id, previous

    def active(self, robot: str) -> str | None:
        row = self.db.one(_ACTIVE, (robot,))
        return None if row is None else row["calibration_id"]

    def history(self, robot: str) -> builtins.list[Applied]:  # `list` is a method's name here
        """Newest first: {seq, time, calibration, previous, mode, session, figures, note}."""
        rows = self.db.all(
            "SELECT a.*, c.mode, c.session_id, c.figures FROM applies a JOIN calibrations c "
            "ON c.id = a.calibration_id WHERE a.robot = ? ORDER BY a.seq DESC",
            (robot,),
        )
        out: builtins.list[Applied] = []
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
                        k: _applied_figures(figs[k]) for k in ("before", "after", "holdout_after") if k in figs
                    },
                    "note": r["note"],
                }
            )
        return out


def _applied_figures(fig: dict) -> AppliedFigures:
    """A figure of a calibration's row (a calib_core Figures' to_dict, as `add` stores it: every key there, NaN as
    None) as the history gives it."""
    return {"mean": fig["mean"], "rms": fig["rms"], "max": fig["max"], "n": fig["n"], "unit": fig["unit"]}


_ACTIVE = "SELECT calibration_id FROM applies WHERE robot = ? ORDER BY seq DESC LIMIT 1"


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
