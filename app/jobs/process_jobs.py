"""Process jobs: a function run in a worker process (pool.py), its payload built in the server first.

`prepare(ctx)` builds a job's payload on one loader thread, in the order the jobs came, so that they reach the
workers in that order and the request that submits answers at once. The pool then says when the job starts in a
worker, each step it reports and how it ended (or that its worker died under it): here those become the job's
moves, and `finish(value, ctx)` turns the worker's value into its result. A worker still running `timeout_s`
after its job started, or `cancel_grace_s` after its job was cancelled, is killed by a timer of the runner's
clock (its deadline), and replaced.
"""

from __future__ import annotations

import logging
import queue
import threading
from functools import partial

from calib_core import InputError
from calib_core.errors import Cancelled

from ..errors import NotFound
from ..store import StoreWriteError
from .job import Finish, Job, JobContext, JobStates, Prepare, spoken
from .pool import WorkerPool
from .snapshot import JobState
from .worker import WorkerFn, internal_error, one_line

log = logging.getLogger(__name__)

PROGRESS_CAP = 0.95  # an iterative job's end is unknown until it comes: its estimate stays below 1 until then
KILLED_ON_CANCEL = "cancelled"  # a kill's reason when the worker ignored a cancel: the job ends cancelled


def crashed(kind: str) -> str:
    """A process job's error when its worker died under it."""
    return f"the {spoken(kind)} worker process stopped unexpectedly (crashed or killed); the worker was restarted"


class ProcessJobs:
    """The process jobs of a runner (`states`): their loader thread, their workers and their deadlines."""

    def __init__(self, states: JobStates, workers: int, *, timeout_s: float, cancel_grace_s: float) -> None:
        self._states = states
        self.timeout_s = timeout_s
        self.cancel_grace_s = cancel_grace_s
        self._pool = WorkerPool(workers, started=self._started, stepped=self._stepped, ended=self._ended)
        self._loads: queue.SimpleQueue[Job | None] = queue.SimpleQueue()
        self._loader = threading.Thread(target=self._load_payloads, name="jobs-load", daemon=True)
        self._loader.start()

    def submit(self, job: Job, fn: WorkerFn, prepare: Prepare, finish: Finish | None) -> None:
        """Queue the job for its payload, then for a worker."""
        job.fn, job.prepare, job.finish = fn, prepare, finish
        self._loads.put(job)

    def withdraw(self, job: Job) -> bool:
        """A cancelled job still waiting for a worker is dropped (True: it ends now); one in a worker is asked to
        stop (False: it ends as its worker finds, or at its deadline)."""
        return self._pool.cancel(job.snap.id)

    def close(self, live: list[Job]) -> None:
        """At shutdown: kill the workers of the `live` jobs still running, then stop the loader and the pool."""
        with self._states.changed:
            running = [job for job in live if job.process and job.pid and not job.snap.state.finished]
            for job in running:
                job.kill_reason = KILLED_ON_CANCEL
        for job in running:
            self._pool.kill(job.snap.id)
        self._loads.put(None)
        self._pool.close()

    # --- the payloads ---------------------------------------------------------------------------------
    def _load_payloads(self) -> None:
        """One thread builds the process jobs' payloads in the order they were submitted, so that they reach
        the workers in that order."""
        while (job := self._loads.get()) is not None:
            self._prepare(job)

    def _prepare(self, job: Job) -> None:
        """Build a process job's payload, then queue it for a worker (unless it was cancelled meanwhile:
        the runner's cancel finished it at once)."""
        prepare = job.prepare
        if prepare is None or job.snap.state.finished:
            return
        error = None
        try:
            payload = prepare(JobContext(self._states, job))
        except Cancelled:
            self._states.finish(job, JobState.CANCELLED)
            return
        except (InputError, NotFound, StoreWriteError) as exc:
            error = one_line(str(exc))
        except Exception as exc:
            log.exception("job %s: its data could not be loaded", job.snap.id)
            error = internal_error(exc)
        with self._states.changed:
            job.prepare = None
            wanted = error is None and not (job.snap.state.finished or job.cancel_requested or self._states.closed)
            fn = job.fn
        if error is not None:
            self._states.finish(job, JobState.FAILED, error=error)
            return
        handed = wanted and fn is not None and self._pool.submit(job.snap.id, fn, payload)
        # A cancel that came while the job was handed over found it in neither place: it is told the pool now.
        if not handed or (job.cancel_requested and self._pool.cancel(job.snap.id)):
            self._states.finish(job, JobState.CANCELLED)

    # --- the pool's calls -----------------------------------------------------------------------------
    def _started(self, job_id: str, pid: int) -> None:
        with self._states.changed:
            job = self._states.job(job_id)
            if job.snap.state != JobState.QUEUED:
                return
            job.pid = pid
        self._states.start(job)

    def _stepped(self, job_id: str, iteration: int, cost: float) -> None:
        with self._states.changed:
            job = self._states.job(job_id)
            if job.snap.state != JobState.RUNNING:
                return
            job.snap.cost.append(cost)
            job.snap.detail["iterations"] = iteration
            job.snap.progress = min(PROGRESS_CAP, iteration / (iteration + 5))
            self._states.touch(job)

    def _ended(self, job_id: str, outcome: JobState | None, value: object, trace: str) -> None:
        """A process job's end, from the pool: its worker's outcome, or None when the worker died under it."""
        job = self._states.job(job_id)
        if outcome is None:
            if job.kill_reason == KILLED_ON_CANCEL:
                outcome, value = JobState.CANCELLED, None
            else:
                outcome, value = JobState.FAILED, job.kill_reason or crashed(job.snap.kind)
        if trace:
            log.warning("job %s failed in its worker:\n%s", job_id, trace)
        result = error = None
        if outcome == JobState.FAILED:
            error = str(value)  # the worker's one-line message (run_in_worker), or why the worker died
        elif outcome == JobState.DONE:
            try:
                result = job.finish(value, JobContext(self._states, job)) if job.finish else _text(value)
            except (InputError, StoreWriteError) as exc:  # StoreWriteError: the disk refused the result
                outcome, error = JobState.FAILED, one_line(str(exc))
            except Exception as exc:
                log.exception("job %s: its result could not be stored", job_id)
                outcome, error = JobState.FAILED, internal_error(exc)
        self._states.finish(job, outcome, result=result, error=error)

    # --- the deadlines --------------------------------------------------------------------------------
    def arm(self, job: Job) -> None:
        """(Re)set the running job's timer for its deadline (at its start, and at a cancel); call with the
        runner's lock held."""
        if job.timer is not None:
            job.timer.cancel()
        due, _ = self._deadline(job)
        clock = self._states.clock
        job.timer = clock.call_later(due - clock.now(), partial(self._overdue, job))

    def _deadline(self, job: Job) -> tuple[float, str]:
        """When a running process job's worker is killed, and why: its cancel grace, or its time limit."""
        if job.cancel_requested:
            return job.cancel_at + self.cancel_grace_s, KILLED_ON_CANCEL
        limit = f"the {spoken(job.snap.kind)} took longer than its limit of {self.timeout_s:g} s and was stopped"
        return job.started + self.timeout_s, limit

    def _overdue(self, job: Job) -> None:
        """A timer's call: kill the worker if the job is still running past its deadline."""
        with self._states.changed:
            if job.snap.state != JobState.RUNNING or job.pid is None or job.kill_reason:
                return
            due, reason = self._deadline(job)
            if self._states.clock.now() < due:  # re-armed meanwhile (a cancel), or a timer a hair early
                self.arm(job)
                return
            job.kill_reason = reason
            job.timer = None
        log.warning("job %s: killing worker %d (%s)", job.snap.id, job.pid, reason)
        self._pool.kill(job.snap.id)


def _text(value: object) -> str | None:
    return None if value is None else str(value)
