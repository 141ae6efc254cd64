"""Driver kinds by name: which module makes the driver of a robot whose configuration names that kind.

A kind is a module of this package with two functions:

    check(profile, options, where) -> dict     the options checked, with their defaults (InputError naming
                                               `where`, the configuration's field, for a wrong one)
    create(profile, options, context) -> RobotDriver

Adding a kind (a ROS 2 robot, say) is that module and one line in KINDS. A kind's module is imported only
when a robot uses it, so a kind whose libraries are not installed costs nothing until then, and its import
may raise InputError saying what to install.
"""

from __future__ import annotations

import importlib
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from types import ModuleType
from typing import TYPE_CHECKING, Any

from calib_core import InputError, Profile

if TYPE_CHECKING:
    from . import RobotDriver

KINDS = {
    "simulated": "app.drivers.simulated",
    "ros2": "app.drivers.ros2",  # a robot on its own ROS 2 graph (the `ros2` extra; app/ros2/)
}


@dataclass(frozen=True)
class DriverSpec:
    """A robot's driver as its configuration gives it: the kind and its options."""

    kind: str
    options: dict[str, Any] = field(default_factory=dict)


@dataclass(frozen=True)
class DriverContext:
    """What every driver may use besides its own options."""

    time_scale: float = 1.0  # the simulated robots' speed (calib serve --sim-speed)
    base_dir: Path = Path()  # relative paths in options are relative to this (the configuration file's folder)


def kind(name: str, where: str = "driver.kind") -> ModuleType:
    if name not in KINDS:
        raise InputError(f"{where}: unknown driver kind '{name}' (known: {', '.join(KINDS)})")
    return importlib.import_module(KINDS[name])


def check(spec: DriverSpec, profile: Profile, where: str = "driver") -> DriverSpec:
    """The spec with its options checked against the kind and the robot's profile."""
    options = kind(spec.kind, f"{where}.kind").check(profile, spec.options, where)
    return DriverSpec(spec.kind, options)


def create(spec: DriverSpec, profile: Profile, context: DriverContext) -> RobotDriver:
    """The robot's driver, its options checked first (InputError naming `driver.<option>`)."""
    module = kind(spec.kind)
    options: Mapping[str, Any] = module.check(profile, spec.options, "driver")
    return module.create(profile, options, context)
