"""Replay (SumVisCal / RoboVisCal): drive a robot through configurations and capture a frame at each.

The configurations are another session's, a session's own (re-measure), or N new ones planned with the
robot's active calibration. A plan from frames is made when the request comes, so its mistakes answer at
once; N new configurations are planned in the job (NAO: tens of ms each), so the request returns at once
and the job shows "planning" meanwhile. The dry run (app/capture.py) checks every configuration before
anything moves; `resume` goes on with a replay a fault or an abort stopped.
"""

from __future__ import annotations

import threading
from dataclasses import dataclass
from typing import Any

import numpy as np

from calib_core import InputError, SimulatedRobot

from ..capture import dry_run, out_of_margin, replay
from ..drivers import LimitError, RobotDriver
from ..jobs import JobContext, JobManager
from ..robots import Robots
from ..store import Store

# A resumed replay leaves out a configuration the session holds a frame at within this on every joint: a
# frame's joints are the encoder readings at the commanded configuration (0.1 deg resolution, servo error).
RESUME_TOLERANCE_DEG = 0.5
MAX_PLANNED = 2000  # new configurations one replay may plan


@dataclass(frozen=True)
class ReplayPlan:
    """What to drive through: another session's frames, the session's own (remeasure), or `count` new
    configurations (planned with `seed`); `resume` leaves out those the session holds a frame at."""

    from_session: str | None = None
    count: int | None = None
    remeasure: bool = False
    seed: int = 0
    resume: bool = False

    @property
    def from_frames(self) -> bool:
        return self.remeasure or bool(self.from_session)


class ReplayService:
    def __init__(self, store: Store, robots: Robots, jobs: JobManager) -> None:
        self.store = store
        self.robots = robots
        self.jobs = jobs
        self._starting = threading.Lock()
        self._driving: dict[str, tuple[str, str, ReplayPlan]] = {}  # robot: its latest replay (job, session, plan)

    def configurations(self, session_id: str, plan: ReplayPlan) -> tuple[np.ndarray, np.ndarray, list[int] | None]:
        """The configurations (rad), targets and frame indices (None: append) a replay drives through."""
        return self.planned(session_id, plan)[:3]

    def planned(self, session_id: str, plan: ReplayPlan) -> tuple[np.ndarray, np.ndarray, list[int] | None, np.ndarray]:
        """configurations(), and which of them were measured in the session they come from (bool; new
        configurations: none), so that the dry run trusts their measurement over a prediction."""
        count = self._check(session_id, plan)
        q, targets, indices, seen = self._plan(session_id, plan, count)
        if not plan.resume:
            return q, targets, indices, seen
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
        return q[todo], targets[todo], None, seen[todo]

    def dry_run(self, session_id: str, plan: ReplayPlan) -> dict[str, Any]:
        robot = self.store.sessions.get(session_id).robot
        q, targets, _, seen = self.planned(session_id, plan)
        _, believed = self.robots.active_params(robot)
        rows = dry_run(self.robots.driver(robot), q, targets, believed, seen=seen)
        return {"ok": all(r["ok"] for r in rows), "configurations": rows}

    def start(self, session_id: str, plan: ReplayPlan) -> str:
        """Queue the replay job; its id. The same request while its replay is queued or running (a double
        click, a second tab) is that replay; another replay of the same robot meanwhile is refused."""
        robot = self.store.sessions.get(session_id).robot
        with self._starting:
            running = self._driving.get(robot)
            if running is not None and self.jobs.get(running[0])["state"] in ("queued", "running"):
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
        ready = self.planned(session_id, plan) if plan.from_frames else None
        if ready is None:
            self._check(session_id, plan)

        def run(ctx: JobContext) -> str | None:
            if ready is None:
                ctx.progress(0.0, phase="planning")
                q, targets, indices, seen = self.planned(session_id, plan)
                ctx.checkpoint()
                ctx.progress(0.0, phase="driving")
            else:
                q, targets, indices, seen = ready
            return replay(ctx, self.store, driver, session_id, q, targets, indices, seen=seen)

        return self.jobs.submit_thread("replay", run, session_id=session_id)

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
        self, session_id: str, plan: ReplayPlan, count: int
    ) -> tuple[np.ndarray, np.ndarray, list[int] | None, np.ndarray]:
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
            seen = np.array([f.status == "measured" for f in frames], dtype=bool)
            return q, targets, [f.index for f in frames] if plan.remeasure else None, seen
        # Configurations the robot believes it sees the fixture in: planned with its active model. Twice
        # as many as asked, since those inside a joint's safety margin are left out.
        _, believed = self.robots.active_params(session.robot)
        planner = SimulatedRobot.from_profile(robot.profile, seed=plan.seed, truth=believed)
        q, targets = planner.configurations(2 * count + 10)
        driver = self.robots.driver(session.robot)
        keep = [k for k in range(len(q)) if _within_limits(driver, q[k])][:count]
        return q[keep], targets[keep], None, np.zeros(len(keep), bool)


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
