"""What tests of jobs share: a job runner on a manual clock (its time limits pass only when the test advances
the clock) and waiting for a job's changes, never for wall time."""

from __future__ import annotations

import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager

from app.clock import ManualClock
from app.jobs.runner import JobRunner
from app.jobs.snapshot import JobSnapshot
from app.store import Store

HOUR_S = 3600.0


@contextmanager
def manual_runner(store: Store) -> Iterator[JobRunner]:
    """A runner with one worker process on a ManualClock, shut down after."""
    runner = JobRunner(store, workers=1, clock=ManualClock())
    try:
        yield runner
    finally:
        runner.shutdown()


def manual_clock(runner: JobRunner) -> ManualClock:
    assert isinstance(runner.clock, ManualClock)
    return runner.clock


def finished(snap: JobSnapshot) -> bool:
    return snap.state.finished


def wait(
    jobs: JobRunner, job_id: str, until: Callable[[JobSnapshot], bool] = finished, timeout_s: float = 60.0
) -> JobSnapshot:
    """The job's snapshot once `until` holds, woken by each of its changes. `timeout_s` bounds the wall time (the
    waits are on the runner's clock, which a ManualClock does not move by itself)."""
    deadline = time.monotonic() + timeout_s
    snap = jobs.get(job_id)
    while not until(snap):
        assert time.monotonic() < deadline, f"job still {snap.state}, detail {snap.detail}"
        snap = jobs.wait_version(job_id, snap.version, HOUR_S)
    return snap
