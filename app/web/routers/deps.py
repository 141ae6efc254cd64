"""What the routers are given (FastAPI `Depends`): the services, the store's repositories a router reads, the
robots on the desk, the viewer a request is for, the desk's limits, and reading an upload whole.

The only module of the API that imports the desk: a router names what it needs here and never reaches through
the desk to get it (the health check alone asks the desk about itself: its instance, its viser port).
"""

from __future__ import annotations

from collections.abc import Callable
from operator import attrgetter
from typing import Annotated, Any

from fastapi import Depends, Header, HTTPException, Request, UploadFile
from fastapi import Path as PathParam

from ...jobs.runner import JobRunner
from ...robots.roster import Robots
from ...scene.viewers import VIEWER_PATTERN, Viewer, Viewers
from ...services.apply import ApplyService
from ...services.calibration import CalibrationService
from ...services.connection import Connection
from ...services.drive import DriveService
from ...services.history import HistoryService
from ...services.replay import ReplayService
from ...services.review import ReviewService
from ...services.robots import RobotService
from ...store import Store
from ...store.calibrations import CalibrationRepository
from ...store.sessions import SessionRepository
from ...store.validation import FRAME_MAX, FRAME_MIN
from ..desk import Desk
from ..limits import Limits


def get_desk(request: Request) -> Desk:
    return request.app.state.desk


DeskDep = Annotated[Desk, Depends(get_desk)]


def _part(path: str) -> Callable[[Desk], Any]:
    """A dependency: the desk's part at `path` (dotted attribute names), read at each request."""
    get = attrgetter(path)

    def part(desk: DeskDep) -> Any:
        return get(desk)

    return part


def get_viewer(
    desk: DeskDep,
    viewer: Annotated[
        str | None,
        Header(
            alias="X-Viewer",
            pattern=VIEWER_PATTERN,
            description="the browser tab (viewer) the request is for: an id its page makes; none: the default viewer",
        ),
    ] = None,
) -> Viewer:
    return desk.viewers.get(viewer)


StoreDep = Annotated[Store, Depends(_part("store"))]
SessionsDep = Annotated[SessionRepository, Depends(_part("store.sessions"))]
CalibrationsDep = Annotated[CalibrationRepository, Depends(_part("store.calibrations"))]
RobotsDep = Annotated[Robots, Depends(_part("robots"))]
JobsDep = Annotated[JobRunner, Depends(_part("jobs"))]
ViewersDep = Annotated[Viewers, Depends(_part("viewers"))]
LimitsDep = Annotated[Limits, Depends(_part("limits"))]
ConnectionDep = Annotated[Connection, Depends(_part("connection"))]
DriveDep = Annotated[DriveService, Depends(_part("drive"))]
RobotServiceDep = Annotated[RobotService, Depends(_part("robot_service"))]
CalibrationDep = Annotated[CalibrationService, Depends(_part("calibration"))]
ApplyDep = Annotated[ApplyService, Depends(_part("apply"))]
ReplayDep = Annotated[ReplayService, Depends(_part("replay"))]
ReviewDep = Annotated[ReviewService, Depends(_part("reviews"))]
HistoryDep = Annotated[HistoryService, Depends(_part("history"))]
ViewerDep = Annotated[Viewer, Depends(get_viewer)]
FrameIndex = Annotated[int, PathParam(ge=FRAME_MIN, le=FRAME_MAX, description="a frame number")]


async def read_upload(limits: Limits, upload: UploadFile) -> bytes:
    """An uploaded file whole, refused (413) beyond the desk's upload limit before it is all read."""
    raw = await upload.read(limits.upload_bytes + 1)
    if len(raw) > limits.upload_bytes:
        raise HTTPException(
            413, f"{upload.filename}: larger than {limits.upload_text} (the desk's upload limit, --max-upload-mb)"
        )
    return raw
