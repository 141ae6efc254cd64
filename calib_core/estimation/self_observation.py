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
from datetime import UTC, datetime

import numpy as np

from ..dataset import Dataset
from ..errors import InputError
from ..model.profile import Mode, Profile
from .calibrate import box, observed_mode, outlier_limit, outliers_of, robust_sigma
from .calibration import Calibration, parameter_estimate
from .identifiability import find_dependencies, report
from .problem import Problem
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
    pooled: dict[str, Figures]  # before, after (and holdout_before, holdout_after) over every sensor
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
    rows: dict[str, list[tuple[str, np.ndarray, np.ndarray, np.ndarray]]] = {"": [], "holdout_": []}
    for name, pr in zip(parts, probs, strict=True):
        rows[""].append((name, pr.predict(p_base), pr.predict(p), pr.data.measured, pr.included))
        prof, data = parts[name]
        test = data.select(np.isin(data.frame_ids, test_ids))
        if test.n_observations:
            # Misread markers among the held-out poses are left out by the training residuals' spread.
            sigma = robust_sigma(pr.residuals(res.x)[: pr.n_data_rows], pr.dim)
            tp = Problem(prof, test, [], p)
            norms = np.sqrt(block_norms_sq(tp.residuals(np.zeros(0)), pr.dim))
            keep = norms <= sigma * outlier_limit(pr.sensor, pr.dim)
            rows["holdout_"].append((name, tp.predict(p_base), tp.predict(p), test.measured, keep))
    out: dict[str, dict[str, Figures]] = {k: {} for k in ("before", "after", "holdout_before", "holdout_after")}
    pooled = {}
    for prefix, entries in rows.items():
        for name, before, after, measured, keep in entries:
            out[f"{prefix}before"][name] = figures(before, measured, "px", keep)
            out[f"{prefix}after"][name] = figures(after, measured, "px", keep)
        if entries:
            before, after, measured, keep = (np.concatenate(c) for c in list(zip(*entries, strict=True))[1:])
            pooled[f"{prefix}before"] = figures(before, measured, "px", keep)
            pooled[f"{prefix}after"] = figures(after, measured, "px", keep)
    return JointFit(p, free, held, _std(probs, res.x), **out, pooled=pooled, result=res)


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


def to_calibration(profile: Profile, fit: JointFit, mode: str, p_base: np.ndarray, source: str) -> Calibration:
    """The result as a calibration file (figures pooled over the sensors, px), which `export`,
    `predict` and the dashboard take like any other."""
    held, free = set(fit.held), set(fit.free)
    note = "the data cannot separate it from the others: held at its base value"
    params = [
        parameter_estimate(
            profile, i, fit.p, p_base, estimated=i in free, std=fit.std.get(i), note=note if i in held else None
        )
        for i in range(len(profile.parameters))
    ]
    res = fit.result
    sensors = ", ".join(f"{name}: {f}" for name, f in fit.after.items())
    return Calibration(
        robot=profile.name,
        mode=mode,
        method="lm",
        created=datetime.now(UTC).isoformat(timespec="seconds"),
        source=source,
        parameters=params,
        figures=dict(fit.pooled),
        solver={
            "method": "lm",
            "iterations": res.iterations,
            "evaluations": res.evaluations,
            "solve_seconds": res.seconds,
            "status": res.status,
            "cost_history": res.cost_history,
            "sensors": sensors,
        },
        identifiability={
            "free": [profile.parameters[i].name for i in fit.free],
            "held_fixed": sorted(profile.parameters[i].name for i in held),
        },
        warnings=[f"{profile.label(i)} cannot be told apart from the others by these data: held" for i in fit.held],
    )
