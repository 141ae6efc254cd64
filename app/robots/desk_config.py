"""Which robots the desk starts with: its defaults, or a desk configuration file (`calib serve --desk FILE`).

    robots:
      - name: nao-1                 # the robot's name on the desk (sessions and calibrations name it)
        profile: nao                # a built-in profile, or a profile YAML (relative to this file; it may
                                    # say `urdf: robot.urdf`)
        driver: simulated           # a driver kind (app/drivers/registry.py), or {kind: simulated, seed: 2,
                                    # day: 1}; none or null: real data only (sessions imported from CSV)
      - {name: nao-2, profile: nao, driver: {kind: simulated, seed: 2}}
    connected: nao-1                # optional: the robot the desk starts connected to

Everything is checked when the file is read, before the desk starts: a wrong field is an InputError naming
the file and the field (`calib serve` exits 2). Without a file the desk has the built-in robots, each named
after its profile and simulated when its profile can be (`robonaut-a` as on the day of its day-2 sample).
"""

from __future__ import annotations

import functools
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from calib_core import InputError
from calib_core.model import BUILTIN_PROFILES
from calib_core.safe_yaml import read_yaml

from ..drivers import registry
from ..drivers.registry import DriverSpec
from ..drivers.simulated import can_simulate
from ..store.profiles import instance_profile
from ..store.validation import check_id

# The simulated robots' "today": Robonaut is the later-day robot of its day-2 sample session (its
# offsets drifted since day 1), so a calibration made on day 1 and applied shows the drift live.
SIMULATED_DAY = {"robonaut-a": 2}
ROBOT_FIELDS = ("name", "profile", "driver")


@dataclass(frozen=True)
class RobotConfig:
    name: str
    profile: str  # a built-in profile's name, or an absolute path to a profile file
    driver: DriverSpec | None
    origin: str  # "builtin" (the desk's defaults) or "config" (a configuration file)


@dataclass(frozen=True)
class DeskConfig:
    robots: tuple[RobotConfig, ...]
    connected: str | None = None
    source: Path | None = None  # the file, None for the defaults

    @property
    def base_dir(self) -> Path:
        return Path() if self.source is None else self.source.parent


def default_config() -> DeskConfig:
    robots = []
    for name in BUILTIN_PROFILES:
        driver = None
        if _simulable(name):
            driver = DriverSpec("simulated", {"seed": 1, "day": SIMULATED_DAY.get(name, 1)})
        robots.append(RobotConfig(name, name, driver, "builtin"))
    return DeskConfig(tuple(robots))


@functools.cache
def _simulable(name: str) -> bool:
    """Whether the built-in profile `name` can be simulated: the same answer for as long as the process runs (the
    profile is the package's), asked once rather than at every desk's start (asking loads
    the profile)."""
    return can_simulate(instance_profile(name, name, Path()))


def load_desk_config(path: Path) -> DeskConfig:
    """Read and check a desk configuration file (every profile loaded, every driver's options checked)."""
    path = Path(path)
    where = str(path)
    doc = read_yaml(path, "desk configuration file")
    if not isinstance(doc, dict):
        raise InputError("a desk configuration is a YAML mapping with a list of robots", file=where)
    unknown = sorted(set(doc) - {"robots", "connected"})
    if unknown:
        raise InputError(f"{unknown[0]}: no such field (fields: robots, connected)", file=where)
    items = doc.get("robots")
    if not isinstance(items, list) or not items:
        raise InputError("robots: expected a list of robots (name, profile, driver)", file=where)
    robots: list[RobotConfig] = []
    for i, item in enumerate(items):
        robot = _robot(item, f"robots[{i}]", path)
        if robot.name in {r.name for r in robots}:
            raise InputError(f"robots[{i}].name: '{robot.name}' is on the desk already", file=where)
        robots.append(robot)
    connected = doc.get("connected")
    if connected is not None and connected not in {r.name for r in robots if r.driver is not None}:
        drivable = ", ".join(r.name for r in robots if r.driver is not None) or "none"
        raise InputError(f"connected: '{connected}' is no robot with a driver here (those: {drivable})", file=where)
    return DeskConfig(tuple(robots), connected, path)


def _robot(item: Any, where: str, path: Path) -> RobotConfig:
    file = str(path)
    if not isinstance(item, dict):
        raise InputError(f"{where}: expected a mapping with name, profile and driver", file=file)
    unknown = sorted(set(item) - set(ROBOT_FIELDS))
    if unknown:
        raise InputError(f"{where}.{unknown[0]}: no such field (fields: {', '.join(ROBOT_FIELDS)})", file=file)
    name = item.get("name")
    try:
        check_id("robot name", name)
    except InputError as exc:
        raise InputError(f"{where}.name: {exc.message}", file=file) from None
    ref = item.get("profile")
    if not isinstance(ref, str) or not ref.strip():
        known = ", ".join(BUILTIN_PROFILES)
        raise InputError(f"{where}.profile: expected a built-in profile ({known}) or a profile file", file=file)
    if ref not in BUILTIN_PROFILES:
        ref = str((path.parent / ref).resolve())
    profile = instance_profile(ref, name, path.parent)  # a broken profile names its own file and field
    driver = item.get("driver")
    if driver is None:
        return RobotConfig(name, ref, None, "config")
    if isinstance(driver, str):
        driver = {"kind": driver}
    if not isinstance(driver, dict) or not isinstance(driver.get("kind"), str):
        raise InputError(f"{where}.driver: expected a driver kind or a mapping with `kind`", file=file)
    options = {k: v for k, v in driver.items() if k != "kind"}
    try:
        spec = registry.check(DriverSpec(driver["kind"], options), profile, f"{where}.driver")
    except InputError as exc:
        raise InputError(exc.message, file=file) from None
    return RobotConfig(name, ref, spec, "config")
