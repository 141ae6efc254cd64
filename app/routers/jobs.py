"""Jobs (calibrations, replays, dry runs): list, one, its progress as server-sent events, cancel / pause /
resume; a dry run job's result."""

from __future__ import annotations

import asyncio
from collections.abc import AsyncIterator
from typing import Annotated, Any, Literal

from fastapi import APIRouter, Depends, Request
from fastapi.sse import EventSourceResponse
from pydantic import BaseModel

from .deps import DeskDep, JobsDep
from .models import DryRun

router = APIRouter()


class JobOut(BaseModel):
    id: str
    kind: str  # "calibration" | "replay" | "dry_run"
    state: str  # "queued" | "running" | "done" | "failed" | "cancelled"
    progress: float  # 0..1
    result: str | None  # a calibration job's calibration id, a replay's or a dry run's session id
    error: str | None  # why it failed, one sentence
    session: str | None
    created: str
    updated: str
    detail: dict[str, Any] = {}  # what the job reports as it runs (phase, frames measured, iterations, ...)
    cost: list[float | None] = []  # a calibration's cost per iteration
    version: int = 0  # grows with every change
    paused: bool = False


@router.get("/jobs")
def jobs(jobs: JobsDep, session: str | None = None) -> list[JobOut]:
    return [JobOut.model_validate(j) for j in jobs.list(session)]


@router.get("/jobs/{job_id}")
def job(jobs: JobsDep, job_id: str) -> JobOut:
    return JobOut.model_validate(jobs.get(job_id))


def _first_snapshot(jobs: JobsDep, job_id: str) -> dict[str, Any]:
    """Taken before the stream starts, so an unknown job answers 404 rather than breaking the stream."""
    return jobs.get(job_id)


@router.get("/jobs/{job_id}/events", response_class=EventSourceResponse)
async def job_events(
    request: Request, jobs: JobsDep, job_id: str, first: Annotated[dict[str, Any], Depends(_first_snapshot)]
) -> AsyncIterator[JobOut]:
    """The job's snapshot now and on every change, until it has finished."""
    snap = first
    yield JobOut.model_validate(snap)
    while snap["state"] in ("queued", "running", "paused") and not await request.is_disconnected():
        snap = await jobs.next_version(job_id, snap["version"], 1.0) or await asyncio.to_thread(jobs.get, job_id)
        yield JobOut.model_validate(snap)


@router.get("/jobs/{job_id}/dry-run")
def dry_run_result(desk: DeskDep, job_id: str) -> DryRun:
    """What a dry run job found once it is done: the dry run's answer (every configuration checked, the
    predicted accuracy). 404 for a job that is not a dry run, or whose result is no longer kept; 422 while it
    runs, or when it ended cancelled or failed."""
    return DryRun.model_validate(desk.replay.dry_run_result(job_id))


@router.post("/jobs/{job_id}/{action}")
def job_action(jobs: JobsDep, job_id: str, action: Literal["cancel", "pause", "resume"]) -> JobOut:
    {"cancel": jobs.cancel, "pause": jobs.pause, "resume": jobs.resume}[action](job_id)
    return JobOut.model_validate(jobs.get(job_id))
