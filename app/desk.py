"""The calibration desk: the store, the jobs, the robots, the viewers with their 3-D scenes and the services over
them, composed.

The HTTP API (app/routers/) is a thin layer over this; a script or a test can drive the desk directly.
One desk per process: it owns the viser server (on loopback: browsers reach it through app/scene_proxy.py) and
the robots' drivers.
"""

from __future__ import annotations

import secrets
import site
import sys
import tempfile
from importlib import resources
from pathlib import Path
from typing import Any

import viser

from . import security
from .capture import capture_frame
from .clock import SYSTEM_CLOCK, Clock
from .desk_config import DeskConfig, default_config
from .drivers.registry import DriverContext, DriverSpec
from .importers import ensure_samples
from .jobs.runner import JobRunner
from .limits import Limits
from .robots import Robot, Robots
from .scene import configure
from .scene_proxy import ViserClients
from .services.apply import ApplyService
from .services.calibration import CalibrationService
from .services.observe import Observer
from .services.replay import ReplayService
from .services.review import ReviewService
from .store import FrameInfo, ProfileFiles, Store
from .viewers import LINGER_S, Shown, Viewer, Viewers
from .viser_private import close_share_tunnel

PACKAGE_DIR = Path(__file__).resolve().parent.parent  # the code: no answer names a path under it
SAMPLE_DIR = Path(str(resources.files("app.sample_sessions")))  # package data, in a wheel as in a checkout


class Desk:
    def __init__(
        self,
        data_dir: Path,
        *,
        config: DeskConfig | None = None,
        sample_dir: Path | None = SAMPLE_DIR,
        viser_port: int = 0,
        time_scale: float = 1.0,
        clock: Clock = SYSTEM_CLOCK,
        workers: int = 1,
        loopback: bool = True,
        viewer_linger_s: float = LINGER_S,
        limits: Limits | None = None,
    ) -> None:
        """`loopback`: the desk is reached from this machine only, so a request may name a file on it.
        `viser_port`: the viser server's port on 127.0.0.1 (0: any free one). `limits`: what one request may ask
        (app/limits.py). `clock`: what the drivers' waits, settles and timeouts are measured on."""
        self.data_dir = Path(data_dir)
        self.config = config or default_config()
        self.sample_dir = sample_dir
        self.viser_port = viser_port
        self.viewer_linger_s = viewer_linger_s
        self.time_scale = time_scale
        self.clock = clock
        self.workers = workers
        self.loopback = loopback
        self.limits = limits or Limits()
        self.scrub = security.Scrubber(server_paths(self.data_dir))  # every error text the desk shows
        self.connected: str | None = None
        self._observer: Observer | None = None

    # --- life ---------------------------------------------------------------------------------
    def start(self) -> None:
        self.instance = secrets.token_hex(8)
        self.store = Store(self.data_dir)
        self.robots = Robots(
            self.store,
            DriverContext(time_scale=self.time_scale, base_dir=self.config.base_dir, clock=self.clock),
            self.limits.unpacked_bytes,
        )
        self.robots.start(self.config)
        if self.sample_dir is not None and self.sample_dir.is_dir():
            ensure_samples(self.store, self.sample_dir, self.robots.names())
        self.jobs = JobRunner(self.store, workers=self.workers, scrub=self.scrub)
        self.calibration = CalibrationService(self.store, self.jobs, max_rows=self.limits.rows)
        drivable = [r.name for r in self.robots.all() if r.drivable]
        self.connected = self.config.connected or (drivable[0] if drivable else None)
        self.viser = viser.ViserServer(host="127.0.0.1", port=self.viser_port, verbose=False)
        close_share_tunnel(self.viser)
        configure(self.viser)
        self.viser_clients = ViserClients(self.viser)
        self.viewers = Viewers(self._shown_first, linger_s=self.viewer_linger_s)
        self.viser.on_client_connect(self.viewers.client_ready)
        self.apply = ApplyService(self.store, self.robots)
        self.replay = ReplayService(self.store, self.robots, self.jobs)
        self.reviews = ReviewService(self.store, self.robots)
        self.viewers.start()

    def stop(self) -> None:
        self.observe(None)
        self.viewers.stop()
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
        self.viewers.replace_robot(name, self._shown_first())

    # --- the robot in view --------------------------------------------------------------------
    def robot_name(self, robot: str | None) -> str:
        """`robot`, or the connected one when None (bad input when no robot can be driven)."""
        if robot:
            return robot
        if self.connected is None:
            raise self.robots.no_driver_error(None)
        return self.connected

    def connect(self, robot: str, viewer: Viewer | None = None) -> None:
        """Connect the desk to a drivable robot; the viewer (None: the default one) shows it, closing its review
        of another robot."""
        self.robots.driver(robot)  # named exactly: robot_name would take "" for the connected one
        if robot != self.connected:
            self.observe(None)
            self.connected = robot
        (viewer or self.viewers.default).show_robot(self._shown(robot))

    def _shown(self, robot: str) -> Shown:
        r = self.robots.get(robot)
        return Shown(r.profile, None if r.urdf is None else r.urdf.read_text(encoding="utf-8"))

    def _shown_first(self) -> Shown | None:
        """What a new viewer shows: the connected robot, or the first one on the desk."""
        robot = self.connected or next(iter(self.robots.names()), None)
        return None if robot is None else self._shown(robot)

    # --- capture and observe ------------------------------------------------------------------
    def capture(self, session_id: str) -> FrameInfo:
        session = self.store.sessions.get(session_id)
        return capture_frame(self.store, self.robots.driver(session.robot), session_id)

    def observe(self, session_id: str | None, *, autocapture: bool = False, viewer: Viewer | None = None) -> None:
        """Observe a session's robot, its live view shown to the viewer (None: the default one) and to those
        already watching that robot; None: stop observing (every viewer watching goes back to its review)."""
        if self._observer is not None:
            self._observer.stop()
            self._observer = None
        if session_id is None:
            self.viewers.unwatch_all()
            return
        viewer = viewer or self.viewers.default
        self.connect(self.store.sessions.get(session_id).robot, viewer)  # another robot: the watchers stop
        self.viewers.watch(viewer, True)
        self._observer = Observer(self.store, self.robots, self.viewers, session_id, autocapture, self.scrub)
        self._observer.start()

    def observing(self) -> dict[str, Any] | None:
        observer = self._observer
        return None if observer is None else observer.snapshot()

    # --- review -------------------------------------------------------------------------------
    def review(
        self,
        session_id: str,
        old: str | None,
        new: str | None,
        viewer: Viewer | None = None,
        sensor: str | None = None,
    ) -> dict[str, Any]:
        """Load a review (as one sensor sees it; None: the data format's) into a viewer (None: the default
        one). A viewer watching another robot live stops watching; the live view ends when nobody watches it
        any more."""
        review, key = self.reviews.build(session_id, old, new, sensor)
        viewer = viewer or self.viewers.default
        observer = self._observer
        if observer is not None and observer.robot != key["robot"]:
            self.viewers.watch(viewer, False)
            if not self.viewers.watched():
                self.observe(None)
        answer = self.reviews.show(viewer, review, key)
        return answer | {"warnings": [self.scrub(w) for w in answer["warnings"]]}  # a mesh's absolute path


def server_paths(data_dir: Path) -> list[Path]:
    """The folders no answer may name a path in: the data directory, the code, the home folder, the
    Python installation (virtualenv, site-packages) and the temporary folder."""
    python = {Path(sys.prefix), Path(sys.base_prefix), Path(sys.exec_prefix), *map(Path, site.getsitepackages())}
    return [Path(data_dir), PACKAGE_DIR, Path.home(), *sorted(python), Path(tempfile.gettempdir())]
