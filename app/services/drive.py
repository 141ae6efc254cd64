"""What a request asks of a robot's driver at once: move it (checked against its joint limits less the safety
margin before anything moves), drive it to the configuration of a session's frame, let a simulated robot
wander, stop every robot and every motion job, and capture a frame now (a look through its sensors)."""

from __future__ import annotations

from collections.abc import Mapping

from calib_core import InputError

from ..capture import capture_frame
from ..drivers import Wandering
from ..jobs.runner import JobRunner
from ..robots import Robots
from ..store import FrameInfo, Store
from ..validation import joints_from_deg
from .connection import Connection

MOTION_JOBS = ("replay", "dry_run")  # the jobs that drive a robot, or plan for one that will


class DriveService:
    def __init__(self, store: Store, robots: Robots, jobs: JobRunner, connection: Connection) -> None:
        self.store = store
        self.robots = robots
        self.jobs = jobs
        self.connection = connection

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

    def stop_all(self) -> None:
        """Halt every robot and every motion job (replays, and the dry runs that plan them) at once."""
        for job in self.jobs.list():
            if job.kind in MOTION_JOBS and not job.state.finished:
                self.jobs.cancel(job.id)
        for r in self.robots.all():
            if r.driver is None:
                continue
            if isinstance(r.driver, Wandering):
                r.driver.wander(False)
            r.driver.stop()

    def capture(self, session_id: str) -> FrameInfo:
        """Look now with the session's robot and keep the frame (measured, or not found and why)."""
        session = self.store.sessions.get(session_id)
        return capture_frame(self.store, self.robots.driver(session.robot), session_id)
