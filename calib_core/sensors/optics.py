"""What a sensor with a lens shares, whatever it measures: its optical frame, intrinsics, image size
and working range (a stereo head's left camera, a camera).

The optical frame is OpenCV's (x right, y down, z forward). A sensor frame can follow the robot's
convention (`x-forward`: x forward, y left, z up, as the NAO paper's Eq. 1) or OpenCV's
(`z-forward`), or give the optical axes explicitly (`optical: {z: [...], x: [...]}`).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from .base import Sensor, SpecReader

X_FORWARD = np.array([[0.0, 0, 1], [-1, 0, 0], [0, -1, 0]])  # x_cv = -y, y_cv = -z, z_cv = x


@dataclass(frozen=True)
class Optical(Sensor):
    """A sensor with an optical frame; `intrinsics` (parameter indices of fx, fy, cx, cy) and `image`
    (width, height px) when it has a camera, `range` (nearest, farthest along the optical axis,
    profile length unit) when it sees only so far."""

    intrinsics: tuple[int, int, int, int] | None
    image: tuple[int, int] | None
    R_frame_optical: np.ndarray  # the optical frame's axes (columns) in the sensor frame
    range: tuple[float, float] | None

    def optical(self, x: np.ndarray) -> np.ndarray:
        """Points (M, 3) of the sensor frame in the optical frame."""
        return x @ self.R_frame_optical

    def in_front(self, x: np.ndarray) -> np.ndarray:
        """Whether points (M, 3) of the sensor frame lie in front of the optical centre."""
        return self.optical(x)[:, 2] > 1e-6

    def pixels(self, p: np.ndarray, x: np.ndarray) -> np.ndarray:
        """The lens model's pixels (M, 2) of points in front of the camera: here the pinhole's."""
        assert self.intrinsics is not None  # project() checks; a sensor without intrinsics has no image
        fx, fy, cx, cy = (p[i] for i in self.intrinsics)
        X = self.optical(x)
        return np.stack([fx * X[:, 0] / X[:, 2] + cx, fy * X[:, 1] / X[:, 2] + cy], axis=1)

    def image_size_px(self) -> tuple[int, int] | None:
        return self.image

    def project(self, p: np.ndarray, x: np.ndarray) -> np.ndarray | None:
        """Pixels (M, 2) of points of the sensor frame; NaN for points behind the camera."""
        if self.intrinsics is None:
            return None
        ahead = self.in_front(x)
        uv = np.full((len(x), 2), np.nan)
        uv[ahead] = self.pixels(p, x[ahead])
        return uv

    def visible(self, p: np.ndarray, x: np.ndarray, margin_px: float = 0.0) -> np.ndarray:
        """In front of the optical centre, within the range, and inside the image `margin_px` clear
        of its border."""
        z = self.optical(x)[:, 2]
        ok = self.in_front(x)
        if self.range is not None:
            ok &= (z >= self.range[0]) & (z <= self.range[1])
        if self.image is not None and self.intrinsics is not None:
            uv = self.project(p, x)
            assert uv is not None
            w, h = self.image
            with np.errstate(invalid="ignore"):  # NaN behind the camera: not visible
                ok &= (uv[:, 0] >= margin_px) & (uv[:, 0] <= w - 1 - margin_px)
                ok &= (uv[:, 1] >= margin_px) & (uv[:, 1] <= h - 1 - margin_px)
        return ok


def read_optics(spec: dict, reader: SpecReader, name: str, where: str, *, need_intrinsics: bool) -> dict[str, Any]:
    """The Optical fields of a sensor's YAML entry (intrinsics become parameters `<name>.fx` ...)."""
    convention = str(spec.get("convention", "z-forward"))
    if convention not in ("x-forward", "z-forward"):
        raise reader.fail(f"{where}.convention", "must be x-forward or z-forward")
    intrinsics = None
    if "intrinsics" in spec:
        intrinsics = reader.add_params(name, "px", spec["intrinsics"], ("fx", "fy", "cx", "cy"), f"{where}.intrinsics")
    elif need_intrinsics:
        raise reader.fail(where, "needs intrinsics")
    R = X_FORWARD if convention == "x-forward" else np.eye(3)
    if "optical" in spec:
        o = spec["optical"]
        z = reader.vector(reader.get(o, "z", f"{where}.optical"), f"{where}.optical.z")
        x = reader.vector(reader.get(o, "x", f"{where}.optical"), f"{where}.optical.x")
        if abs(z @ x) > 1e-9 or abs(np.linalg.norm(z) - 1) > 1e-9 or abs(np.linalg.norm(x) - 1) > 1e-9:
            raise reader.fail(f"{where}.optical", "x and z must be orthogonal unit vectors")
        R = np.stack([x, np.cross(z, x), z], axis=1)
    image = spec.get("image")
    if image is not None:
        if not isinstance(image, list) or len(image) != 2:
            raise reader.fail(f"{where}.image", f"expected [width, height] in px, got {image!r}")
        w, h = (reader.number(v, f"{where}.image[{k}]") for k, v in enumerate(image))
        if w < 1 or h < 1 or w != int(w) or h != int(h):
            raise reader.fail(f"{where}.image", f"expected whole numbers of px, got {image!r}")
        image = (int(w), int(h))
    rng = spec.get("range")
    if rng is not None:
        if not isinstance(rng, list) or len(rng) != 2:
            raise reader.fail(f"{where}.range", f"expected [nearest, farthest], got {rng!r}")
        rng = tuple(reader.number(v, f"{where}.range[{k}]") for k, v in enumerate(rng))
    return {"intrinsics": intrinsics, "image": image, "R_frame_optical": R, "range": rng}
