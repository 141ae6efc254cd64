"""Calibrating a session: the request checked (its options, the session's rows against the desk's limit and
the mode's parameters, the base calibration), then a process job of the runner (app/jobs/runner.py) that reads
the session's measured frames, solves in a worker process and stores the calibration.

A worker process imports this module to run `solve`: it imports nothing of the server at run time (the store
and the runner are only named in type hints).
"""

from __future__ import annotations

import math
import threading
from dataclasses import replace
from typing import TYPE_CHECKING, Any, TypedDict

from calib_core import Calibration, Dataset, InputError, Profile, calibrate
from calib_core.estimation import METHODS, check_can_fit

from ..errors import NotFound
from ..jobs.worker import WorkerLink

if TYPE_CHECKING:
    from ..jobs.runner import JobContext, JobRunner
    from ..store import Store

KIND = "calibration"
MAX_HOLDOUT = 0.9
FEW_FRAMES = 3  # a session of no more measured frames is read and checked whole before its job starts


class SolvePayload(TypedDict):
    """What a calibration job's worker is handed (`CalibrationService.payload`): plain data, pickled."""

    profile: Profile
    session: str
    mode: str
    base: dict | None  # the base calibration's calib-calibration/1 dictionary (None: the nominal model)
    holdout: float
    folds: int
    method: str
    data: Dataset  # the session's measured frames, arrays only


def solve(payload: SolvePayload, link: WorkerLink) -> dict:
    """The worker's part: one calibration from plain data; the result as its calib-calibration/1 dictionary."""
    base = Calibration.from_dict(payload["base"]) if payload["base"] is not None else None
    cal = calibrate(
        payload["profile"],
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


class CalibrationService:
    def __init__(self, store: Store, runner: JobRunner, *, max_rows: int) -> None:
        """A calibration of more than `max_rows` observations is refused (the desk's row limit, app/web/limits.py)."""
        self.store = store
        self.runner = runner
        self.max_rows = max_rows
        self._submitting = threading.Lock()  # a request: checked against the live jobs, then queued
        self._live: dict[tuple, str] = {}  # a request's options: its job, while it may be queued or running

    def submit(
        self, session_id: str, mode: str, base_id: str | None, holdout: float, *, folds: int = 0, method: str = "lm"
    ) -> str:
        """Check, then queue a calibration of the session's measured frames; the job's result is the stored
        calibration's id. Unknown session or base calibration: NotFound; anything else wrong: InputError.
        The same request while its job is queued or running (a double click, a second tab) is that job.

        Loading the data, the held-out split and the solve, which all grow with the data, run in the job: the
        request answers at once, and the job can be cancelled throughout."""
        asked = (session_id, mode, base_id, holdout, folds, method)
        with self._submitting:  # two requests at once: the second finds the first's job
            self._live = {k: j for k, j in self._live.items() if not self.runner.get(j).state.finished}
            if asked in self._live:
                return self._live[asked]
            profile, base, measured = self.check(session_id, mode, base_id, holdout, folds=folds, method=method)
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

            def prepare(ctx: JobContext) -> SolvePayload:
                payload = self.payload(session_id, mode, base, holdout, folds=folds, method=method)
                ctx.checkpoint()  # cancelled while the data were read: no solve
                ctx.report(phase="solving")
                return payload

            def finish(result: dict, ctx: JobContext) -> str:
                return self._store_result(Calibration.from_dict(result), session_id, base_id, holdout, ctx)

            job_id = self.runner.submit_process(
                KIND, solve, prepare, session_id=session_id, detail=detail, finish=finish
            )
            self._live[asked] = job_id
            return job_id

    def check(
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
        base = self._base(base_id, profile)
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
        few_rows = sum(n * sensor_dim[s] for s, n in counts.items()) <= len(m.free)
        if few_rows or session.measured <= FEW_FRAMES:
            # No more rows than parameters: whether they are too few depends on what they determine (the
            # calibration holds what they cannot tell apart); a camera and a board nobody placed need views
            # from FEW_FRAMES configurations. Such a session is small: check it here.
            data = self.store.sessions.dataset(session_id, profile)
            try:
                check_can_fit(profile, data, mode, None if base is None else Calibration.from_dict(base))
            except InputError as exc:
                raise InputError(f"session '{session_id}': {exc.message}") from None
        train = session.measured - round(holdout * session.measured)
        if folds > train:
            raise InputError(f"{folds} folds need at least {folds} training frames, not {train}")
        return profile, base, session.measured

    def payload(
        self, session_id: str, mode: str, base: dict | None, holdout: float, *, folds: int = 0, method: str = "lm"
    ) -> SolvePayload:
        """The plain data `solve` needs (the session's measured frames read from the store); `base`: the base
        calibration as a dictionary. Whether the training share can determine the mode's parameters is the
        worker's check (calibrate), since the held-out split grows with the data."""
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

    def _base(self, base_id: str | None, profile: Profile) -> dict[str, Any] | None:
        """The base calibration as a dictionary (None: the nominal model); it must be of the session's robot."""
        if base_id is None:
            return None
        try:
            info = self.store.calibrations.info(base_id)
        except NotFound:
            raise NotFound.unknown("base calibration", base_id) from None
        if info.robot != profile.name:
            raise InputError(f"base calibration '{base_id}' is for robot '{info.robot}', not '{profile.name}'")
        return self.store.calibrations.load(base_id).to_dict()

    def _store_result(
        self, cal: Calibration, session_id: str, base_id: str | None, holdout: float, ctx: JobContext
    ) -> str:
        """Keep the solved calibration (without its session if that was deleted meanwhile); the job shows its
        figures. Its id is the job's result."""
        try:
            cal_id = self.store.calibrations.add(cal, session_id=session_id, base_id=base_id, holdout=holdout)
        except NotFound:
            cal_id = self.store.calibrations.add(cal, session_id=None, base_id=base_id, holdout=holdout)
        after = cal.figures["after"]
        ctx.report(
            cost=cal.solver.cost_history or None,
            iterations=cal.solver.iterations,
            converged=cal.converged,
            solver_status=cal.solver.status.value,
            before_rms=cal.figures["before"].rms,
            after_rms=after.rms,
            unit=after.unit,
        )
        return cal_id
