"""Reading a profile's fields: each value checked, every problem an InputError naming the file and the field
(`frames[3].mdh.alpha: expected a finite number`), and the profile's parameters as they are read.

The profile loader (loader.py) hands one FieldReader to each of its steps; the measurement models and the
ChArUco board read their own entries through it too (it is their `calib_core.sensors.SpecReader`).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from ..errors import InputError
from ..units import ANGLE_IN_RAD
from .profile import Parameter


@dataclass(frozen=True)
class FieldReader:
    """The checks of a profile's fields, in the profile's units, and its parameters in the order the steps add
    them (`params`, and `index`: name -> position)."""

    source: str  # the file, as errors name it
    length_unit: str = "m"  # the profile's units (`units:`): these defaults until the loader has read them
    to_rad: float = ANGLE_IN_RAD["deg"]  # one of the profile's angle units in rad
    params: list[Parameter] = field(default_factory=list)
    index: dict[str, int] = field(default_factory=dict)

    def fail(self, where: str, message: str) -> InputError:
        return InputError(f"{where}: {message}", file=self.source)

    def get(self, mapping: Any, key: str, where: str, default: Any = ...) -> Any:
        if not isinstance(mapping, dict):
            raise self.fail(where, "expected a mapping")
        if key not in mapping:
            if default is ...:
                raise self.fail(f"{where}.{key}", "missing")
            return default
        return mapping[key]

    def number(self, value: Any, where: str) -> float:
        if isinstance(value, bool) or not isinstance(value, int | float) or not math.isfinite(value):
            raise self.fail(where, f"expected a finite number, got {value!r}")
        return float(value)

    def vector(self, value: Any, where: str) -> np.ndarray:
        if not isinstance(value, list) or len(value) != 3:
            raise self.fail(where, f"expected [x, y, z], got {value!r}")
        return np.array([self.number(v, f"{where}[{i}]") for i, v in enumerate(value)])

    def columns(self, value: Any, where: str, count: int | None = None) -> tuple[str, ...]:
        """A list of column names (of `count` names when given)."""
        if not isinstance(value, list) or not value or not all(isinstance(c, str) and c for c in value):
            raise self.fail(where, f"expected a list of column names, got {value!r}")
        if count is not None and len(value) != count:
            raise self.fail(where, f"expected {count} column names, got {len(value)}")
        return tuple(value)

    def index_of(self, name: Any, items: Sequence[Any], where: str, what: str) -> int:
        """The position of the `what` called `name` among `items` (joints, frames, targets, sensors: what has a
        `name`; the last of that name)."""
        index = {item.name: i for i, item in enumerate(items)}
        if str(name) not in index:
            raise self.fail(where, f"unknown {what} '{name}'")
        return index[str(name)]

    def add_param(self, name: str, kind: str, nominal: float, where: str) -> int:
        """A new parameter, at the end; its position."""
        if name in self.index:
            raise self.fail(where, f"parameter '{name}' is defined twice")
        self.index[name] = len(self.params)
        self.params.append(Parameter(name, kind, nominal))
        return self.index[name]

    def add_params(
        self, prefix: str, kind: str, mapping: Any, keys: tuple[str, ...], where: str, default: Any = ...
    ) -> tuple[int, ...]:
        """Parameters `<prefix>.<key>` from the numbers of a mapping (a point, intrinsics, ...)."""
        return tuple(
            self.add_param(
                f"{prefix}.{k}", kind, self.number(self.get(mapping, k, where, default), f"{where}.{k}"), where
            )
            for k in keys
        )
