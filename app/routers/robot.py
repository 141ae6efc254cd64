"""The robot in view: its state (also as server-sent events), its active calibration and apply history;
connect, move, stop (every robot and every motion job at once), wander."""

from __future__ import annotations

import asyncio
from collections.abc import AsyncIterator
from typing import Annotated

from fastapi import APIRouter, Depends, Request
from fastapi.sse import EventSourceResponse
from pydantic import BaseModel

from calib_core import InputError

from ..drivers import Wandering
from ..validation import joints_from_deg
from .deps import DeskDep, JobsDep, RobotsDep, StoreDep, ViewerDep
from .models import Figures, RobotState, robot_state

ROBOT_EVENT_PERIOD_S = 0.1
router = APIRouter()


@router.get("/robot")
def robot(desk: DeskDep, robot: str | None = None) -> RobotState:
    """A drivable robot's state (`robot`; none: the connected one)."""
    return robot_state(desk, robot)


def _known_robot(desk: DeskDep, robot: str | None = None) -> str | None:
    """Checked before the stream starts, so an unknown robot answers 422 rather than breaking the stream."""
    desk.robots.driver(desk.robot_name(robot))
    return robot


@router.get("/robot/events", response_class=EventSourceResponse)
async def robot_events(
    request: Request, desk: DeskDep, robot: Annotated[str | None, Depends(_known_robot)]
) -> AsyncIterator[RobotState]:
    while not await request.is_disconnected():
        yield robot_state(desk, robot)
        await asyncio.sleep(ROBOT_EVENT_PERIOD_S)


class ActiveCalibration(BaseModel):
    id: str | None  # None: the robot runs with its nominal model
    robot: str
    model: str | None = None  # "nominal" when no calibration was applied
    mode: str | None = None
    session: str | None = None
    created: str | None = None
    applied: str | None = None  # when it was applied
    figures: dict[str, Figures] | None = None  # before, after; holdout_before, holdout_after; cv_after


@router.get("/robot/calibration")
def robot_calibration(desk: DeskDep, store: StoreDep, robot: str | None = None) -> ActiveCalibration:
    """The robot's active calibration (`robot`; none: the connected one)."""
    name = desk.robot_name(robot)
    desk.robots.get(name)
    cal_id = store.calibrations.active(name)
    if cal_id is None:
        return ActiveCalibration(id=None, robot=name, model="nominal")
    info = store.calibrations.info(cal_id)
    history = store.calibrations.history(name)
    return ActiveCalibration(
        id=cal_id,
        robot=name,
        mode=info.mode,
        session=info.session_id,
        created=info.created,
        applied=history[0]["time"] if history else None,
        figures=info.figures,
    )


class FiguresBrief(BaseModel):
    """A calibration's figure in the apply history: its mean, RMS and max error over n observations."""

    mean: float | None
    rms: float | None
    max: float | None
    n: int
    unit: str


class Applied(BaseModel):
    seq: int
    time: str
    calibration: str
    previous: str | None
    mode: str
    session: str | None
    figures: dict[str, FiguresBrief]  # before, after and held-out after (holdout_after)
    note: str


@router.get("/robot/history")
def robot_history(desk: DeskDep, store: StoreDep, robot: str | None = None) -> list[Applied]:
    """Every apply to the robot, newest first (an earlier one re-applied is a rollback)."""
    name = desk.robot_name(robot)
    desk.robots.get(name)
    return [Applied.model_validate(h) for h in store.calibrations.history(name)]


class ConnectRequest(BaseModel):
    robot: str


@router.post("/robot/connect")
def connect(desk: DeskDep, viewer: ViewerDep, body: ConnectRequest) -> RobotState:
    """Connect the desk to a drivable robot; the viewer's scene shows it (closing a review of another robot)."""
    desk.connect(body.robot, viewer)
    return robot_state(desk, body.robot)


class MoveRequest(BaseModel):
    joints: dict[str, float]  # name -> deg; joints not named keep their current angle
    robot: str | None = None


@router.post("/robot/move", status_code=202)
def move(desk: DeskDep, body: MoveRequest) -> RobotState:
    """Move a drivable robot (checked against its joint limits less the margin before anything moves)."""
    driver = desk.robots.driver(desk.robot_name(body.robot))
    q = joints_from_deg(driver.profile, driver.status().joints_rad, body.joints)
    driver.check(q)
    driver.move_to(q, wait=False)
    return robot_state(desk, body.robot)


@router.post("/robot/stop")
def stop(desk: DeskDep, robots: RobotsDep, jobs: JobsDep) -> RobotState | None:
    """Halt every robot and every motion job (replays, and the dry runs that plan them) at once; the connected
    robot's state (None: no robot to drive)."""
    for job in jobs.list():
        if job.kind in ("replay", "dry_run") and not job.state.finished:
            jobs.cancel(job.id)
    for r in robots.all():
        if r.driver is None:
            continue
        if isinstance(r.driver, Wandering):
            r.driver.wander(False)
        r.driver.stop()
    return None if desk.connected is None else robot_state(desk, None)


class WanderRequest(BaseModel):
    on: bool
    robot: str | None = None


@router.post("/robot/wander")
def wander(desk: DeskDep, body: WanderRequest) -> RobotState:
    """Let a simulated robot wander by itself (someone else driving it)."""
    driver = desk.robots.driver(desk.robot_name(body.robot))
    if not isinstance(driver, Wandering):
        raise InputError(f"{driver.profile.name} is a real robot: someone else drives it")
    driver.wander(body.on)
    return robot_state(desk, body.robot)
