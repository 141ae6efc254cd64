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

from .calibrate import box, observed_mode, outlier_limit, outliers_of, robust_sigma
from .dataset import Dataset
from .errors import InputError
from .identifiability import find_dependencies, report
from .problem import Problem
from .profile import Mode, Profile
from .solver import SolveResult, block_norms_sq, levenberg_marquardt
from .validation import Figures, figures


@dataclass
class JointFit:
    p: np.ndarray
    free: list[int]
    held: list[int]  # free parameters the data could not separate, held at their base values
    std: dict[int, float]  # free parameter -> standard deviation (internal units), clustered by pose
    before: dict[str, Figures]  # per sensor, px, on the training poses
    after: dict[str, Figures]
    holdout_before: dict[str, Figures]  # per sensor, on the held-out poses (empty without a hold-out)
    holdout_after: dict[str, Figures]
    result: SolveResult


def calibrate_sensors(
    parts: dict[str, tuple[Profile, Dataset]],
    mode: Mode,
    p_base: np.ndarray,
    *,
    holdout: float = 0.0,
    seed: int = 0,
) -> JointFit:
    """Estimate `mode`'s parameters from every (profile, dataset) part: a profile per sensor, whose
    `data.sensor` says which sensor the part's observations come from. A pose has the same frame id
    in every part; `holdout` keeps that share of the poses out of the fit, in every part."""
    profile = next(iter(parts.values()))[0]
    test_ids = _held_out_poses(parts, holdout, seed)
    train = {n: (prof, data.select(~np.isin(data.frame_ids, test_ids))) for n, (prof, data) in parts.items()}
    free: list[int] = []
    for prof, data in train.values():
        free += observed_mode(prof, data, mode).free
    free = list(dict.fromkeys(i for i in mode.free if i in set(free)))

    def problems(free: list[int]) -> list[Problem]:
        out = []
        for k, (prof, data) in enumerate(train.values()):
            out.append(Problem(prof, data, free, p_base, mode.ties, mode.priors if k == 0 else None))
        return out

    probs = problems(free)
    J = np.vstack([pr.residuals_jacobian(pr.x0)[1][: pr.n_data_rows] for pr in probs])
    held = [d.fixed for d in find_dependencies(profile, J, free)]
    if held:
        free = [i for i in free if i not in held]
        probs = problems(free)
    lower, upper = box(profile, mode, free)

    def fun_jac(x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        pieces = [pr.residuals_jacobian(x) for pr in probs]
        return np.concatenate([r for r, _ in pieces]), np.vstack([j for _, j in pieces])

    def data_rows(x: np.ndarray) -> np.ndarray:
        return np.concatenate([pr.residuals(x)[: pr.n_data_rows] for pr in probs])

    res = levenberg_marquardt(fun_jac, probs[0].x0, lower=lower, upper=upper)
    for pr in probs:  # leave out misread markers, then solve again
        pr.included = ~outliers_of(pr.residuals(res.x)[: pr.n_data_rows], pr.dim, outlier_limit(pr.sensor, pr.dim))
    probs[0].prior_scale = robust_sigma(data_rows(res.x), probs[0].dim)  # priors against the actual scale
    res = levenberg_marquardt(fun_jac, res.x, lower=lower, upper=upper)
    p = probs[0].params(res.x)
    out = {k: {} for k in ("before", "after", "holdout_before", "holdout_after")}
    for name, pr in zip(parts, probs, strict=True):
        out["before"][name] = figures(pr.predict(p_base), pr.data.measured, "px", pr.included)
        out["after"][name] = figures(pr.predict(p), pr.data.measured, "px", pr.included)
        prof, data = parts[name]
        test = data.select(np.isin(data.frame_ids, test_ids))
        if test.n_observations:
            # Misread markers among the held-out poses are left out by the training residuals' spread.
            sigma = robust_sigma(pr.residuals(res.x)[: pr.n_data_rows], pr.dim)
            tp = Problem(prof, test, [], p)
            keep = np.sqrt(block_norms_sq(tp.residuals(np.zeros(0)), pr.dim)) <= sigma * outlier_limit(
                pr.sensor, pr.dim
            )
            out["holdout_before"][name] = figures(tp.predict(p_base), test.measured, "px", keep)
            out["holdout_after"][name] = figures(tp.predict(p), test.measured, "px", keep)
    return JointFit(p, free, held, _std(probs, res.x), **out, result=res)


def _held_out_poses(parts: dict[str, tuple[Profile, Dataset]], share: float, seed: int) -> np.ndarray:
    if not 0.0 <= share < 1.0:
        raise InputError(f"held-out share {share} must be in [0, 1)")
    poses = np.unique(np.concatenate([data.frame_ids for _, data in parts.values()]))
    rng = np.random.default_rng(seed)
    return rng.permutation(poses)[: round(share * len(poses))]


def _std(probs: list[Problem], x: np.ndarray) -> dict[int, float]:
    """Standard deviations from the stacked whitened Jacobian (data rows, then the priors), with the
    observations of one pose clustered: they share its joint readings, whichever camera saw them."""
    pieces = [pr.residuals_jacobian(x) for pr in probs]
    rows = [pr.n_data_rows for pr in probs]
    J = np.vstack([j[:n] for (_, j), n in zip(pieces, rows, strict=True)] + [pieces[0][1][rows[0] :]])
    r = np.concatenate([q[:n] for (q, _), n in zip(pieces, rows, strict=True)] + [pieces[0][0][rows[0] :]])
    clusters = np.concatenate([np.repeat(pr.data.frame_ids[pr.data.cfg], pr.dim) for pr in probs])
    n_data = sum(rows)
    n_in = sum(int(pr.included.sum()) * pr.dim for pr in probs)
    sigma = float(np.sqrt(np.sum(r[:n_data] ** 2) / max(n_in - len(x), 1)))
    rep = report(J, r, sigma, clusters)
    return {} if rep.std is None else {i: float(v) for i, v in zip(probs[0].free, rep.std, strict=True)}
