"""Background jobs: calibrations in worker processes, captures, replays and dry runs on threads.

A calibration runs in its own spawned process (never forked: the server process runs viser and
uvicorn threads), so the solver neither holds the server's GIL nor takes the server down when it
crashes. Each worker slot is a one-process ProcessPoolExecutor: a crashed or killed worker breaks
only its own pool, which fails only its own job and is then rebuilt. Workers send (iteration, cost)
through a queue of a spawned multiprocessing Manager (a killed client cannot corrupt it) and read
their cancel flag from the same Manager; a thread in the server turns the messages into the job's
snapshot and kills a worker that overruns its time limit or ignores a cancel. Workers and the Manager
end by themselves when the server dies without cleaning up (SIGKILL): app/parent_watch.py.

A job's snapshot is what the API shows: {"id", "kind", "state", "progress", "result", "error",
"session", "created", "updated", "detail", "cost", "version", "paused"}. `version` grows on every
change (wait_version serves server-sent events); the store keeps the snapshot on every state change.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import math
import multiprocessing
import os
import queue
import secrets
import signal
import threading
import time
import traceback
from collections import deque
from collections.abc import Callable
from concurrent.futures import CancelledError, Future, ProcessPoolExecutor
from concurrent.futures.process import BrokenProcessPool
from dataclasses import dataclass, replace
from datetime import UTC, datetime
from functools import partial
from multiprocessing.managers import SyncManager
from typing import TYPE_CHECKING, Any

from calib_core import Calibration, InputError, Profile, calibrate
from calib_core.estimation.calibrate import METHODS, check_can_fit
from calib_core.estimation.solver import Cancelled

from .errors import NotFound
from .limits import DEFAULT_MAX_ROWS
from .parent_watch import light_main, watch_parent
from .store import StoreWriteError
from .store.db import jsonable

if TYPE_CHECKING:
    from .store import Store

log = logging.getLogger(__name__)

STATES = ("queued", "running", "done", "failed", "cancelled")
FINISHED = ("done", "failed", "cancelled")
MAX_HOLDOUT = 0.9
PROGRESS_CAP = 0.95  # a solve's end is unknown until it comes: the estimate stays below 1 until then
CANCEL_POLL_S = 0.05  # how often a worker asks the Manager whether it was cancelled
CRASHED = "the calibration worker process stopped unexpectedly (crashed or killed); the worker was restarted"


# --- the worker's side (runs in the spawned process) ---------------------------------------------------
@dataclass
class WorkerLink:
    """What a worker process holds of its job: the progress queue and the cancel flags (Manager proxies)."""

    job_id: str
    messages: Any
    cancelled: Any
    _next_poll: float = 0.0
    _stop: bool = False

    def send(self, kind: str, *values: Any) -> None:
        # Progress is best-effort: a lost message never fails the solve.
        with contextlib.suppress(Exception):
            self.messages.put((kind, self.job_id, *values))

    def progress(self, iteration: int, cost: float) -> None:
        self.send("progress", int(iteration), float(cost))

    def should_stop(self) -> bool:
        now = time.monotonic()
        if not self._stop and now >= self._next_poll:
            self._next_poll = now + CANCEL_POLL_S
            with contextlib.suppress(Exception):
                self._stop = bool(self.cancelled.get(self.job_id, False))
        return self._stop


def run_in_worker(fn: Callable[[Any, WorkerLink], Any], payload: Any, link: WorkerLink) -> tuple[str, Any, str]:
    """(outcome, value, traceback): ("done", result), ("cancelled", None) or ("failed", one-line message)."""
    link.send("start", os.getpid())
    try:
        return "done", fn(payload, link), ""
    except Cancelled:
        return "cancelled", None, ""
    except InputError as exc:
        return "failed", _one_line(str(exc)), ""
    except Exception as exc:
        return "failed", internal_error(exc), traceback.format_exc()


def calibration_worker(payload: dict, link: WorkerLink) -> dict:
    """Solve one calibration from plain data; the result as its calib-calibration/1 dictionary."""
    profile = payload["profile"]
    base = Calibration.from_dict(payload["base"]) if payload["base"] is not None else None
    cal = calibrate(
        profile,
        payload["data"],
        payload["mode"],
        base,
        holdout=payload["holdout"],
        folds=payload["folds"],
        method=payload["method"],
        progress=link.progress,
        should_stop=link.should_stop,
    )
    cal.source = payload["session"]
    return cal.to_dict()


def warm_up() -> int:
    """Run first in every new worker: spawning and importing numpy/scipy take a second or two."""
    return os.getpid()


def internal_error(exc: BaseException) -> str:
    return _one_line(f"internal error: {type(exc).__name__}: {exc}")


def _one_line(text: str) -> str:
    return " ".join(text.split())


# --- the server's side --------------------------------------------------------------------------------
class JobContext:
    """What a thread job sees of itself."""

    def __init__(self, manager: JobManager, job_id: str) -> None:
        self._manager = manager
        self.job_id = job_id

    def progress(self, fraction: float, **detail: Any) -> None:
        """Report progress (0..1); `detail` is merged into the job's detail."""
        self._manager._thread_progress(self.job_id, fraction, detail)

    def checkpoint(self) -> None:
        """Blocks while the job is paused; raises Cancelled once it is cancelled."""
        self._manager._checkpoint(self.job_id)

    @property
    def cancelled(self) -> bool:
        return self._manager._job(self.job_id).cancel_requested


@dataclass
class _Job:
    snap: dict
    process: bool
    fn: Callable | None = None  # process jobs: the worker function and its payload
    payload: Any = None
    finish: Callable[[Any], str | None] | None = None  # turns the worker's result into the job's result
    cancel_requested: bool = False
    cancel_at: float = 0.0
    started: float = 0.0
    pid: int | None = None
    kill_reason: str | None = None  # set when the server kills the worker on purpose
    resent: bool = False  # handed to a new worker once, its first having died before it started the job
    preparing: bool = False  # its payload is still being built (_prepare): not yet queued for a worker
    pausable: bool = True  # a thread job that can wait at its checkpoints (a dry run has none: it computes only)


@dataclass
class _Slot:
    executor: ProcessPoolExecutor
    job_id: str | None = None
    generation: int = 0


class JobManager:
    def __init__(
        self,
        store: Store,
        workers: int = 1,
        *,
        timeout_s: float = 1800.0,
        cancel_grace_s: float = 5.0,
        scrub: Callable[[str], str] | None = None,
        max_rows: int = DEFAULT_MAX_ROWS,
    ) -> None:
        """`workers` calibration processes. A worker still running after `timeout_s`, or `cancel_grace_s` after its
        job was cancelled, is killed (the job fails, or ends cancelled) and replaced. `scrub` takes the server's
        paths out of a failed job's message (the one the HTTP errors go through). A calibration of more than
        `max_rows` observations is refused."""
        if workers < 1:
            raise ValueError("at least one worker")
        self.store = store
        self._scrub = scrub or (lambda text: text)
        self.timeout_s = timeout_s
        self.cancel_grace_s = cancel_grace_s
        self.max_rows = max_rows
        self._lock = threading.RLock()
        self._submitting = threading.Lock()  # a calibration request: checked against the live jobs, then queued
        self._save_lock = threading.Lock()
        self._changed = threading.Condition(self._lock)
        self._watchers: set[tuple[asyncio.AbstractEventLoop, asyncio.Event]] = set()  # streams waiting (next_version)
        self._jobs: dict[str, _Job] = {}
        self._pending: deque[str] = deque()
        self._closed = False
        self._ctx = multiprocessing.get_context("spawn")
        light_main()
        self._mp = SyncManager(ctx=self._ctx)
        self._mp.start(watch_parent, (os.getpid(),))
        self._messages = self._mp.Queue()
        self._cancel_flags = self._mp.dict()
        self._slots = [_Slot(self._new_executor()) for _ in range(workers)]
        self.store.jobs.fail_interrupted()
        self._pump = threading.Thread(target=self._pump_messages, name="jobs-progress", daemon=True)
        self._pump.start()
        self._loads: queue.SimpleQueue[tuple[_Job, Callable[[], Any]] | None] = queue.SimpleQueue()
        self._loader = threading.Thread(target=self._load_payloads, name="jobs-load", daemon=True)
        self._loader.start()

    # --- submitting ---------------------------------------------------------------------------------
    def submit_calibration(
        self, session_id: str, mode: str, base_id: str | None, holdout: float, *, folds: int = 0, method: str = "lm"
    ) -> str:
        """Validate, then queue a calibration of the session's measured frames; the job's result is the
        stored calibration's id. Unknown session or base calibration: NotFound; anything else wrong: InputError.
        The same request while such a job is queued or running (a double click, a second tab) is that job."""
        with self._submitting:  # two requests at once: the second finds the first's job
            asked = {"mode": mode, "base": base_id, "holdout": holdout, "folds": folds, "method": method}
            with self._lock:
                for job_id, job in self._jobs.items():
                    snap = job.snap
                    live = snap["state"] in ("queued", "running") and snap["session"] == session_id
                    if (
                        live
                        and snap["kind"] == "calibration"
                        and all(snap["detail"].get(k) == v for k, v in asked.items())
                    ):
                        return job_id
            return self._submit_calibration(session_id, mode, base_id, holdout, folds, method)

    def _submit_calibration(
        self, session_id: str, mode: str, base_id: str | None, holdout: float, folds: int, method: str
    ) -> str:
        """Checks what can be checked from the request and the counts of the session's rows, then creates
        the job; loading the data, the held-out split and the solve, which all grow with the data, run in
        the job (the request answers at once, and the job can be cancelled throughout)."""
        profile, base, measured = self.check_calibration(session_id, mode, base_id, holdout, folds=folds, method=method)

        def finish(result: dict, job_id: str) -> str:
            cal = Calibration.from_dict(result)
            try:
                cal_id = self.store.calibrations.add(cal, session_id=session_id, base_id=base_id, holdout=holdout)
            except NotFound:  # the session was deleted meanwhile: the result stays, without its session
                cal_id = self.store.calibrations.add(cal, session_id=None, base_id=base_id, holdout=holdout)
            with self._changed:
                job = self._jobs[job_id]
                job.snap["cost"] = list(cal.solver.cost_history or job.snap["cost"])
                after = cal.figures["after"]
                job.snap["detail"].update(
                    iterations=cal.solver.iterations,
                    converged=cal.converged,
                    solver_status=cal.solver.status.value,
                    before_rms=cal.figures["before"].rms,
                    after_rms=after.rms,
                    unit=after.unit,
                )
            return cal_id

        detail = {
            "robot": profile.name,
            "mode": mode,
            "base": base_id,
            "holdout": holdout,
            "folds": folds,
            "method": method,
            "frames": measured,
            "phase": "loading",
        }
        job = self._create("calibration", session_id, detail, process=True)
        job.fn, job.finish, job.preparing = calibration_worker, finish, True

        def prepare() -> dict:
            return self.calibration_payload(session_id, mode, base, holdout, folds=folds, method=method)

        self._loads.put((job, prepare))
        return job.snap["id"]

    def check_calibration(
        self, session_id: str, mode: str, base_id: str | None, holdout: float, *, folds: int = 0, method: str = "lm"
    ) -> tuple[Profile, dict | None, int]:
        """Check a calibration request against its options and the counts of the session's rows, reading no
        more than those unless they are no more than the mode's parameters (then the few observations, to count
        what they determine): (profile, base calibration as a dictionary or None, measured frames)."""
        session = self.store.sessions.get(session_id)
        profile = self.store.sessions.profile(session.robot)
        m = profile.mode(mode)
        if method not in METHODS:
            raise InputError(f"unknown method '{method}' (known: {', '.join(METHODS)})")
        if isinstance(holdout, bool) or not isinstance(holdout, int | float) or not math.isfinite(holdout):
            raise InputError(f"held-out share {holdout!r} is not a number")
        if not 0.0 <= holdout <= MAX_HOLDOUT:
            raise InputError(f"held-out share {holdout:g} must be between 0 and {MAX_HOLDOUT:g}")
        if isinstance(folds, bool) or not isinstance(folds, int) or folds < 0 or folds == 1:
            raise InputError(f"folds {folds!r} must be 0 (no cross-validation) or at least 2")
        base = None
        if base_id is not None:
            try:
                info = self.store.calibrations.info(base_id)
            except NotFound:
                raise NotFound.unknown("base calibration", base_id) from None
            if info.robot != profile.name:
                raise InputError(f"base calibration '{base_id}' is for robot '{info.robot}', not '{profile.name}'")
            base = self.store.calibrations.load(base_id).to_dict()
        counts = self.store.sessions.observation_counts(session_id)
        n_observations = sum(counts.values())
        if session.measured == 0 or n_observations == 0:
            raise InputError(f"session '{session_id}' has no measured frames to calibrate on")
        if n_observations > self.max_rows:
            raise InputError(
                f"session '{session_id}' has {n_observations:,} observations; a calibration takes at most "
                f"{self.max_rows:,} (the desk's row limit, calib serve --max-rows): calibrate on a part of it"
            )
        sensor_dim = {s: profile.sensors[profile.data.sensor if s is None else s].dim for s in counts}
        if sum(n * sensor_dim[s] for s, n in counts.items()) <= len(m.free):
            # No more rows than parameters: whether they are too few depends on what they determine (the
            # calibration holds what they cannot tell apart). Such a session is small: check it here.
            data = self.store.sessions.dataset(session_id, profile)
            try:
                check_can_fit(profile, data, mode, None if base is None else Calibration.from_dict(base))
            except InputError as exc:
                raise InputError(f"session '{session_id}': {exc.message}") from None
        train = session.measured - round(holdout * session.measured)
        if folds > train:
            raise InputError(f"{folds} folds need at least {folds} training frames, not {train}")
        return profile, base, session.measured

    def calibration_payload(
        self,
        session_id: str,
        mode: str,
        base: dict | None,
        holdout: float,
        *,
        folds: int = 0,
        method: str = "lm",
    ) -> dict:
        """The plain data a calibration's worker needs (the session's measured frames read from the store);
        `base`: the base calibration as a dictionary. Whether the training share can determine the mode's
        parameters is the worker's check (calibrate), since the held-out split grows with the data."""
        session = self.store.sessions.get(session_id)
        profile = self.store.sessions.profile(session.robot)
        data = self.store.sessions.dataset(session_id, profile)
        if data.n_configurations == 0:
            raise InputError(f"session '{session_id}' has no measured frames to calibrate on")
        return {
            "profile": profile,
            "session": session_id,
            "mode": mode,
            "base": base,
            "holdout": float(holdout),
            "folds": folds,
            "method": method,
            "data": replace(data, header=[], rows=[]),  # the worker needs the arrays only
        }

    def _load_payloads(self) -> None:
        """One thread builds the process jobs' payloads in the order they were submitted, so that they reach
        the workers in that order."""
        while (item := self._loads.get()) is not None:
            self._prepare(*item)

    def _prepare(self, job: _Job, build: Callable[[], Any]) -> None:
        """Build a process job's payload, then queue it for a worker (unless it was cancelled meanwhile:
        cancel() finished it at once)."""
        job_id = job.snap["id"]
        if job.snap["state"] in FINISHED:
            return
        try:
            payload = build()
        except (InputError, NotFound, StoreWriteError) as exc:
            payload, error = None, _one_line(str(exc))
        except Exception as exc:
            log.exception("job %s: its data could not be loaded", job_id)
            payload, error = None, internal_error(exc)
        with self._changed:
            job.preparing = False
            wanted = job.snap["state"] not in FINISHED and not job.cancel_requested and not self._closed
            if payload is not None and wanted:
                job.payload = payload
                job.snap["detail"]["phase"] = "solving"
                self._touch(job)
                self._pending.append(job_id)
        if payload is None:
            self._finish(job, "failed", error=error)
        elif wanted:
            self._dispatch()
        else:
            self._finish(job, "cancelled")

    def submit_process(
        self,
        kind: str,
        fn: Callable[[Any, WorkerLink], Any],
        payload: Any,
        *,
        session_id: str | None,
        finish: Callable[[Any, str], str | None] | None = None,
        detail: dict | None = None,
    ) -> str:
        """Queue fn(payload, link) for a worker process (fn: a module-level function). `finish(value,
        job_id)` runs in the server on the worker's value and gives the job's result."""
        job = self._create(kind, session_id, detail, process=True)
        job.fn, job.payload, job.finish = fn, payload, finish
        with self._lock:
            self._pending.append(job.snap["id"])
        self._dispatch()
        return job.snap["id"]

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
        job_id = job.snap["id"]
        threading.Thread(target=self._run_thread, args=(job_id, fn), name=f"job-{job_id}", daemon=True).start()
        return job_id

    # --- reading ------------------------------------------------------------------------------------
    def get(self, job_id: str) -> dict:
        with self._lock:
            job = self._jobs.get(job_id)
            if job is not None:
                return _copy(job.snap)
        return self.store.jobs.get(job_id)

    def list(self, session_id: str | None = None) -> list[dict]:
        """Every job this store knows (this run's live, earlier runs' as stored), newest first."""
        stored = {j["id"]: j for j in self.store.jobs.list(session_id)}
        with self._lock:
            for job_id, job in self._jobs.items():
                if session_id is None or job.snap["session"] == session_id:
                    stored[job_id] = _copy(job.snap)
        return sorted(stored.values(), key=lambda j: j["created"], reverse=True)

    def wait_version(self, job_id: str, version: int, timeout_s: float) -> dict:
        """The snapshot once its version exceeds `version`, or after `timeout_s` (for server-sent events)."""
        with self._changed:
            job = self._jobs.get(job_id)
            if job is not None:
                self._changed.wait_for(lambda: job.snap["version"] > version, timeout=timeout_s)
                return _copy(job.snap)
        return self.store.jobs.get(job_id)

    async def next_version(self, job_id: str, version: int, timeout_s: float) -> dict | None:
        """wait_version on the event loop: a server-sent event stream waits holding no thread, so open streams
        cannot starve the requests that need one. None for a job no longer in memory (read it from the store)."""
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
                    if job.snap["version"] > version or loop.time() >= deadline:
                        return _copy(job.snap)
                with contextlib.suppress(TimeoutError):
                    await asyncio.wait_for(watcher[1].wait(), deadline - loop.time())
        finally:
            with self._lock:
                self._watchers.discard(watcher)

    def worker_pid(self, job_id: str) -> int | None:
        """The process a running calibration job runs in (None before it starts)."""
        return self._job(job_id).pid

    # --- control ------------------------------------------------------------------------------------
    def cancel(self, job_id: str) -> None:
        """Waiting for a worker: cancelled at once. Running: asked to stop (a worker that does not stop
        within cancel_grace_s is killed). Finished: nothing to do."""
        with self._changed:
            job = self._job(job_id)
            if job.snap["state"] in FINISHED or job.cancel_requested:
                return
            job.cancel_requested = True
            job.cancel_at = time.monotonic()
            waiting = job_id in self._pending or job.preparing
            if job_id in self._pending:
                self._pending.remove(job_id)
            self._changed.notify_all()
        if waiting:
            self._finish(job, "cancelled")
        elif job.process:
            self._cancel_flags[job_id] = True

    def pause(self, job_id: str) -> None:
        self._set_paused(job_id, True)

    def resume(self, job_id: str) -> None:
        self._set_paused(job_id, False)

    def shutdown(self) -> None:
        """Cancel everything; give workers a moment to stop, then stop them."""
        with self._changed:
            if self._closed:
                return
            self._closed = True
            live = [j for j in self._jobs if self._jobs[j].snap["state"] not in FINISHED]
        for job_id in live:
            self.cancel(job_id)
        deadline = time.monotonic() + min(self.cancel_grace_s, 3.0)
        with self._changed:
            self._changed.wait_for(
                lambda: all(self._jobs[j].snap["state"] in FINISHED for j in live),
                timeout=max(0.0, deadline - time.monotonic()),
            )
            running = [self._jobs[j] for j in live if self._jobs[j].process and self._jobs[j].pid]
        for job in running:
            if job.snap["state"] not in FINISHED:
                job.kill_reason = "cancelled"
                _kill(job.pid)
        self._loads.put(None)
        for slot in self._slots:
            slot.executor.shutdown(wait=True, cancel_futures=True)
        self._pump.join(timeout=2.0)
        self._mp.shutdown()

    # --- internals: jobs ----------------------------------------------------------------------------
    def _job(self, job_id: str) -> _Job:
        with self._lock:
            job = self._jobs.get(job_id)
        if job is None:
            raise NotFound.unknown("job", job_id)
        return job

    def _create(self, kind: str, session_id: str | None, detail: dict | None, *, process: bool) -> _Job:
        if self._closed:
            raise RuntimeError("the job manager is shut down")
        now = _now()
        snap = {
            "id": "j-" + secrets.token_hex(4),
            "kind": kind,
            "state": "queued",
            "progress": 0.0,
            "result": None,
            "error": None,
            "session": session_id,
            "created": now,
            "updated": now,
            "detail": dict(detail or {}),
            "cost": [],
            "version": 0,
            "paused": False,
        }
        job = _Job(snap, process)
        with self._lock:
            self._jobs[snap["id"]] = job
        self._save(job)
        return job

    def _touch(self, job: _Job) -> None:
        """Call with the lock held after changing a snapshot."""
        job.snap["version"] += 1
        job.snap["updated"] = _now()
        self._changed.notify_all()
        for loop, event in self._watchers:
            loop.call_soon_threadsafe(event.set)

    def _start(self, job: _Job) -> None:
        with self._changed:
            if job.snap["state"] != "queued":
                return
            job.snap["state"] = "running"
            job.started = time.monotonic()
            self._touch(job)
        self._save(job)

    def _finish(self, job: _Job, state: str, result: str | None = None, error: str | None = None) -> None:
        with self._changed:
            if job.snap["state"] in FINISHED:
                return
            if error is not None:  # a job's message is shown to the page: no path of the server in it
                error = self._scrub(error)
            job.snap.update(state=state, result=result, error=error, paused=False)
            if state == "done":
                job.snap["progress"] = 1.0
            job.fn = job.payload = None
            self._touch(job)
        self._save(job)

    def _save(self, job: _Job) -> None:
        """Store the snapshot as it is now. Never call with the lock held: saves are serialised, each
        taking its copy inside, so the last write is always the newest state."""
        with self._save_lock:
            with self._lock:
                snap = _copy(job.snap)
            try:
                self.store.jobs.save(snap)
            except Exception:
                log.exception("job %s: its snapshot could not be stored", snap["id"])

    # --- internals: thread jobs ---------------------------------------------------------------------
    def _run_thread(self, job_id: str, fn: Callable[[JobContext], str | None]) -> None:
        job = self._job(job_id)
        if job.cancel_requested:
            self._finish(job, "cancelled")
            return
        self._start(job)
        try:
            result = fn(JobContext(self, job_id))
        except Cancelled:
            self._finish(job, "cancelled")
        except (InputError, StoreWriteError) as exc:
            self._finish(job, "failed", error=_one_line(str(exc)))
        except Exception as exc:
            log.exception("job %s (%s) failed", job_id, job.snap["kind"])
            self._finish(job, "failed", error=internal_error(exc))
        else:
            self._finish(job, "done", result=result)

    def _thread_progress(self, job_id: str, fraction: float, detail: dict) -> None:
        job = self._job(job_id)
        with self._changed:
            job.snap["progress"] = min(1.0, max(0.0, float(fraction)))
            job.snap["detail"].update(jsonable(detail))
            self._touch(job)

    def _checkpoint(self, job_id: str) -> None:
        job = self._job(job_id)
        with self._changed:
            self._changed.wait_for(lambda: not job.snap["paused"] or job.cancel_requested)
            if job.cancel_requested:
                raise Cancelled("cancelled")

    def _set_paused(self, job_id: str, paused: bool) -> None:
        job = self._job(job_id)
        if job.process:
            raise InputError(f"a {job.snap['kind']} job runs in a worker process and cannot be paused; cancel it")
        if not job.pausable:
            raise InputError(f"a {job.snap['kind'].replace('_', ' ')} job cannot be paused; cancel it")
        with self._changed:
            if job.snap["state"] in FINISHED or job.snap["paused"] == paused:
                return
            job.snap["paused"] = paused
            self._touch(job)
        self._save(job)

    # --- internals: process jobs --------------------------------------------------------------------
    def _new_executor(self) -> ProcessPoolExecutor:
        executor = ProcessPoolExecutor(
            max_workers=1, mp_context=self._ctx, initializer=watch_parent, initargs=(os.getpid(),)
        )
        executor.submit(warm_up)
        return executor

    def _dispatch(self) -> None:
        """Hand queued process jobs to free worker slots."""
        submitted = []
        with self._lock:
            for slot in self._slots:
                if slot.job_id is not None or not self._pending or self._closed:
                    continue
                job = self._jobs[self._pending.popleft()]
                job_id = job.snap["id"]
                slot.job_id = job_id
                link = WorkerLink(job_id, self._messages, self._cancel_flags)
                try:
                    future = slot.executor.submit(run_in_worker, job.fn, job.payload, link)
                except (BrokenProcessPool, RuntimeError):
                    # The idle worker died (killed, out of memory) and its pool knows: a new one takes the job.
                    self._rebuild(slot)
                    future = slot.executor.submit(run_in_worker, job.fn, job.payload, link)
                submitted.append((future, partial(self._process_done, job_id, slot, slot.generation)))
        # A callback may run at once, in this thread: never while holding the lock (see _save).
        for future, callback in submitted:
            future.add_done_callback(callback)

    def _rebuild(self, slot: _Slot) -> None:
        old = slot.executor
        slot.executor = self._new_executor()
        slot.generation += 1
        old.shutdown(wait=False, cancel_futures=True)

    def _process_done(self, job_id: str, slot: _Slot, generation: int, future: Future) -> None:
        """Runs on the executor's thread when a worker's future resolves (result, error or crash)."""
        job = self._jobs[job_id]
        broken = False
        try:
            outcome, value, trace = future.result()
        except CancelledError:  # dropped from the pool at shutdown
            outcome, value, trace = "cancelled", None, ""
        except BrokenProcessPool:
            broken = True
            if job.pid is None and not (job.kill_reason or job.cancel_requested or job.resent or self._closed):
                # The worker died before it took the job (killed while idle, and its pool did not know yet
                # when the job was handed to it): the job goes to the slot's new worker, once.
                job.resent = True
                with self._lock:
                    if slot.generation == generation:
                        self._rebuild(slot)
                    slot.job_id = None
                    self._pending.appendleft(job_id)
                self._dispatch()
                return
            if job.kill_reason == "cancelled":
                outcome, value, trace = "cancelled", None, ""
            else:
                outcome, value, trace = "failed", job.kill_reason or CRASHED, ""
        except Exception as exc:  # the payload or the result could not cross the process boundary
            outcome, value, trace = "failed", internal_error(exc), traceback.format_exc()
        if trace:
            log.warning("job %s failed in its worker:\n%s", job_id, trace)
        result = None
        if outcome == "done":
            try:
                result = job.finish(value, job_id) if job.finish else (None if value is None else str(value))
            except (InputError, StoreWriteError) as exc:  # StoreWriteError: the disk refused the result
                outcome, value = "failed", _one_line(str(exc))
            except Exception as exc:
                log.exception("job %s: its result could not be stored", job_id)
                outcome, value = "failed", internal_error(exc)
        with self._lock:
            if broken and slot.generation == generation and not self._closed:
                self._rebuild(slot)
            slot.job_id = None
        with contextlib.suppress(Exception):
            self._cancel_flags.pop(job_id, None)
        self._finish(job, outcome, result=result, error=value if outcome == "failed" else None)
        self._dispatch()

    def _pump_messages(self) -> None:
        """Progress from the workers into the snapshots; kills overdue workers."""
        while not self._closed:
            try:
                message = self._messages.get(timeout=0.1)
            except queue.Empty:
                message = None
            except (EOFError, OSError):
                if not self._closed:
                    log.error("the jobs' progress channel closed: progress is no longer reported")
                return
            if message is not None:
                self._handle(message)
            self._watchdog()

    def _handle(self, message: tuple) -> None:
        kind, job_id, *values = message
        with self._changed:
            job = self._jobs.get(job_id)
            if job is None or job.snap["state"] in FINISHED:
                return
            if kind == "progress" and job.snap["state"] == "running":
                iteration, cost = values
                job.snap["cost"].append(cost)
                job.snap["detail"]["iterations"] = iteration
                job.snap["progress"] = min(PROGRESS_CAP, iteration / (iteration + 5))
                self._touch(job)
            starting = kind == "start" and job.snap["state"] == "queued"
            if starting:
                job.pid = int(values[0])
        if starting:
            self._start(job)

    def _watchdog(self) -> None:
        now = time.monotonic()
        with self._lock:
            for job in self._jobs.values():
                if not job.process or job.snap["state"] != "running" or job.pid is None or job.kill_reason:
                    continue
                if job.cancel_requested and now - job.cancel_at > self.cancel_grace_s:
                    job.kill_reason = "cancelled"
                elif now - job.started > self.timeout_s:
                    job.kill_reason = (
                        f"the calibration took longer than its limit of {self.timeout_s:g} s and was stopped"
                    )
                else:
                    continue
                log.warning("job %s: killing worker %d (%s)", job.snap["id"], job.pid, job.kill_reason)
                _kill(job.pid)


def _kill(pid: int) -> None:
    with contextlib.suppress(ProcessLookupError):
        os.kill(pid, getattr(signal, "SIGKILL", signal.SIGTERM))


def _copy(snap: dict) -> dict:
    return {**snap, "detail": dict(snap["detail"]), "cost": list(snap["cost"])}


def _now() -> str:
    return datetime.now(UTC).isoformat(timespec="milliseconds")
