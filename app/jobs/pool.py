"""The worker processes of the runner's process jobs.

A process job runs in its own spawned process (never forked: the server process runs viser and uvicorn
threads), so it neither holds the server's GIL nor takes the server down when it crashes. Each worker slot is a
one-process ProcessPoolExecutor: a crashed or killed worker breaks only its own pool, which fails only its own
job and is then rebuilt. Workers send their steps through a queue of a spawned multiprocessing Manager (a
killed client cannot corrupt it) and read their cancel flag from the same Manager; a thread here turns the
messages into calls to the process jobs (process_jobs.py). Workers and the Manager end by themselves when the
server dies without cleaning up (SIGKILL): app/jobs/parent_watch.py.

The pool knows jobs by id only: it tells process_jobs.py when a job starts in a worker (with its pid), each step
the job reports, and how it ended, or that its worker died under it. What that makes of the job is theirs.
"""

from __future__ import annotations

import contextlib
import logging
import multiprocessing
import os
import signal
import threading
import traceback
from collections import deque
from collections.abc import Callable
from concurrent.futures import CancelledError, Future, ProcessPoolExecutor
from concurrent.futures.process import BrokenProcessPool
from dataclasses import dataclass
from functools import partial
from multiprocessing.managers import SyncManager

from .parent_watch import light_main, watch_parent
from .snapshot import JobState
from .worker import WorkerFn, WorkerLink, internal_error, run_in_worker, warm_up

log = logging.getLogger(__name__)

Started = Callable[[str, int], None]  # (job, the worker's pid)
Stepped = Callable[[str, int, float], None]  # (job, iteration, cost)
# (job, outcome, value, traceback): run_in_worker's; outcome None: the worker died
Ended = Callable[[str, JobState | None, object, str], None]


@dataclass(eq=False)
class _Task:
    job_id: str
    fn: WorkerFn
    payload: object  # fn's, handed on as it is
    pid: int | None = None  # once the worker has said it took the job
    stopping: bool = False  # cancelled or killed: never handed to a new worker
    resent: bool = False  # handed to a new worker once, its first having died before it took the job


@dataclass
class _Slot:
    executor: ProcessPoolExecutor
    task: _Task | None = None
    generation: int = 0


class WorkerPool:
    def __init__(self, workers: int, *, started: Started, stepped: Stepped, ended: Ended) -> None:
        """`workers` worker processes (each started at once, and warmed up). The callbacks run on the pool's
        threads, never while it holds its lock."""
        if workers < 1:
            raise ValueError("at least one worker")
        self._started, self._stepped, self._ended = started, stepped, ended
        self._lock = threading.Lock()
        self._tasks: dict[str, _Task] = {}  # waiting for a worker, or in one
        self._pending: deque[_Task] = deque()
        self._closed = False
        self._ctx = multiprocessing.get_context("spawn")
        light_main()
        self._mp = SyncManager(ctx=self._ctx)
        self._mp.start(watch_parent, (os.getpid(),))
        self._messages = self._mp.Queue()
        self._cancel_flags = self._mp.dict()
        self._slots = [_Slot(self._new_executor()) for _ in range(workers)]
        self._pump = threading.Thread(target=self._pump_messages, name="jobs-progress", daemon=True)
        self._pump.start()

    def submit(self, job_id: str, fn: WorkerFn, payload: object) -> bool:
        """Queue fn(payload, link) for the next free worker; False once the pool is closed."""
        with self._lock:
            if self._closed:
                return False
            task = _Task(job_id, fn, payload)
            self._tasks[job_id] = task
            self._pending.append(task)
        self._dispatch()
        return True

    def cancel(self, job_id: str) -> bool:
        """A job still waiting for a worker is dropped (True: it will not be heard of again); one handed to a
        worker has its cancel flag set (False: it ends as its worker finds)."""
        with self._lock:
            task = self._tasks.get(job_id)
            if task is None:
                return False
            task.stopping = True
            if task in self._pending:
                self._pending.remove(task)
                del self._tasks[job_id]
                return True
        with contextlib.suppress(Exception):
            self._cancel_flags[job_id] = True
        return False

    def kill(self, job_id: str) -> None:
        """Kill the worker the job runs in (it ends with `ended(job, None, ...)`; the slot gets a new worker)."""
        with self._lock:
            task = self._tasks.get(job_id)
            if task is None or task.pid is None:
                return
            task.stopping = True
            pid = task.pid
        with contextlib.suppress(ProcessLookupError):
            os.kill(pid, getattr(signal, "SIGKILL", signal.SIGTERM))

    def close(self) -> None:
        """Stop taking jobs, wait for the workers' current ones (kill them first to not wait), stop everything."""
        with self._lock:
            self._closed = True
        with contextlib.suppress(Exception):
            self._messages.put(None)  # ends the pump
        for slot in self._slots:
            slot.executor.shutdown(wait=True, cancel_futures=True)
        self._pump.join(timeout=2.0)
        self._mp.shutdown()

    def _new_executor(self) -> ProcessPoolExecutor:
        executor = ProcessPoolExecutor(
            max_workers=1, mp_context=self._ctx, initializer=watch_parent, initargs=(os.getpid(),)
        )
        executor.submit(warm_up)
        return executor

    def _rebuild(self, slot: _Slot) -> None:
        old = slot.executor
        slot.executor = self._new_executor()
        slot.generation += 1
        old.shutdown(wait=False, cancel_futures=True)

    def _dispatch(self) -> None:
        """Hand waiting jobs to free slots."""
        submitted = []
        with self._lock:
            for slot in self._slots:
                if slot.task is not None or not self._pending or self._closed:
                    continue
                task = slot.task = self._pending.popleft()
                link = WorkerLink(task.job_id, self._messages, self._cancel_flags)
                try:
                    future = slot.executor.submit(run_in_worker, task.fn, task.payload, link)
                except (BrokenProcessPool, RuntimeError):
                    # The idle worker died (killed, out of memory) and its pool knows: a new one takes the job.
                    self._rebuild(slot)
                    future = slot.executor.submit(run_in_worker, task.fn, task.payload, link)
                submitted.append((future, partial(self._done, task, slot, slot.generation)))
        # A callback may run at once, in this thread: never while holding the lock.
        for future, callback in submitted:
            future.add_done_callback(callback)

    def _done(self, task: _Task, slot: _Slot, generation: int, future: Future) -> None:
        """Runs on the executor's thread when a worker's future resolves (a result, an error or a crash)."""
        broken = False
        try:
            outcome, value, trace = future.result()
        except CancelledError:  # dropped from the pool at close
            outcome, value, trace = JobState.CANCELLED, None, ""
        except BrokenProcessPool:
            broken = True
            with self._lock:
                # The worker died before it took the job (killed while idle, and its pool did not know yet when
                # the job was handed to it): the job goes to the slot's new worker, once.
                resend = task.pid is None and not (task.stopping or task.resent or self._closed)
                if resend:
                    task.resent = True
                    if slot.generation == generation:
                        self._rebuild(slot)
                    slot.task = None
                    self._pending.appendleft(task)
            if resend:
                self._dispatch()
                return
            outcome, value, trace = None, None, ""
        except Exception as exc:  # the payload or the value could not cross the process boundary
            outcome, value, trace = JobState.FAILED, internal_error(exc), traceback.format_exc()
        with self._lock:
            if broken and slot.generation == generation and not self._closed:
                self._rebuild(slot)
            slot.task = None
            self._tasks.pop(task.job_id, None)
        with contextlib.suppress(Exception):
            self._cancel_flags.pop(task.job_id, None)
        self._ended(task.job_id, outcome, value, trace)
        self._dispatch()

    def _pump_messages(self) -> None:
        """The workers' messages into calls to the process jobs, until close sends None."""
        while True:
            try:
                message = self._messages.get()
            except (EOFError, OSError):
                if not self._closed:
                    log.error("the jobs' progress channel closed: progress is no longer reported")
                return
            if message is None:
                return
            kind, job_id, *values = message
            if kind == "progress":
                self._stepped(job_id, *values)
            elif kind == "start":
                with self._lock:
                    task = self._tasks.get(job_id)
                    if task is not None:
                        task.pid = int(values[0])
                if task is not None:
                    self._started(job_id, int(values[0]))
