"""How good a calibration is on data it was not fitted on: the error figures of its predictions,
pooled and per sensor, every observation counted (none left out as an outlier), in the data
format's measurement unit (cm for Robonaut, m for the Motoman's tracker, px for a camera)."""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np

from ..dataset import Dataset
from ..errors import InputError
from ..model.profile import Profile
from ..units import LENGTH_IN_M, length_factor
from .calibration import Calibration
from .problem import Problem
from .registration import register, registration_params
from .validation import Figures, sensor_figures


@dataclass(frozen=True)
class Evaluation:
    """A calibration's figures on a dataset: pooled over the sensors of the first one's unit, and
    each sensor's (by name) when there are several."""

    figures: Figures
    sensors: dict[str, Figures] = field(default_factory=dict)
    registered: bool = False  # the tracker's pose was fitted to these data (another set-up)

    def to_dict(self) -> dict:
        """The pinned JSON answer ({mean, rms, max, n, unit}) plus each sensor's when several."""
        out = _brief(self.figures)
        if len(self.sensors) > 1:
            out["sensors"] = {name: _brief(f) for name, f in self.sensors.items()}
        return out


def evaluate(
    profile: Profile, calibration: Calibration | None, data: Dataset, *, reregister: bool = False
) -> Evaluation:
    """The figures of `calibration` (None: the nominal model) predicting `data`. `reregister`: fit
    the tracker's pose to these data first (data from another tracker set-up); the robot's own
    parameters stay the calibration's."""
    p = calibration.params(profile) if calibration is not None else profile.nominal()
    # The nominal model has no idea where a tracker stands: it is always seen from a fitted pose.
    registered = (reregister or calibration is None) and bool(registration_params(profile, data.sensors))
    pred = Problem(profile, data, [], p, noise_model=False).predict(p)
    _check_predicted(profile, data, pred)
    if registered:
        p = register(profile, data, p)
        pred = Problem(profile, data, [], p, noise_model=False).predict(p)
    pooled, each = sensor_figures(profile, [(data, pred, None)])
    unit = profile.data.measurement_unit
    return Evaluation(_in(pooled, unit), {n: _in(f, unit) for n, f in each.items()}, registered)


def _check_predicted(profile: Profile, data: Dataset, pred: np.ndarray) -> None:
    """Refuse observations the model cannot predict (NaN figures are no answer): a board's row without a
    vertex id or a point, a point on the camera's plane."""
    dims = np.array([profile.sensors[s].dim for s in data.sensor])
    bad = np.flatnonzero([not np.isfinite(row[:d]).all() for row, d in zip(pred, dims, strict=True)])
    if len(bad):
        where = "" if data.lines is None else f" (lines {', '.join(str(int(n)) for n in data.lines[bad[:5]])})"
        raise InputError(
            f"{len(bad)} of {data.n_observations} observations{where} have no prediction: a board's row needs its "
            "vertex id or its point's columns",
            file=data.source,
        )


def _in(f: Figures, unit: str) -> Figures:
    """Figures in the data format's length unit (pixels stay pixels)."""
    if f.unit == unit or f.unit not in LENGTH_IN_M or unit not in LENGTH_IN_M:
        return f
    k = length_factor(f.unit, unit)
    return replace(
        f,
        mean=f.mean * k,
        rms=f.rms * k,
        max=f.max * k,
        median=f.median * k,
        unit=unit,
        rms_axes=[v * k for v in f.rms_axes],
    )


def _brief(f: Figures) -> dict:
    return {"mean": f.mean, "rms": f.rms, "max": f.max, "n": f.n, "unit": f.unit}
