"""Measurement models: what a sensor reports for a point given in the sensor's frame, with derivatives.

- `point3d`: the point itself (a stereo head with a sphere finder; a laser tracker).
- `pinhole`: pixels. With the robot convention (x forward, y left, z up) and no distortion this is
  the NAO paper's Eq. 1, u = c_u - f y / x, v = c_v - f z / x. Optionally OpenCV's radial-tangential
  distortion (k1, k2, p1, p2, k3, and the rational model's k4, k5, k6) between normalisation and the
  intrinsics.
"""

from __future__ import annotations

import numpy as np

from ..model.profile import Sensor


def dimension(sensor: Sensor) -> int:
    return 3 if sensor.model == "point3d" else 2


def intrinsic_params(sensor: Sensor) -> list[int]:
    """Parameter indices that the model depends on directly (not through the point)."""
    if sensor.model != "pinhole":
        return []
    return list(sensor.intrinsics or ()) + list(sensor.distortion or ())


def distortion_coefficients(sensor: Sensor, p: np.ndarray) -> tuple[float, ...]:
    """k1, k2, p1, p2, k3, k4, k5, k6 in OpenCV's order; zero where the sensor has none."""
    values = [float(p[i]) for i in sensor.distortion or ()]
    return tuple(values + [0.0] * (8 - len(values)))


def radial_terms(k: tuple[float, ...], r2: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The radial factor's numerator 1 + k1 r2 + k2 r2^2 + k3 r2^3 and denominator 1 + k4 r2 + ..."""
    k1, k2, _, _, k3, k4, k5, k6 = k
    return 1 + r2 * (k1 + r2 * (k2 + r2 * k3)), 1 + r2 * (k4 + r2 * (k5 + r2 * k6))


def predict(
    sensor: Sensor, p: np.ndarray, x: np.ndarray, *, derivatives: bool = False
) -> tuple[np.ndarray, np.ndarray | None, np.ndarray | None]:
    """Prediction (M, dim) for points x (M, 3) in the sensor frame, parameters p (internal units).

    With `derivatives`, also d(prediction)/dx (M, dim, 3) and d(prediction)/d(intrinsic params)
    (M, dim, len(intrinsic_params(sensor))).
    """
    if sensor.model == "point3d":
        if not derivatives:
            return x, None, None
        return x, np.broadcast_to(np.eye(3), (x.shape[0], 3, 3)), np.zeros((x.shape[0], 3, 0))
    assert sensor.intrinsics is not None
    fx, fy, cx, cy = (p[i] for i in sensor.intrinsics)
    M = sensor.R_frame_optical.T  # p_optical = M p_sensor
    X = x @ M.T
    Z = X[:, 2]
    a, b = X[:, 0] / Z, X[:, 1] / Z
    k = distortion_coefficients(sensor, p)
    k1, k2, p1, p2, k3, k4, k5, k6 = k
    r2 = a * a + b * b
    num, den = radial_terms(k, r2)
    radial = num / den
    ad = a * radial + 2 * p1 * a * b + p2 * (r2 + 2 * a * a)
    bd = b * radial + p1 * (r2 + 2 * b * b) + 2 * p2 * a * b
    uv = np.stack([fx * ad + cx, fy * bd + cy], axis=1)
    if not derivatives:
        return uv, None, None
    # d(radial)/d(r2), then d(ad, bd)/d(a, b).
    dnum = k1 + r2 * (2 * k2 + 3 * k3 * r2)
    dden = k4 + r2 * (2 * k5 + 3 * k6 * r2)
    drad = (dnum * den - num * dden) / den**2
    dad_da = radial + 2 * a * a * drad + 2 * p1 * b + 6 * p2 * a
    dad_db = 2 * a * b * drad + 2 * p1 * a + 2 * p2 * b
    dbd_da = 2 * a * b * drad + 2 * p1 * a + 2 * p2 * b
    dbd_db = radial + 2 * b * b * drad + 6 * p1 * b + 2 * p2 * a
    inv_z = 1.0 / Z
    # d(a, b)/dX (M, 2, 3) in the optical frame.
    dab_dX = np.zeros((x.shape[0], 2, 3))
    dab_dX[:, 0, 0] = inv_z
    dab_dX[:, 0, 2] = -a * inv_z
    dab_dX[:, 1, 1] = inv_z
    dab_dX[:, 1, 2] = -b * inv_z
    duv_dab = np.empty((x.shape[0], 2, 2))
    duv_dab[:, 0, 0] = fx * dad_da
    duv_dab[:, 0, 1] = fx * dad_db
    duv_dab[:, 1, 0] = fy * dbd_da
    duv_dab[:, 1, 1] = fy * dbd_db
    duv_dx = duv_dab @ dab_dX @ M
    cols = [
        np.stack([ad, np.zeros_like(ad)], 1),  # fx
        np.stack([np.zeros_like(bd), bd], 1),  # fy
        np.stack([np.ones_like(ad), np.zeros_like(ad)], 1),  # cx
        np.stack([np.zeros_like(bd), np.ones_like(bd)], 1),  # cy
    ]
    if sensor.distortion is not None:
        cols += [
            np.stack([fx * a * r2 / den, fy * b * r2 / den], 1),  # k1
            np.stack([fx * a * r2**2 / den, fy * b * r2**2 / den], 1),  # k2
            np.stack([fx * 2 * a * b, fy * (r2 + 2 * b * b)], 1),  # p1
            np.stack([fx * (r2 + 2 * a * a), fy * 2 * a * b], 1),  # p2
            np.stack([fx * a * r2**3 / den, fy * b * r2**3 / den], 1),  # k3
        ]
        if len(sensor.distortion) == 8:
            g = -radial / den  # d(radial)/d(den), times d(den)/d(k4..k6) = r2, r2^2, r2^3
            cols += [np.stack([fx * a * g * r2**n, fy * b * g * r2**n], 1) for n in (1, 2, 3)]
    return uv, duv_dx, np.stack(cols, axis=2)


def in_front(sensor: Sensor, x: np.ndarray) -> np.ndarray:
    """Whether points x (M, 3) in the sensor frame lie in front of its optical centre."""
    return (x @ optical_rotation(sensor))[:, 2] > 0


def optical_rotation(sensor: Sensor) -> np.ndarray:
    """R_sensor_optical: the OpenCV optical frame's axes (columns) in the sensor frame."""
    return sensor.R_frame_optical


def project_to_image(sensor: Sensor, p: np.ndarray, x: np.ndarray) -> np.ndarray:
    """Pixel position (M, 2) of points x in the sensor frame; a point3d sensor uses its optical frame."""
    if sensor.model == "pinhole":
        return predict(sensor, p, x)[0]
    X = x @ sensor.R_frame_optical
    fx, fy, cx, cy = (p[i] for i in sensor.intrinsics or ())
    return np.stack([fx * X[:, 0] / X[:, 2] + cx, fy * X[:, 1] / X[:, 2] + cy], axis=1)


def whitening(
    sensor: Sensor, p: np.ndarray, measured: np.ndarray, extra: np.ndarray | None = None
) -> np.ndarray | float:
    """Square-root information of each measurement: W (M, dim, dim), or a scalar for isotropic noise.

    W r has unit variance per row when the noise model holds. The stereo model follows
    triangulation: lateral sigma = z * pixel / f; along the view ray, sigma = z |X| disparity /
    (f * baseline) (z^2 growth), so far points weigh less, and only along their view ray.
    `extra` (M, dim, dim) adds covariance from other sources (the joint readings' rounding).
    """
    noise = sensor.noise
    dim = measured.shape[1]
    if noise.get("model", "isotropic") == "isotropic":
        sigma = float(noise.get("sigma", 1.0))
        if extra is None:
            return 1.0 / sigma
        cov = np.broadcast_to(np.eye(dim) * sigma**2, extra.shape)
    else:
        assert sensor.intrinsics is not None and sensor.baseline is not None and sensor.range is not None
        f = float(p[sensor.intrinsics[0]])
        R = sensor.R_frame_optical
        X = measured @ R
        X[:, 2] = np.clip(X[:, 2], sensor.range[0] * 0.5, None)
        z = X[:, 2]
        # Triangulation X = (u - cx, v - cy, f) b / d: pixel noise moves the point sideways, and
        # disparity noise moves it along its view ray X (not along the optical axis).
        var = np.zeros((len(z), 3, 3))
        var[:, 0, 0] = var[:, 1, 1] = (z * noise["pixel"] / f) ** 2
        ray = X * (z * noise["disparity"] / (f * sensor.baseline))[:, None]
        var += ray[:, :, None] * ray[:, None, :]
        cov = R @ var @ R.T
    if extra is not None:
        cov = cov + extra
    return np.linalg.inv(np.linalg.cholesky(cov))
