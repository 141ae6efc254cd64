"""Measurement models: what a sensor reports for a point on the robot, with exact derivatives and
its noise model (the protocol: `base.SensorModel`). A new kind of measurement is one module here and
one line in SENSOR_MODELS."""

from __future__ import annotations

from .base import Reading, Sensor, SensorModel, SpecReader, check_noise
from .pinhole import Pinhole
from .plane import Plane
from .point3d import Point3D
from .pose6d import Pose6D

SENSOR_MODELS: dict[str, type[Point3D | Pinhole | Plane | Pose6D]] = {
    Point3D.kind: Point3D,
    Pinhole.kind: Pinhole,
    Plane.kind: Plane,
    Pose6D.kind: Pose6D,
}

__all__ = [
    "SENSOR_MODELS",
    "Pinhole",
    "Plane",
    "Point3D",
    "Pose6D",
    "Reading",
    "Sensor",
    "SensorModel",
    "SpecReader",
    "check_noise",
]
