"""Jobs (calibrations, replays, dry runs): list, one, its progress as server-sent events, cancel / pause /
resume; a dry run job's result. A job is answered as its snapshot (app/jobs/snapshot.py)."""

from __future__ import annotations

import asyncio
from collections.abc import AsyncIterator
from typing import Annotated, Literal

from fastapi import APIRouter, Depends, Request
from fastapi.sse import EventSourceResponse

from ...jobs.snapshot import JobSnapshot
from .deps import JobsDep, ReplayDep
from .models import DryRun

router = APIRouter()


@router.get("/jobs")
def jobs(jobs: JobsDep, session: str | None = None) -> list[JobSnapshot]:
    return jobs.list(session)


@router.get("/jobs/{job_id}")
def job(jobs: JobsDep, job_id: str) -> JobSnapshot:
    return jobs.get(job_id)


def _first_snapshot(jobs: JobsDep, job_id: str) -> JobSnapshot:
    """Taken before the stream starts, so an unknown job answers 404 rather than breaking the stream."""
    return jobs.get(job_id)


@router.get("/jobs/{job_id}/events", response_class=EventSourceResponse)
async def job_events(
    request: Request, jobs: JobsDep, job_id: str, first: Annotated[JobSnapshot, Depends(_first_snapshot)]
) -> AsyncIterator[JobSnapshot]:
    """The job's snapshot now and on every change, until it has finished (or the server stops)."""
    snap = first
    yield snap
    closing = request.app.state.closing
    while not snap.state.finished and not closing.is_set() and not await request.is_disconnected():
        snap = await jobs.next_version(job_id, snap.version, 1.0) or await asyncio.to_thread(jobs.get, job_id)
        yield snap


@router.get("/jobs/{job_id}/dry-run")
def dry_run_result(replay: ReplayDep, job_id: str) -> DryRun:
    """What a dry run job found once it is done: the dry run's answer (every configuration checked, the
    predicted accuracy). 404 for a job that is not a dry run, or whose result is no longer kept; 422 while it
    runs, or when it ended cancelled or failed."""
    return DryRun.model_validate(replay.dry_run_result(job_id))


@router.post("/jobs/{job_id}/{action}")
def job_action(jobs: JobsDep, job_id: str, action: Literal["cancel", "pause", "resume"]) -> JobSnapshot:
    {"cancel": jobs.cancel, "pause": jobs.pause, "resume": jobs.resume}[action](job_id)
    return jobs.get(job_id)
