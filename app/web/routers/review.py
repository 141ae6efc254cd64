"""Review: load a session with an old and a new calibration into a viewer's scene, select frames, the 2-D marks.

Each request is for the viewer its `X-Viewer` header names (a browser tab; none: the default viewer), so tabs
reviewing different sessions never move each other (app/scene/viewers.py)."""

from __future__ import annotations

from typing import Literal

from fastapi import APIRouter
from pydantic import BaseModel, Field

from calib_core import FrameStatus

from ...scene.review_scene.marks import MAGNIFY_MAX
from ...store.validation import FRAME_MAX, FRAME_MIN
from .deps import FrameIndex, ReviewDep, ViewerDep, ViewersDep

router = APIRouter()


class ReviewRequest(BaseModel):
    session: str
    old: str | None = "active"  # a calibration of the session's robot, "active" or None (the nominal model)
    new: str | None = None
    sensor: str | None = Field(default=None, max_length=200)  # the sensor whose observations (None: the data format's)


class ReviewRow(BaseModel):
    index: int
    status: FrameStatus
    target: int
    err_old: float | None  # None: not measured
    err_new: float | None
    heldout: bool
    band: float | None = (
        None  # how far the calibrations' uncertainty moves the frame's predictions (None: no covariance)
    )
    verdict: Literal["better", "worse", "same"] | None = None  # new - old beyond / within k bands (None: no band)


# Its docstring is the API document's description, kept as written (app/review.py: now app/scene/review.py).
class ReviewFigures(BaseModel):
    """The distances between prediction and measurement of the measured observations (app/review.py): their mean,
    RMS and max (None: none measured) and their count."""

    mean: float | None
    rms: float | None
    max: float | None
    n: int


class Histogram(BaseModel):
    """The observations' errors in bins of the review's unit (no bins: nothing measured, or no error at all)."""

    edges: list[float]
    old: list[int]
    new: list[int] | None  # None: no new calibration


# Its docstring is the API document's description, kept as written (app/review.py: now app/scene/review.py).
class ChangeBand(BaseModel):
    """What a frame's change is read against (app/review.py): better or worse beyond k times its band, the RMS
    over its points of how far the uncertainty of the calibrations named in `of` moves their predictions."""

    k: float
    of: list[str]  # the sides ("old", "new") with a covariance; [] : no band, no verdict
    median: float | None  # over the measured frames


class ReviewSummary(BaseModel):
    """Counted over observations, like a calibration's figures; heldout_* over the new calibration's held-out
    frames (None: it held none out, or there is no new calibration)."""

    unit: str
    frames: int
    measured: int  # frames with a measurement of the sensor reviewed
    heldout_frames: int
    old: ReviewFigures
    heldout_old: ReviewFigures | None
    new: ReviewFigures | None  # None: no new calibration
    heldout_new: ReviewFigures | None
    histogram: Histogram
    band: ChangeBand


class ReviewOut(BaseModel):
    session: str
    robot: str
    old: str | None
    new: str | None
    sensor: str  # the sensor the table, the summary and the scene's red marks are of
    sensors: list[str]  # the sensors the session has observations of
    images: list[str]  # those of them that take an image: the sensors a 2-D view can be of
    table: list[ReviewRow]
    summary: ReviewSummary
    warnings: list[str] = []  # what the scene could not show as asked (a URDF robot's mesh that cannot be read)


@router.post("/review")
def review(reviews: ReviewDep, viewer: ViewerDep, body: ReviewRequest) -> ReviewOut:
    return ReviewOut.model_validate(reviews.load(viewer, body.session, body.old, body.new, body.sensor))


class ReviewTable(BaseModel):
    table: list[ReviewRow]
    summary: ReviewSummary


@router.post("/review/table")
def review_table(reviews: ReviewDep, body: ReviewRequest) -> ReviewTable:
    """A review's frame table and summary as `POST /review` answers them, the scene untouched (what the page asks
    when frames join the session it shows: a live view keeps running)."""
    review, _ = reviews.build(body.session, body.old, body.new, body.sensor)
    return ReviewTable.model_validate({"table": review.table(), "summary": review.summary()})


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
def select(reviews: ReviewDep, viewer: ViewerDep, body: SelectRequest) -> Selected:
    return Selected.model_validate(reviews.select(viewer, body.index, show_all=body.all, overlay=body.overlay))


class MagnifyRequest(BaseModel):
    """The 3-D view's residuals drawn `factor` times their length: a measurement at prediction + factor
    (measurement - prediction), the copies' labels saying so."""

    factor: float = Field(ge=1, le=MAGNIFY_MAX)


class Magnified(BaseModel):
    factor: float


@router.post("/review/magnify")
def magnify(reviews: ReviewDep, viewer: ViewerDep, body: MagnifyRequest) -> Magnified:
    return Magnified(factor=reviews.magnify(viewer, body.factor))


class Framed(BaseModel):
    index: int | None  # the frame whose marks the camera was brought onto


@router.post("/review/frame-marks")
def frame_marks(reviews: ReviewDep, viewer: ViewerDep) -> Framed:
    """The page's "frame it": the viewer's 3-D camera onto the selected frame's marks, both copies seen from nearly
    the same direction (a narrow field of view), never inside a body (without a review: onto the robot). Selecting a
    frame leaves the camera where it is."""
    return Framed(index=reviews.frame_marks(viewer))


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
def marks(reviews: ReviewDep, viewer: ViewerDep, index: FrameIndex) -> Marks:
    return Marks.model_validate(reviews.marks(viewer, index))


class ViewerOut(BaseModel):
    """A viewer (a browser tab) and what it shows."""

    id: str
    connected: bool  # its scene's websocket is open
    robot: str | None  # the robot its scene shows
    session: str | None  # the session it reviews (None: no review loaded)
    old: str | None
    new: str | None
    sensor: str | None  # the sensor reviewed
    index: int | None  # the frame selected
    overlay: bool
    all: bool
    magnify: float  # its 3-D residuals drawn this many times their length
    live: bool  # its scene shows Observe's live view


@router.get("/viewers")
def viewers(viewers: ViewersDep) -> list[ViewerOut]:
    """Every viewer on the desk: the default one, and one per open tab (a closed tab's goes a few seconds later)."""
    return [ViewerOut.model_validate(v.state()) for v in viewers.all()]
