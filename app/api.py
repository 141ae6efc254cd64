"""The JSON API under /api (specs/api.md is the pinned part; the rest serves the page).

Every handler is a thin call into the Desk. Bad input answers 4xx with {"detail": "..."}: unknown
ids 404, the user's mistakes 422 (a CSV's line and column, a joint and its limit), never a 500 or a
traceback. Handlers that touch viser or the store are plain `def` (FastAPI runs them in its thread
pool), so the event loop never waits on them.
"""

from __future__ import annotations

import asyncio
import json
import math
import re
from collections.abc import AsyncIterator
from pathlib import Path
from typing import Annotated, Any, Literal

import numpy as np
from fastapi import APIRouter, Depends, File, Form, HTTPException, Request, UploadFile
from fastapi import Path as PathParam
from fastapi.responses import FileResponse, Response
from fastapi.sse import EventSourceResponse
from pydantic import BaseModel, Field

from calib_core import InputError
from calib_core.io.export import calibrated_urdf, offsets_yaml

from .desk import Desk
from .store import FrameInfo

VERSION = "0.4.0"
MAX_UPLOAD_BYTES = 20 * 1024 * 1024
ROBOT_EVENT_PERIOD_S = 0.1
IMAGE_NAME = re.compile(r"^\d{4}_[a-z]+\.jpg$")
ID = re.compile(r"^[A-Za-z0-9][A-Za-z0-9._-]{0,80}$")


# Every 4xx answer is one sentence naming what is wrong (app/server.py's handlers), also for the
# event streams; declared here so that the OpenAPI document tells the truth about it.
PROBLEM = {
    "description": 'Bad input: {"detail": one sentence naming the problem}',
    "content": {
        "application/json": {
            "schema": {"type": "object", "properties": {"detail": {"type": "string"}}, "required": ["detail"]}
        }
    },
}
router = APIRouter(prefix="/api", responses={"4XX": PROBLEM})
# A frame number as the store keeps it (SQLite INTEGER): beyond it a 422, not an overflow deep inside.
FrameIndex = Annotated[int, PathParam(ge=-(2**63), le=2**63 - 1, description="a frame number")]


def desk(request: Request) -> Desk:
    return request.app.state.desk


def _deg(profile_joint_names: list[str], q_rad: np.ndarray) -> dict[str, float | None]:
    return {
        name: (None if not math.isfinite(v) else round(math.degrees(v), 4))
        for name, v in zip(profile_joint_names, q_rad, strict=True)
    }


def _frame_json(d: Desk, robot: str, f: FrameInfo) -> dict[str, Any]:
    return {
        "index": f.index,
        "joints": _deg(d.profile(robot).joint_names, f.joints_rad),
        "target": d.profile(robot).targets[f.target].name,
        "status": f.status,
        "reason": f.reason,
        "images": {role: f"/api/files/{path}" for role, path in f.images.items()},
        "detail": f.detail,
        "captured": f.captured,
    }


# --- health and robots ------------------------------------------------------------------------
@router.get("/health")
def health(request: Request) -> dict[str, Any]:
    return {"status": "ok", "version": VERSION, "viser_port": desk(request).viser_port_number}


@router.get("/robots")
def robots(request: Request) -> list[dict[str, Any]]:
    """Every robot: `simulated` ones can be connected, moved, observed and replayed; the others (real data
    only) have sessions imported from CSV, calibrations and reviews."""
    d = desk(request)
    out = []
    for name in d.robots:
        p = d.profile(name)
        sensor = p.sensors[p.data.sensor]
        out.append(
            {
                "name": name,
                "title": p.title,
                "simulated": name in d.drivers,
                "joints": [
                    {
                        "name": j.name,
                        "lower_deg": math.degrees(j.lower),
                        "upper_deg": math.degrees(j.upper),
                        "velocity_deg_s": math.degrees(j.velocity),
                    }
                    for j in p.joints
                ],
                "modes": [{"name": m.name, "description": m.description} for m in p.modes.values()],
                "targets": [t.name for t in p.targets],
                "sensor": {
                    "kind": sensor.kind,
                    "unit": sensor.unit,
                    "image": list(sensor.image) if getattr(sensor, "image", None) else None,
                },
            }
        )
    return out


# --- sessions ---------------------------------------------------------------------------------
@router.get("/sessions")
def sessions(request: Request) -> list[dict[str, Any]]:
    return [
        {
            "id": s.id,
            "robot": s.robot,
            "name": s.name,
            "frames": s.frames,
            "measured": s.measured,
            "created": s.created,
            "source": s.source,
        }
        for s in desk(request).store.sessions()
    ]


@router.get("/sessions/{session_id}")
def session(request: Request, session_id: str) -> dict[str, Any]:
    d = desk(request)
    s = d.store.session(session_id)
    return {
        "id": s.id,
        "robot": s.robot,
        "name": s.name,
        "description": s.description,
        "created": s.created,
        "source": s.source,
        "measured": s.measured,
        "truth": s.truth,
        "frames": [_frame_json(d, s.robot, f) for f in d.store.frames(session_id)],
    }


class NewSession(BaseModel):
    robot: str
    name: str = Field(min_length=1, max_length=200)


@router.post("/sessions", status_code=201)
def create_session(request: Request, body: NewSession) -> dict[str, str]:
    d = desk(request)
    d.profile(body.robot)
    return {"id": d.store.create_session(body.robot, body.name, source="capture")}


@router.delete("/sessions/{session_id}")
def delete_session(request: Request, session_id: str) -> dict[str, str]:
    desk(request).store.delete_session(session_id)
    return {"deleted": session_id}


@router.post("/sessions/import", status_code=201)
async def import_session(
    request: Request,
    robot: Annotated[str, Form()],
    name: Annotated[str, Form(min_length=1, max_length=200)],
    data: Annotated[UploadFile, File()],
) -> dict[str, str]:
    raw = await data.read(MAX_UPLOAD_BYTES + 1)
    if len(raw) > MAX_UPLOAD_BYTES:
        raise HTTPException(413, f"{data.filename}: larger than {MAX_UPLOAD_BYTES // (1024 * 1024)} MB")
    try:
        text = raw.decode("utf-8-sig")
    except UnicodeDecodeError as exc:
        raise HTTPException(422, f"{data.filename}: not UTF-8 text (byte {exc.start})") from None
    d = desk(request)
    d.profile(robot)
    filename = Path(data.filename or "data.csv").name
    session_id = await asyncio.to_thread(d.store.import_csv, robot, name, text, filename)
    return {"id": session_id}


@router.get("/sessions/{session_id}/calibrations")
def session_calibrations(request: Request, session_id: str) -> list[dict[str, Any]]:
    d = desk(request)
    d.store.session(session_id)
    return [
        {
            "id": c.id,
            "mode": c.mode,
            "created": c.created,
            "base": c.base_id,
            "holdout": c.holdout,
            "figures": c.figures,
        }
        for c in d.store.calibrations(session_id=session_id)
    ]


@router.get("/files/sessions/{session_id}/images/{name}", responses={200: {"content": {"image/jpeg": {}}}})
def image_file(request: Request, session_id: str, name: str) -> FileResponse:
    if not ID.match(session_id) or not IMAGE_NAME.match(name):
        raise HTTPException(404, "no such image")
    path = desk(request).data_dir / "sessions" / session_id / "images" / name
    if not path.is_file():
        raise HTTPException(404, "no such image")
    return FileResponse(path, media_type="image/jpeg")


# --- calibrations and jobs --------------------------------------------------------------------
class CalibrationRequest(BaseModel):
    mode: str
    base: str | None = None
    holdout: float = Field(0.0, ge=0.0, le=0.9)
    folds: int = Field(0, ge=0, le=20)


@router.post("/sessions/{session_id}/calibrations", status_code=202)
def start_calibration(request: Request, session_id: str, body: CalibrationRequest) -> dict[str, str]:
    d = desk(request)
    job = d.jobs.submit_calibration(session_id, body.mode, body.base, body.holdout, folds=body.folds)
    return {"job": job}


@router.get("/jobs")
def jobs(request: Request, session: str | None = None) -> list[dict[str, Any]]:
    return [j for j in desk(request).jobs.list() if session is None or j.get("session") == session]


@router.get("/jobs/{job_id}")
def job(request: Request, job_id: str) -> dict[str, Any]:
    return desk(request).jobs.get(job_id)


def _first_snapshot(request: Request, job_id: str) -> dict[str, Any]:
    """Taken before the stream starts, so an unknown job answers 404 rather than breaking the stream."""
    return desk(request).jobs.get(job_id)


@router.get("/jobs/{job_id}/events", response_class=EventSourceResponse)
async def job_events(
    request: Request, job_id: str, first: Annotated[dict[str, Any], Depends(_first_snapshot)]
) -> AsyncIterator[dict[str, Any]]:
    d = desk(request)
    snap = first
    yield snap
    while snap["state"] in ("queued", "running", "paused") and not await request.is_disconnected():
        snap = await asyncio.to_thread(d.jobs.wait_version, job_id, snap["version"], 1.0)
        yield snap


@router.post("/jobs/{job_id}/{action}")
def job_action(request: Request, job_id: str, action: Literal["cancel", "pause", "resume"]) -> dict[str, Any]:
    d = desk(request)
    getattr(d.jobs, action)(job_id)
    return d.jobs.get(job_id)


@router.get("/calibrations/{cal_id}")
def calibration(request: Request, cal_id: str) -> dict[str, Any]:
    d = desk(request)
    info = d.store.calibration_info(cal_id)
    body = d.store.calibration(cal_id).to_dict()
    return {**body, "id": cal_id, "session": info.session_id, "base": info.base_id, "holdout": info.holdout}


class ApplyRequest(BaseModel):
    note: str = Field("", max_length=500)
    confirm: bool = False  # apply even if it is worse than the active one or moves beyond sane bounds


class ApplyConcerns(BaseModel):
    """409: what needs the operator's confirmation (re-post with {"confirm": true})."""

    detail: str
    reasons: list[str]


@router.post("/calibrations/{cal_id}/apply", responses={409: {"model": ApplyConcerns}})
def apply(request: Request, cal_id: str, body: ApplyRequest | None = None) -> dict[str, Any]:
    body = body or ApplyRequest()
    return desk(request).apply(cal_id, body.note, confirm=body.confirm)


@router.get(
    "/calibrations/{cal_id}/export",
    responses={200: {"content": {"application/json": {}, "application/yaml": {}, "application/xml": {}}}},
)
def export(request: Request, cal_id: str, format: Literal["json", "yaml", "urdf"] = "json") -> Response:
    d = desk(request)
    cal = d.store.calibration(cal_id)
    profile = d.profile(cal.robot)
    if format == "json":
        text, media = json.dumps(cal.to_dict(), indent=2) + "\n", "application/json"
    elif format == "yaml":
        text, media = offsets_yaml(profile, cal), "application/yaml"
    else:
        text, media = calibrated_urdf(profile, cal), "application/xml"
    name = f"{cal.robot}-{cal.mode}-{cal_id}.{ {'json': 'json', 'yaml': 'offsets.yaml', 'urdf': 'urdf'}[format] }"
    return Response(text, media_type=media, headers={"Content-Disposition": f'attachment; filename="{name}"'})


# --- the robot --------------------------------------------------------------------------------
def _robot_json(d: Desk, robot: str | None) -> dict[str, Any]:
    driver = d.driver(robot)
    st = driver.status()
    profile = driver.profile
    return {
        "robot": st.robot,
        "connected": st.connected,
        "moving": st.moving,
        "joints": _deg(profile.joint_names, st.joints_rad),
        "target": profile.targets[st.target].name,
        "calibration": st.calibration_id,
        "message": st.message,
        "observing": d.observing(),
    }


@router.get("/robot")
def robot(request: Request, robot: str | None = None) -> dict[str, Any]:
    return _robot_json(desk(request), robot)


def _known_robot(request: Request, robot: str | None = None) -> str | None:
    """Checked before the stream starts, so an unknown robot answers 422 rather than breaking the stream."""
    desk(request).driver(robot)
    return robot


@router.get("/robot/events", response_class=EventSourceResponse)
async def robot_events(
    request: Request, robot: Annotated[str | None, Depends(_known_robot)]
) -> AsyncIterator[dict[str, Any]]:
    d = desk(request)
    while not await request.is_disconnected():
        yield _robot_json(d, robot)
        await asyncio.sleep(ROBOT_EVENT_PERIOD_S)


@router.get("/robot/calibration")
def robot_calibration(request: Request, robot: str | None = None) -> dict[str, Any]:
    d = desk(request)
    robot = robot or d.connected
    d.profile(robot)
    cal_id = d.store.active(robot)
    if cal_id is None:
        return {"id": None, "robot": robot, "model": "nominal"}
    info = d.store.calibration_info(cal_id)
    history = d.store.history(robot)
    return {
        "id": cal_id,
        "robot": robot,
        "mode": info.mode,
        "session": info.session_id,
        "created": info.created,
        "applied": history[0]["time"] if history else None,
        "figures": info.figures,
    }


@router.get("/robot/history")
def robot_history(request: Request, robot: str | None = None) -> list[dict[str, Any]]:
    d = desk(request)
    robot = robot or d.connected
    d.profile(robot)
    return d.store.history(robot)


class ConnectRequest(BaseModel):
    robot: str


@router.post("/robot/connect")
def connect(request: Request, body: ConnectRequest) -> dict[str, Any]:
    d = desk(request)
    d.connect(body.robot)
    return _robot_json(d, body.robot)


class MoveRequest(BaseModel):
    joints: dict[str, float]  # name -> deg; joints not named keep their current angle
    robot: str | None = None


@router.post("/robot/move", status_code=202)
def move(request: Request, body: MoveRequest) -> dict[str, Any]:
    d = desk(request)
    driver = d.driver(body.robot)
    names = driver.profile.joint_names
    q = driver.status().joints_rad.copy()
    for name, value in body.joints.items():
        if name not in names:
            raise InputError(f"joints.{name}: no such joint (known: {', '.join(names)})")
        if not math.isfinite(value):
            raise InputError(f"joints.{name}: {value} is not a finite angle")
        q[names.index(name)] = math.radians(value)
    driver.check(q)
    driver.move_to(q, wait=False)
    return _robot_json(d, body.robot)


@router.post("/robot/stop")
def stop(request: Request) -> dict[str, Any]:
    """Halt every robot and every motion job at once."""
    d = desk(request)
    for job_snapshot in d.jobs.list():
        if job_snapshot["kind"] == "replay" and job_snapshot["state"] in ("queued", "running", "paused"):
            d.jobs.cancel(job_snapshot["id"])
    for driver in d.drivers.values():
        if hasattr(driver, "wander"):
            driver.wander(False)
        driver.stop()
    return _robot_json(d, None)


class WanderRequest(BaseModel):
    on: bool
    robot: str | None = None


@router.post("/robot/wander")
def wander(request: Request, body: WanderRequest) -> dict[str, Any]:
    d = desk(request)
    driver = d.driver(body.robot)
    if not hasattr(driver, "wander"):
        raise InputError(f"{driver.profile.name} is a real robot: someone else drives it")
    driver.wander(body.on)
    return _robot_json(d, body.robot)


# --- capture ----------------------------------------------------------------------------------
@router.post("/sessions/{session_id}/capture", status_code=201)
def capture(request: Request, session_id: str) -> dict[str, Any]:
    d = desk(request)
    frame = d.capture(session_id)
    return {"frame": _frame_json(d, d.store.session(session_id).robot, frame)}


class ObserveRequest(BaseModel):
    on: bool
    autocapture: bool = False


@router.post("/sessions/{session_id}/observe")
def observe(request: Request, session_id: str, body: ObserveRequest) -> dict[str, Any]:
    d = desk(request)
    d.store.session(session_id)
    d.observe(session_id if body.on else None, autocapture=body.autocapture)
    return {"observing": d.observing()}


class ReplayRequest(BaseModel):
    from_session: str | None = None
    count: int | None = Field(None, ge=1, le=2000)
    remeasure: bool = False
    dry_run: bool = False
    seed: int = Field(0, ge=0, le=2**32 - 1)  # numpy takes non-negative seeds only
    resume: bool = False  # leave out the configurations the session holds a frame at (go on after a fault)


@router.post("/sessions/{session_id}/replay")
def start_replay(request: Request, session_id: str, body: ReplayRequest, response: Response) -> dict[str, Any]:
    d = desk(request)
    plan = {
        "from_session": body.from_session,
        "count": body.count,
        "remeasure": body.remeasure,
        "seed": body.seed,
        "resume": body.resume,
    }
    if body.dry_run:
        return d.dry_run(session_id, **plan)
    response.status_code = 202
    return {"job": d.start_replay(session_id, **plan)}


@router.post("/sessions/{session_id}/frames/{index}/goto", status_code=202)
def goto(request: Request, session_id: str, index: FrameIndex) -> dict[str, Any]:
    d = desk(request)
    s = d.store.session(session_id)
    frame = d.store.frame(session_id, index)
    driver = d.driver(s.robot)
    driver.check(frame.joints_rad)
    driver.set_target(frame.target)
    driver.move_to(frame.joints_rad, wait=False)
    return _robot_json(d, s.robot)


# --- review -----------------------------------------------------------------------------------
class ReviewRequest(BaseModel):
    session: str
    old: str | None = "active"
    new: str | None = None


@router.post("/review")
def review(request: Request, body: ReviewRequest) -> dict[str, Any]:
    return desk(request).review(body.session, body.old, body.new)


class SelectRequest(BaseModel):
    index: int = Field(ge=-(2**63), le=2**63 - 1)
    all: bool = False
    overlay: bool = False


@router.post("/review/frame")
def select(request: Request, body: SelectRequest) -> dict[str, Any]:
    return desk(request).select(body.index, show_all=body.all, overlay=body.overlay)


@router.get("/review/marks/{index}")
def marks(request: Request, index: FrameIndex) -> dict[str, Any]:
    return desk(request).marks(index)
