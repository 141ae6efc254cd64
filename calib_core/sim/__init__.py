"""The simulated robot: hidden true parameters, realistic noise, rendered images.

The names below load their module on first use (calib_core/_lazy.py)."""

from __future__ import annotations

from typing import TYPE_CHECKING

from .._lazy import lazy_exports

__getattr__ = lazy_exports(
    __name__,
    {
        "days": ("Law", "measured_on"),
        "simulator": ("ImageSimulation", "SimulatedRobot", "Simulation"),
    },
)
__all__ = ["ImageSimulation", "Law", "SimulatedRobot", "Simulation", "measured_on"]

if TYPE_CHECKING:
    from .days import Law, measured_on
    from .simulator import ImageSimulation, SimulatedRobot, Simulation
