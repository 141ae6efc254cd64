"""The calibration desk: the store, the jobs, the robots, the viewers with their 3-D scenes and the services over
them (app/services/), composed; nothing more.

The HTTP API (app/web/routers/) is a thin layer over the services, each given to a router as a dependency
(app/web/routers/deps.py); a script or a test can use them directly. One desk per process: it owns the viser server
(on loopback: browsers reach it through app/web/scene_proxy.py) and the robots' drivers.
"""

from __future__ import annotations

import secrets
import site
import sys
import tempfile
from importlib import resources
from pathlib import Path

import viser

from ..clock import SYSTEM_CLOCK, Clock
from ..drivers.registry import DriverContext
from ..jobs.runner import JobRunner
from ..robots.desk_config import DeskConfig, default_config
from ..robots.roster import Robots
from ..scene.theme import configure
from ..scene.viewers import Viewers
from ..scene.viser_private import close_share_tunnel
from ..services.apply import ApplyService
from ..services.calibration import CalibrationService
from ..services.connection import Connection
from ..services.drive import DriveService
from ..services.history import HistoryService
from ..services.replay import ReplayService
from ..services.review import ReviewService
from ..services.robots import RobotService
from ..store import Store
from ..store.importers import ensure_samples
from . import security
from .limits import Limits
from .scene_proxy import ViserClients

PACKAGE_DIR = Path(__file__).resolve().parents[2]  # the code: no answer names a path under it
SAMPLE_DIR = Path(str(resources.files("app.sample_sessions")))  # package data, in a wheel as in a checkout


class Desk:
    def __init__(self, data_dir: Path, *, loopback: bool = True, limits: Limits | None = None) -> None:
        """`loopback`: the desk is reached from this machine only, so a request may name a file on it. `limits`:
        what one request may ask (app/web/limits.py; read at each request, so a test may change them)."""
        self.data_dir = Path(data_dir)
        self.loopback = loopback
        self.limits = limits or Limits()
        self.scrub = security.Scrubber(server_paths(self.data_dir))  # every error text the desk shows

    # --- life ---------------------------------------------------------------------------------
    def start(
        self,
        *,
        config: DeskConfig | None = None,
        sample_dir: Path | None = SAMPLE_DIR,
        viser_port: int = 0,
        time_scale: float = 1.0,
        clock: Clock = SYSTEM_CLOCK,
        workers: int = 1,
    ) -> None:
        """`config`: the robots (None: the built-in ones); `sample_dir`: the sample sessions imported into a fresh
        store (None: none); `viser_port`: the viser server's port on 127.0.0.1 (0: any free one); `clock`: what
        the drivers' waits, settles and timeouts are measured on; `workers`: calibration worker processes."""
        config = config or default_config()
        self.instance = secrets.token_hex(8)
        self.store = Store(self.data_dir)
        self.robots = Robots(
            self.store,
            DriverContext(time_scale=time_scale, base_dir=config.base_dir, clock=clock),
            self.limits.unpacked_bytes,
        )
        self.robots.start(config)
        if sample_dir is not None and sample_dir.is_dir():
            ensure_samples(self.store, sample_dir, self.robots.names())
        self.jobs = JobRunner(self.store, workers=workers, scrub=self.scrub)
        self.viser = viser.ViserServer(host="127.0.0.1", port=viser_port, verbose=False)
        close_share_tunnel(self.viser)
        configure(self.viser)
        self.viser_clients = ViserClients(self.viser)
        self.viewers = Viewers(lambda: self.connection.shown_first())
        drivable = [r.name for r in self.robots.all() if r.drivable]
        connected = config.connected or (drivable[0] if drivable else None)
        self.connection = Connection(self.store, self.robots, self.viewers, self.scrub, connected)
        self.viser.on_client_connect(self.viewers.client_ready)
        self.calibration = CalibrationService(self.store, self.jobs, max_rows=self.limits.rows)
        self.apply = ApplyService(self.store, self.robots)
        self.history = HistoryService(self.store, self.robots)
        self.replay = ReplayService(self.store, self.robots, self.jobs)
        self.reviews = ReviewService(self.store, self.robots, self.connection, self.scrub)
        self.drive = DriveService(self.store, self.robots, self.jobs, self.connection, clock)
        self.robot_service = RobotService(
            self.robots, self.connection, loopback=self.loopback, max_unpacked_bytes=self.limits.unpacked_bytes
        )
        self.viewers.start()

    def stop(self) -> None:
        self.connection.stop()
        self.viewers.stop()
        self.jobs.shutdown()  # first: a replay ends cancelled, not failed by its driver closing under it
        self.robots.close()
        self.viser.stop()

    @property
    def viser_port_number(self) -> int:
        return int(self.viser.get_port())


def server_paths(data_dir: Path) -> list[Path]:
    """The folders no answer may name a path in: the data directory, the code, the home folder, the
    Python installation (virtualenv, site-packages) and the temporary folder."""
    python = {Path(sys.prefix), Path(sys.base_prefix), Path(sys.exec_prefix), *map(Path, site.getsitepackages())}
    return [Path(data_dir), PACKAGE_DIR, Path.home(), *sorted(python), Path(tempfile.gettempdir())]
