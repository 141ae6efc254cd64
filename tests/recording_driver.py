"""A driver kind for the tests of the registry: the simulated robot, recording when it is closed."""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

from app.drivers.registry import DriverContext
from app.drivers.simulated import SimulatedDriver
from calib_core import InputError, Profile

CLOSED: list[str] = []


class RecordingDriver(SimulatedDriver):
    def close(self) -> None:
        CLOSED.append(self.profile.name)
        super().close()


def check(profile: Profile, options: Mapping[str, Any], where: str, options_at: str) -> dict[str, Any]:
    if options:
        raise InputError(f"{options_at}.{next(iter(options))}: the recording driver has no options")
    return {}


def create(profile: Profile, options: Mapping[str, Any], context: DriverContext) -> RecordingDriver:
    return RecordingDriver(profile, seed=1, time_scale=context.time_scale)
