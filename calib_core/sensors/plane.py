"""A plane constraint: a point on the robot known to lie on a plane (touch-probing a table, a wall).

The plane is the x-y plane of the sensor's frame (or the plane through its origin with the given
`normal`); one observation is the signed distance of the target point from it, in the profile's
length unit: 0 for a touch probe in contact, a reading for a distance sensor. Where the plane stands
is the pose of its frame: with that frame's parameters free in a mode (for example
`ops: [{tz: 0, param: table.z}, {rx: 0, param: table.rx}, {ry: 0, param: table.ry}]`) the
calibration estimates it with the robot (an unknown plane); otherwise it is known. A single plane
cannot tell apart what moves the point within the plane (a rotation about its normal, a shift
along it): the identifiability report names such parameters; several planes at angles to each other
determine them.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar

import numpy as np

from .base import Sensor, SpecReader


@dataclass(frozen=True)
class Plane(Sensor):
    normal: np.ndarray  # unit normal in the sensor frame

    kind: ClassVar[str] = "plane"
    dim: ClassVar[int] = 1
    axes: ClassVar[tuple[str, ...]] = ("distance",)

    def predict(
        self, p: np.ndarray, x: np.ndarray, *, derivatives: bool = False
    ) -> tuple[np.ndarray, np.ndarray | None, np.ndarray | None]:
        h = (x @ self.normal)[:, None]
        if not derivatives:
            return h, None, None
        return h, np.broadcast_to(self.normal, (len(x), 1, 3)), np.zeros((len(x), 1, 0))

    def place(self, p: np.ndarray, measured: np.ndarray, x: np.ndarray, normal: np.ndarray) -> np.ndarray:
        """A distance fixes the point's height over the plane only: the predicted point moved along the
        plane's normal until its distance is the measured one."""
        return x + (measured[:, :1] - x @ self.normal[:, None]) * self.normal

    @classmethod
    def from_spec(cls, spec: dict, reader: SpecReader, name: str, frame: int, where: str) -> Plane:
        normal = reader.vector(spec.get("normal", [0, 0, 1]), f"{where}.normal")
        length = float(np.linalg.norm(normal))
        if length < 1e-9:
            raise reader.fail(f"{where}.normal", "must not be zero")
        sensor = cls(name, frame, reader.length_unit, {}, normal / length)
        return sensor.with_noise(spec.get("noise"), f"{where}.noise")
