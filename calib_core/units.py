"""Unit names and conversions. Internally lengths are in the profile's length unit and angles in rad."""

from __future__ import annotations

import math

LENGTH_IN_M = {"m": 1.0, "cm": 0.01, "mm": 0.001}
ANGLE_IN_RAD = {"rad": 1.0, "deg": math.pi / 180.0}


def length_factor(from_unit: str, to_unit: str) -> float:
    """Multiply a length in `from_unit` by this to get it in `to_unit`."""
    return LENGTH_IN_M[from_unit] / LENGTH_IN_M[to_unit]


def angle_factor(from_unit: str, to_unit: str = "rad") -> float:
    """Multiply an angle in `from_unit` by this to get it in `to_unit`."""
    return ANGLE_IN_RAD[from_unit] / ANGLE_IN_RAD[to_unit]
