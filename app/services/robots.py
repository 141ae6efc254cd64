"""Adding a robot to the running desk and taking one off: the request checked (its profile given one way, the
URDF and meshes that go with an uploaded profile, a profile file named only on a loopback desk, the driver's
kind and options), then app/robots/roster.py's Robots does it and the robot in view follows
(app/services/connection.py).
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from typing import Any

from calib_core import InputError

from ..drivers.registry import KINDS, DriverSpec
from ..errors import NotAllowed
from ..robots.roster import Robot, Robots
from ..store import ProfileFiles
from ..store.meshes import check_archive
from ..store.profiles import file_name, is_builtin
from .connection import Connection


@dataclass(frozen=True)
class Upload:
    """An uploaded file: the name it came with (None: none) and its bytes."""

    filename: str | None
    data: bytes


@dataclass(frozen=True)
class NewRobot:
    """A robot to add: its profile named (`profile`: a built-in one, or a file on this machine) or uploaded
    (`profile_file`, with the `urdf_file` it names and a zip of that URDF's meshes); its driver's kind (None: real
    data only) and options (a JSON object)."""

    name: str
    profile: str | None = None
    profile_file: Upload | None = None
    urdf_file: Upload | None = None
    meshes_zip: Upload | None = None
    driver: str | None = None
    driver_options: str | None = None


class RobotService:
    def __init__(self, robots: Robots, connection: Connection, *, loopback: bool, max_unpacked_bytes: int) -> None:
        """`loopback`: the desk is reached from this machine only, so a request may name a file on it;
        `max_unpacked_bytes`: of an uploaded zip of meshes, unpacked (MeshesTooLarge beyond)."""
        self.robots = robots
        self.connection = connection
        self.loopback = loopback
        self.max_unpacked_bytes = max_unpacked_bytes

    def add(self, new: NewRobot) -> Robot:
        """Add the robot, kept after a restart; InputError naming the field (or the file and its entry) for
        anything wrong, NotAllowed for a profile file named on a desk reached from elsewhere."""
        robot = self.robots.add(new.name, profile=new.profile or None, files=self._files(new), driver=_driver(new))
        self.connection.added(robot)
        return robot

    def remove(self, name: str) -> None:
        """Take a robot added through the API off the desk (one with sessions or calibrations stays: they name
        it); its driver is closed."""
        self.connection.release(name)
        self.robots.remove(name)
        self.connection.removed(name)

    def _files(self, new: NewRobot) -> ProfileFiles | None:
        """The uploaded profile with its URDF and meshes (None: the profile is named)."""
        if new.profile_file is None:
            if new.urdf_file is not None:
                raise InputError("a URDF goes with its profile: upload the profile (profile_file) too")
            if new.meshes_zip is not None:
                raise InputError(
                    "meshes go with an uploaded profile and its URDF: upload them too (profile_file, urdf_file)"
                )
            if new.profile and not is_builtin(new.profile) and not self.loopback:
                raise NotAllowed(
                    "a profile file on the server can be named only on a desk bound to loopback: upload it"
                )
            return None
        if new.profile:
            raise InputError("give the profile either as a file (profile_file) or by name (profile), not both")
        if new.meshes_zip is not None and new.urdf_file is None:
            raise InputError("meshes go with a URDF: upload the URDF (urdf_file) the profile names too")
        urdf = None if new.urdf_file is None else (file_name(new.urdf_file.filename, "robot.urdf"), new.urdf_file.data)
        meshes = None
        if new.meshes_zip is not None:
            zip_name = file_name(new.meshes_zip.filename, "meshes.zip")
            meshes = check_archive(zip_name, new.meshes_zip.data, self.max_unpacked_bytes)
        return ProfileFiles(file_name(new.profile_file.filename, "profile.yaml"), new.profile_file.data, urdf, meshes)


def _driver(new: NewRobot) -> DriverSpec | None:
    """The driver asked for: its kind and its options (checked by the kind when the driver is made)."""
    if not new.driver:
        if new.driver_options:
            raise InputError("driver_options: options of which driver? give the driver's kind (driver) too")
        return None
    if new.driver not in KINDS:
        raise InputError(f"driver: unknown driver kind '{new.driver}' (known: {', '.join(KINDS)})")
    return DriverSpec(new.driver, _options(new.driver_options))


def _options(text: str | None) -> dict[str, Any]:
    """The `driver_options` form field: a JSON object (empty or absent: none)."""
    if not text:
        return {}
    try:
        options = json.loads(text)
    except json.JSONDecodeError as exc:
        raise InputError(f"driver_options: not valid JSON ({exc.msg} at character {exc.pos})") from None
    if not isinstance(options, dict):
        raise InputError('driver_options: expected a JSON object of the driver\'s options, like {"seed": 2}')
    return options
