"""What every measurement model provides: the SensorModel protocol, and the part all sensors share.

A sensor is fixed to a frame of the robot's tree and reports something about a target point given
in its own frame: the point itself (a laser tracker, a stereo head), its pixel (a camera), its
distance from a plane (a touch probe on a table). A measurement model is one class in one module of
this package, registered by its YAML name in `calib_core.sensors.SENSOR_MODELS`; nothing outside
this package asks which kind a sensor is. It says:

- `dim`, `axes`, `unit`: how many numbers one observation has, their names and their unit;
- `predict(p, x, derivatives=True)`: the measurement of points x (M, 3) in the sensor frame, with
  the exact derivatives by x and by the parameters the model reads directly (`direct_params`:
  intrinsics, distortion); `predict_pose` the same given also the target frame's orientation, which a
  sensor that measures one (`rotation_axes`, a 6-D pose) needs, with the derivatives by it;
- `error(predicted, measured)` and `error_jacobian`: the residual (prediction - measurement, or for a
  rotation the rotation between them) and its derivative by the prediction;
- `covariance` and `whitening`: the noise model the calibration weighs observations by;
- `reading`: what it takes to get a measurement: `stereo` (a depth map from a stereo pair, where the
  BallFinder finds a sphere), `image` (a camera image, where a board detector finds the corners) or
  `direct` (the device reports the measurement itself);
- `visible`, `project`: whether the sensor can see points, and where they fall in its image;
- `simulate`: a noisy reading as the real device would give it (for the simulator);
- `place`, `measured_pixels`, `image_roles`, `image_size_px`: where a measurement puts its point in 3-D and
  its mark in the image, and which images one reading takes (what a review shows of it).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from typing import Any, ClassVar, Literal, Protocol, runtime_checkable

import numpy as np

from ..errors import InputError

Reading = Literal["stereo", "image", "direct"]
# The images one reading takes, by their role in a stored frame; a sensor's pixels are in the first.
IMAGE_ROLES: dict[str, tuple[str, ...]] = {"stereo": ("left", "right"), "image": ("image",), "direct": ()}


class SpecReader(Protocol):
    """What a measurement model needs from the profile loader to compile its YAML entry."""

    length_unit: str

    def get(self, mapping: Any, key: str, where: str, default: Any = ...) -> Any: ...

    def number(self, value: Any, where: str) -> float: ...

    def vector(self, value: Any, where: str) -> np.ndarray: ...

    def add_params(
        self, prefix: str, kind: str, mapping: Any, keys: tuple[str, ...], where: str, default: Any = ...
    ) -> tuple[int, ...]: ...

    def fail(self, where: str, message: str) -> InputError: ...


@runtime_checkable
class SensorModel(Protocol):
    """The protocol of a measurement model (see the module doc)."""

    name: str
    frame: int
    unit: str
    kind: ClassVar[str]
    dim: ClassVar[int]
    axes: ClassVar[tuple[str, ...]]
    rotation_axes: ClassVar[int]

    @property
    def reading(self) -> Reading: ...

    def direct_params(self) -> tuple[int, ...]: ...

    def predict(
        self, p: np.ndarray, x: np.ndarray, *, derivatives: bool = False
    ) -> tuple[np.ndarray, np.ndarray | None, np.ndarray | None]: ...

    def predict_pose(
        self, p: np.ndarray, x: np.ndarray, rotation: np.ndarray | None, *, derivatives: bool = False
    ) -> tuple[np.ndarray, np.ndarray | None, np.ndarray | None, np.ndarray | None]: ...

    def error(self, predicted: np.ndarray, measured: np.ndarray) -> np.ndarray: ...

    def error_jacobian(self, predicted: np.ndarray, measured: np.ndarray) -> np.ndarray | None: ...

    def whitening(self, p: np.ndarray, measured: np.ndarray, extra: np.ndarray | None = None) -> np.ndarray | float: ...

    def visible(self, p: np.ndarray, x: np.ndarray, margin_px: float = 0.0) -> np.ndarray: ...

    def project(self, p: np.ndarray, x: np.ndarray) -> np.ndarray | None: ...

    def simulate(
        self, p: np.ndarray, x: np.ndarray, rng: np.random.Generator, noise: dict[str, float]
    ) -> np.ndarray: ...

    def place(self, p: np.ndarray, measured: np.ndarray, x: np.ndarray, normal: np.ndarray) -> np.ndarray: ...

    def measured_pixels(self, p: np.ndarray, measured: np.ndarray) -> np.ndarray: ...

    @property
    def image_roles(self) -> tuple[str, ...]: ...

    def image_size_px(self) -> tuple[int, int] | None: ...


# The fields of each noise model (isotropic: `sigma` may be left out, meaning 1 in the measurement's unit).
NOISE_FIELDS = {"isotropic": ("sigma",), "stereo": ("pixel", "disparity"), "pose": ("position", "rotation_deg")}


@dataclass(frozen=True)
class Sensor:
    """The part every measurement model shares: a name, the frame it is fixed to, the unit of its
    measurements and its checked noise model (`check_noise`)."""

    name: str
    frame: int
    unit: str
    noise: dict[str, Any]

    kind: ClassVar[str]
    dim: ClassVar[int]
    axes: ClassVar[tuple[str, ...]]
    noise_models: ClassVar[tuple[str, ...]] = ("isotropic",)
    rotation_axes: ClassVar[int] = 0  # the measurement's last columns that are a rotation vector (rad)

    @property
    def reading(self) -> Reading:
        return "direct"

    def direct_params(self) -> tuple[int, ...]:
        """Parameter indices the model reads directly, not through the point (intrinsics...)."""
        return ()

    def predict(
        self, p: np.ndarray, x: np.ndarray, *, derivatives: bool = False
    ) -> tuple[np.ndarray, np.ndarray | None, np.ndarray | None]:
        """Measurements (M, dim) of points x (M, 3) in the sensor frame, parameters p (internal
        units); with `derivatives` also d/dx (M, dim, 3) and d/d(direct_params) (M, dim, k)."""
        raise NotImplementedError

    def predict_pose(
        self, p: np.ndarray, x: np.ndarray, rotation: np.ndarray | None, *, derivatives: bool = False
    ) -> tuple[np.ndarray, np.ndarray | None, np.ndarray | None, np.ndarray | None]:
        """`predict`, given also the target frame's orientation in the sensor frame (M, 3, 3; None when
        `rotation_axes` is 0); with `derivatives` also d/d(a small rotation of the target frame about the
        sensor frame's axes) (M, dim, 3), None when the measurement does not depend on it."""
        h, dh_dx, dh_direct = self.predict(p, x, derivatives=derivatives)
        return h, dh_dx, dh_direct, None

    def error(self, predicted: np.ndarray, measured: np.ndarray) -> np.ndarray:
        """The residual of measurements (M, dim): prediction - measurement."""
        return predicted - measured

    def error_jacobian(self, predicted: np.ndarray, measured: np.ndarray) -> np.ndarray | None:
        """d(error)/d(prediction) (M, dim, dim), a rotation's by its small rotation (`predict_pose`); None:
        the identity."""
        return None

    def covariance(self, p: np.ndarray, measured: np.ndarray) -> np.ndarray:
        """The noise model's covariance of each measurement (M, dim, dim)."""
        sigma = float(self.noise.get("sigma", 1.0))
        return np.broadcast_to(np.eye(self.dim) * sigma**2, (len(measured), self.dim, self.dim))

    def whitening(self, p: np.ndarray, measured: np.ndarray, extra: np.ndarray | None = None) -> np.ndarray | float:
        """Square-root information of each measurement: W (M, dim, dim), or a scalar for isotropic
        noise, so that W r has unit variance per row when the noise model holds. `extra`
        (M, dim, dim) adds covariance from other sources (the joint readings' rounding)."""
        if self.noise.get("model", "isotropic") == "isotropic" and extra is None:
            return 1.0 / float(self.noise.get("sigma", 1.0))
        cov = self.covariance(p, measured)
        if extra is not None:
            cov = cov + extra
        return np.linalg.inv(np.linalg.cholesky(cov))

    def checked_noise(self, noise: Any, where: str) -> dict[str, Any]:
        """A noise model for this sensor, checked (`check_noise`); InputError naming `where`."""
        return check_noise(noise, self.kind, self.noise_models, where)

    def with_noise(self, noise: Any, where: str) -> Sensor:
        """The same sensor weighed by another noise model (data measured with another precision)."""
        return replace(self, noise=self.checked_noise(noise, where))

    def outlier_sigmas(self) -> float | None:
        """The profile's limit for an outlier in robust sigmas (`noise.outliers`), or None."""
        value = self.noise.get("outliers")
        return None if value is None else float(value)

    def visible(self, p: np.ndarray, x: np.ndarray, margin_px: float = 0.0) -> np.ndarray:
        """Whether the sensor can measure each point x (M, 3) of its frame (M,) bool."""
        return np.ones(len(x), bool)

    def project(self, p: np.ndarray, x: np.ndarray) -> np.ndarray | None:
        """Where points x (M, 3) of the sensor frame fall in its image (M, 2) px; None: no image."""
        return None

    def simulate(self, p: np.ndarray, x: np.ndarray, rng: np.random.Generator, noise: dict[str, float]) -> np.ndarray:
        """A noisy reading of points x as the device gives it; `noise`: the simulation's settings
        (profile `simulation.noise`: `point` in the length unit for a direct reading)."""
        h = self.predict(p, x)[0]
        return h + rng.normal(0.0, float(noise.get("point", 0.0)), h.shape)

    def place(self, p: np.ndarray, measured: np.ndarray, x: np.ndarray, normal: np.ndarray) -> np.ndarray:
        """Where measurements (M, dim) put their points (M, 3) in the sensor frame, for a 3-D view: given
        each point's prediction x (M, 3) and the target's surface normal there (M, 3, unit; a board's z axis),
        both in the sensor frame. A measurement too few to fix a point is placed nearest the prediction.
        NaN rows: nothing to place (NaN measured, a ray parallel to the surface)."""
        raise NotImplementedError

    def measured_pixels(self, p: np.ndarray, measured: np.ndarray) -> np.ndarray:
        """Where measurements (M, dim) fall in the sensor's image (M, 2) px; NaN: it makes no image, or the
        point lies behind the camera."""
        return np.full((len(measured), 2), np.nan)

    @property
    def image_roles(self) -> tuple[str, ...]:
        """The images one reading takes, by their role in a stored frame (IMAGE_ROLES); none for a direct one."""
        return IMAGE_ROLES[self.reading]

    def image_size_px(self) -> tuple[int, int] | None:
        """Width and height of the image its pixels are in; None: no image, or its size is not given."""
        return None


def check_noise(noise: Any, sensor_kind: str, allowed: tuple[str, ...], where: str) -> dict[str, Any]:
    """A checked copy of a noise model (the YAML's `sensors[].noise`); InputError naming `where` and
    the field if it is wrong. isotropic: `sigma` in the measurement's unit; stereo: `pixel`
    (lateral) and `disparity` noise in px; pose: `position` in the length unit and `rotation_deg` in
    deg. Any model may set `outliers`, in robust sigmas."""
    if noise is None:
        noise = {}
    if not isinstance(noise, dict):
        raise InputError(f"{where}: expected a mapping")
    out: dict[str, Any] = {str(k): v for k, v in noise.items()}
    model = out.get("model", "isotropic")
    if model not in NOISE_FIELDS:
        raise InputError(f"{where}.model: unknown noise model '{model}' ({', '.join(NOISE_FIELDS)})")
    if model not in allowed:
        raise InputError(f"{where}.model: a {sensor_kind} sensor takes the {' or '.join(allowed)} noise model")
    wanted = NOISE_FIELDS[model]
    for k, v in out.items():
        if k == "model":
            continue
        if k not in (*wanted, "outliers"):
            raise InputError(f"{where}.{k}: not a field of the {model} noise model ({', '.join(wanted)}, outliers)")
        if isinstance(v, bool) or not isinstance(v, int | float) or not math.isfinite(v) or v <= 0:
            raise InputError(f"{where}.{k}: expected a positive number, got {v!r}")
        out[k] = float(v)
    missing = [k for k in wanted if k not in out and model != "isotropic"]
    if missing:
        raise InputError(f"{where}.{missing[0]}: the {model} noise model needs it")
    return out
