"""Thread jobs: a function run on a thread of its own, in the server (a replay, a capture, a dry run).

The function is given the job's context (job.py); its return value is the job's result. What it raises ends the
job: `Cancelled` cancelled, `InputError` or `StoreWriteError` failed with its sentence, anything else failed as an
internal error on one line (its traceback in the log).
"""

from __future__ import annotations

import logging
import threading
from collections.abc import Callable

from calib_core import InputError
from calib_core.errors import Cancelled

from ..store import StoreWriteError
from .job import Job, JobContext, JobStates
from .snapshot import JobState
from .worker import internal_error, one_line

log = logging.getLogger(__name__)


def start_thread(states: JobStates, job: Job, fn: Callable[[JobContext], str | None]) -> None:
    """Run fn(ctx) for the job on a thread of its own."""
    threading.Thread(target=_run, args=(states, job, fn), name=f"job-{job.snap.id}", daemon=True).start()


def _run(states: JobStates, job: Job, fn: Callable[[JobContext], str | None]) -> None:
    if job.cancel_requested:
        states.finish(job, JobState.CANCELLED)
        return
    states.start(job)
    try:
        result = fn(JobContext(states, job))
    except Cancelled:
        states.finish(job, JobState.CANCELLED)
    except (InputError, StoreWriteError) as exc:
        states.finish(job, JobState.FAILED, error=one_line(str(exc)))
    except Exception as exc:
        log.exception("job %s (%s) failed", job.snap.id, job.snap.kind)
        states.finish(job, JobState.FAILED, error=internal_error(exc))
    else:
        states.finish(job, JobState.DONE, result=result)
