"""Driver kinds by name: which module makes the driver of a robot whose configuration names that kind.

A kind is a module of this package with two functions:

    check(profile, options, where, options_at) -> dict    the options checked, with their defaults: InputError
                                                          naming `where` (the driver's field) when the kind
                                                          cannot drive this profile, `options_at.<option>` for
                                                          a wrong option
    create(profile, options, context) -> RobotDriver      usually core.Driver over the kind's transport

Adding a kind is that module and one line in KINDS (docs/drivers.md). A kind's module is imported only
when a robot uses it, so a kind whose libraries are not installed costs nothing until then, and its import
may raise InputError saying what to install.
"""

from __future__ import annotations

import importlib
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any, Protocol, cast

from calib_core import InputError, Profile

from ..clock import SYSTEM_CLOCK, Clock

if TYPE_CHECKING:
    from . import RobotDriver

KINDS = {
    "simulated": "app.drivers.simulated",
    "ros2": "app.drivers.ros2.driver",  # a robot on its own ROS 2 graph (the `ros2` extra; app/drivers/ros2/)
    "naoqi": "app.drivers.naoqi.driver",  # a NAO through NAOqi over libqi (the `naoqi` extra; app/drivers/naoqi/)
}


# A driver's options as a robot's configuration gives them (YAML or JSON, as written): each kind's `check` says which
# it takes and answers them checked, with their defaults.
Options = dict[str, Any]


@dataclass(frozen=True)
class DriverSpec:
    """A robot's driver as its configuration gives it: the kind and its options."""

    kind: str
    options: Options = field(default_factory=dict)


@dataclass(frozen=True)
class DriverContext:
    """What every driver may use besides its own options."""

    time_scale: float = 1.0  # the simulated robots' speed (calib serve --sim-speed)
    base_dir: Path = Path()  # relative paths in options are relative to this (the configuration file's folder)
    clock: Clock = SYSTEM_CLOCK  # what the drivers' waits, settles and timeouts are measured on


class DriverKind(Protocol):
    """A kind's module (the module doc): its two functions."""

    def check(self, profile: Profile, options: Options, where: str, options_at: str) -> Options: ...

    def create(self, profile: Profile, options: Options, context: DriverContext) -> RobotDriver: ...


def kind(name: str, where: str = "driver.kind") -> DriverKind:
    """The module of the kind `name` (InputError naming `where` for an unknown one)."""
    if name not in KINDS:
        raise InputError(f"{where}: unknown driver kind '{name}' (known: {', '.join(KINDS)})")
    # Which module a name loads is known at run time only; each of KINDS has the protocol's two functions.
    return cast(DriverKind, importlib.import_module(KINDS[name]))


def check(spec: DriverSpec, profile: Profile, where: str = "driver", options_at: str | None = None) -> DriverSpec:
    """The spec with its options checked against the kind and the robot's profile: InputError naming `where`
    (the driver's field) or `options_at` (the options' field, default `where`) with the option."""
    options = kind(spec.kind, f"{where}.kind").check(profile, spec.options, where, options_at or where)
    return DriverSpec(spec.kind, options)


def create(
    spec: DriverSpec, profile: Profile, context: DriverContext, where: str = "driver", options_at: str | None = None
) -> RobotDriver:
    """The robot's driver, its options checked first (check)."""
    module = kind(spec.kind, f"{where}.kind")
    options = module.check(profile, spec.options, where, options_at or where)
    return module.create(profile, options, context)
