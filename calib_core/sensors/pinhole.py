"""A camera: the pixel of a point. With the robot convention (x forward, y left, z up) and no
distortion this is the NAO paper's Eq. 1, u = c_u - f y / x, v = c_v - f z / x. Optionally OpenCV's
radial-tangential distortion (k1, k2, p1, p2, k3, and the rational model's k4, k5, k6) between
normalisation and the intrinsics, with its exact derivatives.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar

import numpy as np

from .base import Reading, SpecReader
from .optics import Optical, read_optics


@dataclass(frozen=True)
class Pinhole(Optical):
    distortion: tuple[int, ...] | None  # parameter indices of k1, k2, p1, p2, k3 (and k4, k5, k6)

    kind: ClassVar[str] = "pinhole"
    dim: ClassVar[int] = 2
    axes: ClassVar[tuple[str, ...]] = ("u", "v")

    @property
    def reading(self) -> Reading:
        return "image"

    def direct_params(self) -> tuple[int, ...]:
        return tuple(self.intrinsics or ()) + tuple(self.distortion or ())

    def distortion_coefficients(self, p: np.ndarray) -> tuple[float, ...]:
        """k1, k2, p1, p2, k3, k4, k5, k6 in OpenCV's order; zero where the sensor has none."""
        values = [float(p[i]) for i in self.distortion or ()]
        return tuple(values + [0.0] * (8 - len(values)))

    def pixels(self, p: np.ndarray, x: np.ndarray) -> np.ndarray:
        return self.predict(p, x)[0]

    def predict(
        self, p: np.ndarray, x: np.ndarray, *, derivatives: bool = False
    ) -> tuple[np.ndarray, np.ndarray | None, np.ndarray | None]:
        assert self.intrinsics is not None  # from_spec requires them
        fx, fy, cx, cy = (p[i] for i in self.intrinsics)
        M = self.R_frame_optical.T  # p_optical = M p_sensor
        X = x @ M.T
        Z = X[:, 2]
        a, b = X[:, 0] / Z, X[:, 1] / Z
        k = self.distortion_coefficients(p)
        p1, p2 = k[2], k[3]
        r2 = a * a + b * b
        num, den = radial_terms(k, r2)
        radial = num / den
        ad = a * radial + 2 * p1 * a * b + p2 * (r2 + 2 * a * a)
        bd = b * radial + p1 * (r2 + 2 * b * b) + 2 * p2 * a * b
        uv = np.stack([fx * ad + cx, fy * bd + cy], axis=1)
        if not derivatives:
            return uv, None, None
        # d(radial)/d(r2), then d(ad, bd)/d(a, b).
        drad = radial_slope(k, r2)
        dad_da = radial + 2 * a * a * drad + 2 * p1 * b + 6 * p2 * a
        dad_db = 2 * a * b * drad + 2 * p1 * a + 2 * p2 * b
        dbd_da = 2 * a * b * drad + 2 * p1 * a + 2 * p2 * b
        dbd_db = radial + 2 * b * b * drad + 6 * p1 * b + 2 * p2 * a
        # d(a, b)/dx (M, 2, 3): d(a)/dX = (e_x - a e_z) / Z, d(b)/dX = (e_y - b e_z) / Z in the optical frame, X = M x.
        dab_dx = (M[:2] - np.stack([a, b], axis=1)[:, :, None] * M[2]) / Z[:, None, None]
        duv_dab = np.empty((len(x), 2, 2))
        duv_dab[:, 0, 0] = fx * dad_da
        duv_dab[:, 0, 1] = fx * dad_db
        duv_dab[:, 1, 0] = fy * dbd_da
        duv_dab[:, 1, 1] = fy * dbd_db
        duv_dx = duv_dab @ dab_dx
        # d(u, v)/d(the direct parameters), column by column: (du, dv).
        cols: list[tuple[np.ndarray | float, np.ndarray | float]] = [(ad, 0.0), (0.0, bd), (1.0, 0.0), (0.0, 1.0)]
        if self.distortion is not None:
            cols += [
                (fx * a * r2 / den, fy * b * r2 / den),  # k1
                (fx * a * r2**2 / den, fy * b * r2**2 / den),  # k2
                (fx * 2 * a * b, fy * (r2 + 2 * b * b)),  # p1
                (fx * (r2 + 2 * a * a), fy * 2 * a * b),  # p2
                (fx * a * r2**3 / den, fy * b * r2**3 / den),  # k3
            ]
            if len(self.distortion) == 8:
                g = -radial / den  # d(radial)/d(den), times d(den)/d(k4..k6) = r2, r2^2, r2^3
                cols += [(fx * a * g * r2**n, fy * b * g * r2**n) for n in (1, 2, 3)]
        direct = np.empty((len(x), 2, len(cols)))
        for j, (du, dv) in enumerate(cols):
            direct[:, 0, j], direct[:, 1, j] = du, dv
        return uv, duv_dx, direct

    def visible(self, p: np.ndarray, x: np.ndarray, margin_px: float = 0.0) -> np.ndarray:
        """As any lens (`Optical.visible`), and within the field where the distortion still grows outward: beyond
        it OpenCV's polynomial folds back, and a point 70 deg off the axis would land inside the image."""
        ok = super().visible(p, x, margin_px)
        if self.distortion is None or not ok.any():
            return ok
        X = self.optical(x[ok])
        r2 = (X[:, 0] ** 2 + X[:, 1] ** 2) / X[:, 2] ** 2
        k = self.distortion_coefficients(p)
        num, den = radial_terms(k, r2)
        ok[ok] = num / den + 2 * r2 * radial_slope(k, r2) > 0  # d(r radial)/dr
        return ok

    def simulate(self, p: np.ndarray, x: np.ndarray, rng: np.random.Generator, noise: dict[str, float]) -> np.ndarray:
        """Gaussian pixel noise (`noise.pixel` px per axis)."""
        h = self.predict(p, x)[0]
        return h + rng.normal(0.0, float(noise.get("pixel", 0.0)), h.shape)

    def place(self, p: np.ndarray, measured: np.ndarray, x: np.ndarray, normal: np.ndarray) -> np.ndarray:
        """A pixel fixes a ray only: the point is where the ray meets the target's surface, the plane through
        the predicted point x with that normal (NaN where it meets it behind the camera, or never)."""
        ray = self.view_rays(p, measured[:, :2])
        with np.errstate(invalid="ignore", divide="ignore"):
            depth = np.einsum("ij,ij->i", normal, x) / np.einsum("ij,ij->i", normal, ray)
        return np.where(depth > 0, depth, np.nan)[:, None] * ray

    def measured_pixels(self, p: np.ndarray, measured: np.ndarray) -> np.ndarray:
        """The measurement is the pixel."""
        return np.array(measured[:, :2], dtype=float)

    def view_rays(self, p: np.ndarray, uv: np.ndarray) -> np.ndarray:
        """Unit view rays (M, 3) in the sensor frame through pixels uv (M, 2): the pinhole model
        inverted, distortion undone by fixed-point iteration (as OpenCV's undistortPoints)."""
        assert self.intrinsics is not None
        fx, fy, cx, cy = (p[i] for i in self.intrinsics)
        ad, bd = (uv[:, 0] - cx) / fx, (uv[:, 1] - cy) / fy
        a, b = ad.copy(), bd.copy()
        if self.distortion is not None:
            k = self.distortion_coefficients(p)
            p1, p2 = k[2], k[3]
            for _ in range(20):
                r2 = a * a + b * b
                num, den = radial_terms(k, r2)
                radial = num / den
                a = (ad - 2 * p1 * a * b - p2 * (r2 + 2 * a * a)) / radial
                b = (bd - p1 * (r2 + 2 * b * b) - 2 * p2 * a * b) / radial
        optical = np.stack([a, b, np.ones_like(a)], axis=1)
        optical /= np.linalg.norm(optical, axis=1, keepdims=True)
        return optical @ self.R_frame_optical.T

    @classmethod
    def from_spec(cls, spec: dict, reader: SpecReader, name: str, frame: int, where: str) -> Pinhole:
        optics = read_optics(spec, reader, name, where, need_intrinsics=True)
        distortion = None
        if "distortion" in spec:
            # OpenCV's order: k1 k2 p1 p2 k3, and k4 k5 k6 of the rational model when any is given.
            d = spec["distortion"]
            rational = isinstance(d, dict) and any(k in d for k in ("k4", "k5", "k6"))
            keys = ("k1", "k2", "p1", "p2", "k3") + (("k4", "k5", "k6") if rational else ())
            distortion = reader.add_params(name, "scalar", d, keys, f"{where}.distortion", default=0.0)
        sensor = cls(name, frame, "px", {}, **optics, distortion=distortion)
        return sensor.with_noise(spec.get("noise"), f"{where}.noise")


def radial_terms(k: tuple[float, ...], r2: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The radial factor's numerator 1 + k1 r2 + k2 r2^2 + k3 r2^3 and denominator 1 + k4 r2 + ..."""
    k1, k2, _, _, k3, k4, k5, k6 = k
    return 1 + r2 * (k1 + r2 * (k2 + r2 * k3)), 1 + r2 * (k4 + r2 * (k5 + r2 * k6))


def radial_slope(k: tuple[float, ...], r2: np.ndarray) -> np.ndarray:
    """d(radial factor)/d(r2) of `radial_terms`."""
    k1, k2, _, _, k3, k4, k5, k6 = k
    num, den = radial_terms(k, r2)
    dnum = k1 + r2 * (2 * k2 + 3 * k3 * r2)
    dden = k4 + r2 * (2 * k5 + 3 * k6 * r2)
    return (dnum * den - num * dden) / den**2
