"""What the routers are given (FastAPI `Depends`): the desk and its parts, the viewer a request is for, and
reading an upload whole."""

from __future__ import annotations

from typing import Annotated

from fastapi import Depends, Header, HTTPException, Request, UploadFile
from fastapi import Path as PathParam

from ..desk import Desk
from ..jobs.runner import JobRunner
from ..robots import Robots
from ..store import Store
from ..validation import FRAME_MAX, FRAME_MIN
from ..viewers import VIEWER_PATTERN, Viewer


def get_desk(request: Request) -> Desk:
    return request.app.state.desk


DeskDep = Annotated[Desk, Depends(get_desk)]


def get_store(desk: DeskDep) -> Store:
    return desk.store


def get_jobs(desk: DeskDep) -> JobRunner:
    return desk.jobs


def get_robots(desk: DeskDep) -> Robots:
    return desk.robots


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


StoreDep = Annotated[Store, Depends(get_store)]
JobsDep = Annotated[JobRunner, Depends(get_jobs)]
RobotsDep = Annotated[Robots, Depends(get_robots)]
ViewerDep = Annotated[Viewer, Depends(get_viewer)]
FrameIndex = Annotated[int, PathParam(ge=FRAME_MIN, le=FRAME_MAX, description="a frame number")]


async def read_upload(desk: Desk, upload: UploadFile) -> bytes:
    """An uploaded file whole, refused (413) beyond the desk's upload limit before it is all read."""
    limit = desk.limits.upload_bytes
    raw = await upload.read(limit + 1)
    if len(raw) > limit:
        raise HTTPException(
            413, f"{upload.filename}: larger than {desk.limits.upload_text} (the desk's upload limit, --max-upload-mb)"
        )
    return raw
