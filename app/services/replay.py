"""Replay (SumVisCal / RoboVisCal): drive a robot through configurations and capture a frame at each.

The configurations are another session's, a session's own (re-measure), or N new ones planned with the
robot's active calibration (for the least predicted error of a calibration in a mode, or at random);
`until` plans each next configuration from the frames measured so far and stops when the predicted error
reaches a target. A robot whose camera or board has no pose yet (a hand-eye set-up before its first
calibration: calib_core.estimation.plan_seed) is planned for with the registrations fitted on the session's
measured frames once they fix them, and before that around where it stands: the board's finder on its live
image seeds the model, and the new configurations keep near it (`base_model`). A plan from frames is made
when the request comes, so its mistakes answer at once; N new configurations are planned in the job (about
0.1 s each on Robonaut), so the request returns at once and the job shows "planning" meanwhile. The dry run
(app/robots/capture.py) checks every configuration before anything moves and predicts the accuracy of a
calibration from those it would capture: of frames, in the request; of new configurations, in a job of its
own (kind "dry_run": planning, checking, predicting; its result read with `dry_run_result`), and the plan it
checked is the one the replay after it drives. `resume` goes on with a replay a fault or an abort stopped.
"""

from __future__ import annotations

import threading
from collections.abc import Callable
from contextlib import suppress
from dataclasses import dataclass, replace
from typing import TypedDict

import numpy as np

from calib_core import FrameStatus, InputError, Profile
from calib_core.estimation import (
    Around,
    Plan,
    PlanProgress,
    SequentialPlan,
    around_seed,
    candidates,
    needs_seed,
    predict_accuracy,
    register,
    seeded_model,
)
from calib_core.estimation import plan as plan_configurations
from calib_core.vision import Sampler, Visibility

from ..drivers import LimitError, RobotDriver
from ..errors import NotFound
from ..jobs.runner import JobContext, JobRunner
from ..jobs.snapshot import JobState
from ..robots.capture import DryRunRow, Until, capture_until, dry_run, out_of_margin, replay
from ..robots.roster import Robots
from ..store import Store

# A resumed replay leaves out a configuration the session holds a frame at within this on every joint: a
# frame's joints are the encoder readings at the commanded configuration (0.1 deg resolution, servo error).
RESUME_TOLERANCE_DEG = 0.5
MAX_PLANNED = 2000  # new configurations one replay may plan
PLANS_KEPT = 8  # recent plans kept, so that a replay after its dry run drives the plan the dry run checked
DRY_RUNS_KEPT = 8  # results of recent dry run jobs kept for dry_run_result
SEEDS_KEPT = 8  # recent base models of robots without a pose for their camera or board (base_model)
MIN_REGISTRATION_FRAMES = 3  # measured frames a camera's and its board's poses are fitted on (turns about 2 axes)
# A dry run job's progress: planning up to this share, then checking every configuration, then predicting.
PLANNING_SHARE, CHECKING_SHARE = 0.9, 0.07


class DryRunResult(TypedDict):
    """A dry run's answer (the API's DryRun): every configuration checked, and the accuracy predicted."""

    ok: bool  # every configuration would be captured
    configurations: list[DryRunRow]
    mode: str  # the mode the accuracy is predicted for
    predicted: dict | None  # calib_core's AccuracyPrediction.to_dict() (None: no configuration would be captured)


class Pacing(TypedDict, total=False):
    """plan()'s arguments that pace it as a job's (`_pacing`; none: it runs outside a job)."""

    progress: Callable[[PlanProgress], None]
    should_stop: Callable[[], bool]


@dataclass(frozen=True)
class ReplayPlan:
    """What to drive through: another session's frames, the session's own (remeasure), or `count` new
    configurations (planned with `seed`); `resume` leaves out those the session holds a frame at."""

    from_session: str | None = None
    count: int | None = None
    remeasure: bool = False
    seed: int = 0
    resume: bool = False
    mode: str | None = None  # the calibration mode new configurations are planned for (default: full, or the first)
    planner: str = "task"  # new configurations: "task" (planned, calib_core.estimation.planning) or "random"
    until: Until | None = None  # capture until the predicted error reaches a target (sequential design)

    @property
    def from_frames(self) -> bool:
        return self.remeasure or bool(self.from_session)


def default_mode(profile: Profile, mode: str | None) -> str:
    """The mode a replay plans for: the one asked (checked), else `full` when the profile has it, else its first."""
    if mode is not None:
        return profile.mode(mode).name
    return "full" if "full" in profile.modes else next(iter(profile.modes))


class ReplayService:
    def __init__(self, store: Store, robots: Robots, jobs: JobRunner) -> None:
        self.store = store
        self.robots = robots
        self.jobs = jobs
        self._plans: dict[tuple, Plan] = {}
        self._dry_runs: dict[str, DryRunResult] = {}  # dry run job: its result (the latest DRY_RUNS_KEPT)
        self._seeds: dict[tuple, tuple[np.ndarray, Around | None]] = {}  # base_model's, the latest SEEDS_KEPT
        self._lock = threading.Lock()
        self._starting = threading.Lock()
        self._driving: dict[str, tuple[str, str, ReplayPlan]] = {}  # robot: its latest replay (job, session, plan)
        self._checking: dict[str, tuple[str, str, ReplayPlan]] = {}  # robot: its latest dry run job (the same)

    def configurations(self, session_id: str, plan: ReplayPlan) -> tuple[np.ndarray, np.ndarray, list[int] | None]:
        """The configurations (rad), targets and frame indices (None: append) a replay drives through."""
        return self.planned(session_id, plan)[:3]

    def planned(
        self, session_id: str, plan: ReplayPlan, ctx: JobContext | None = None
    ) -> tuple[np.ndarray, np.ndarray, list[int] | None, np.ndarray]:
        """configurations(), and which of them were measured in the session they come from (bool; new
        configurations: none), so that the dry run trusts their measurement over a prediction. `ctx`: the job
        that plans them (its progress while planning; a cancel stops the planning)."""
        return self._configurations(session_id, plan, ctx)[:4]

    def base_model(self, session_id: str) -> tuple[np.ndarray, Around | None]:
        """The model new configurations of a session are planned and checked with, and the neighbourhood they
        keep to (None: anywhere). The robot's active calibration; without one, for a camera or board of
        unknown pose (`needs_seed`), the registrations fitted on the session's measured frames once they fix
        them, else the model seeded by the board in the camera's live image where the robot stands, and its
        neighbourhood (calib_core.estimation.plan_seed). The same robot, readings and frames: the same model,
        so that a replay after its dry run drives the plan the dry run checked."""
        robot = self.store.sessions.get(session_id).robot
        profile = self.robots.get(robot).profile
        cal_id, believed = self.robots.active_params(robot)
        if cal_id is not None or not needs_seed(profile):
            return believed, None
        driver = self.robots.driver(robot)
        frames = [f.index for f in self.store.sessions.frames(session_id) if f.status == FrameStatus.MEASURED]
        readings = np.round(np.degrees(driver.read_joints()), 1)
        key = (robot, session_id, tuple(frames), readings.tobytes())
        with self._lock:
            if key in self._seeds:
                return self._seeds[key]
        base: tuple[np.ndarray, Around | None] | None = None
        if len(frames) >= MIN_REGISTRATION_FRAMES:
            with suppress(InputError):  # the frames may not fix the poses yet (no board pose, turns about one axis)
                base = (register(profile, self.store.sessions.dataset(session_id, profile), believed), None)
        if base is None:
            look = driver.look(believed)
            sighting = look.sightings[0]
            if sighting.measured is None:
                raise InputError(
                    f"{robot} has no calibration yet and {profile.sensors[sighting.sensor].name} does not see "
                    f"{profile.targets[sighting.target].name} where the robot stands ({sighting.reason}): move it "
                    "where the camera sees the board (Observe shows the live image) and plan again; the first "
                    "configurations are planned around that view"
                )
            base = (seeded_model(profile, believed, look.readings_rad, sighting), around_seed(look.readings_rad))
        with self._lock:
            self._seeds[key] = base
            while len(self._seeds) > SEEDS_KEPT:
                self._seeds.pop(next(iter(self._seeds)))
        return base

    def _configurations(
        self, session_id: str, plan: ReplayPlan, ctx: JobContext | None = None, share: float = 1.0
    ) -> tuple[np.ndarray, np.ndarray, list[int] | None, np.ndarray, Plan | None]:
        """planned(), and the plan of new configurations they come from (None: frames, or random). `share`: of
        the job's progress that planning fills."""
        count = self._check(session_id, plan)
        q, targets, indices, seen, made = self._plan(session_id, plan, count, ctx, share)
        if not plan.resume:
            return q, targets, indices, seen, made
        have = np.array([f.joints_rad for f in self.store.sessions.frames(session_id)]).reshape(-1, q.shape[1])
        driver = self.robots.driver(self.store.sessions.get(session_id).robot)
        driven = np.array([_driven(driver, qk) for qk in q]).reshape(q.shape)  # where the replay took each
        todo = np.ones(len(q), bool)
        for at in (q, driven):  # a skipped frame records the configuration asked for, a captured one the readings
            near = np.abs(at[:, None, :] - have[None, :, :]) <= np.radians(RESUME_TOLERANCE_DEG)
            todo &= ~np.all(near, axis=2).any(axis=1)
        if not todo.any():
            raise InputError(
                f"nothing to resume: session '{session_id}' has a frame at each of the {len(q)} configurations"
            )
        return q[todo], targets[todo], None, seen[todo], made

    def dry_run(self, session_id: str, plan: ReplayPlan, ctx: JobContext | None = None) -> DryRunResult:
        """Every configuration checked, and the accuracy a calibration from those captured is predicted to
        have (with `until`: the plan of its `max` configurations, and the predicted error after each). `ctx`:
        the dry run's job (start_dry_run), told its progress: planning, checking, predicting."""
        robot = self.store.sessions.get(session_id).robot
        profile = self.robots.get(robot).profile
        mode = default_mode(profile, plan.mode)
        plan = _counted(plan)
        q, targets, _, seen, made = self._configurations(session_id, plan, ctx, PLANNING_SHARE)
        believed = self._checked_with(session_id, plan)

        def checked(k: int, n: int) -> None:
            assert ctx is not None
            ctx.checkpoint()
            ctx.progress(PLANNING_SHARE + CHECKING_SHARE * k / n, phase="checking", checked=k, total=n)

        driver = self.robots.driver(robot)
        rows = dry_run(driver, q, targets, believed, seen=seen, progress=None if ctx is None else checked)
        if ctx is not None:
            ctx.progress(PLANNING_SHARE + CHECKING_SHARE, phase="predicting")
        captured = [k for k, r in enumerate(rows) if r["action"] == "capture"]
        predicted = None
        if made is not None and not plan.resume and len(captured) == len(rows) == plan.count:
            predicted = made.predicted.to_dict()  # the plan's own prediction holds
        elif captured:
            pred = predict_accuracy(profile, mode, q[captured], targets[captured], believed, seed=plan.seed)
            predicted = pred.to_dict()
        return {"ok": all(r["ok"] for r in rows), "configurations": rows, "mode": mode, "predicted": predicted}

    def start_dry_run(self, session_id: str, plan: ReplayPlan) -> str:
        """Queue the dry run of new configurations (planning them takes about 0.1 s each on Robonaut) as a job;
        its id. What can be wrong with the request is refused at once. The same request while its dry run is
        queued or running (a double click, a second tab) is that dry run; another dry run of the same robot
        meanwhile is refused naming the job. The job's result, once done: dry_run_result."""
        robot = self.store.sessions.get(session_id).robot
        default_mode(self.robots.get(robot).profile, plan.mode)  # an unknown mode answers at once
        count = self._check(session_id, _counted(plan))
        with self._starting:
            running = self._checking.get(robot)
            if running is not None and not self.jobs.get(running[0]).state.finished:
                if running[1:] == (session_id, plan):
                    return running[0]
                raise InputError(
                    f"a dry run (job {running[0]}) is planning for {robot}: wait for it to end, or cancel it first"
                )

            def run(ctx: JobContext) -> str:
                result = self.dry_run(session_id, plan, ctx)
                with self._lock:
                    self._dry_runs[ctx.job_id] = result
                    while len(self._dry_runs) > DRY_RUNS_KEPT:
                        self._dry_runs.pop(next(iter(self._dry_runs)))
                return session_id

            detail = {"robot": robot, "count": count, "phase": "planning"}
            job_id = self.jobs.submit_thread("dry_run", run, session_id=session_id, detail=detail, pausable=False)
            self._checking[robot] = (job_id, session_id, plan)
            return job_id

    def dry_run_result(self, job_id: str) -> DryRunResult:
        """What a dry run job found (the dry run's answer), once it is done."""
        job = self.jobs.get(job_id)
        if job.kind != "dry_run":
            raise NotFound(f"job '{job_id}' is a {job.kind}, not a dry run: it has no dry run result")
        if not job.state.finished:
            raise InputError(f"the dry run (job {job_id}) is still {job.state}: its result comes when it is done")
        if job.state != JobState.DONE:
            why = f": {job.error}" if job.error else ""
            raise InputError(f"the dry run (job {job_id}) ended {job.state}{why}; it has no result")
        with self._lock:
            result = self._dry_runs.get(job_id)
        if result is None:
            raise NotFound(
                f"the result of dry run job '{job_id}' is no longer kept (the desk keeps the latest {DRY_RUNS_KEPT} "
                "until it restarts): run the dry run again"
            )
        return result

    def start(self, session_id: str, plan: ReplayPlan) -> str:
        """Queue the replay job; its id. The same request while its replay is queued or running (a double
        click, a second tab) is that replay; another replay of the same robot meanwhile is refused."""
        robot = self.store.sessions.get(session_id).robot
        with self._starting:
            running = self._driving.get(robot)
            if running is not None and not self.jobs.get(running[0]).state.finished:
                if running[1:] == (session_id, plan):
                    return running[0]
                raise InputError(
                    f"a replay (job {running[0]}) is driving {robot}: wait for it to end, or abort it first"
                )
            job_id = self._start(session_id, plan)
            self._driving[robot] = (job_id, session_id, plan)
            return job_id

    def _start(self, session_id: str, plan: ReplayPlan) -> str:
        driver = self.robots.driver(self.store.sessions.get(session_id).robot)
        if plan.until is not None:
            return self._start_until(session_id, plan, driver)
        ready = self.planned(session_id, plan) if plan.from_frames else None
        if ready is None:
            self._check(session_id, plan)

        def run(ctx: JobContext) -> str | None:
            if ready is None:
                ctx.progress(0.0, phase="planning")
                q, targets, indices, seen = self.planned(session_id, plan, ctx)
                ctx.checkpoint()
                ctx.progress(0.0, phase="driving")
            else:
                q, targets, indices, seen = ready
            believed = self._checked_with(session_id, plan)
            return replay(ctx, self.store, driver, session_id, q, targets, indices, seen=seen, believed=believed)

        return self.jobs.submit_thread("replay", run, session_id=session_id)

    def _start_until(self, session_id: str, plan: ReplayPlan, driver: RobotDriver) -> str:
        assert plan.until is not None
        session = self.store.sessions.get(session_id)
        profile = self.robots.get(session.robot).profile
        mode = default_mode(profile, plan.mode)
        if plan.resume or plan.from_frames:
            raise InputError("until plans its own configurations: give it without from_session, remeasure or resume")
        if not plan.until.error > 0 or not 1 <= plan.until.max <= MAX_PLANNED:
            raise InputError(f"until needs a positive error and a max between 1 and {MAX_PLANNED}")
        believed, near = self.base_model(session_id)

        def run(ctx: JobContext) -> str | None:
            ctx.progress(0.0, phase="planning")
            done = [f for f in self.store.sessions.frames(session_id) if f.status == FrameStatus.MEASURED]
            sequence = SequentialPlan(
                profile,
                mode,
                believed,
                around=near,
                seed=plan.seed,
                q_done=np.array([f.joints_rad for f in done]).reshape(-1, len(profile.joints)),
                targets_done=np.array([f.target for f in done], int),
                admissible=lambda q: _within_limits(driver, q),
                should_stop=lambda: ctx.cancelled,
            )
            ctx.checkpoint()
            return capture_until(ctx, self.store, driver, session_id, sequence, plan.until, believed)

        return self.jobs.submit_thread("replay", run, session_id=session_id)

    def _planned(
        self,
        profile: Profile,
        mode: str,
        count: int,
        believed: np.ndarray,
        seed: int,
        ctx: JobContext | None = None,
        share: float = 1.0,
        near: Around | None = None,
    ) -> Plan:
        """A plan (the same request, the same plan: a dry run's plan is the replay's, and is made once). `ctx`:
        the job that makes it, told each step (up to `share` of its progress) and stopped by a cancel; `near`:
        the neighbourhood it keeps to (base_model)."""
        where = None if near is None else (near.q_rad.tobytes(), near.spread_rad)
        key = (profile.name, mode, count, seed, believed.tobytes(), where)
        with self._lock:
            if key in self._plans:
                return self._plans[key]
        planned = plan_configurations(
            profile,
            mode,
            count,
            believed,
            seed=seed,
            criterion=profile.mode(mode).plan,
            around=near,
            **_pacing(ctx, share),
        )
        with self._lock:
            self._plans[key] = planned
            while len(self._plans) > PLANS_KEPT:
                self._plans.pop(next(iter(self._plans)))
        return planned

    def _checked_with(self, session_id: str, plan: ReplayPlan) -> np.ndarray:
        """The model a replay's dry run checks its configurations with: the robot's active calibration for
        configurations from frames, the base model new ones were planned with."""
        if plan.from_frames:
            return self.robots.active_params(self.store.sessions.get(session_id).robot)[1]
        return self.base_model(session_id)[0]

    def _check(self, session_id: str, plan: ReplayPlan) -> int:
        """What can be wrong with a request before any planning: the session, its robot, the options. Returns
        the count of new configurations to plan (0 for a plan from frames)."""
        robot = self.store.sessions.get(session_id).robot
        self.robots.driver(robot)  # a robot with real data only has nothing to replay on
        if plan.resume and plan.remeasure:
            raise InputError("resume goes on with a replay that adds frames; start a re-measure again instead")
        if plan.from_frames:
            return 0
        if plan.count is None or not 1 <= plan.count <= MAX_PLANNED:
            raise InputError(f"give from_session, remeasure, or a count of configurations between 1 and {MAX_PLANNED}")
        return plan.count

    def _plan(
        self, session_id: str, plan: ReplayPlan, count: int, ctx: JobContext | None = None, share: float = 1.0
    ) -> tuple[np.ndarray, np.ndarray, list[int] | None, np.ndarray, Plan | None]:
        session = self.store.sessions.get(session_id)
        robot = self.robots.get(session.robot)
        if plan.from_frames:
            source = self.store.sessions.get(session_id if plan.remeasure else str(plan.from_session))
            if source.robot != session.robot:
                raise InputError(f"session '{source.id}' is of robot {source.robot}, not {session.robot}")
            frames = self.store.sessions.frames(source.id)
            if not frames:
                raise InputError(f"session '{source.id}' has no frames to replay")
            q = np.array([f.joints_rad for f in frames])
            targets = np.array([f.target for f in frames])
            seen = np.array([f.status == FrameStatus.MEASURED for f in frames], dtype=bool)
            return q, targets, [f.index for f in frames] if plan.remeasure else None, seen, None
        # Configurations the robot believes it sees the target in: with its base model (base_model). Random:
        # twice as many as asked, since those inside a joint's safety margin are left out. Planned: for the
        # least predicted error of a calibration in the mode, inside the limits less the margin already.
        believed, near = self.base_model(session_id)
        driver = self.robots.driver(session.robot)
        made = None
        stop = None if ctx is None else (lambda: ctx.cancelled)
        if plan.planner == "random" and near is not None:
            if ctx is not None:
                ctx.progress(0.0, phase="planning", stage="drawing")
            q, targets = candidates(
                robot.profile, believed, seed=plan.seed, count=2 * count + 10, should_stop=stop, around=near
            )
        elif plan.planner == "random":
            planner = Sampler(Visibility(robot.profile, believed), np.random.default_rng(plan.seed))
            if ctx is not None:
                ctx.progress(0.0, phase="planning", stage="drawing")
            q, targets = planner.configurations(2 * count + 10, should_stop=stop)
        else:
            mode = default_mode(robot.profile, plan.mode)
            made = self._planned(robot.profile, mode, count, believed, plan.seed, ctx, share, near)
            q, targets = made.q, made.targets
        keep = [k for k in range(len(q)) if _within_limits(driver, q[k])][:count]
        return q[keep], targets[keep], None, np.zeros(len(keep), bool), made


def _counted(plan: ReplayPlan) -> ReplayPlan:
    """What a dry run checks of `until`: the plan of its `max` configurations."""
    return plan if plan.until is None else replace(plan, count=plan.until.max, until=None)


def _pacing(ctx: JobContext | None, share: float) -> Pacing:
    """plan()'s `progress` and `should_stop` for a job: its progress up to `share` while planning (with the
    stage and its steps in the detail), and planning stops at the next step once the job is cancelled."""
    if ctx is None:
        return {}

    def progress(step: PlanProgress) -> None:
        ctx.progress(share * step.fraction, phase="planning", stage=step.stage, step=step.done, steps=step.total)

    return {"progress": progress, "should_stop": lambda: ctx.cancelled}


def _within_limits(driver: RobotDriver, q_rad: np.ndarray) -> bool:
    try:
        driver.check(q_rad)
    except LimitError:
        return False
    return True


def _driven(driver: RobotDriver, q_rad: np.ndarray) -> np.ndarray:
    """Where a replay drives the robot for q: out of the safety margin (a pose beyond a limit: q itself,
    which the dry run refuses anyway)."""
    try:
        return out_of_margin(driver, q_rad)[0]
    except LimitError:
        return q_rad
