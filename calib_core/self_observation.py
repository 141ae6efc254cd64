"""Self-observation with several sensors at once: one calibration from the pixels of every camera
(the Motoman's two eyes seeing the marker faces on both end effectors).

Each sensor's observations form a Problem of their own (its noise model, its projection); the
problems share the free parameters, so the stacked residuals and exact Jacobians go to one
Levenberg-Marquardt solve, with the mode's priors counted once. Observations beyond their sensor's
outlier limit (a misread marker) are left out after a first least-squares pass, as `calibrate`
does for one sensor.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .calibrate import observed_mode, outlier_limit, outliers_of
from .dataset import Dataset
from .identifiability import find_dependencies
from .problem import Problem
from .profile import Mode, Profile
from .solver import SolveResult, levenberg_marquardt
from .validation import Figures, figures


@dataclass
class JointFit:
    p: np.ndarray
    free: list[int]
    held: list[int]  # free parameters the data could not separate, held at their base values
    before: dict[str, Figures]  # per sensor, px
    after: dict[str, Figures]
    result: SolveResult


def calibrate_sensors(parts: dict[str, tuple[Profile, Dataset]], mode: Mode, p_base: np.ndarray) -> JointFit:
    """Estimate `mode`'s parameters from every (profile, dataset) part: a profile per sensor, whose
    `data.sensor` says which sensor the part's observations come from."""
    free: list[int] = []
    for prof, data in parts.values():
        free += observed_mode(prof, data, mode).free
    free = list(dict.fromkeys(i for i in mode.free if i in set(free)))

    def problems(free: list[int]) -> list[Problem]:
        out = []
        for k, (prof, data) in enumerate(parts.values()):
            out.append(Problem(prof, data, free, p_base, mode.ties, mode.priors if k == 0 else None))
        return out

    probs = problems(free)
    J = np.vstack([pr.residuals_jacobian(pr.x0)[1][: pr.n_data_rows] for pr in probs])
    held = [d.fixed for d in find_dependencies(next(iter(parts.values()))[0], J, free)]
    if held:
        free = [i for i in free if i not in held]
        probs = problems(free)

    def fun_jac(x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        pieces = [pr.residuals_jacobian(x) for pr in probs]
        return np.concatenate([r for r, _ in pieces]), np.vstack([j for _, j in pieces])

    x0 = probs[0].x0
    res = levenberg_marquardt(fun_jac, x0)
    for pr in probs:  # leave out misread markers, then solve again
        pr.included = ~outliers_of(pr.residuals(res.x)[: pr.n_data_rows], pr.dim, outlier_limit(pr.sensor, pr.dim))
    res = levenberg_marquardt(fun_jac, res.x)
    p = probs[0].params(res.x)
    before, after = {}, {}
    for name, pr in zip(parts, probs, strict=True):
        before[name] = figures(pr.predict(p_base), pr.data.measured, "px", pr.included)
        after[name] = figures(pr.predict(p), pr.data.measured, "px", pr.included)
    return JointFit(p, free, held, before, after, res)
