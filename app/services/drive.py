"""What a request asks of a robot's driver at once: move it (checked against its joint limits less the safety
margin before anything moves), drive it to the configuration of a session's frame, let a simulated robot
wander, stop every robot and every motion job, and capture a frame now (a look through its sensors).

STOP never waits on a robot: every robot's halt goes out on its own command lane (app/drivers/calls.py) at
once, and the answer comes within STOP_ANSWER_S of the desk's clock, saying of each robot whether it took the
stop."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass

from calib_core import InputError

from ..clock import SYSTEM_CLOCK, Clock
from ..drivers import Wandering
from ..drivers.calls import Halt
from ..jobs.runner import JobRunner
from ..robots.capture import capture_frame
from ..robots.roster import Robots
from ..store import FrameInfo, Store
from ..store.validation import joints_from_deg
from .connection import Connection

MOTION_JOBS = ("replay", "dry_run")  # the jobs that drive a robot, or plan for one that will
STOP_ANSWER_S = 0.15  # STOP answers within this, whatever the robots do


@dataclass(frozen=True)
class StopOutcome:
    """One robot's answer to STOP."""

    robot: str
    confirmed: bool  # the robot took the halt
    message: str  # "nao-3 stopped", or what it did not do and what the operator should do


class DriveService:
    def __init__(
        self, store: Store, robots: Robots, jobs: JobRunner, connection: Connection, clock: Clock = SYSTEM_CLOCK
    ) -> None:
        self.store = store
        self.robots = robots
        self.jobs = jobs
        self.connection = connection
        self.clock = clock

    def move(self, robot: str | None, joints_deg: Mapping[str, float]) -> str:
        """Start moving a robot (None: the connected one) to `joints_deg` (name -> deg; joints not named keep
        their reading); the robot's name."""
        name = self.connection.robot_name(robot)
        driver = self.robots.driver(name)
        q = joints_from_deg(driver.profile, driver.status().joints_rad, joints_deg)
        driver.check(q)
        driver.move_to(q, wait=False)
        return name

    def goto(self, session_id: str, index: int) -> str:
        """Start driving the session's robot to the configuration of its frame `index`; the robot's name."""
        robot = self.store.sessions.get(session_id).robot
        frame = self.store.sessions.frame(session_id, index)
        driver = self.robots.driver(robot)
        driver.check(frame.joints_rad)
        driver.set_target(frame.target)
        driver.move_to(frame.joints_rad, wait=False)
        return robot

    def wander(self, robot: str | None, on: bool) -> str:
        """Let a simulated robot (None: the connected one) wander by itself, or stop it; the robot's name."""
        name = self.connection.robot_name(robot)
        driver = self.robots.driver(name)
        if not isinstance(driver, Wandering):
            raise InputError(f"{driver.profile.name} is a real robot: someone else drives it")
        driver.wander(on)
        return name

    def stop_all(self) -> list[StopOutcome]:
        """Halt every robot (a wander too) and every motion job (replays, and the dry runs that plan them) at once:
        each robot told on its own lane, the answer within STOP_ANSWER_S, per robot whether it took the stop."""
        for job in self.jobs.list():
            if job.kind in MOTION_JOBS and not job.state.finished:
                self.jobs.cancel(job.id)
        halts: list[Halt] = [r.driver.stop(wait_s=0.0) for r in self.robots.all() if r.driver is not None]
        deadline = self.clock.now() + STOP_ANSWER_S
        for halt in halts:
            if halt.call is not None:
                self.clock.wait_call(halt.call.finished, max(0.0, deadline - self.clock.now()))
        return [StopOutcome(h.robot, h.confirmed, h.sentence()) for h in halts]

    def capture(self, session_id: str) -> FrameInfo:
        """Look now with the session's robot and keep the frame (measured, or not found and why)."""
        session = self.store.sessions.get(session_id)
        return capture_frame(self.store, self.robots.driver(session.robot), session_id)
