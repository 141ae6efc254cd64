"""Daily and full calibration: from a dataset and a mode to a Calibration.

The procedure, for the Levenberg-Marquardt method:
1. At the start values, find the parameter directions the data cannot determine and hold one
   parameter of each at its base value (named in the report), so nothing wanders.
2. Least squares from the base calibration (or the nominal model) to the basin of the solution.
3. With the robust loss (default): re-solve with a Cauchy loss scaled to the residuals' robust
   spread, then flag observations beyond the 99.99% quantile of that spread as outliers and solve
   once more on the rest (plain least squares, so the covariance is the textbook one).
4. At the solution: standard deviations and correlations, singular values, condition and O1.
The held-out share and the k-fold cross-validation repeat steps 1-3 on the training part only.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass, replace
from datetime import UTC, datetime

import numpy as np
from scipy.stats import chi2

from ..dataset import Dataset
from ..errors import InputError
from ..model.profile import Mode, Profile, Sensor
from ..units import LENGTH_IN_M
from .calibration import Calibration, Outlier, parameter_estimate
from .identifiability import Dependency, find_dependencies, report, strong_correlations, weak_parameters
from .problem import Problem
from .registration import register, registration_params
from .solver import Robust, SolveResult, block_norms_sq, levenberg_marquardt, nelder_mead
from .validation import Figures, figures, holdout_split, kfold_splits

METHODS = ("lm", "nelder-mead")
OUTLIER_QUANTILE = 0.9999
# No robot's nominal model is this far off once the tracker's pose is fitted; rows from two tracker
# set-ups (or the wrong arm) are.
REGISTRATION_MISFIT_M = 0.05


@dataclass
class Fit:
    problem: Problem
    p: np.ndarray
    dependencies: list[Dependency]
    iterations: int
    evaluations: int
    seconds: float
    status: str
    cost_history: list[float]
    sigma: float  # scale of the whitened residuals at the solution


def calibrate(
    profile: Profile,
    data: Dataset,
    mode: str,
    base: Calibration | None = None,
    *,
    holdout: float = 0.0,
    folds: int = 0,
    method: str = "lm",
    robust: bool = True,
    seed: int = 0,
    progress: Callable[[int, float], None] | None = None,
    should_stop: Callable[[], bool] | None = None,
) -> Calibration:
    """Estimate the parameters of `mode` from `data`, starting from `base` (or the nominal model)."""
    m = profile.mode(mode)
    if method not in METHODS:
        raise InputError(f"unknown method '{method}' ({', '.join(METHODS)})")
    if not 0.0 <= holdout < 1.0:
        raise InputError(f"held-out share {holdout} must be in [0, 1)")
    p_base = base.params(profile) if base is not None else profile.nominal()
    if holdout > 0:
        train_idx, test_idx = holdout_split(data, holdout, seed)
    else:
        train_idx, test_idx = np.arange(data.n_configurations), np.array([], int)
    train = data.select(train_idx)
    if train.n_observations * _dim(profile) < len(m.free):
        raise InputError(
            f"{train.n_observations} observations cannot determine the {len(m.free)} parameters of mode '{mode}'",
            file=data.source,
        )
    m = observed_mode(profile, train, m)
    reg = set(registration_params(profile))
    if reg and not reg & set(m.free) and base is None:
        raise InputError(
            f"mode '{mode}' does not estimate the registration of '{profile.sensors[profile.data.sensor].name}' "
            "(where it stands), which these data need: choose a mode that does, or start from a calibration "
            "of the same set-up (--base)"
        )
    if reg & set(m.free):
        # A tracker set-up of its own: "before" is the old model with only the registration fitted.
        p_base = register(profile, train, p_base)
    fit = fit_parameters(
        profile,
        train,
        m,
        p_base,
        method=method,
        robust=robust,
        progress=progress,
        should_stop=should_stop,
    )

    unit = _measure_unit(profile)
    keep = fit.problem.included
    figs: dict[str, Figures] = {
        "before": figures(fit.problem.predict(p_base), train.measured, unit, keep),
        "after": figures(fit.problem.predict(fit.p), train.measured, unit, keep),
    }
    if len(test_idx):
        test = data.select(test_idx)
        tp = Problem(profile, test, [], p_base)
        keep = inliers(profile, test, fit.p, fit.sigma) if robust else None
        figs["holdout_before"] = figures(tp.predict(p_base), test.measured, unit, keep)
        figs["holdout_after"] = figures(tp.predict(fit.p), test.measured, unit, keep)
    solver = {
        "method": method,
        "robust": robust,
        "iterations": fit.iterations,
        "evaluations": fit.evaluations,
        "solve_seconds": fit.seconds,
        "status": fit.status,
        "cost_history": fit.cost_history,
        "sigma": fit.sigma,
    }
    if folds >= 2:
        figs["cv_after"], cv_seconds = cross_validate(
            profile, train, m, p_base, folds, method, robust, seed, should_stop
        )
        solver["folds"] = folds
        solver["cv_seconds"] = cv_seconds
    return _result(profile, data, train, mode, method, fit, p_base, figs, solver, test_idx)


def observed_mode(profile: Profile, data: Dataset, mode: Mode) -> Mode:
    """The mode without the parameters no observation depends on: those of chains the data do not
    use (the other arm of a two-armed robot) and the points of targets never seen."""
    sensor = profile.sensors[profile.data.sensor]
    targets = [profile.targets[t] for t in np.unique(data.target)]
    frames = set(profile.chain(sensor.frame)).union(*(profile.chain(t.frame) for t in targets))
    used = {op.param for f in frames for op in profile.frames[f].ops}
    used |= {i for t in targets for i in (t.point_params or ())}
    used |= set(sensor.intrinsics or ()) | set(sensor.distortion or ())
    leaders = {t.leader for t in mode.ties if t.follower in used}
    return replace(mode, free=tuple(i for i in mode.free if i in used or i in leaders))


def box(profile: Profile, mode: Mode, free: list[int]) -> tuple[np.ndarray, np.ndarray]:
    """The mode's bounds on the free parameters: nominal -/+ the largest change it allows."""
    nominal = profile.nominal()
    reach = np.array([mode.bounds.get(i, np.inf) for i in free])
    return nominal[free] - reach, nominal[free] + reach


def fit_parameters(
    profile: Profile,
    data: Dataset,
    mode: Mode,
    p_base: np.ndarray,
    *,
    method: str = "lm",
    robust: bool = True,
    progress: Callable[[int, float], None] | None = None,
    should_stop: Callable[[], bool] | None = None,
) -> Fit:
    start = time.perf_counter()
    problem = Problem(profile, data, list(mode.free), p_base, mode.ties, mode.priors)
    initial = problem.residuals_jacobian(problem.x0)
    deps = find_dependencies(profile, initial[1][: problem.n_data_rows], problem.free)
    if deps:
        fixed = {d.fixed for d in deps}
        free = [i for i in mode.free if i not in fixed]
        problem = Problem(profile, data, free, p_base, mode.ties, mode.priors, noise_model=problem.W)
        initial = None
    dim = problem.dim
    n_rows = problem.n_data_rows
    lower, upper = box(profile, mode, problem.free)
    iterations = 0
    evaluations = 0
    history: list[float] = []

    def tick(it: int, cost: float) -> None:
        if progress is not None:
            progress(iterations + it, cost)

    def run(x0: np.ndarray, loss: Robust | None, start: tuple | None = None) -> SolveResult:
        nonlocal iterations, evaluations
        # The robust pass only has to sort inliers from outliers (IRLS converges linearly), so it
        # stops early; the least-squares passes converge quadratically to full precision.
        res = levenberg_marquardt(
            problem.residuals_jacobian,
            x0,
            initial=start,
            robust=loss,
            ftol=1e-6 if loss else 1e-10,
            progress=tick,
            should_stop=should_stop,
            lower=lower,
            upper=upper,
        )
        iterations += res.iterations
        evaluations += res.evaluations
        history.extend(res.cost_history)
        return res

    if method == "nelder-mead":
        res = nelder_mead(problem.raw_residuals, problem.x0, dim, n_rows, should_stop=should_stop)
        iterations, evaluations, history, status = (
            res.iterations,
            res.evaluations,
            res.cost_history,
            res.status,
        )
        x = res.x
    else:
        res = run(problem.x0, None, initial)
        x = res.x
        if problem.priors:
            # A prior's sigma is meant against the residuals' actual scale (a MAP estimate), not
            # the declared sensor noise: on a real robot the model error outweighs the noise.
            problem.prior_scale = robust_sigma(problem.residuals(x)[:n_rows], dim)
            res = run(x, None)
            x = res.x
        # Outliers show in the least-squares residuals; only then is the robust pass worth its time.
        limit = outlier_limit(problem.sensor, dim)
        if robust and len(problem.free) and outliers_of(problem.residuals(x)[:n_rows], dim, limit).any():
            sigma = robust_sigma(problem.residuals(x)[:n_rows], dim)
            problem.prior_scale = sigma
            res = run(x, Robust(dim, n_rows, sigma * np.sqrt(chi2.ppf(0.95, dim))))
            x = res.x
            r = problem.residuals(x)[:n_rows]
            problem.included = ~outliers_of(r, dim, limit)
            problem.prior_scale = robust_sigma(r, dim)
            res = run(x, None)
            x = res.x
        status = res.status
    r = problem.residuals(x)
    n_in = int(problem.included.sum()) * dim
    sigma = float(np.sqrt(np.sum(r[:n_rows] ** 2) / max(n_in - len(problem.free), 1)))
    return Fit(
        problem,
        problem.params(x),
        deps,
        iterations,
        evaluations,
        time.perf_counter() - start,
        status,
        history,
        sigma,
    )


def cross_validate(
    profile: Profile,
    data: Dataset,
    mode: Mode,
    p_base: np.ndarray,
    folds: int,
    method: str,
    robust: bool,
    seed: int,
    should_stop: Callable[[], bool] | None = None,
) -> tuple[Figures, float]:
    """Pooled held-out figures: every configuration predicted by a calibration that did not see it."""
    start = time.perf_counter()
    preds, meas, keeps = [], [], []
    for train_idx, test_idx in kfold_splits(data, folds, seed):
        if len(test_idx) == 0 or len(train_idx) == 0:
            continue
        fit = fit_parameters(
            profile,
            data.select(train_idx),
            mode,
            p_base,
            method=method,
            robust=robust,
            should_stop=should_stop,
        )
        test = data.select(test_idx)
        tp = Problem(profile, test, [], p_base)
        preds.append(tp.predict(fit.p))
        meas.append(test.measured)
        keeps.append(inliers(profile, test, fit.p, fit.sigma) if robust else np.ones(test.n_observations, bool))
    keep = np.concatenate(keeps)
    return figures(
        np.concatenate(preds), np.concatenate(meas), _measure_unit(profile), keep
    ), time.perf_counter() - start


def error_clusters(profile: Profile, data: Dataset) -> np.ndarray | None:
    """Configurations whose observations share joint-reading errors, as one label per configuration.

    Observations of one configuration share its joint readings' errors (encoder quantisation,
    backlash), and so do configurations that repeat the target chain's readings (a NAO stance seen
    in three head postures). None when every observation stands alone (one per configuration, no
    repeated target-side readings): then the errors are independent.
    """
    sensor_frame = profile.sensors[profile.data.sensor].frame
    sensor_joints = {profile.frames[f].joint for f in profile.chain(sensor_frame)}
    target_joints = set()
    for t in np.unique(data.target):
        target_joints |= {profile.frames[f].joint for f in profile.chain(profile.targets[t].frame)}
    cols = sorted(j for j in target_joints - sensor_joints if j >= 0)
    key = np.column_stack([np.round(np.nan_to_num(data.joints[:, cols]), 9), np.zeros(data.n_configurations)])
    first_target = np.zeros(data.n_configurations, int)
    first_target[data.cfg[::-1]] = data.target[::-1]
    key[:, -1] = first_target
    _, label = np.unique(key, axis=0, return_inverse=True)
    label = label.ravel()
    if len(np.unique(label)) == data.n_observations:
        return None
    return label


def inliers(profile: Profile, data: Dataset, p: np.ndarray, sigma: float) -> np.ndarray:
    """Observations that calibration p, with residual scale `sigma`, explains (not failed detections)."""
    problem = Problem(profile, data, [], p)
    r = problem.residuals(np.zeros(0))[: problem.n_data_rows]
    norms = np.sqrt(block_norms_sq(r, problem.dim))
    return norms <= sigma * outlier_limit(problem.sensor, problem.dim)


def outlier_limit(sensor: Sensor, dim: int) -> float:
    """How many robust sigmas make an outlier: the sensor's declared `noise.outliers`, else the
    99.99% quantile. A detector fails now and then (a misread corner); a laser tracker does not, and
    the heavy tail of a real robot's model error is not an outlier, so its profile sets a wide limit."""
    return float(sensor.noise.get("outliers", np.sqrt(chi2.ppf(OUTLIER_QUANTILE, dim))))


def outliers_of(r: np.ndarray, dim: int, limit: float) -> np.ndarray:
    """Observations beyond `limit` times the residuals' robust spread."""
    norms = np.sqrt(block_norms_sq(r, dim))
    return norms > robust_sigma(r, dim) * limit


def robust_sigma(r: np.ndarray, dim: int) -> float:
    """Scale of whitened residual blocks from their median norm (|r|^2 ~ sigma^2 chi2(dim))."""
    norms = np.sqrt(block_norms_sq(r, dim))
    norms = norms[norms > 0]
    if len(norms) == 0:
        return 1.0
    return float(np.median(norms) / np.sqrt(chi2.ppf(0.5, dim)))


def _dim(profile: Profile) -> int:
    return 3 if profile.sensors[profile.data.sensor].model == "point3d" else 2


def _measure_unit(profile: Profile) -> str:
    return "px" if profile.sensors[profile.data.sensor].model == "pinhole" else profile.length_unit


def _result(
    profile: Profile,
    data: Dataset,
    train: Dataset,
    mode: str,
    method: str,
    fit: Fit,
    p_base: np.ndarray,
    figs: dict[str, Figures],
    solver: dict,
    test_idx: np.ndarray,
) -> Calibration:
    problem = fit.problem
    r, J = problem.residuals_jacobian(fit.p[problem.free])
    clusters = error_clusters(profile, train)
    rep = report(J, r, fit.sigma, None if clusters is None else np.repeat(clusters[train.cfg], problem.dim))
    std_of = {}
    for k, i in enumerate(problem.free):
        std_of[i] = float(rep.std[k]) if rep.std is not None else None
    ties = {t.follower: t for t in profile.mode(mode).ties}
    dep_note = {d.fixed: d.describe(profile) for d in fit.dependencies}
    nominal = profile.nominal()
    params = []
    for i in range(len(profile.parameters)):
        estimated = i in std_of
        std = std_of.get(i)
        note = None
        tie = ties.get(i)
        if tie is not None and tie.leader in std_of:
            estimated = True
            std = std_of[tie.leader]
            note = f"tied: {'-' if tie.sign < 0 else ''}{profile.label(tie.leader)}"
        if i in dep_note:
            note = dep_note[i]
        params.append(parameter_estimate(profile, i, fit.p, p_base, estimated=estimated, std=std, note=note))
    corr = strong_correlations(profile, rep.correlation, problem.free) if rep.correlation is not None else []
    unit = figs["after"].unit
    norms = np.linalg.norm(problem.predict(fit.p) - train.measured, axis=1)
    outliers = [
        Outlier(
            int(train.frame_ids[train.cfg[k]]),
            None if train.lines is None else int(train.lines[k]),
            float(norms[k]),
            unit,
        )
        for k in np.flatnonzero(~problem.included)
    ]
    warnings = [d.describe(profile) for d in fit.dependencies]
    warnings += weak_parameters(profile, rep, problem.free, frozenset(registration_params(profile)))
    if outliers:
        frames = sorted({o.frame for o in outliers})
        shown = ", ".join(str(f) for f in frames[:10]) + (" ..." if len(frames) > 10 else "")
        warnings.append(f"{len(outliers)} observations rejected as outliers (frames {shown})")
    bounded = [
        profile.label(i)
        for i in problem.free
        if i in profile.mode(mode).bounds and abs(fit.p[i] - nominal[i]) >= profile.mode(mode).bounds[i] * (1 - 1e-9)
    ]
    if bounded:
        warnings.append(
            f"{', '.join(bounded)} stopped at the bound the profile allows: the data push further than a "
            "physical error would (a wrong nominal value, or data from another set-up?)"
        )
    if method == "lm" and solver["status"] == "maximum iterations reached":
        warnings.append("the solver stopped at its iteration limit: the result may not be converged")
    if "holdout_after" in figs and figs["holdout_after"].rms > 1.5 * figs["after"].rms:
        warnings.append(
            f"held-out RMS {figs['holdout_after'].rms:.3g} {unit} is much worse than training RMS "
            f"{figs['after'].rms:.3g} {unit}: the calibration may not generalise "
            "(too few or too similar configurations)"
        )
    misfit = REGISTRATION_MISFIT_M / LENGTH_IN_M[profile.length_unit]
    if set(registration_params(profile)) & set(problem.free) and figs["before"].rms > misfit:
        warnings.append(
            f"with only the registration fitted the model is {figs['before'].rms:.3g} {unit} RMS off: are these rows "
            "from one tracker set-up and the arm the data say? Calibrate each set-up on its own (calib solve --where)"
        )
    if figs["after"].rms > figs["before"].rms:
        warnings.append("the calibration fits the data worse than its starting point")
    ident = {
        "singular_values": rep.singular_values,
        "rank": rep.rank,
        "free": [profile.parameters[i].name for i in problem.free],
        "condition": rep.condition,
        "o1": rep.o1,
        "held_fixed": [
            {"parameter": profile.parameters[d.fixed].name, "message": d.describe(profile)} for d in fit.dependencies
        ],
        "correlations": [{"a": a, "b": b, "rho": rho} for a, b, rho in corr],
        "inflation": {profile.parameters[i].name: float(v) for i, v in zip(problem.free, rep.inflation, strict=True)}
        if rep.inflation is not None
        else {},
        "note": "computed on the Jacobian of the noise-weighted residuals with unit-length columns",
    }
    return Calibration(
        robot=profile.name,
        mode=mode,
        method=method,
        created=datetime.now(UTC).isoformat(timespec="seconds"),
        source=data.source,
        parameters=params,
        figures=figs,
        solver=solver,
        identifiability=ident,
        outliers=outliers,
        warnings=warnings,
        frames={
            "train": [int(f) for f in train.frame_ids],
            "holdout": [int(data.frame_ids[i]) for i in test_idx],
        },
    )
