"""Sessions: list, one with its frames, create, delete, import a CSV; capture, observe, replay, go to a frame;
the frame images; a session's calibrations (list, start one)."""

from __future__ import annotations

import asyncio
from pathlib import Path
from typing import Annotated, Literal

from fastapi import APIRouter, File, Form, HTTPException, Response, UploadFile
from fastapi.responses import FileResponse
from pydantic import BaseModel, Field

from ...errors import TooLarge
from ...robots.capture import Until
from ...robots.flange_import import FlangeUpload, import_flange_session
from ...services.replay import ReplayPlan
from ...store.importers import csv_text, import_csv, measured_time
from ...store.validation import ID, IMAGE_NAME
from .deps import (
    CalibrationDep,
    CalibrationsDep,
    ConnectionDep,
    DriveDep,
    FrameIndex,
    LimitsDep,
    ReplayDep,
    RobotsDep,
    SessionsDep,
    StoreDep,
    ViewerDep,
    read_upload,
)
from .models import (
    DryRun,
    Figures,
    FrameOut,
    JobStarted,
    ObserveState,
    RobotState,
    frame_out,
    observe_state,
    robot_state,
)

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
def sessions(sessions: SessionsDep) -> list[SessionSummary]:
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
        for s in sessions.list()
    ]


@router.get("/sessions/{session_id}")
def session(sessions: SessionsDep, robots: RobotsDep, session_id: str) -> SessionOut:
    s = sessions.get(session_id)
    profile = robots.get(s.robot).profile
    counts = sessions.sensor_counts(session_id)
    return SessionOut(
        id=s.id,
        robot=s.robot,
        name=s.name,
        description=s.description,
        created=s.created,
        source=s.source,
        measured=s.measured,
        truth=s.truth,
        frames=[frame_out(profile, f, counts.get(f.index)) for f in sessions.frames(session_id)],
    )


class NewSession(BaseModel):
    robot: str
    name: str = Field(min_length=1, max_length=200)


@router.post("/sessions", status_code=201)
def create_session(sessions: SessionsDep, robots: RobotsDep, body: NewSession) -> Created:
    robots.get(body.robot)
    return Created(id=sessions.create(body.robot, body.name, source="capture"))


@router.delete("/sessions/{session_id}")
def delete_session(sessions: SessionsDep, session_id: str) -> Deleted:
    sessions.delete(session_id)
    return Deleted(deleted=session_id)


@router.post("/sessions/import", status_code=201)
async def import_session(
    store: StoreDep,
    robots: RobotsDep,
    limits: LimitsDep,
    robot: Annotated[str, Form()],
    name: Annotated[str, Form(min_length=1, max_length=200)],
    data: Annotated[UploadFile, File()],
    measured: Annotated[str | None, Form(max_length=64)] = None,
) -> ImportedOut:
    """A session from a CSV in the robot's pinned format, `measured` when its data were (ISO 8601, a date or a
    time; default now: a robot's history reads its calibrations in this order); a mistake answers 422 naming line
    and column (or the field), a file beyond the desk's limits (its size, its rows) 413 naming the limit."""
    when = measured_time(measured)
    raw = await read_upload(limits, data)
    robots.get(robot)
    filename = Path(data.filename or "data.csv").name
    text = csv_text(raw, filename, limits.rows)
    imported = await asyncio.to_thread(import_csv, store, robot, name, text, filename, when)
    return ImportedOut(id=imported.id, notes=imported.notes)


class FlangeImportedOut(BaseModel):
    id: str  # the session
    robot: str
    added: bool  # the robot is new on the desk: a robot known by its flange pose
    notes: list[str]  # images left out, and why


@router.post("/sessions/import-handeye", status_code=201)
async def import_handeye_session(
    robots: RobotsDep,
    limits: LimitsDep,
    robot: Annotated[str, Form(min_length=1, max_length=64)],
    name: Annotated[str, Form(min_length=1, max_length=200)],
    board: Annotated[str, Form(min_length=1, max_length=200)],
    poses: Annotated[UploadFile, File()],
    camera: Annotated[UploadFile, File()],
    images: Annotated[list[UploadFile], File()],
    setup: Annotated[Literal["eye-in-hand", "eye-to-hand"], Form()] = "eye-in-hand",
    length_unit: Annotated[Literal["m", "mm"], Form()] = "m",
    angle_unit: Annotated[Literal["rad", "deg"], Form()] = "rad",
    measured: Annotated[str | None, Form(max_length=64)] = None,
) -> FlangeImportedOut:
    """A session from images of a board and the flange pose the controller reported for each, as `calib handeye`
    takes them (specs handeye-poses.md): `poses` (CSV with x, y, z and a rotation vector or a quaternion, or one
    4 x 4 matrix a line), `camera` (ROS camera_info or OpenCV YAML), `images` (the image files, or one zip of them),
    `board` (`chessboard:9x6:18`, `charuco:8x6:30:22:5X5_100`), `setup`. `robot` names a robot known by its flange
    pose: added to the desk when new (its profile from these images: the corners' and the poses' noise they show),
    else this is another session of it. No pose is guessed. A mistake answers 422 naming the file (and line) or the
    field, and changes nothing; images whose board is not found are listed in `notes` and left out."""
    when = measured_time(measured)
    files = {}
    total = 0
    for upload in images:
        data = await read_upload(limits, upload)
        total += len(data)
        if total > limits.unpacked_bytes:
            raise TooLarge(f"images: more than {limits.unpacked_bytes // 2**20} MB together (the desk's limit)")
        files[Path(upload.filename or f"image-{len(files)}").name] = data
    upload = FlangeUpload(
        (poses.filename or "poses.csv", await read_upload(limits, poses)),
        (camera.filename or "camera.yaml", await read_upload(limits, camera)),
        files,
        board,
        setup,
        length_unit,
        angle_unit,
    )
    done = await asyncio.to_thread(
        import_flange_session, robots, robot, name, upload, measured=when, max_unpacked_bytes=limits.unpacked_bytes
    )
    return FlangeImportedOut(id=done.id, robot=done.robot, added=done.added, notes=done.notes)


@router.get("/sessions/{session_id}/calibrations")
def session_calibrations(
    sessions: SessionsDep, calibrations: CalibrationsDep, session_id: str
) -> list[CalibrationSummary]:
    sessions.get(session_id)
    return [
        CalibrationSummary(
            id=c.id, mode=c.mode, created=c.created, base=c.base_id, holdout=c.holdout, figures=c.figures
        )
        for c in calibrations.list(session_id=session_id)
    ]


class CalibrationRequest(BaseModel):
    mode: str
    base: str | None = None  # a calibration of the same robot to start from (None: the nominal model)
    holdout: float = Field(0.0, ge=0.0, le=0.9)
    folds: int = Field(0, ge=0, le=20)


@router.post("/sessions/{session_id}/calibrations", status_code=202)
def start_calibration(calibration: CalibrationDep, session_id: str, body: CalibrationRequest) -> JobStarted:
    return JobStarted(job=calibration.submit(session_id, body.mode, body.base, body.holdout, folds=body.folds))


@router.get("/files/sessions/{session_id}/images/{name}", responses={200: {"content": {"image/jpeg": {}}}})
def image_file(sessions: SessionsDep, session_id: str, name: str) -> FileResponse:
    if not ID.fullmatch(session_id) or not IMAGE_NAME.fullmatch(name):
        raise HTTPException(404, "no such image")
    path = sessions.folder(session_id) / "images" / name
    if not path.is_file():
        raise HTTPException(404, "no such image")
    return FileResponse(path, media_type="image/jpeg")


# --- capture, observe, replay ---------------------------------------------------------------------
class Captured(BaseModel):
    frame: FrameOut


@router.post("/sessions/{session_id}/capture", status_code=201)
def capture(drive: DriveDep, sessions: SessionsDep, robots: RobotsDep, session_id: str) -> Captured:
    frame = drive.capture(session_id)
    return Captured(frame=frame_out(robots.get(sessions.get(session_id).robot).profile, frame))


class ObserveRequest(BaseModel):
    on: bool
    autocapture: bool = False


class Observing(BaseModel):
    observing: ObserveState | None  # None: not observing


@router.post("/sessions/{session_id}/observe")
def observe(
    connection: ConnectionDep, sessions: SessionsDep, viewer: ViewerDep, session_id: str, body: ObserveRequest
) -> Observing:
    sessions.get(session_id)
    connection.observe(session_id if body.on else None, autocapture=body.autocapture, viewer=viewer)
    return Observing(observing=observe_state(connection.observing()))


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
def start_replay(replay: ReplayDep, session_id: str, body: ReplayRequest, response: Response) -> DryRun | JobStarted:
    """A replay answers 202 with its job. A dry run (`dry_run`: every configuration checked, nothing moves) of
    frames (`from_session`, `remeasure`) answers 200 with what it found; one of new configurations (`count`,
    `until`) 202 with its job, which plans them, checks them and predicts (its result: GET
    /api/jobs/{id}/dry-run)."""
    until = None if body.until is None else Until(body.until.error, body.until.max)
    plan = ReplayPlan(
        body.from_session, body.count, body.remeasure, body.seed, body.resume, body.mode, body.planner, until
    )
    if body.dry_run and plan.from_frames:
        return DryRun.model_validate(replay.dry_run(session_id, plan))
    response.status_code = 202
    if body.dry_run:
        return JobStarted(job=replay.start_dry_run(session_id, plan))
    return JobStarted(job=replay.start(session_id, plan))


@router.post("/sessions/{session_id}/frames/{index}/goto", status_code=202)
def goto(drive: DriveDep, connection: ConnectionDep, session_id: str, index: FrameIndex) -> RobotState:
    """Drive the session's robot to the configuration of one of its frames."""
    return robot_state(connection, drive.goto(session_id, index))
