"""Waiting for a job of an in-process desk (conftest.py's `client`), woken by each change of the job (what its
server-sent events send), not by polling: `timeout_s`, wall time, only bounds a failure."""

from __future__ import annotations

import time
from collections.abc import Callable

from fastapi.testclient import TestClient

from app.jobs.snapshot import JobSnapshot


def wait_for(client: TestClient, job: str, ok: Callable[[JobSnapshot], bool], timeout_s: float = 120.0) -> JobSnapshot:
    """The job's snapshot once `ok` holds for it; AssertionError if it ends or the time runs out before."""
    jobs = client.app.state.desk.jobs
    deadline = time.monotonic() + timeout_s
    snap = jobs.get(job)
    while not ok(snap):
        assert not snap.state.finished and time.monotonic() < deadline, snap
        snap = jobs.wait_version(job, snap.version, deadline - time.monotonic())
    return snap


def wait_job(client: TestClient, job: str, timeout_s: float = 120.0) -> dict:
    """The job's answer (GET /api/jobs/{job}) once it has finished."""
    wait_for(client, job, lambda snap: snap.state.finished, timeout_s)
    return client.get(f"/api/jobs/{job}").json()
