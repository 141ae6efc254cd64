"""Review: load a session with an old and a new calibration into the scene, select frames, the 2-D marks."""

from __future__ import annotations

from typing import Any

from fastapi import APIRouter
from pydantic import BaseModel, Field

from ..validation import FRAME_MAX, FRAME_MIN
from .deps import DeskDep, FrameIndex

router = APIRouter()


class ReviewRequest(BaseModel):
    session: str
    old: str | None = "active"  # a calibration of the session's robot, "active" or None (the nominal model)
    new: str | None = None


class ReviewRow(BaseModel):
    index: int
    status: str
    target: int
    err_old: float | None  # None: not measured
    err_new: float | None
    heldout: bool


class ReviewOut(BaseModel):
    session: str
    robot: str
    old: str | None
    new: str | None
    table: list[ReviewRow]
    summary: dict[str, Any]  # old and new mean, RMS, max (held out too), unit, histogram


@router.post("/review")
def review(desk: DeskDep, body: ReviewRequest) -> ReviewOut:
    return ReviewOut.model_validate(desk.review(body.session, body.old, body.new))


class SelectRequest(BaseModel):
    index: int = Field(ge=FRAME_MIN, le=FRAME_MAX)
    all: bool = False
    overlay: bool = False


class Selected(BaseModel):
    index: int
    all: bool
    overlay: bool
    server_ms: float


@router.post("/review/frame")
def select(desk: DeskDep, body: SelectRequest) -> Selected:
    return Selected.model_validate(desk.reviews.select(body.index, show_all=body.all, overlay=body.overlay))


class Marks(BaseModel):
    """The 2-D split view of one frame: [u, v] px per point (None: not measured, or behind the camera)."""

    index: int
    role: str | None  # the image the marks belong to
    width: int | None
    height: int | None
    measured: list[list[float] | None]
    old: list[list[float] | None]
    new: list[list[float] | None] | None
    image: str | None  # its URL


@router.get("/review/marks/{index}")
def marks(desk: DeskDep, index: FrameIndex) -> Marks:
    return Marks.model_validate(desk.reviews.marks(index))
