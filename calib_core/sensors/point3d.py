"""A 3-D point in the sensor frame: a laser tracker or motion capture (read directly), or a stereo
head (intrinsics and a baseline: the sphere the BallFinder finds in its depth map).

The stereo head's noise follows triangulation from the left pixel (u, v) and the disparity d,
X = (u - cx, v - cy, f) b / d: pixel noise moves the point sideways (sigma z * pixel / f), disparity
noise along its view ray (sigma z |X| disparity / (f b), growing with z^2), so far points weigh
less, and only along their view ray.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, ClassVar

import numpy as np

from ..errors import InputError
from .base import Reading, SpecReader
from .optics import Optical, read_optics


@dataclass(frozen=True)
class Point3D(Optical):
    baseline: float | None  # stereo baseline, profile length unit

    kind: ClassVar[str] = "point3d"
    dim: ClassVar[int] = 3
    axes: ClassVar[tuple[str, ...]] = ("x", "y", "z")
    noise_models: ClassVar[tuple[str, ...]] = ("isotropic", "stereo")

    @property
    def reading(self) -> Reading:
        return "stereo" if self.baseline is not None and self.intrinsics is not None else "direct"

    def predict(
        self, p: np.ndarray, x: np.ndarray, *, derivatives: bool = False
    ) -> tuple[np.ndarray, np.ndarray | None, np.ndarray | None]:
        if not derivatives:
            return x, None, None
        return x, np.broadcast_to(np.eye(3), (len(x), 3, 3)), np.zeros((len(x), 3, 0))

    def place(self, p: np.ndarray, measured: np.ndarray, x: np.ndarray, normal: np.ndarray) -> np.ndarray:
        """The measurement is the point."""
        return np.array(measured[:, :3], dtype=float)

    def measured_pixels(self, p: np.ndarray, measured: np.ndarray) -> np.ndarray:
        """The measured point projected into the (left) image."""
        uv = self.project(p, np.array(measured[:, :3], dtype=float))
        return np.full((len(measured), 2), np.nan) if uv is None else uv

    def visible(self, p: np.ndarray, x: np.ndarray, margin_px: float = 0.0) -> np.ndarray:
        if self.intrinsics is None and self.range is None:
            return np.ones(len(x), bool)  # a tracker sees the whole workspace
        return super().visible(p, x, margin_px)

    def covariance(self, p: np.ndarray, measured: np.ndarray) -> np.ndarray:
        if self.noise.get("model") != "stereo":
            return super().covariance(p, measured)
        assert self.intrinsics is not None and self.baseline is not None and self.range is not None  # from_spec
        f = float(p[self.intrinsics[0]])
        X = self.optical(measured)
        X[:, 2] = np.clip(X[:, 2], self.range[0] * 0.5, None)
        z = X[:, 2]
        var = np.zeros((len(z), 3, 3))
        var[:, 0, 0] = var[:, 1, 1] = (z * self.noise["pixel"] / f) ** 2
        ray = X * (z * self.noise["disparity"] / (f * self.baseline))[:, None]
        var += ray[:, :, None] * ray[:, None, :]
        R = self.R_frame_optical
        return R @ var @ R.T

    def simulate(self, p: np.ndarray, x: np.ndarray, rng: np.random.Generator, noise: dict[str, float]) -> np.ndarray:
        """A stereo head triangulates from a noisy left pixel (`noise.pixel`) and a noisy disparity
        (`noise.disparity`); a tracker adds `noise.point` per axis."""
        if self.reading != "stereo":
            return super().simulate(p, x, rng, noise)
        assert self.intrinsics is not None and self.baseline is not None
        pixel, disparity = float(noise.get("pixel", 0.0)), float(noise.get("disparity", 0.0))
        fx, fy, cx, cy = (p[i] for i in self.intrinsics)
        X = self.optical(x)
        u = fx * X[:, 0] / X[:, 2] + cx + rng.normal(0.0, pixel, len(X))
        v = fy * X[:, 1] / X[:, 2] + cy + rng.normal(0.0, pixel, len(X))
        d = fx * self.baseline / X[:, 2] + rng.normal(0.0, disparity, len(X))
        z = fx * self.baseline / d
        return np.stack([(u - cx) * z / fx, (v - cy) * z / fy, z], axis=1) @ self.R_frame_optical.T

    def checked_noise(self, noise: Any, where: str) -> dict[str, Any]:
        out = super().checked_noise(noise, where)
        if out.get("model") == "stereo" and (self.intrinsics is None or self.baseline is None or self.range is None):
            raise InputError(f"{where}: the stereo noise model needs intrinsics, a baseline and a range")
        return out

    @classmethod
    def from_spec(cls, spec: dict, reader: SpecReader, name: str, frame: int, where: str) -> Point3D:
        optics = read_optics(spec, reader, name, where, need_intrinsics=False)
        baseline = spec.get("baseline")
        baseline = None if baseline is None else reader.number(baseline, f"{where}.baseline")
        sensor = cls(name, frame, reader.length_unit, {}, **optics, baseline=baseline)
        return sensor.with_noise(spec.get("noise"), f"{where}.noise")
