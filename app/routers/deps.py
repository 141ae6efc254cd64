"""What the routers are given (FastAPI `Depends`): the desk and its parts, and reading an upload whole."""

from __future__ import annotations

from typing import Annotated

from fastapi import Depends, HTTPException, Request, UploadFile
from fastapi import Path as PathParam

from ..desk import Desk
from ..jobs import JobManager
from ..robots import Robots
from ..security import MAX_UPLOAD_BYTES
from ..store import Store
from ..validation import FRAME_MAX, FRAME_MIN


def get_desk(request: Request) -> Desk:
    return request.app.state.desk


DeskDep = Annotated[Desk, Depends(get_desk)]


def get_store(desk: DeskDep) -> Store:
    return desk.store


def get_jobs(desk: DeskDep) -> JobManager:
    return desk.jobs


def get_robots(desk: DeskDep) -> Robots:
    return desk.robots


StoreDep = Annotated[Store, Depends(get_store)]
JobsDep = Annotated[JobManager, Depends(get_jobs)]
RobotsDep = Annotated[Robots, Depends(get_robots)]
FrameIndex = Annotated[int, PathParam(ge=FRAME_MIN, le=FRAME_MAX, description="a frame number")]


async def read_upload(upload: UploadFile) -> bytes:
    """An uploaded file whole, refused (413) beyond MAX_UPLOAD_BYTES before it is all read."""
    raw = await upload.read(MAX_UPLOAD_BYTES + 1)
    if len(raw) > MAX_UPLOAD_BYTES:
        raise HTTPException(413, f"{upload.filename}: larger than {MAX_UPLOAD_BYTES // (1024 * 1024)} MB")
    return raw
