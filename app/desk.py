"""The calibration desk: the store, the jobs, the robots, the 3-D scene and the services over them, composed.

The HTTP API (app/routers/) is a thin layer over this; a script or a test can drive the desk directly.
One desk per process: it owns the viser server and the robots' drivers.
"""

from __future__ import annotations

import site
import sys
import tempfile
from importlib import resources
from pathlib import Path
from typing import Any

import viser

from . import security
from .capture import capture_frame
from .desk_config import DeskConfig, default_config
from .drivers.registry import DriverContext, DriverSpec
from .importers import ensure_samples
from .jobs import JobManager
from .robots import Robot, Robots
from .scene import ReviewScene
from .services.apply import ApplyService
from .services.observe import Observer
from .services.replay import ReplayService
from .services.review import ReviewService
from .store import FrameInfo, ProfileFiles, Store

PACKAGE_DIR = Path(__file__).resolve().parent.parent  # the code: no answer names a path under it
SAMPLE_DIR = Path(str(resources.files("app.sample_sessions")))  # package data, in a wheel as in a checkout


class Desk:
    def __init__(
        self,
        data_dir: Path,
        *,
        config: DeskConfig | None = None,
        sample_dir: Path | None = SAMPLE_DIR,
        viser_host: str = "127.0.0.1",
        viser_port: int = 0,
        time_scale: float = 1.0,
        workers: int = 1,
        loopback: bool = True,
    ) -> None:
        """`loopback`: the desk is reached from this machine only, so a request may name a file on it."""
        self.data_dir = Path(data_dir)
        self.config = config or default_config()
        self.sample_dir = sample_dir
        self.viser_host = viser_host
        self.viser_port = viser_port
        self.time_scale = time_scale
        self.workers = workers
        self.loopback = loopback
        self.scrub = security.Scrubber(server_paths(self.data_dir))  # every error text the desk shows
        self.connected: str | None = None
        self._observer: Observer | None = None

    # --- life ---------------------------------------------------------------------------------
    def start(self) -> None:
        self.store = Store(self.data_dir)
        self.robots = Robots(self.store, DriverContext(time_scale=self.time_scale, base_dir=self.config.base_dir))
        self.robots.start(self.config)
        if self.sample_dir is not None and self.sample_dir.is_dir():
            ensure_samples(self.store, self.sample_dir, self.robots.names())
        self.jobs = JobManager(self.store, workers=self.workers, scrub=self.scrub)
        drivable = [r.name for r in self.robots.all() if r.drivable]
        self.connected = self.config.connected or (drivable[0] if drivable else None)
        self.viser = viser.ViserServer(host=self.viser_host, port=self.viser_port, verbose=False)
        security.close_viser_share(self.viser)
        self.scene = ReviewScene(self.viser)
        self.apply = ApplyService(self.store, self.robots)
        self.replay = ReplayService(self.store, self.robots, self.jobs)
        self.reviews = ReviewService(self.store, self.robots, self.scene)
        shown = self.connected or next(iter(self.robots.names()), None)
        if shown is not None:
            self._show(shown)

    def stop(self) -> None:
        self.observe(None)
        self.robots.close()
        self.jobs.shutdown()
        self.viser.stop()

    @property
    def viser_port_number(self) -> int:
        return int(self.viser.get_port())

    # --- robots -------------------------------------------------------------------------------
    def add_robot(
        self, name: str, *, profile: str | None, files: ProfileFiles | None, driver: DriverSpec | None
    ) -> Robot:
        """A robot added to the running desk (Robots.add); the first drivable one is connected."""
        robot = self.robots.add(name, profile=profile, files=files, driver=driver)
        if self.connected is None and robot.drivable:
            self.connected = name
        return robot

    def remove_robot(self, name: str) -> None:
        """A robot added through the API taken off the desk (Robots.remove); its driver is closed."""
        observer = self._observer
        if observer is not None and observer.robot == name:
            self.observe(None)
        self.robots.remove(name)
        if self.connected == name:
            self.connected = next((r.name for r in self.robots.all() if r.drivable), None)
        shown = self.connected or next(iter(self.robots.names()), None)
        if self.scene.robot == name and shown is not None:
            self._show(shown)

    # --- the robot in view --------------------------------------------------------------------
    def robot_name(self, robot: str | None) -> str:
        """`robot`, or the connected one when None (bad input when no robot can be driven)."""
        if robot:
            return robot
        if self.connected is None:
            raise self.robots.no_driver_error(None)
        return self.connected

    def connect(self, robot: str) -> None:
        self.robots.driver(robot)  # named exactly: robot_name would take "" for the connected one
        if robot != self.connected:
            self.observe(None)
            self.connected = robot
        self._show(robot)

    def _show(self, robot: str) -> None:
        """The scene shows this robot (at zero joint angles) unless it shows it already; the review of another
        robot it showed is closed."""
        r = self.robots.get(robot)
        with self.reviews.lock:
            if self.scene.robot == robot:
                return
            self.scene.show_robot(r.profile, None if r.urdf is None else r.urdf.read_text(encoding="utf-8"))
            self.reviews.close()

    # --- capture and observe ------------------------------------------------------------------
    def capture(self, session_id: str) -> FrameInfo:
        session = self.store.sessions.get(session_id)
        return capture_frame(self.store, self.robots.driver(session.robot), session_id)

    def observe(self, session_id: str | None, *, autocapture: bool = False) -> None:
        """Observe a session's robot (None: stop observing)."""
        if self._observer is not None:
            self._observer.stop()
            self._observer = None
        if session_id is None:
            return
        self.connect(self.store.sessions.get(session_id).robot)
        self._observer = Observer(self.store, self.robots, self.scene, session_id, autocapture, self.scrub)
        self._observer.start()

    def observing(self) -> dict[str, Any] | None:
        observer = self._observer
        return None if observer is None else observer.snapshot()

    # --- review -------------------------------------------------------------------------------
    def review(self, session_id: str, old: str | None, new: str | None) -> dict[str, Any]:
        review, key = self.reviews.build(session_id, old, new)
        observer = self._observer
        if observer is not None and observer.robot != key["robot"]:
            self.observe(None)  # the scene shows one robot: the review replaces the live view of another
        return self.reviews.show(review, key)


def server_paths(data_dir: Path) -> list[Path]:
    """The folders no answer may name a path in: the data directory, the code, the home folder, the
    Python installation (virtualenv, site-packages) and the temporary folder."""
    python = {Path(sys.prefix), Path(sys.base_prefix), Path(sys.exec_prefix), *map(Path, site.getsitepackages())}
    return [Path(data_dir), PACKAGE_DIR, Path.home(), *sorted(python), Path(tempfile.gettempdir())]
