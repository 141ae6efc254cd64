"""A robot's applied calibrations read together (drift), and the robots of one model side by side (team).

The history is the calibrations applied to the robot, each once (a rollback re-applies one already there), in the
order their data were measured: the first frame of the session each was made from (a CSV import says when with
its `measured` field, a session folder in its session.json), or when the calibration was made if its session is
gone. The statistics are calib_core's (calib_core/estimation/drift.py); this composes the store with them.
"""

from __future__ import annotations

import csv
import io
from dataclasses import dataclass
from datetime import UTC, datetime

from calib_core.estimation import Drift, Epoch, Team, compare_team, find_drift

from ..robots.roster import Robots
from ..store import Store


@dataclass
class Member:
    """A robot of the team and its active calibration (None: it runs the nominal model)."""

    robot: str
    calibration: str | None
    mode: str | None
    applied: datetime | None
    measured: datetime | None


class HistoryService:
    def __init__(self, store: Store, robots: Robots) -> None:
        self.store = store
        self.robots = robots

    def epochs(self, robot: str) -> tuple[list[Epoch], list[str]]:
        """The robot's applied calibrations as epochs, oldest data first, and what the reader should know."""
        name = self.robots.get(robot).name
        applied = list(dict.fromkeys(h["calibration"] for h in reversed(self.store.calibrations.history(name))))
        infos = [self.store.calibrations.info(c) for c in applied]
        measured = self.store.sessions.measured([i.session_id for i in infos if i.session_id])
        epochs, notes = [], []
        for info in infos:
            when = measured.get(info.session_id or "") or datetime.fromisoformat(info.created)
            cal = self.store.calibrations.load(info.id)
            epochs.append(Epoch.of(cal, info.id, when.astimezone(UTC)))
            loose = [t for t in cal.solver.noise_tests if t.warns]
            if loose:
                notes.append(
                    f"{info.id}: its residuals are {max(t.factor for t in loose):.3g} times the noise its sensor "
                    "declares, so its uncertainty leaves out model error: a change involving it may be the mode's "
                    "error on other configurations as much as the robot's"
                )
            if info.session_id not in measured:
                notes.append(f"{info.id}: its session is gone; placed at the time it was made ({info.created[:16]})")
        for e in epochs:
            if not e.correlated:
                notes.append(f"{e.id} kept no covariance (an older file): read with its standard deviations alone")
        modes = sorted({e.mode for e in epochs})
        if len(modes) > 1:
            notes.append(
                f"calibrations of modes {', '.join(modes)}: each change compares the parameters both calibrations "
                "estimated, the trends those every one did"
            )
        return sorted(epochs, key=lambda e: e.time), notes

    def drift(self, robot: str, alpha: float) -> tuple[Drift, list[str]]:
        epochs, notes = self.epochs(robot)
        return find_drift(epochs, alpha), notes

    def series_csv(self, robot: str) -> str:
        """Every parameter's value at each applied calibration: one row per calibration and parameter."""
        epochs, _ = self.epochs(robot)
        drift = find_drift(epochs)
        modes = {e.id: e.mode for e in epochs}
        out = io.StringIO()
        w = csv.writer(out, lineterminator="\n")
        w.writerow(["calibration", "measured", "mode", "parameter", "unit", "value", "sd", "held", "held_sd"])
        rows = [(p.time, s, p) for s in drift.series for p in s.points]
        for _, s, p in sorted(rows, key=lambda r: (r[0], drift.epochs.index(r[2].calibration), r[1].parameter)):
            held = ["", ""] if p.held is None else [f"{p.held:.10g}", f"{p.held_sd:.6g}"]
            what = [p.calibration, p.time.isoformat(), modes[p.calibration], s.parameter, s.unit]
            w.writerow([*what, f"{p.value:.10g}", f"{p.sd:.6g}", *held])
        return out.getvalue()

    def team(self, model: str, alpha: float) -> tuple[Team, list[Member]]:
        """The robots of `model` (a profile's name), each with its active calibration, compared parameter by
        parameter over those that have one."""
        robots = [r.name for r in self.robots.all() if r.model == model]
        members, epochs = [], {}
        for name in robots:
            cal_id = self.store.calibrations.active(name)
            if cal_id is None:
                members.append(Member(name, None, None, None, None))
                continue
            info = self.store.calibrations.info(cal_id)
            applied = datetime.fromisoformat(self.store.calibrations.history(name)[0]["time"])
            when = self.store.sessions.measured([info.session_id] if info.session_id else []).get(info.session_id or "")
            members.append(Member(name, cal_id, info.mode, applied, when))
            epochs[name] = Epoch.of(self.store.calibrations.load(cal_id), cal_id, when or applied)
        return compare_team(epochs, alpha), members
