"""The worker's side of a process job: what runs in the spawned worker process.

A worker imports this module, its job function's module and what that needs; none of the server's (the store,
the routers, viser). Its initializer, app/jobs/parent_watch.py's watch_parent, imports nothing of the project.
"""

from __future__ import annotations

import contextlib
import os
import time
import traceback
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, Protocol

from calib_core.errors import Cancelled, InputError

from .snapshot import JobState

CANCEL_POLL_S = 0.05  # how often a worker asks the Manager whether it was cancelled (a rate, not a time limit)


class Messages(Protocol):
    """Where a worker puts its messages (a Manager's queue): (kind, job id, *values)."""

    def put(self, item: tuple[object, ...]) -> None: ...


class CancelFlags(Protocol):
    """A Manager's dict of the jobs asked to stop: job id -> True."""

    def get(self, key: str, default: bool, /) -> bool: ...


# A process job's function: fn(payload, link) in the worker. Its payload is what the job's prepare built, of the
# job kind's own type (JobRunner.submit_process ties the two); the pool hands on any kind's, so here it is free.
WorkerFn = Callable[[Any, "WorkerLink"], object]


@dataclass
class WorkerLink:
    """What a worker process holds of its job: the progress queue and the cancel flags (Manager proxies)."""

    job_id: str
    messages: Messages
    cancelled: CancelFlags
    _next_poll: float = 0.0
    _stop: bool = False

    def send(self, kind: str, *values: object) -> None:
        # Progress is best-effort: a lost message never fails the job.
        with contextlib.suppress(Exception):
            self.messages.put((kind, self.job_id, *values))

    def progress(self, iteration: int, cost: float) -> None:
        """An iterative job's step: its iteration and cost (the snapshot's `cost` and progress estimate)."""
        self.send("progress", int(iteration), float(cost))

    def should_stop(self) -> bool:
        now = time.monotonic()
        if not self._stop and now >= self._next_poll:
            self._next_poll = now + CANCEL_POLL_S
            with contextlib.suppress(Exception):
                self._stop = bool(self.cancelled.get(self.job_id, False))
        return self._stop


def run_in_worker(fn: WorkerFn, payload: object, link: WorkerLink) -> tuple[JobState, object, str]:
    """(outcome, value, traceback): (DONE, result), (CANCELLED, None) or (FAILED, one-line message)."""
    link.send("start", os.getpid())
    try:
        return JobState.DONE, fn(payload, link), ""
    except Cancelled:
        return JobState.CANCELLED, None, ""
    except InputError as exc:
        return JobState.FAILED, one_line(str(exc)), ""
    except Exception as exc:
        return JobState.FAILED, internal_error(exc), traceback.format_exc()


def warm_up() -> int:
    """Run first in every new worker: spawning and importing numpy and SciPy (with Cancelled) take a second or two."""
    return os.getpid()


def internal_error(exc: BaseException) -> str:
    return one_line(f"internal error: {type(exc).__name__}: {exc}")


def one_line(text: str) -> str:
    return " ".join(text.split())
