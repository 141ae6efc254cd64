"""The robot in view: its state (also as server-sent events), its active calibration and apply history;
connect, move, stop (every robot and every motion job at once), wander."""

from __future__ import annotations

import asyncio
from collections.abc import AsyncIterator
from typing import Annotated

from fastapi import APIRouter, Depends, Request
from fastapi.sse import EventSourceResponse
from pydantic import BaseModel

from .deps import CalibrationsDep, ConnectionDep, DriveDep, RobotsDep, ViewerDep
from .models import Figures, RobotState, robot_state

ROBOT_EVENT_PERIOD_S = 0.1
# The state is looked at every period and sent when it changed; a state like the one before is sent again only
# every ROBOT_EVENT_REPEAT periods (a second: the page still hears that the stream lives). A robot at rest sent ten
# a second cost each open page and the server a few percent of a core, for nothing.
ROBOT_EVENT_REPEAT = 10
router = APIRouter()


@router.get("/robot")
def robot(connection: ConnectionDep, robot: str | None = None) -> RobotState:
    """A drivable robot's state (`robot`; none: the connected one)."""
    return robot_state(connection, robot)


def _known_robot(connection: ConnectionDep, robot: str | None = None) -> str | None:
    """Checked before the stream starts, so an unknown robot answers 422 rather than breaking the stream."""
    connection.driver(robot)
    return robot


@router.get("/robot/events", response_class=EventSourceResponse)
async def robot_events(
    request: Request, connection: ConnectionDep, robot: Annotated[str | None, Depends(_known_robot)]
) -> AsyncIterator[RobotState]:
    closing = request.app.state.closing  # the server stops: the stream ends, so the stop need not wait for it
    sent, unchanged = None, 0
    while not closing.is_set() and not await request.is_disconnected():
        state = robot_state(connection, robot)
        if state != sent or unchanged + 1 >= ROBOT_EVENT_REPEAT:
            yield state
            sent, unchanged = state, 0
        else:
            unchanged += 1
        await asyncio.sleep(ROBOT_EVENT_PERIOD_S)


class LiveLook(BaseModel):
    """Observe's latest look through the data sensor's camera: its image and marks, as the Review's 2-D view."""

    look: int  # its count since Observe began: a new one has a higher number
    sensor: str
    target: str
    status: str  # measured or not found
    reason: str
    width: int | None  # px; None with no image
    height: int | None
    image: str | None  # a JPEG data URL; None: the sensor takes no image
    measured: list[list[float] | None] | None  # [u, v] px per point found (vision); None: nothing found
    predicted: list[list[float] | None] | None  # [u, v] px per target point, the active calibration's


@router.get("/robot/look", responses={404: {"description": "not observing that robot, or no look yet"}})
def robot_look(connection: ConnectionDep, robot: str | None = None) -> LiveLook:
    """Observe's latest settled look through the camera (`robot`; none: the one observed): the image, what the
    finder found and where the active calibration predicts the target."""
    return LiveLook.model_validate(connection.look(robot))


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
def robot_calibration(
    connection: ConnectionDep, robots: RobotsDep, calibrations: CalibrationsDep, robot: str | None = None
) -> ActiveCalibration:
    """The robot's active calibration (`robot`; none: the connected one)."""
    name = robots.get(connection.robot_name(robot)).name
    cal_id = calibrations.active(name)
    if cal_id is None:
        return ActiveCalibration(id=None, robot=name, model="nominal")
    info = calibrations.info(cal_id)
    history = calibrations.history(name)
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
def robot_history(
    connection: ConnectionDep, robots: RobotsDep, calibrations: CalibrationsDep, robot: str | None = None
) -> list[Applied]:
    """Every apply to the robot, newest first (an earlier one re-applied is a rollback)."""
    name = robots.get(connection.robot_name(robot)).name
    return [Applied.model_validate(h) for h in calibrations.history(name)]


class ConnectRequest(BaseModel):
    robot: str


@router.post("/robot/connect")
def connect(connection: ConnectionDep, viewer: ViewerDep, body: ConnectRequest) -> RobotState:
    """Connect the desk to a drivable robot; the viewer's scene shows it (closing a review of another robot)."""
    connection.connect(body.robot, viewer)
    return robot_state(connection, body.robot)


class MoveRequest(BaseModel):
    joints: dict[str, float]  # name -> deg; joints not named keep their current angle
    robot: str | None = None


@router.post("/robot/move", status_code=202)
def move(drive: DriveDep, connection: ConnectionDep, body: MoveRequest) -> RobotState:
    """Move a drivable robot (checked against its joint limits less the margin before anything moves)."""
    return robot_state(connection, drive.move(body.robot, body.joints))


class RobotStop(BaseModel):
    """One robot's answer to STOP."""

    robot: str
    confirmed: bool  # the robot took the halt within the answer's time
    message: str  # "nao-3 stopped", or what it did not do and what to do ("use its own emergency stop")


class StopAnswer(RobotState):
    """The connected robot's state after STOP, and every robot's answer."""

    stops: list[RobotStop]


@router.post("/robot/stop")
def stop(drive: DriveDep, connection: ConnectionDep) -> StopAnswer | None:
    """Halt every robot and every motion job (replays, and the dry runs that plan them) at once, never waiting on
    a robot: within 200 ms (it waits 150 ms for the robots to take the halt), the connected robot's state and
    whether each robot took the stop (`stops`; one that did not answer says so: use its own emergency stop). None:
    no robot to drive."""
    outcomes = drive.stop_all()
    if connection.connected is None:
        return None
    stops = [RobotStop(robot=o.robot, confirmed=o.confirmed, message=o.message) for o in outcomes]
    return StopAnswer(**robot_state(connection, None).model_dump(), stops=stops)


class WanderRequest(BaseModel):
    on: bool
    robot: str | None = None


@router.post("/robot/wander")
def wander(drive: DriveDep, connection: ConnectionDep, body: WanderRequest) -> RobotState:
    """Let a simulated robot wander by itself (someone else driving it)."""
    return robot_state(connection, drive.wander(body.robot, body.on))
