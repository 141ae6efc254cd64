"""What the desk asks before it rewrites a robot's kinematics: the apply gate.

Applying a calibration changes where the robot believes every link is, so one that is worse than the
active calibration, or that moves a parameter further than a daily drift plausibly does, is applied only
when the operator confirms it. Two rules, both against what the robot runs with now (the active
calibration, or the nominal model when none was applied):

- worse: both parameter sets predict the same observations, the candidate's own session's held-out
  frames (all its measured frames when nothing was held out; never its training frames alone, which
  favour it); the candidate is worse when its mean error exceeds the active one's by more than
  WORSE_BY (relative). A calibration whose session was deleted is not compared.
- beyond sane bounds: a parameter whose value moves by more than SANE_CHANGE for its kind (angles 10
  deg: joint offsets, twists, camera angles; lengths 5 cm, converted to the profile's unit, so 5 cm for
  Robonaut and 50 mm for NAO; camera intrinsics 50 px; dimensionless scalars 0.1). From the nominal model
  (no calibration applied yet) the bounds are FROM_NOMINAL times wider: the nominal model is the drawing,
  and a first calibration corrects assembly tolerances as well as drift (the paper's own full
  calibration of Robonaut moves wrist_yaw.a by 7.5 cm); later ones correct drift (the simulated daily
  drift of a joint offset has a 4 deg standard deviation, so 10 deg is 2.5 of them). An external
  tracker's registration (Motoman's laser tracker) is where the tracker stood, not the robot's geometry:
  it has no bound.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from calib_core import Dataset, Profile
from calib_core.estimation import Problem, registration_params
from calib_core.units import length_factor

WORSE_BY = 0.05
SANE_CHANGE = {"angle_deg": 10.0, "length_m": 0.05, "px": 50.0, "scalar": 0.1}
FROM_NOMINAL = 2.0
MAX_REASONS = 8


class ConfirmationRequired(Exception):
    """An apply that needs the operator's explicit confirmation; `reasons` says what is worse or beyond."""

    def __init__(self, detail: str, reasons: list[str]) -> None:
        super().__init__(detail)
        self.detail = detail
        self.reasons = reasons


@dataclass(frozen=True)
class Bound:
    """How far one parameter may move without a confirmation, internal and display units."""

    internal: float
    display: float
    unit: str


def bound(profile: Profile, kind: str, factor: float = 1.0) -> Bound:
    """The sane change of a parameter of this kind ("angle", "length", "px", "scalar"), times `factor`."""
    if kind == "angle":
        deg = SANE_CHANGE["angle_deg"] * factor
        return Bound(math.radians(deg), deg, "deg")
    if kind == "length":
        value = SANE_CHANGE["length_m"] * factor * length_factor("m", profile.length_unit)
        return Bound(value, value, profile.length_unit)
    key = "px" if kind == "px" else "scalar"
    return Bound(SANE_CHANGE[key] * factor, SANE_CHANGE[key] * factor, "px" if kind == "px" else "")


def parameter_jumps(
    profile: Profile, new_p: np.ndarray, active_p: np.ndarray, active: str, *, from_nominal: bool = False
) -> list[str]:
    """One sentence per parameter that moves beyond its sane bound, largest move (relative to bound) first."""
    found = []
    factor = FROM_NOMINAL if from_nominal else 1.0
    tracker = set(registration_params(profile))  # where an external tracker stood: not the robot's geometry
    for i, q in enumerate(profile.parameters):
        if i in tracker:
            continue
        b = bound(profile, q.kind, factor)
        change = float(new_p[i] - active_p[i])
        if not math.isfinite(change) or abs(change) > b.internal:
            shown = profile.to_display(i, new_p[i]) - profile.to_display(i, active_p[i])
            unit = f" {b.unit}" if b.unit else ""
            found.append(
                (
                    abs(change) / b.internal if math.isfinite(change) else math.inf,
                    f"{q.name} moves by {shown:+.2f}{unit} from {active} (sane bound {b.display:g}{unit})",
                )
            )
    found.sort(key=lambda f: -f[0])
    return [text for _, text in found]


def mean_error(profile: Profile, data: Dataset, p: np.ndarray) -> float:
    """The papers' figure: mean distance between prediction and measurement over the observations."""
    predicted = Problem(profile, data, [], p, noise_model=False).predict(p)
    return float(np.nanmean(np.linalg.norm(predicted - data.measured, axis=1)))


def worse_than_active(
    profile: Profile, data: Dataset, new_p: np.ndarray, active_p: np.ndarray, active: str, where: str
) -> str | None:
    """A sentence when the candidate predicts `data` worse than the active parameters, else None."""
    if data.n_observations == 0:
        return None
    new_e, old_e = mean_error(profile, data, new_p), mean_error(profile, data, active_p)
    if not math.isfinite(new_e) or new_e > old_e * (1 + WORSE_BY):
        unit = profile.sensors[profile.data.sensor].unit
        return (
            f"on {where} its mean error is {new_e:.3f} {unit}, {active}'s {old_e:.3f} {unit} "
            f"(worse by more than {WORSE_BY:.0%})"
        )
    return None


def concerns(reasons: list[str]) -> list[str]:
    """At most MAX_REASONS sentences, the rest counted."""
    if len(reasons) <= MAX_REASONS:
        return reasons
    return [*reasons[: MAX_REASONS - 1], f"and {len(reasons) - MAX_REASONS + 1} more parameters beyond their bounds"]
