"""Days of a robot whose parameters move by a known law: a steady drift per day and a fixed shift (a board
mounted off, a joint repaired), nothing else. What a history's drift analysis is checked against."""

from __future__ import annotations

from dataclasses import dataclass, field
from datetime import datetime, timedelta

import numpy as np

from ..errors import InputError
from ..model.profile import Profile


@dataclass
class Law:
    """How the true robot moves: parameter -> change a day (`drift_per_day`) and parameter -> change from the
    profile's truth (`shift`), display units (deg, the profile's length unit)."""

    drift_per_day: dict[str, float] = field(default_factory=dict)
    shift: dict[str, float] = field(default_factory=dict)

    def check(self, profile: Profile) -> Law:
        """The law, every parameter it names one of the profile's (else InputError naming it)."""
        for option, changes in (("--drift", self.drift_per_day), ("--shift", self.shift)):
            for name, value in changes.items():
                if name not in profile.parameter_names:
                    raise InputError(f"{option} {name}: robot '{profile.name}' has no parameter '{name}'")
                if not np.isfinite(value):
                    raise InputError(f"{option} {name}: {value} is not a finite number")
        return self

    def truth(self, profile: Profile, truth: np.ndarray, day: int) -> np.ndarray:
        """The true parameters (internal units) on day `day` (1: the first, shifted but not yet drifted)."""
        p = truth.copy()
        for name, value in self.shift.items():
            i = profile.param(name)
            p[i] += profile.from_display(i, value)
        for name, rate in self.drift_per_day.items():
            i = profile.param(name)
            p[i] += profile.from_display(i, rate * (day - 1))
        return p


def measured_on(start: datetime, day: int) -> datetime:
    """When day `day` (1, 2, ...) was measured: one day after the other from `start`."""
    return start + timedelta(days=day - 1)
