"""The robots on the desk: each an instance of a profile, with its own driver (or none) and calibrations.

A robot is its name, its profile (the model, named after the robot: app/store/profiles.py), the driver that can
move it (or none: real data only, sessions imported from CSV) and, in the store, its own active
calibration and apply history. Five NAOs are five robots of one profile, each calibrated on its own.

The desk starts with the robots of its configuration (app/robots/desk_config.py), those added through the API
before (kept in the store), and any other robot the store has sessions or calibrations of (without a
driver, so that its data stay reachable). "Drivable" means: has a driver that can move it.
"""

from __future__ import annotations

import logging
import threading
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from calib_core import InputError, Profile
from calib_core.files import read_regular_file
from calib_core.safe_yaml import MAX_YAML_BYTES, load_yaml

from ..drivers import RobotDriver
from ..drivers import registry as drivers
from ..drivers.registry import DriverContext, DriverSpec
from ..errors import NotFound
from ..store import ProfileFiles, RobotRecord, Store
from ..store.profiles import as_instance, builtin_urdf, file_name, is_builtin, load_model
from ..store.robots import kept_urdf_path
from .desk_config import DeskConfig
from .profile_meshes import gather_meshes

log = logging.getLogger(__name__)


@dataclass
class Robot:
    name: str
    model: str  # the profile's own name (nao for nao-1 ... nao-5)
    profile: Profile  # named after the robot
    urdf: Path | None  # a built-in profile's URDF for the scene; None: the scene draws the profile
    driver_kind: str | None
    driver: RobotDriver | None
    origin: str  # "builtin", "config" or "api" (store.robots.RobotRecord)

    @property
    def drivable(self) -> bool:
        """Has a driver that can move it."""
        return self.driver is not None

    @property
    def simulated(self) -> bool:
        """Its driver is the simulated robot."""
        return self.driver_kind == "simulated"


class Robots:
    def __init__(self, store: Store, context: DriverContext, max_mesh_bytes: int) -> None:
        """`max_mesh_bytes`: of the meshes a robot added by naming its profile file brings, together."""
        self.store = store
        self.context = context
        self.max_mesh_bytes = max_mesh_bytes
        self._robots: dict[str, Robot] = {}
        self._lock = threading.Lock()

    # --- life ---------------------------------------------------------------------------------------
    def start(self, config: DeskConfig) -> None:
        for rc in config.robots:
            spec = rc.driver
            self.store.robots.put(
                RobotRecord(rc.name, rc.profile, spec and spec.kind, {} if spec is None else spec.options, rc.origin)
            )
            self._open(rc.name, rc.profile, spec, rc.origin)
        configured = {rc.name for rc in config.robots}
        with_data = set(self.store.robots.names_with_data())
        for record in self.store.robots.list():
            if record.name in configured or (record.origin != "api" and record.name not in with_data):
                continue
            keeps_driver = record.origin == "api" and record.driver is not None  # others: as configured, or none
            spec = DriverSpec(record.driver, record.options) if keeps_driver else None
            try:
                self._open(record.name, record.profile, spec, record.origin)
            except (InputError, OSError) as exc:  # its profile file or its driver is gone: its data stay
                log.warning("robot %s is not on the desk: %s", record.name, exc)
        for name in with_data - set(self._robots):
            if is_builtin(name):  # of a store made before robots were recorded
                self._open(name, name, None, "builtin")

    def close(self) -> None:
        """Close every driver."""
        with self._lock:
            robots = list(self._robots.values())
        for robot in robots:
            _close(robot)

    # --- reading ------------------------------------------------------------------------------------
    def names(self) -> list[str]:
        with self._lock:
            return list(self._robots)

    def all(self) -> list[Robot]:
        with self._lock:
            return list(self._robots.values())

    def get(self, name: str) -> Robot:
        """The robot; an unknown name is bad input (422)."""
        with self._lock:
            robot = self._robots.get(name)
            if robot is None:
                raise InputError(f"unknown robot '{name}' (known: {', '.join(self._robots) or 'none'})")
            return robot

    def driver(self, name: str) -> RobotDriver:
        """The robot's driver; a robot without one (or unknown) is bad input naming those that have one."""
        with self._lock:
            robot = self._robots.get(name)
        if robot is None or robot.driver is None:
            raise self.no_driver_error(name)
        return robot.driver

    def no_driver_error(self, name: str | None) -> InputError:
        """Why `name` (None: any robot) cannot be driven."""
        with self._lock:
            known = name in self._robots
            drivable = ", ".join(r.name for r in self._robots.values() if r.drivable) or "none"
        if name is None:
            return InputError(f"no robot to drive here (robots to drive: {drivable})")
        if known:
            return InputError(
                f"{name} has no robot to drive here (real data only, no driver): import its sessions from CSV to "
                f"calibrate and review them (robots to drive: {drivable})"
            )
        return InputError(f"no robot '{name}' to drive (robots to drive: {drivable})")

    def active_params(self, name: str) -> tuple[str | None, np.ndarray]:
        """The robot's active calibration id and its parameters (the nominal model when none)."""
        profile = self.get(name).profile
        cal_id = self.store.calibrations.active(name)
        if cal_id is None:
            return None, profile.nominal()
        return cal_id, self.store.calibrations.load(cal_id).params(profile)

    def push_active(self, name: str) -> None:
        """Give the robot's driver (if any) its active calibration."""
        driver = self.get(name).driver
        if driver is not None:
            cal_id, p = self.active_params(name)
            driver.apply_calibration(cal_id, None if cal_id is None else p)

    # --- changing -----------------------------------------------------------------------------------
    def add(self, name: str, *, profile: str | None, files: ProfileFiles | None, driver: DriverSpec | None) -> Robot:
        """A new robot on the running desk, kept in the store: `profile` a built-in profile's name or a file on
        this machine (its URDF and that URDF's meshes copied with it), or `files` uploaded. Nothing changes when
        anything is wrong."""
        if (profile is None) == (files is None):
            raise InputError("give the robot's profile: a built-in profile's name, a profile file, or an upload")
        ref = profile if profile is not None and is_builtin(profile) else None
        if profile is not None and ref is None:
            files = read_profile_files(Path(profile), self.max_mesh_bytes)
        made: list[Robot] = []

        def prepare(model: Profile) -> Robot:
            made.append(self._instance(name, model, ref, driver, "api", options_at="driver_options"))
            return made[0]

        record = RobotRecord(name, ref or "", driver and driver.kind, {} if driver is None else driver.options)
        try:
            robot = self.store.robots.add(record, files, prepare)
        except BaseException:
            for robot in made:
                _close(robot)
            raise
        with self._lock:
            self._robots[name] = robot
        self.push_active(name)
        return robot

    def remove(self, name: str) -> None:
        """Take a robot added through the API off the desk (it must have no sessions or calibrations)."""
        with self._lock:
            if name not in self._robots:
                raise NotFound.unknown("robot", name)
        self.store.robots.remove(name)
        with self._lock:
            robot = self._robots.pop(name)
        _close(robot)

    def _open(self, name: str, ref: str, spec: DriverSpec | None, origin: str) -> None:
        robot = self._instance(name, load_model(ref, self.store.data_dir), ref, spec, origin)
        with self._lock:
            self._robots[name] = robot
        self.push_active(name)

    def _instance(
        self,
        name: str,
        model: Profile,
        ref: str | None,
        spec: DriverSpec | None,
        origin: str,
        options_at: str = "driver",
    ) -> Robot:
        """The robot `name` of profile `model` (`ref`: its built-in name, if it is one) with its driver (a wrong
        option named `options_at`.<option>)."""
        profile = as_instance(model, name)
        driver = None if spec is None else drivers.create(spec, profile, self.context, options_at=options_at)
        return Robot(
            name=name,
            model=model.name,
            profile=profile,
            urdf=None if ref is None else builtin_urdf(ref),
            driver_kind=None if spec is None else spec.kind,
            driver=driver,
            origin=origin,
        )


def read_profile_files(path: Path, max_mesh_bytes: int) -> ProfileFiles:
    """A profile file on this machine, the URDF it names (relative to it) and that URDF's meshes (at most
    `max_mesh_bytes` together: app/robots/profile_meshes.py), for the store to keep."""
    text = read_regular_file(path, MAX_YAML_BYTES, "robot profile file")
    doc = load_yaml(text, str(path))
    ref = doc.get("urdf") if isinstance(doc, dict) else None
    urdf = meshes = None
    if isinstance(ref, str) and ref.strip():
        urdf_file = path.parent / ref
        urdf = (file_name(urdf_file.name, "robot.urdf"), read_regular_file(urdf_file, max_mesh_bytes, f"URDF {ref}"))
        meshes = gather_meshes(urdf_file, path.parent, kept_urdf_path(ref, urdf[0]), max_mesh_bytes)
    return ProfileFiles(file_name(path.name, "profile.yaml"), text, urdf, meshes)


def _close(robot: Robot) -> None:
    if robot.driver is not None:
        try:
            robot.driver.close()
        except Exception:  # one driver failing to close must not keep the others open
            log.exception("robot %s: its driver did not close cleanly", robot.name)
