"""A job as the runner and its kinds hold it in memory, and what the job's own code sees of it.

`Job` is a snapshot with the runner's bookkeeping (a cancel asked, a pause's lock, a process job's functions and
worker); `JobContext` is what a thread job's function and a process job's prepare and finish are given.
`JobStates` is the runner's side that both ask: the job's moves (start, change, finish) and its waits. The
runner (runner.py) is that side; the kinds of job (thread_jobs.py, process_jobs.py) and the contexts reach it
only through this protocol, so they import nothing above them.
"""

from __future__ import annotations

import threading
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any, Protocol, TypeVar

from ..clock import Clock, Timer
from .snapshot import JobSnapshot, JobState
from .worker import WorkerFn

T = TypeVar("T")
Prepare = Callable[["JobContext"], object]  # builds a process job's payload, in the server
# Turns a process job's value into its result, in the server. The value is what the job's worker function
# returned, of the job kind's own type (JobRunner.submit_process ties the two); a job holds any kind's.
Finish = Callable[[Any, "JobContext"], str | None]


@dataclass
class Job:
    snap: JobSnapshot
    process: bool
    fn: WorkerFn | None = None  # a process job's worker function
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


class JobStates(Protocol):
    """The runner as a kind of job and a job's context see it. `changed` is its lock (a condition notified at
    every change of a snapshot): hold it to read or change a job's state."""

    clock: Clock
    changed: threading.Condition

    @property
    def closed(self) -> bool: ...

    def job(self, job_id: str) -> Job: ...

    def start(self, job: Job) -> None: ...

    def update(self, job: Job, fraction: float | None, detail: dict, cost: list[float] | None) -> None: ...

    def touch(self, job: Job) -> None: ...

    def checkpoint(self, job: Job) -> None: ...

    def finish(self, job: Job, state: JobState, result: str | None = None, error: str | None = None) -> None: ...


class JobContext:
    """What a job's own code sees of it: a thread job's function, a process job's prepare and finish."""

    def __init__(self, states: JobStates, job: Job) -> None:
        self._states = states
        self._job = job
        self.job_id = job.snap.id

    def progress(self, fraction: float, **detail: object) -> None:
        """Report progress (0..1); `detail` is merged into the job's detail."""
        self._states.update(self._job, fraction, detail, None)

    def report(self, *, cost: list[float] | None = None, **detail: object) -> None:
        """Merge `detail` into the job's detail, and replace its cost history when given; progress stays."""
        self._states.update(self._job, None, detail, cost)

    def checkpoint(self) -> None:
        """Blocks while the job is paused; raises Cancelled once it is cancelled."""
        self._states.checkpoint(self._job)

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


def spoken(kind: str) -> str:
    """A job's kind as a message says it (`dry_run`: dry run)."""
    return kind.replace("_", " ")
