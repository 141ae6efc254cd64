"""A robot's history read together (what moved, what drifts, each parameter's series, as JSON or CSV) and the
robots of one model side by side (the odd one out, which calibration each runs and how old it is)."""

from __future__ import annotations

from datetime import UTC, datetime
from typing import Annotated

from fastapi import APIRouter, Depends, Query
from fastapi.responses import PlainTextResponse
from pydantic import BaseModel

from calib_core.estimation import DRIFT_LEVEL, MOVED_SHOWN

from .deps import ConnectionDep, HistoryDep, RobotsDep

router = APIRouter()
Level = Annotated[float, Query(gt=0.0, lt=0.5, description="each test's false-alarm rate (default 0.01)")]


class PointOut(BaseModel):
    calibration: str
    measured: str  # when its data were measured, ISO 8601 UTC
    value: float  # as the calibration estimated it (display units)
    sd: float
    held: float | None  # with the other compared parameters at what the history fits for them (None: not compared)
    held_sd: float | None


class TrendOut(BaseModel):
    parameter: str
    unit: str
    rate_per_day: float
    sd: float
    days: float
    calibrations: int
    steady: bool  # the rest of the history is noise (False: it jumps as well)
    sentence: str  # "LKneePitch: +0.05 deg a day over 9 days (10 calibrations; +/- 0.0012)"


class SeriesOut(BaseModel):
    parameter: str
    unit: str
    moved_sd: float  # how far it moved, in standard deviations (the list is sorted by it)
    moved: bool  # moved_sd >= 3 (MOVED_SHOWN), or named by a change or a trend: the page plots it
    points: list[PointOut]
    trend: TrendOut | None


class MovedOut(BaseModel):
    parameter: str
    unit: str
    change: float
    sd: float
    z: float


class StepOut(BaseModel):
    before: str
    after: str
    days: float
    parameters: int  # compared: those both calibrations estimated
    chi2: float
    p: float
    flagged: bool  # beyond what both calibrations' covariances explain, at the level asked
    moved: list[MovedOut]  # the parameters that explain it, one at a time
    sentence: str


class DriftOut(BaseModel):
    robot: str
    level: float
    calibrations: list[str]  # applied, oldest data first
    compared: list[str]  # the parameters every one estimated: what the trends read
    steps: list[StepOut]
    trends: list[TrendOut]
    series: list[SeriesOut]  # most moved first
    notes: list[str]


def _robot(connection: ConnectionDep, robots: RobotsDep, robot: str | None = None) -> str:
    """The robot asked for (`robot`; none: the connected one), by its name on the desk."""
    return robots.get(connection.robot_name(robot)).name


RobotName = Annotated[str, Depends(_robot)]


@router.get("/robot/drift")
def robot_drift(history: HistoryDep, name: RobotName, level: Level = DRIFT_LEVEL) -> DriftOut:
    """The robot's applied calibrations read together (`robot`; none: the connected one): each change from one to
    the next tested against both calibrations' covariances (flagged with the parameters that moved), steady
    trends with their rate a day, and every parameter's series, most moved first."""
    drift, notes = history.drift(name, level)
    named = {m.parameter for s in drift.steps for m in s.moved} | {t.parameter for t in drift.trends}
    return DriftOut(
        robot=name,
        level=level,
        calibrations=drift.epochs,
        compared=drift.compared,
        steps=[StepOut.model_validate(s, from_attributes=True) for s in drift.steps],
        trends=[TrendOut.model_validate(t, from_attributes=True) for t in drift.trends],
        series=[
            SeriesOut(
                parameter=s.parameter,
                unit=s.unit,
                moved_sd=s.moved_sd,
                moved=s.moved_sd >= MOVED_SHOWN or s.parameter in named,
                points=[
                    PointOut(
                        calibration=p.calibration,
                        measured=p.time.isoformat(),
                        value=p.value,
                        sd=p.sd,
                        held=p.held,
                        held_sd=p.held_sd,
                    )
                    for p in s.points
                ],
                trend=None if s.trend is None else TrendOut.model_validate(s.trend, from_attributes=True),
            )
            for s in drift.series
        ],
        notes=notes,
    )


@router.get("/robot/drift.csv", response_class=PlainTextResponse, responses={200: {"content": {"text/csv": {}}}})
def robot_drift_csv(history: HistoryDep, name: RobotName) -> PlainTextResponse:
    """Every parameter's value at each applied calibration, a row each (calibration, measured, mode, parameter,
    unit, value, sd, held, held_sd)."""
    return PlainTextResponse(
        history.series_csv(name),
        media_type="text/csv",
        headers={"Content-Disposition": f'attachment; filename="{name}-history.csv"'},
    )


class MemberOut(BaseModel):
    robot: str
    calibration: str | None  # its active calibration; None: it runs the nominal model
    mode: str | None
    applied: str | None
    measured: str | None  # when that calibration's data were measured
    age_days: float | None  # since then (since it was applied, if not known)


class StandingOut(BaseModel):
    robot: str
    value: float
    sd: float
    z: float  # from the others' mean, in standard deviations of that difference


class ColumnOut(BaseModel):
    parameter: str
    unit: str
    robots: list[StandingOut]
    odd: str | None  # the robot far from the others, if one is


class OddOut(BaseModel):
    robot: str
    parameter: str
    unit: str
    value: float
    others_mean: float
    others_spread: float
    z: float
    sentence: str


class TeamOut(BaseModel):
    model: str
    level: float
    members: list[MemberOut]
    parameters: list[ColumnOut]  # the most off first
    odd: list[OddOut]


@router.get("/team")
def team(history: HistoryDep, robots: RobotsDep, name: RobotName, level: Level = DRIFT_LEVEL) -> TeamOut:
    """The robots of one model as `robot`'s (none: the connected one) side by side: which calibration each runs
    and how old it is, each parameter across them, and the robot far from the others, named."""
    model = robots.get(name).model
    result, members = history.team(model, level)
    now = datetime.now(UTC)
    return TeamOut(
        model=model,
        level=level,
        members=[
            MemberOut(
                robot=m.robot,
                calibration=m.calibration,
                mode=m.mode,
                applied=None if m.applied is None else m.applied.isoformat(),
                measured=None if m.measured is None else m.measured.isoformat(),
                age_days=None
                if m.calibration is None
                else ((now - (m.measured or m.applied)).total_seconds() / 86400.0),
            )
            for m in members
        ],
        parameters=[ColumnOut.model_validate(c, from_attributes=True) for c in result.parameters],
        odd=[OddOut.model_validate(o, from_attributes=True) for o in result.odd],
    )
