"""The job runner: background jobs, each with a versioned snapshot, on threads or in worker processes.

It knows no kind of job: a service gives it a function and its data (app/services/calibration.py runs the
solver in a worker process; app/services/replay.py drives a robot on a thread). The runner keeps the jobs (its
registry), their moves from state to state, their versions and their snapshots in the store, and answers
cancel, pause and resume. How a job runs is its way's own module: thread_jobs.py runs a function on a thread;
process_jobs.py builds a payload and runs a function in a worker process (pool.py), with its time limits.
Both reach the runner through job.py's JobStates.

Every change of a snapshot grows its `version` (wait_version and next_version wait for one); the store keeps
the snapshot on every change of state.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import secrets
import threading
from collections.abc import Callable
from datetime import UTC, datetime
from typing import TYPE_CHECKING, TypeVar

from calib_core import InputError
from calib_core.errors import Cancelled

from ..clock import Clock, SystemClock, wait_for
from ..errors import NotFound
from ..store.db import jsonable
from .job import Job, JobContext, spoken
from .process_jobs import ProcessJobs
from .snapshot import JobSnapshot, JobState
from .thread_jobs import start_thread
from .worker import WorkerLink

Payload = TypeVar("Payload")  # a process job's: what its prepare builds, its worker function takes
Value = TypeVar("Value")  # what its worker function returns, its finish takes

if TYPE_CHECKING:
    from ..store import Store

log = logging.getLogger(__name__)

SHUTDOWN_GRACE_S = 3.0  # at most this long for cancelled jobs to end at shutdown before their workers are killed


class JobRunner:
    def __init__(
        self,
        store: Store,
        workers: int = 1,
        *,
        clock: Clock | None = None,
        timeout_s: float = 1800.0,
        cancel_grace_s: float = 5.0,
        scrub: Callable[[str], str] | None = None,
    ) -> None:
        """`workers` worker processes. A worker still running after `timeout_s`, or `cancel_grace_s` after its job
        was cancelled (both on `clock`), is killed: the job fails, or ends cancelled. `scrub` takes the server's
        paths out of a failed job's message (the one the HTTP errors go through)."""
        self.store = store
        self.clock = clock or SystemClock()
        self._scrub = scrub or (lambda text: text)
        self._lock = threading.RLock()
        self._save_lock = threading.Lock()
        self.changed = threading.Condition(self._lock)  # notified at every change of a snapshot
        self._watchers: set[tuple[asyncio.AbstractEventLoop, asyncio.Event]] = set()  # streams waiting (next_version)
        self._jobs: dict[str, Job] = {}
        self._closed = False
        self._processes = ProcessJobs(self, workers, timeout_s=timeout_s, cancel_grace_s=cancel_grace_s)
        self.store.jobs.fail_interrupted()

    @property
    def timeout_s(self) -> float:
        """How long a worker may run its job (its kill, process_jobs.py's)."""
        return self._processes.timeout_s

    @property
    def cancel_grace_s(self) -> float:
        """How long a worker may go on after its job was cancelled."""
        return self._processes.cancel_grace_s

    # --- submitting ---------------------------------------------------------------------------------
    def submit_thread(
        self,
        kind: str,
        fn: Callable[[JobContext], str | None],
        *,
        session_id: str | None,
        detail: dict | None = None,
        pausable: bool = True,
    ) -> str:
        """Run fn(ctx) on a thread of its own; its return value is the job's result. `pausable=False`: a pause
        is refused (a job that only computes, a dry run, has nothing to hold still)."""
        job = self._create(kind, session_id, detail, process=False)
        job.pausable = pausable
        start_thread(self, job, fn)
        return job.snap.id

    def submit_process(
        self,
        kind: str,
        fn: Callable[[Payload, WorkerLink], Value],
        prepare: Callable[[JobContext], Payload],
        *,
        session_id: str | None,
        detail: dict | None = None,
        finish: Callable[[Value, JobContext], str | None] | None = None,
    ) -> str:
        """Queue fn(payload, link) for a worker process (fn: a module-level function of a light module, see
        worker.py). `prepare(ctx)` builds the payload in the server, on one thread in the order the jobs came,
        so the request that submits answers at once and a cancel meanwhile ends the job. `finish(value, ctx)`
        turns the worker's value into the job's result, in the server (default: the value as text)."""
        job = self._create(kind, session_id, detail, process=True)
        self._processes.submit(job, fn, prepare, finish)
        return job.snap.id

    # --- reading ------------------------------------------------------------------------------------
    def get(self, job_id: str) -> JobSnapshot:
        with self._lock:
            job = self._jobs.get(job_id)
            if job is not None:
                return job.snap.copy()
        return self.store.jobs.get(job_id)

    def list(self, session_id: str | None = None) -> list[JobSnapshot]:
        """Every job this store knows (this run's live, earlier runs' as stored), newest first."""
        stored = {j.id: j for j in self.store.jobs.list(session_id)}
        with self._lock:
            for job_id, job in self._jobs.items():
                if session_id is None or job.snap.session == session_id:
                    stored[job_id] = job.snap.copy()
        return sorted(stored.values(), key=lambda j: j.created, reverse=True)

    def wait_version(self, job_id: str, version: int, timeout_s: float) -> JobSnapshot:
        """The snapshot once its version exceeds `version`, or after `timeout_s` on the runner's clock."""
        with self.changed:
            job = self._jobs.get(job_id)
            if job is not None:
                wait_for(self.clock, self.changed, lambda: job.snap.version > version, timeout_s)
                return job.snap.copy()
        return self.store.jobs.get(job_id)

    async def next_version(self, job_id: str, version: int, timeout_s: float) -> JobSnapshot | None:
        """wait_version on the event loop: a server-sent event stream waits holding no thread, so open streams
        cannot starve the requests that need one. Its timeout, a stream's heartbeat and no job's limit, is on the
        loop's time. None for a job no longer in memory (read it from the store)."""
        loop = asyncio.get_running_loop()
        watcher = (loop, asyncio.Event())
        deadline = loop.time() + timeout_s
        with self._lock:
            self._watchers.add(watcher)
        try:
            while True:
                watcher[1].clear()  # before the check: a change after it sets the event again
                with self._lock:
                    job = self._jobs.get(job_id)
                    if job is None:
                        return None
                    if job.snap.version > version or loop.time() >= deadline:
                        return job.snap.copy()
                with contextlib.suppress(TimeoutError):
                    await asyncio.wait_for(watcher[1].wait(), deadline - loop.time())
        finally:
            with self._lock:
                self._watchers.discard(watcher)

    def worker_pid(self, job_id: str) -> int | None:
        """The process a running process job runs in (None before it starts)."""
        return self.job(job_id).pid

    # --- control ------------------------------------------------------------------------------------
    def cancel(self, job_id: str) -> None:
        """Waiting (for its payload or a worker): cancelled at once. Running: asked to stop (a worker that does
        not stop within cancel_grace_s is killed). Finished: nothing to do."""
        with self.changed:
            job = self.job(job_id)
            if job.snap.state.finished or job.cancel_requested:
                return
            job.cancel_requested = True
            job.cancel_at = self.clock.now()
            preparing = job.prepare is not None
            if job.process and job.snap.state == JobState.RUNNING:
                self._processes.arm(job)  # its deadline: now the cancel grace
            self.changed.notify_all()  # a paused job wakes to see it
        with job.hold:
            hooks, job.cancel_hooks = job.cancel_hooks, []
        for hook in hooks:
            hook()
        if preparing or (job.process and self._processes.withdraw(job)):  # not yet in a worker
            self.finish(job, JobState.CANCELLED)

    def pause(self, job_id: str) -> None:
        self._set_paused(job_id, True)

    def resume(self, job_id: str) -> None:
        self._set_paused(job_id, False)

    def shutdown(self) -> None:
        """Cancel everything; give the jobs a moment to stop, then stop their workers."""
        with self.changed:
            if self._closed:
                return
            self._closed = True
            live = [job for job in self._jobs.values() if not job.snap.state.finished]
        for job in live:
            self.cancel(job.snap.id)

        def ended() -> bool:
            return all(job.snap.state.finished for job in live)

        with self.changed:
            wait_for(self.clock, self.changed, ended, min(self.cancel_grace_s, SHUTDOWN_GRACE_S))
        self._processes.close(live)  # the workers of those still running killed

    # --- the jobs' moves (job.py's JobStates: what the kinds of job and a job's context call) ------------
    @property
    def closed(self) -> bool:
        return self._closed

    def job(self, job_id: str) -> Job:
        with self._lock:
            job = self._jobs.get(job_id)
        if job is None:
            raise NotFound.unknown("job", job_id)
        return job

    def touch(self, job: Job) -> None:
        """Call with the lock held after changing a snapshot."""
        job.snap.version += 1
        job.snap.updated = _now()
        self.changed.notify_all()
        for loop, event in self._watchers:
            loop.call_soon_threadsafe(event.set)

    def update(self, job: Job, fraction: float | None, detail: dict, cost: list[float] | None) -> None:
        with self.changed:
            if fraction is not None:
                job.snap.progress = min(1.0, max(0.0, float(fraction)))
            job.snap.detail.update(jsonable(detail))
            if cost is not None:
                job.snap.cost = [float(c) for c in cost]
            self.touch(job)

    def start(self, job: Job) -> None:
        with self.changed:
            if job.snap.state != JobState.QUEUED:
                return
            job.snap.state = JobState.RUNNING
            job.started = self.clock.now()
            if job.process:
                self._processes.arm(job)  # its worker's time limit
            self.touch(job)
        self._save(job)

    def checkpoint(self, job: Job) -> None:
        with self.changed:
            wait_for(self.clock, self.changed, lambda: not job.snap.paused or job.cancel_requested, None)
            if job.cancel_requested:
                raise Cancelled("cancelled")

    def finish(self, job: Job, state: JobState, result: str | None = None, error: str | None = None) -> None:
        with self.changed:
            if job.snap.state.finished:
                return
            if error is not None:  # a job's message is shown to the page: no path of the server in it
                error = self._scrub(error)
            job.snap.state, job.snap.result, job.snap.error, job.snap.paused = state, result, error, False
            if state == JobState.DONE:
                job.snap.progress = 1.0
            job.fn = job.prepare = job.finish = None
            if job.timer is not None:
                job.timer.cancel()
                job.timer = None
            self.touch(job)
        self._save(job)

    # --- internals ----------------------------------------------------------------------------------
    def _create(self, kind: str, session_id: str | None, detail: dict | None, *, process: bool) -> Job:
        if self._closed:
            raise RuntimeError("the job runner is shut down")
        now = _now()
        snap = JobSnapshot(
            id="j-" + secrets.token_hex(4),
            kind=kind,
            state=JobState.QUEUED,
            progress=0.0,
            result=None,
            error=None,
            session=session_id,
            created=now,
            updated=now,
            detail=dict(detail or {}),
        )
        job = Job(snap, process)
        with self._lock:
            self._jobs[snap.id] = job
        self._save(job)
        return job

    def _set_paused(self, job_id: str, paused: bool) -> None:
        job = self.job(job_id)
        kind = spoken(job.snap.kind)
        if job.process:
            raise InputError(f"a {kind} job runs in a worker process and cannot be paused; cancel it")
        if not job.pausable:
            raise InputError(f"a {kind} job cannot be paused; cancel it")
        with job.hold, self.changed:
            if job.snap.state.finished or job.snap.paused == paused:
                return
            job.snap.paused = paused
            self.touch(job)
        self._save(job)

    def _save(self, job: Job) -> None:
        """Store the snapshot as it is now. Never call with the lock held: saves are serialised, each
        taking its copy inside, so the last write is always the newest state."""
        with self._save_lock:
            with self._lock:
                snap = job.snap.copy()
            try:
                self.store.jobs.save(snap)
            except Exception:
                log.exception("job %s: its snapshot could not be stored", snap.id)


def _now() -> str:
    return datetime.now(UTC).isoformat(timespec="milliseconds")
