"""The job runner: background jobs on threads or in worker processes (pool.py), each with a versioned snapshot.

It knows no kind of job: a service gives it a function and its data (app/services/calibration.py runs the
solver in a worker process; app/services/replay.py drives a robot on a thread). A worker still running
`timeout_s` after its job started, or `cancel_grace_s` after its job was cancelled, is killed by a timer of the
runner's clock (app/clock.py), and replaced.

Every change of a snapshot grows its `version` (wait_version and next_version wait for one); the store keeps
the snapshot on every change of state.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import queue
import secrets
import threading
from collections.abc import Callable
from dataclasses import dataclass, field
from datetime import UTC, datetime
from functools import partial
from typing import TYPE_CHECKING, Any, TypeVar

from calib_core import InputError
from calib_core.errors import Cancelled

from ..clock import Clock, SystemClock, Timer, wait_for
from ..errors import NotFound
from ..store import StoreWriteError
from ..store.db import jsonable
from .pool import WorkerPool
from .snapshot import JobSnapshot, JobState
from .worker import WorkerLink, internal_error, one_line

if TYPE_CHECKING:
    from ..store import Store

log = logging.getLogger(__name__)

PROGRESS_CAP = 0.95  # an iterative job's end is unknown until it comes: its estimate stays below 1 until then
SHUTDOWN_GRACE_S = 3.0  # at most this long for cancelled jobs to end at shutdown before their workers are killed
KILLED_ON_CANCEL = "cancelled"  # a kill's reason when the worker ignored a cancel: the job ends cancelled

T = TypeVar("T")
Prepare = Callable[["JobContext"], Any]  # builds a process job's payload, in the server
Finish = Callable[[Any, "JobContext"], str | None]  # turns a process job's value into its result, in the server


def crashed(kind: str) -> str:
    """A process job's error when its worker died under it."""
    return f"the {_spoken(kind)} worker process stopped unexpectedly (crashed or killed); the worker was restarted"


class JobContext:
    """What a job's own code sees of it: a thread job's function, a process job's prepare and finish."""

    def __init__(self, runner: JobRunner, job: _Job) -> None:
        self._runner = runner
        self._job = job
        self.job_id = job.snap.id

    def progress(self, fraction: float, **detail: Any) -> None:
        """Report progress (0..1); `detail` is merged into the job's detail."""
        self._runner._update(self._job, fraction, detail, None)

    def report(self, *, cost: list[float] | None = None, **detail: Any) -> None:
        """Merge `detail` into the job's detail, and replace its cost history when given; progress stays."""
        self._runner._update(self._job, None, detail, cost)

    def checkpoint(self) -> None:
        """Blocks while the job is paused; raises Cancelled once it is cancelled."""
        self._runner._checkpoint(self._job)

    def on_cancel(self, fn: Callable[[], object]) -> None:
        """Call fn (at once, on the cancelling thread) when the job is cancelled, or now if it is: a job waiting on a
        robot is let go of then (a replay stops its robot), not at its next checkpoint."""
        with self._job.hold:
            if not self._job.cancel_requested:
                self._job.cancel_hooks.append(fn)
                return
        fn()

    def unless_paused(self, fn: Callable[[], T]) -> T | None:
        """fn() unless the job is paused or cancelled (None then): a pause answered before it comes finds fn not
        run, and one asked while fn runs is answered once it has (what a replay keeps, its frames, never
        comes after the pause)."""
        with self._job.hold:
            if self._job.snap.paused or self._job.cancel_requested:
                return None
            return fn()

    @property
    def cancelled(self) -> bool:
        return self._job.cancel_requested

    @property
    def paused(self) -> bool:
        return self._job.snap.paused


@dataclass
class _Job:
    snap: JobSnapshot
    process: bool
    fn: Callable[[Any, WorkerLink], Any] | None = None  # a process job's worker function
    prepare: Prepare | None = None  # set until the payload is built (the job is not yet queued for a worker)
    finish: Finish | None = None
    pausable: bool = True  # a thread job that may be held at its checkpoints
    cancel_requested: bool = False
    cancel_at: float = 0.0
    started: float = 0.0
    pid: int | None = None
    kill_reason: str | None = None  # set when the runner kills the worker on purpose
    timer: Timer | None = None  # the running process job's time limit (or cancel grace)
    hold: threading.Lock = field(default_factory=threading.Lock)  # a pause waits for a step unless_paused runs
    cancel_hooks: list[Callable[[], object]] = field(default_factory=list)  # JobContext.on_cancel's


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
        self.timeout_s = timeout_s
        self.cancel_grace_s = cancel_grace_s
        self._scrub = scrub or (lambda text: text)
        self._lock = threading.RLock()
        self._save_lock = threading.Lock()
        self._changed = threading.Condition(self._lock)
        self._watchers: set[tuple[asyncio.AbstractEventLoop, asyncio.Event]] = set()  # streams waiting (next_version)
        self._jobs: dict[str, _Job] = {}
        self._closed = False
        self._pool = WorkerPool(
            workers, started=self._worker_started, stepped=self._worker_stepped, ended=self._worker_ended
        )
        self.store.jobs.fail_interrupted()
        self._loads: queue.SimpleQueue[_Job | None] = queue.SimpleQueue()
        self._loader = threading.Thread(target=self._load_payloads, name="jobs-load", daemon=True)
        self._loader.start()

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
        job_id = job.snap.id
        threading.Thread(target=self._run_thread, args=(job, fn), name=f"job-{job_id}", daemon=True).start()
        return job_id

    def submit_process(
        self,
        kind: str,
        fn: Callable[[Any, WorkerLink], Any],
        prepare: Prepare,
        *,
        session_id: str | None,
        detail: dict | None = None,
        finish: Finish | None = None,
    ) -> str:
        """Queue fn(payload, link) for a worker process (fn: a module-level function of a light module, see
        worker.py). `prepare(ctx)` builds the payload in the server, on one thread in the order the jobs came,
        so the request that submits answers at once and a cancel meanwhile ends the job. `finish(value, ctx)`
        turns the worker's value into the job's result, in the server (default: the value as text)."""
        job = self._create(kind, session_id, detail, process=True)
        job.fn, job.prepare, job.finish = fn, prepare, finish
        self._loads.put(job)
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
        with self._changed:
            job = self._jobs.get(job_id)
            if job is not None:
                wait_for(self.clock, self._changed, lambda: job.snap.version > version, timeout_s)
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
        return self._job(job_id).pid

    # --- control ------------------------------------------------------------------------------------
    def cancel(self, job_id: str) -> None:
        """Waiting (for its payload or a worker): cancelled at once. Running: asked to stop (a worker that does
        not stop within cancel_grace_s is killed). Finished: nothing to do."""
        with self._changed:
            job = self._job(job_id)
            if job.snap.state.finished or job.cancel_requested:
                return
            job.cancel_requested = True
            job.cancel_at = self.clock.now()
            preparing = job.prepare is not None
            if job.process and job.snap.state == JobState.RUNNING:
                self._arm(job)
            self._changed.notify_all()  # a paused job wakes to see it
        with job.hold:
            hooks, job.cancel_hooks = job.cancel_hooks, []
        for hook in hooks:
            hook()
        if preparing or (job.process and self._pool.cancel(job_id)):  # not yet in a worker
            self._finish(job, JobState.CANCELLED)

    def pause(self, job_id: str) -> None:
        self._set_paused(job_id, True)

    def resume(self, job_id: str) -> None:
        self._set_paused(job_id, False)

    def shutdown(self) -> None:
        """Cancel everything; give the jobs a moment to stop, then stop their workers."""
        with self._changed:
            if self._closed:
                return
            self._closed = True
            live = [job for job in self._jobs.values() if not job.snap.state.finished]
        for job in live:
            self.cancel(job.snap.id)

        def ended() -> bool:
            return all(job.snap.state.finished for job in live)

        with self._changed:
            wait_for(self.clock, self._changed, ended, min(self.cancel_grace_s, SHUTDOWN_GRACE_S))
            running = [job for job in live if job.process and job.pid and not job.snap.state.finished]
            for job in running:
                job.kill_reason = KILLED_ON_CANCEL
        for job in running:
            self._pool.kill(job.snap.id)
        self._loads.put(None)
        self._pool.close()

    # --- internals: jobs ----------------------------------------------------------------------------
    def _job(self, job_id: str) -> _Job:
        with self._lock:
            job = self._jobs.get(job_id)
        if job is None:
            raise NotFound.unknown("job", job_id)
        return job

    def _create(self, kind: str, session_id: str | None, detail: dict | None, *, process: bool) -> _Job:
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
        job = _Job(snap, process)
        with self._lock:
            self._jobs[snap.id] = job
        self._save(job)
        return job

    def _touch(self, job: _Job) -> None:
        """Call with the lock held after changing a snapshot."""
        job.snap.version += 1
        job.snap.updated = _now()
        self._changed.notify_all()
        for loop, event in self._watchers:
            loop.call_soon_threadsafe(event.set)

    def _update(self, job: _Job, fraction: float | None, detail: dict, cost: list[float] | None) -> None:
        with self._changed:
            if fraction is not None:
                job.snap.progress = min(1.0, max(0.0, float(fraction)))
            job.snap.detail.update(jsonable(detail))
            if cost is not None:
                job.snap.cost = [float(c) for c in cost]
            self._touch(job)

    def _start(self, job: _Job) -> None:
        with self._changed:
            if job.snap.state != JobState.QUEUED:
                return
            job.snap.state = JobState.RUNNING
            job.started = self.clock.now()
            if job.process:
                self._arm(job)
            self._touch(job)
        self._save(job)

    def _finish(self, job: _Job, state: JobState, result: str | None = None, error: str | None = None) -> None:
        with self._changed:
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
            self._touch(job)
        self._save(job)

    def _save(self, job: _Job) -> None:
        """Store the snapshot as it is now. Never call with the lock held: saves are serialised, each
        taking its copy inside, so the last write is always the newest state."""
        with self._save_lock:
            with self._lock:
                snap = job.snap.copy()
            try:
                self.store.jobs.save(snap)
            except Exception:
                log.exception("job %s: its snapshot could not be stored", snap.id)

    # --- internals: thread jobs ---------------------------------------------------------------------
    def _run_thread(self, job: _Job, fn: Callable[[JobContext], str | None]) -> None:
        if job.cancel_requested:
            self._finish(job, JobState.CANCELLED)
            return
        self._start(job)
        try:
            result = fn(JobContext(self, job))
        except Cancelled:
            self._finish(job, JobState.CANCELLED)
        except (InputError, StoreWriteError) as exc:
            self._finish(job, JobState.FAILED, error=one_line(str(exc)))
        except Exception as exc:
            log.exception("job %s (%s) failed", job.snap.id, job.snap.kind)
            self._finish(job, JobState.FAILED, error=internal_error(exc))
        else:
            self._finish(job, JobState.DONE, result=result)

    def _checkpoint(self, job: _Job) -> None:
        with self._changed:
            wait_for(self.clock, self._changed, lambda: not job.snap.paused or job.cancel_requested, None)
            if job.cancel_requested:
                raise Cancelled("cancelled")

    def _set_paused(self, job_id: str, paused: bool) -> None:
        job = self._job(job_id)
        kind = _spoken(job.snap.kind)
        if job.process:
            raise InputError(f"a {kind} job runs in a worker process and cannot be paused; cancel it")
        if not job.pausable:
            raise InputError(f"a {kind} job cannot be paused; cancel it")
        with job.hold, self._changed:
            if job.snap.state.finished or job.snap.paused == paused:
                return
            job.snap.paused = paused
            self._touch(job)
        self._save(job)

    # --- internals: process jobs --------------------------------------------------------------------
    def _load_payloads(self) -> None:
        """One thread builds the process jobs' payloads in the order they were submitted, so that they reach
        the workers in that order."""
        while (job := self._loads.get()) is not None:
            self._prepare(job)

    def _prepare(self, job: _Job) -> None:
        """Build a process job's payload, then queue it for a worker (unless it was cancelled meanwhile:
        cancel() finished it at once)."""
        prepare = job.prepare
        if prepare is None or job.snap.state.finished:
            return
        error = None
        try:
            payload = prepare(JobContext(self, job))
        except Cancelled:
            self._finish(job, JobState.CANCELLED)
            return
        except (InputError, NotFound, StoreWriteError) as exc:
            error = one_line(str(exc))
        except Exception as exc:
            log.exception("job %s: its data could not be loaded", job.snap.id)
            error = internal_error(exc)
        with self._changed:
            job.prepare = None
            wanted = error is None and not (job.snap.state.finished or job.cancel_requested or self._closed)
            fn = job.fn
        if error is not None:
            self._finish(job, JobState.FAILED, error=error)
            return
        handed = wanted and fn is not None and self._pool.submit(job.snap.id, fn, payload)
        # A cancel that came while the job was handed over found it in neither place: it is told the pool now.
        if not handed or (job.cancel_requested and self._pool.cancel(job.snap.id)):
            self._finish(job, JobState.CANCELLED)

    def _worker_started(self, job_id: str, pid: int) -> None:
        with self._lock:
            job = self._jobs.get(job_id)
            if job is None or job.snap.state != JobState.QUEUED:
                return
            job.pid = pid
        self._start(job)

    def _worker_stepped(self, job_id: str, iteration: int, cost: float) -> None:
        with self._changed:
            job = self._jobs.get(job_id)
            if job is None or job.snap.state != JobState.RUNNING:
                return
            job.snap.cost.append(cost)
            job.snap.detail["iterations"] = iteration
            job.snap.progress = min(PROGRESS_CAP, iteration / (iteration + 5))
            self._touch(job)

    def _worker_ended(self, job_id: str, outcome: JobState | None, value: Any, trace: str) -> None:
        """A process job's end, from the pool: its worker's outcome, or None when the worker died under it."""
        job = self._job(job_id)
        if outcome is None:
            if job.kill_reason == KILLED_ON_CANCEL:
                outcome, value = JobState.CANCELLED, None
            else:
                outcome, value = JobState.FAILED, job.kill_reason or crashed(job.snap.kind)
        if trace:
            log.warning("job %s failed in its worker:\n%s", job_id, trace)
        result = None
        if outcome == JobState.DONE:
            try:
                result = job.finish(value, JobContext(self, job)) if job.finish else _text(value)
            except (InputError, StoreWriteError) as exc:  # StoreWriteError: the disk refused the result
                outcome, value = JobState.FAILED, one_line(str(exc))
            except Exception as exc:
                log.exception("job %s: its result could not be stored", job_id)
                outcome, value = JobState.FAILED, internal_error(exc)
        self._finish(job, outcome, result=result, error=value if outcome == JobState.FAILED else None)

    # --- internals: the watchdog --------------------------------------------------------------------
    def _deadline(self, job: _Job) -> tuple[float, str]:
        """When a running process job's worker is killed, and why: its cancel grace, or its time limit."""
        if job.cancel_requested:
            return job.cancel_at + self.cancel_grace_s, KILLED_ON_CANCEL
        limit = f"the {_spoken(job.snap.kind)} took longer than its limit of {self.timeout_s:g} s and was stopped"
        return job.started + self.timeout_s, limit

    def _arm(self, job: _Job) -> None:
        """(Re)set the running process job's timer for its deadline; call with the lock held."""
        if job.timer is not None:
            job.timer.cancel()
        due, _ = self._deadline(job)
        job.timer = self.clock.call_later(due - self.clock.now(), partial(self._overdue, job))

    def _overdue(self, job: _Job) -> None:
        """A timer's call: kill the worker if the job is still running past its deadline."""
        with self._lock:
            if job.snap.state != JobState.RUNNING or job.pid is None or job.kill_reason:
                return
            due, reason = self._deadline(job)
            if self.clock.now() < due:  # re-armed meanwhile (a cancel), or a timer a hair early
                self._arm(job)
                return
            job.kill_reason = reason
            job.timer = None
        log.warning("job %s: killing worker %d (%s)", job.snap.id, job.pid, reason)
        self._pool.kill(job.snap.id)


def _spoken(kind: str) -> str:
    return kind.replace("_", " ")


def _text(value: Any) -> str | None:
    return None if value is None else str(value)


def _now() -> str:
    return datetime.now(UTC).isoformat(timespec="milliseconds")
