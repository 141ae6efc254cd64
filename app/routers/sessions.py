"""Sessions: list, one with its frames, create, delete, import a CSV; capture, observe, replay, go to a frame;
the frame images; a session's calibrations (list, start one)."""

from __future__ import annotations

import asyncio
from pathlib import Path
from typing import Annotated, Literal

from fastapi import APIRouter, File, Form, HTTPException, Response, UploadFile
from fastapi.responses import FileResponse
from pydantic import BaseModel, Field

from ..capture import Until
from ..importers import import_csv
from ..services.replay import ReplayPlan
from ..validation import ID, IMAGE_NAME
from .deps import DeskDep, FrameIndex, RobotsDep, StoreDep, ViewerDep, read_upload
from .models import DryRun, Figures, FrameOut, JobStarted, ObserveState, RobotState, frame_out, robot_state

router = APIRouter()


class SessionSummary(BaseModel):
    id: str
    robot: str  # the robot on the desk (an instance name)
    name: str
    frames: int
    measured: int
    created: str
    source: str  # "sample" | "import" | "capture"


class SessionOut(BaseModel):
    id: str
    robot: str
    name: str
    description: str
    created: str
    source: str
    measured: int
    truth: dict[str, float | None] | None  # a simulated session's hidden true parameters
    frames: list[FrameOut]


class Created(BaseModel):
    id: str


class ImportedOut(BaseModel):
    id: str
    notes: list[str]  # worth the operator's eye, not refused: readings beyond a joint's limits (file, line, column)


class Deleted(BaseModel):
    deleted: str


class CalibrationSummary(BaseModel):
    id: str
    mode: str
    created: str
    base: str | None
    holdout: float
    figures: dict[str, Figures]  # before, after; holdout_before, holdout_after; cv_after


@router.get("/sessions")
def sessions(store: StoreDep) -> list[SessionSummary]:
    return [
        SessionSummary(
            id=s.id,
            robot=s.robot,
            name=s.name,
            frames=s.frames,
            measured=s.measured,
            created=s.created,
            source=s.source,
        )
        for s in store.sessions.list()
    ]


@router.get("/sessions/{session_id}")
def session(store: StoreDep, robots: RobotsDep, session_id: str) -> SessionOut:
    s = store.sessions.get(session_id)
    profile = robots.get(s.robot).profile
    counts = store.sessions.sensor_counts(session_id)
    return SessionOut(
        id=s.id,
        robot=s.robot,
        name=s.name,
        description=s.description,
        created=s.created,
        source=s.source,
        measured=s.measured,
        truth=s.truth,
        frames=[frame_out(profile, f, counts.get(f.index)) for f in store.sessions.frames(session_id)],
    )


class NewSession(BaseModel):
    robot: str
    name: str = Field(min_length=1, max_length=200)


@router.post("/sessions", status_code=201)
def create_session(store: StoreDep, robots: RobotsDep, body: NewSession) -> Created:
    robots.get(body.robot)
    return Created(id=store.sessions.create(body.robot, body.name, source="capture"))


@router.delete("/sessions/{session_id}")
def delete_session(store: StoreDep, session_id: str) -> Deleted:
    store.sessions.delete(session_id)
    return Deleted(deleted=session_id)


@router.post("/sessions/import", status_code=201)
async def import_session(
    desk: DeskDep,
    store: StoreDep,
    robots: RobotsDep,
    robot: Annotated[str, Form()],
    name: Annotated[str, Form(min_length=1, max_length=200)],
    data: Annotated[UploadFile, File()],
) -> ImportedOut:
    """A session from a CSV in the robot's pinned format; a mistake answers 422 naming line and column, a file
    beyond the desk's limits (its size, its rows) 413 naming the limit."""
    raw = await read_upload(desk, data)
    try:
        text = raw.decode("utf-8-sig")
    except UnicodeDecodeError as exc:
        raise HTTPException(422, f"{data.filename}: not UTF-8 text (byte {exc.start})") from None
    robots.get(robot)
    filename = Path(data.filename or "data.csv").name
    rows = text.count("\n") - 1 + (not text.endswith("\n"))  # less the header: at least the rows a parse would read
    if rows > desk.limits.rows:
        raise HTTPException(
            413,
            f"{filename}: {rows:,} rows; an import takes at most {desk.limits.rows:,} "
            "(the desk's row limit, --max-rows)",
        )
    imported = await asyncio.to_thread(import_csv, store, robot, name, text, filename)
    return ImportedOut(id=imported.id, notes=imported.notes)


@router.get("/sessions/{session_id}/calibrations")
def session_calibrations(store: StoreDep, session_id: str) -> list[CalibrationSummary]:
    store.sessions.get(session_id)
    return [
        CalibrationSummary(
            id=c.id, mode=c.mode, created=c.created, base=c.base_id, holdout=c.holdout, figures=c.figures
        )
        for c in store.calibrations.list(session_id=session_id)
    ]


class CalibrationRequest(BaseModel):
    mode: str
    base: str | None = None  # a calibration of the same robot to start from (None: the nominal model)
    holdout: float = Field(0.0, ge=0.0, le=0.9)
    folds: int = Field(0, ge=0, le=20)


@router.post("/sessions/{session_id}/calibrations", status_code=202)
def start_calibration(desk: DeskDep, session_id: str, body: CalibrationRequest) -> JobStarted:
    return JobStarted(job=desk.calibration.submit(session_id, body.mode, body.base, body.holdout, folds=body.folds))


@router.get("/files/sessions/{session_id}/images/{name}", responses={200: {"content": {"image/jpeg": {}}}})
def image_file(desk: DeskDep, session_id: str, name: str) -> FileResponse:
    if not ID.fullmatch(session_id) or not IMAGE_NAME.fullmatch(name):
        raise HTTPException(404, "no such image")
    path = desk.data_dir / "sessions" / session_id / "images" / name
    if not path.is_file():
        raise HTTPException(404, "no such image")
    return FileResponse(path, media_type="image/jpeg")


# --- capture, observe, replay ---------------------------------------------------------------------
class Captured(BaseModel):
    frame: FrameOut


@router.post("/sessions/{session_id}/capture", status_code=201)
def capture(desk: DeskDep, session_id: str) -> Captured:
    frame = desk.capture(session_id)
    return Captured(frame=frame_out(desk.robots.get(desk.store.sessions.get(session_id).robot).profile, frame))


class ObserveRequest(BaseModel):
    on: bool
    autocapture: bool = False


class Observing(BaseModel):
    observing: ObserveState | None  # None: not observing


@router.post("/sessions/{session_id}/observe")
def observe(desk: DeskDep, viewer: ViewerDep, session_id: str, body: ObserveRequest) -> Observing:
    desk.store.sessions.get(session_id)
    desk.observe(session_id if body.on else None, autocapture=body.autocapture, viewer=viewer)
    return Observing(observing=desk.observing())


class UntilRequest(BaseModel):
    """Capture until good enough: stop when the predicted mean error over the workspace reaches `error` (the
    measurement's unit: cm, px, m) or after `max` configurations."""

    error: float = Field(gt=0)
    max: int = Field(ge=1, le=2000)


class ReplayRequest(BaseModel):
    from_session: str | None = None
    count: int | None = Field(None, ge=1, le=2000)
    remeasure: bool = False
    dry_run: bool = False
    seed: int = Field(0, ge=0, le=2**32 - 1)  # numpy takes non-negative seeds only
    resume: bool = False  # leave out the configurations the session holds a frame at (go on after a fault)
    mode: str | None = None  # the calibration mode new configurations are planned for (default: full, or the first)
    planner: Literal["task", "random"] = "task"  # new configurations: planned for accuracy, or random
    until: UntilRequest | None = None  # plan each next configuration from the frames so far, until good enough


@router.post("/sessions/{session_id}/replay", responses={202: {"model": JobStarted}})
def start_replay(desk: DeskDep, session_id: str, body: ReplayRequest, response: Response) -> DryRun | JobStarted:
    """A replay answers 202 with its job. A dry run (`dry_run`: every configuration checked, nothing moves) of
    frames (`from_session`, `remeasure`) answers 200 with what it found; one of new configurations (`count`,
    `until`) 202 with its job, which plans them, checks them and predicts (its result: GET
    /api/jobs/{id}/dry-run)."""
    until = None if body.until is None else Until(body.until.error, body.until.max)
    plan = ReplayPlan(
        body.from_session, body.count, body.remeasure, body.seed, body.resume, body.mode, body.planner, until
    )
    if body.dry_run and plan.from_frames:
        return DryRun.model_validate(desk.replay.dry_run(session_id, plan))
    response.status_code = 202
    if body.dry_run:
        return JobStarted(job=desk.replay.start_dry_run(session_id, plan))
    return JobStarted(job=desk.replay.start(session_id, plan))


@router.post("/sessions/{session_id}/frames/{index}/goto", status_code=202)
def goto(desk: DeskDep, session_id: str, index: FrameIndex) -> RobotState:
    """Drive the session's robot to the configuration of one of its frames."""
    s = desk.store.sessions.get(session_id)
    frame = desk.store.sessions.frame(session_id, index)
    driver = desk.robots.driver(s.robot)
    driver.check(frame.joints_rad)
    driver.set_target(frame.target)
    driver.move_to(frame.joints_rad, wait=False)
    return robot_state(desk, s.robot)
