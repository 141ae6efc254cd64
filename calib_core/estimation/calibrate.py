"""Daily and full calibration: from a dataset (one sensor or several) and a mode to a Calibration.

The procedure, for the Levenberg-Marquardt method:
1. At the start values, find the parameter directions the data cannot determine and hold one
   parameter of each at its base value (named in the report), so nothing wanders.
2. Least squares from the base calibration (or the nominal model) to the basin of the solution. If
   that solution stays far above the noise and the mode estimates a pose nobody measured (a camera's
   mount), several starts (`starts`), the lowest cost kept.
   With several sensors, each is then weighed by its actual scatter (one step of variance-component
   estimation), so that a declared noise that is too optimistic for one of them does not let it
   drown the others.
3. With the robust loss (default): re-solve with a Cauchy loss scaled to each sensor's robust
   spread, then flag observations beyond the 99.99% quantile of that spread as outliers and solve
   once more on the rest (plain least squares, so the covariance is the textbook one).
4. At the solution: standard deviations and correlations, singular values, condition and O1, and per
   sensor a chi-square test of the residuals against its declared noise (`noise_test`).
The held-out share and the k-fold cross-validation repeat steps 1-3 on the training part only.
Self-observation with several cameras, a tracker with cameras, several planes: the same procedure.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import replace
from datetime import UTC, datetime

import numpy as np

from ..dataset import Dataset
from ..errors import InputError
from ..model.profile import AUTO, Mode, Profile
from .calibration import Calibration, Covariance, Outlier, parameter_estimate
from .chi_square import upper_quantile
from .diagnostics import diagnose, richer_mode
from .fit import Fit
from .identifiability import Dependency, find_dependencies, identifiability_report, minimal_set, report
from .model_choice import choose
from .noise_test import noise_tests, sensor_scatter
from .outliers import OutlierVerdict, inliers, pooled_robust_sigma, problem_outliers, robust_sigma, sort_outliers
from .problem import Problem
from .registration import register, registration_params
from .reports import Diagnostic, ModelChoice, Severity, SolverReport
from .solver import Robust, SolveResult, levenberg_marquardt, nelder_mead
from .starts import SOLVED_STARTS, Start, closed_form_starts, far_above_noise, turned_starts, unknown_poses
from .validation import Figures, check_share, holdout_split, kfold_splits, sensor_figures

METHODS = ("lm", "nelder-mead")


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
    minimal: bool = False,
    progress: Callable[[int, float], None] | None = None,
    should_stop: Callable[[], bool] | None = None,
) -> Calibration:
    """Estimate the parameters of `mode` from `data`, starting from `base` (or the nominal model).

    `mode` `auto`: the profile's mode and the strength of its priors that predict the training configurations
    best in cross-validation (calib_core.estimation.model_choice); the calibration is named `auto` and says what
    was chosen and why (`choice`, and a `model-choice` note). With `folds`, its cross-validated figures repeat the
    choice in every fold.
    `minimal`: estimate a minimal identifiable set of the mode's parameters, chosen by QR with column
    pivoting at the start values, without the mode's priors; the others are held (and named)."""
    m = profile.mode(mode)
    if method not in METHODS:
        raise InputError(f"unknown method '{method}' ({', '.join(METHODS)})")
    check_share(holdout)
    auto = mode == AUTO
    if auto and minimal:
        raise InputError("mode 'auto' chooses the strength of the priors and a minimal set has none: choose a mode")
    if not auto:
        data = sensors_of(profile, data, m)
    if holdout > 0:
        train_idx, test_idx = holdout_split(data, holdout, seed)
    else:
        train_idx, test_idx = np.arange(data.n_configurations), np.array([], int)
    train = data.select(train_idx)
    choice = None

    def fit_mode(part: Dataset, candidate: Mode, near: Fit | None = None) -> Fit:
        return _fit_mode(profile, part, candidate, base, method, robust, should_stop, near)

    def fit_candidate(part: Dataset, candidate: Mode, near: Fit | None = None) -> Fit:
        return _fit_mode(profile, part, candidate, base, method, robust, should_stop, near, precise=False)

    if auto:
        m, choice = choose(profile, train, fit_candidate, robust=robust, seed=seed, should_stop=should_stop)
    chosen = m
    m = observed_mode(profile, train, m)
    p_base = start_values(profile, train, m, base)
    _check_rows(profile, train, m, p_base)
    fit = fit_parameters(
        profile,
        train,
        m,
        p_base,
        method=method,
        robust=robust,
        minimal=minimal,
        progress=progress,
        should_stop=should_stop,
    )
    figs, each = _figures(profile, train, fit, p_base, data.select(test_idx) if len(test_idx) else None, robust)
    solver = SolverReport(
        method=method,
        status=fit.status,
        iterations=fit.iterations,
        evaluations=fit.evaluations,
        solve_seconds=fit.seconds,
        robust=robust,
        cost_history=fit.cost_history,
        sigma=fit.sigma,
        minimal=minimal,
        noise_tests=fit.noise_tests,
        starts=fit.starts,
        start=fit.start,
    )
    if folds >= 2:
        start = time.perf_counter()

        def fit_part(part: Dataset) -> Fit:
            if auto:  # the choice too is made without the fold's held-out part
                return fit_mode(
                    part, choose(profile, part, fit_candidate, robust=robust, seed=seed, should_stop=should_stop)[0]
                )
            return fit_parameters(
                profile, part, m, p_base, method=method, robust=robust, minimal=minimal, should_stop=should_stop
            )

        figs["cv_after"] = cross_validate(profile, train, fit_part, folds, robust, seed)
        solver.folds, solver.cv_seconds = folds, time.perf_counter() - start
    frames = {"train": [int(f) for f in train.frame_ids], "holdout": [int(data.frame_ids[i]) for i in test_idx]}
    cal = _result(profile, data, train, chosen, fit, p_base, figs, each, solver, frames, choice)
    if not auto and len(test_idx) and any(t.rejected and not t.warns for t in fit.noise_tests):
        better = _richer_predicts(profile, train, data.select(test_idx), m, fit, base, method, robust, should_stop)
        if better is not None:
            cal.diagnostics.append(better)
    return cal


def _fit_mode(
    profile: Profile,
    data: Dataset,
    mode: Mode,
    base: Calibration | None,
    method: str,
    robust: bool,
    should_stop: Callable[[], bool] | None,
    near: Fit | None = None,
    precise: bool = True,
) -> Fit:
    """`mode` fitted on `data` as `calibrate` fits it on its training part (InputError where it cannot be);
    `near`, `precise`: see `fit_parameters`."""
    mode = observed_mode(profile, data, mode)
    p_start = start_values(profile, data, mode, base)
    _check_rows(profile, data, mode, p_start, near)
    return fit_parameters(
        profile, data, mode, p_start, method=method, robust=robust, should_stop=should_stop, near=near, precise=precise
    )


def _richer_predicts(
    profile: Profile,
    train: Dataset,
    test: Dataset,
    mode: Mode,
    fit: Fit,
    base: Calibration | None,
    method: str,
    robust: bool,
    should_stop: Callable[[], bool] | None,
) -> Diagnostic | None:
    """A fit within a fifth of its sensors' noise is a line in the report, not a warning (noise-scatter), unless the
    profile's next richer mode, fitted on the same training data, predicts the held-out data better: by more than
    RICHER_MARGIN of their mean error and two standard errors of the difference over the held-out configurations."""
    name, clause = richer_mode(profile, mode, [observed_mode(profile, train, m) for m in profile.modes.values()])
    units = {profile.sensors[s].unit for s in np.unique(test.sensor)}
    if name is None or len(units) != 1 or test.n_configurations < 3:
        return None
    rich = observed_mode(profile, train, profile.mode(name))
    richer_fit = fit_parameters(
        profile, train, rich, start_values(profile, train, rich, base), method=method, robust=robust,
        should_stop=should_stop,
    )  # fmt: skip
    now, then = _configuration_errors(profile, test, fit.p), _configuration_errors(profile, test, richer_fit.p)
    gain = now - then
    se = float(np.std(gain, ddof=1) / np.sqrt(len(gain)))
    if not (gain.mean() > 2 * se and gain.mean() > RICHER_MARGIN * now.mean()):
        return None
    unit = units.pop()
    return Diagnostic(
        Severity.WARNING,
        "richer-predicts",
        f"mode '{name}' predicts the held-out data better: {then.mean():.3g} against {now.mean():.3g} {unit} mean "
        f"error ({100 * gain.mean() / now.mean():.0f}% less, {gain.mean() / se:.1f} standard errors over "
        f"{len(gain)} held-out configurations), though this fit is within a fifth of the declared noise; {clause}",
        mode=name,
    )


def _configuration_errors(profile: Profile, data: Dataset, p: np.ndarray) -> np.ndarray:
    """Each configuration's mean distance between measured and predicted, the sensors' unit."""
    problem = Problem(profile, data, [], p, noise_model=False)
    r = problem.raw_residuals(np.zeros(0))
    error = np.zeros(data.n_observations)
    for b in problem.blocks:
        error[b.obs] = np.linalg.norm(r[b.rows].reshape(-1, b.dim), axis=1)
    return np.bincount(data.cfg, weights=error) / np.maximum(np.bincount(data.cfg), 1)


def check_can_fit(profile: Profile, data: Dataset, mode: str, base: Calibration | None = None) -> None:
    """Refuse (InputError) data from which `calibrate` cannot estimate `mode`, as it would on these data
    as its training part: a registration these data need that neither the mode nor a base gives, or too few
    observations (`_check_rows`). Mode `auto`: when none of the profile's modes can be estimated from them (the
    first one's reason)."""
    if mode == AUTO:
        refusals = []
        for name in profile.modes:
            try:
                return check_can_fit(profile, data, name, base)
            except InputError as exc:
                refusals.append(exc)
        raise refusals[0]
    m = profile.mode(mode)
    data = sensors_of(profile, data, m)
    m = observed_mode(profile, data, m)
    _check_rows(profile, data, m, start_values(profile, data, m, base))


def start_values(profile: Profile, data: Dataset, mode: Mode, base: Calibration | None) -> np.ndarray:
    """Where the solver starts: the base calibration (or the nominal model), with each tracker's
    registration fitted in closed form when the mode estimates it (a tracker set-up of its own: "before"
    is the old model with only the registration fitted). A tracker whose pose is neither estimated nor
    known from a base is refused."""
    p = base.params(profile) if base is not None else profile.nominal()
    reg = set(registration_params(profile, data.sensors, np.unique(data.target).tolist()))
    if reg and not reg & set(mode.free) and base is None:
        frames = [f.name for f in profile.frames if f.registration and {op.param for op in f.ops} & reg]
        raise InputError(
            f"mode '{mode.name}' does not estimate the registration of '{', '.join(frames)}' (where it stands), "
            "which these data need: choose a mode that does, or start from a calibration of the same set-up (--base)"
        )
    return register(profile, data, p) if reg & set(mode.free) else p


def _check_rows(profile: Profile, data: Dataset, mode: Mode, p_start: np.ndarray, near: Fit | None = None) -> None:
    """Refuse only observations that leave nothing to check a fit: no parameter of the mode stays free, or
    the rows are no more than the parameters they determine (each row then goes to fixing a parameter,
    and the fit passes through every observation, noise and all). Parameters the data cannot tell apart
    are held and named by the fit (`find_dependencies`), so a mode with more parameters than rows is
    refused only when the rows do not exceed what they determine. `near`: see `fit_parameters`."""
    rows = sum(profile.sensors[s].dim * int(np.sum(data.sensor == s)) for s in data.sensors)
    n = len(mode.free)
    if rows > n:  # more rows than parameters: some are left over, whatever the data determine
        return
    problem = Problem(profile, data, list(mode.free), p_start, mode.ties)
    J = problem.residuals_jacobian(problem.x0)[1][: problem.n_data_rows]
    held = len(_dependencies(profile, problem.free, J, near)[2])
    free = n - held
    if free == 0:
        raise InputError(
            f"{data.n_observations} observations determine none of the {n} parameters of mode '{mode.name}' "
            "(no parameter changes what they predict): measure configurations that move the parameters",
            file=data.source,
        )
    if rows <= free:
        raise InputError(
            f"{data.n_observations} observations ({rows} rows) cannot calibrate mode '{mode.name}': they would fix "
            f"{free} of its {n} parameters exactly ({held} more held: the data cannot tell them apart), with no row "
            "left to check the fit against the noise: measure more configurations, or choose a mode with fewer "
            "parameters",
            file=data.source,
        )


def sensors_of(profile: Profile, data: Dataset, mode: Mode) -> Dataset:
    """The observations of the sensors a mode fits (all of them unless the mode names its sensors)."""
    if mode.sensors is None or set(data.sensors) <= set(mode.sensors):
        return data
    keep = np.isin(data.sensor, mode.sensors)
    if not keep.any():
        names = ", ".join(profile.sensors[s].name for s in mode.sensors)
        have = ", ".join(profile.sensors[s].name for s in data.sensors)
        raise InputError(f"mode '{mode.name}' fits observations of {names}; these data hold {have}", file=data.source)
    return data.observations(keep)


def observed_mode(profile: Profile, data: Dataset, mode: Mode) -> Mode:
    """The mode without the parameters no observation depends on: those of chains the data do not
    use (the other arm of a two-armed robot), the points of targets never seen and the intrinsics
    of sensors that saw nothing."""
    sensors = [profile.sensors[s] for s in data.sensors]
    targets = [profile.targets[t] for t in np.unique(data.target)]
    frames = set().union(*(profile.chain(s.frame) for s in sensors), *(profile.chain(t.frame) for t in targets))
    used = {op.param for f in frames for op in profile.frames[f].ops}
    used |= {i for t in targets for i in (t.point_params or ())}
    used |= {i for s in sensors for i in s.direct_params()}
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
    minimal: bool = False,
    progress: Callable[[int, float], None] | None = None,
    should_stop: Callable[[], bool] | None = None,
    near: Fit | None = None,
    precise: bool = True,
) -> Fit:
    """Steps 1-3 of the module doc on `data`: the estimate, how the solver got there, the scales.
    `minimal`: see `calibrate`. `near`: the fit of a nearby model on the same data (mode `auto` fits its
    candidates one after another, the next prior width from the last one's estimate): Levenberg-Marquardt starts
    from its estimate instead of p_base, nearly Gauss-Newton, and where it looked for dependencies among the same
    parameters with the same Jacobian, what it found stands. `precise=False`: the last solve too stops once the next
    step would gain less than 1e-6 of the cost (its estimate within 0.06 sd of the optimum at most), as mode
    `auto`'s candidates are fitted: what they predict of the configurations they did not see moves by far less than
    it differs between folds (the same choices and held-out figures on FIGAROH's splits in 10-20% less CPU,
    benchmarks/fit_speed.py)."""
    start = time.perf_counter()
    priors = {} if minimal else mode.priors
    problem = Problem(profile, data, list(mode.free), p_base, mode.ties, priors, readings=True)
    initial: tuple[np.ndarray, np.ndarray] | None = problem.residuals_jacobian(problem.x0)
    J = initial[1][: problem.n_data_rows]
    found = _dependencies(profile, problem.free, J, near)
    deps = list(found[2])
    if minimal:
        kept = [k for k, i in enumerate(problem.free) if i not in {d.fixed for d in deps}]
        first = frozenset(registration_params(profile, data.sensors))
        deps += minimal_set(profile, J[:, kept], [problem.free[k] for k in kept], first)
    if deps:
        fixed = {d.fixed for d in deps}
        free = [i for i in mode.free if i not in fixed]
        problem = Problem(profile, data, free, p_base, mode.ties, priors, noise_model=problem.weights, readings=True)
        initial = None
    passes = _Passes(problem, mode, profile, progress, should_stop, precise)
    if method == "nelder-mead":
        segments = [(b.rows, b.dim) for b in problem.blocks]
        passes.absorb(nelder_mead(problem.raw_residuals, problem.x0, segments, should_stop=should_stop))
    else:
        # A tracker's registration starts from its closed-form fit (`register`), a bounded pose near its start.
        settled = frozenset(registration_params(profile, data.sensors)) | frozenset(mode.bounds)
        x0 = None if near is None else near.p[problem.free]
        passes.least_squares(initial, robust, unknown_poses(profile, problem.free, settled), x0)
    res = passes.last
    x = res.x
    r = problem.residuals(x)
    n_free = len(problem.free)
    n_in = sum(int(problem.included[b.obs].sum()) * b.dim for b in problem.blocks)
    fitted = np.concatenate([r[: problem.n_data_rows], r[problem.reading_rows]])
    sigma = float(np.sqrt(np.sum(fitted**2) / max(n_in - n_free, 1)))
    # Per sensor, of the residuals whitened by its noise model alone (as `inliers` computes them: with the
    # readings' rounding in each observation's covariance, where the fit eliminated it).
    plain, r_plain = problem, r
    if problem.readings is not None:
        # The noise test weighs the readings' rounding as the fit's corrections do: their Jacobian at the first fit.
        Jq = problem.readings.Jq
        plain = Problem(profile, data, [], problem.params(x), probes=problem.probes, rounding_jacobian=Jq)
        plain.included = problem.included
        plain.share_predictions(problem)
        r_plain = plain.residuals(np.zeros(0))
    sigmas = {
        s: float(np.sqrt(total / max(dof, 1))) for s, (total, _, dof) in sensor_scatter(plain, r_plain, n_free).items()
    }
    return Fit(
        problem,
        problem.params(x),
        deps,
        passes.iterations,
        passes.evaluations,
        time.perf_counter() - start,
        res.status,
        passes.history,
        sigma,
        sigmas,
        passes.verdict,
        noise_tests(plain, r_plain, n_free),
        passes.starts,
        passes.start,
        found,
    )


def _dependencies(
    profile: Profile, free: list[int], J: np.ndarray, near: Fit | None
) -> tuple[list[int], np.ndarray, list[Dependency]]:
    """`find_dependencies` among `free` in the data rows' Jacobian J at the start values, with what they were found
    on (Fit.found): `near`'s where it looked among the same parameters in the same Jacobian."""
    if near is not None and near.found is not None and near.found[0] == free and np.array_equal(near.found[1], J):
        return near.found
    return free, J, find_dependencies(profile, J, free)


class _Passes:
    """The solver passes of one fit, their counts and cost history."""

    def __init__(
        self,
        problem: Problem,
        mode: Mode,
        profile: Profile,
        progress: Callable[[int, float], None] | None,
        should_stop: Callable[[], bool] | None,
        precise: bool = True,
    ) -> None:
        self.problem, self.progress, self.should_stop = problem, progress, should_stop
        self.precise = precise
        self.lower, self.upper = box(profile, mode, problem.free)
        self.iterations = self.evaluations = 0
        self.history: list[float] = []
        self.last: SolveResult
        self.verdict: OutlierVerdict | None = None
        self.starts, self.start = 1, "the start values"  # start vectors tried, and the one that won

    def absorb(self, res: SolveResult) -> None:
        self.iterations += res.iterations
        self.evaluations += res.evaluations
        self.history.extend(res.cost_history)
        self.last = res

    def run(
        self, x0: np.ndarray, loss: Robust | None, start: tuple | None = None, near: bool = False, rough: bool = False
    ) -> np.ndarray:
        """One solve from x0; `near`: x0 is the solution of the problem weighed a little differently; `rough`: a
        refit from the solution follows (the readings' scales, the sensors' and the priors' weights), so it stops
        short of the last digits."""
        done = self.iterations

        def tick(it: int, cost: float) -> None:
            if self.progress is not None:
                self.progress(done + it, cost)

        # The robust pass only has to sort inliers from outliers (IRLS converges linearly), so it
        # stops early; the least-squares passes converge quadratically to full precision, but for a refit from the
        # solution of the problem weighed a little differently: it stops once the next step would gain less than
        # 1e-6 of the cost (its estimate within 0.06 sd of the optimum at most), usually after one step.
        self.absorb(
            levenberg_marquardt(
                self.problem.residuals_jacobian,
                x0,
                fun=self.problem.residuals,
                initial=start,
                robust=loss,
                ftol=1e-6 if loss or near or not self.precise else 1e-5 if rough else 1e-10,
                progress=tick,
                should_stop=self.should_stop,
                lower=self.lower,
                upper=self.upper,
                damping=NEAR_DAMPING if near else 1e-3,
            )
        )
        return self.last.x

    def least_squares(
        self, initial: tuple | None, robust: bool, poses: list[tuple[str, list[int]]], x0: np.ndarray | None = None
    ) -> None:
        """`poses`: the free poses nobody measured (`unknown_poses`), turned when the first solution stays
        far above the noise, when the other closed-form starts of a camera's registration are tried too. `x0`:
        where the first solve starts, in the box (a nearby fit's estimate; `initial` is at the problem's x0)."""
        problem = self.problem
        # The problem is weighed anew at the first solution (the readings' scales, each sensor's scatter, the priors
        # against it) and solved again from there: the first need not reach the last digits.
        rough = problem.readings is not None or len(problem.blocks) > 1 or bool(problem.priors)
        if x0 is None:
            x = self.run(problem.x0, None, initial, rough=rough)
        else:
            x = self.run(np.clip(x0, self.lower, self.upper), None, near=True, rough=rough)
        if far_above_noise(problem, problem.residuals(x)):
            starts = turned_starts(problem, problem.x0, poses, self.should_stop) + closed_form_starts(problem)
            if starts:
                x = self.best_start(starts)
        if problem.readings is not None:
            x = self.reading_scales(x)
        if len(problem.blocks) > 1 or problem.priors:
            if len(problem.blocks) > 1 and problem.readings is None:
                # Each sensor weighed by its actual scatter, not only its declared noise.
                r = problem.residuals(x)
                for b in problem.blocks:
                    b.scale = robust_sigma(r[b.rows], b.dim)
            # A prior's sigma is meant against the residuals' actual scale (a MAP estimate), not
            # the declared sensor noise: on a real robot the model error outweighs the noise.
            problem.prior_scale = pooled_robust_sigma(problem, problem.residuals(x))
            x = self.run(x, None)
        # Outliers show in the least-squares residuals; only then is the robust pass worth its time.
        if robust and len(problem.free) and problem_outliers(problem, problem.residuals(x)).any():
            r = problem.residuals(x)
            problem.prior_scale = pooled_robust_sigma(problem, r)
            scale = {
                b.index: robust_sigma(r[b.rows], b.dim) * np.sqrt(upper_quantile(b.dim, 0.05)) for b in problem.blocks
            }
            x = self.run(x, Robust([(b.rows, b.dim, scale[b.index]) for b in problem.blocks]))
            r = problem.residuals(x)
            # Beyond the limit is not enough: only what no smooth model predicts is a gross error.
            self.verdict = sort_outliers(problem, x, problem_outliers(problem, r))
            problem.included = ~self.verdict.gross
            problem.prior_scale = pooled_robust_sigma(problem, r)
            self.run(x, None)

    def reading_scales(self, x: np.ndarray) -> np.ndarray:
        """Each configuration's observations of a sensor weighed by their actual scatter against the readings'
        rounding, whose size is known (a detector measures a board seen obliquely worse than one seen face on):
        the scatter of their rows after the elimination over the degrees of freedom the corrections and the
        parameters leave them (`ReadingErrors.leverage`), shrunk towards the sensor's pooled scatter
        (SCALE_PRIOR_DOF; the pooled one alone below FRAME_SCALE_DOF), refitted until it settles; never below
        MIN_SCALE of the declared noise. Returns the solution at the scales found."""
        problem = self.problem
        assert problem.readings is not None
        M, N = problem.data.n_observations, problem.data.n_configurations
        obs_of_row = np.concatenate([np.repeat(np.arange(M)[b.obs], b.dim) for b in problem.blocks])
        block_of_obs = np.zeros(M, int)
        for k, b in enumerate(problem.blocks):
            block_of_obs[b.obs] = k
        group_of_obs = block_of_obs * N + problem.data.cfg
        _, group_of_obs = np.unique(group_of_obs, return_inverse=True)
        group_of_row = group_of_obs[obs_of_row]
        block_of_group = np.zeros(group_of_obs.max() + 1, int)
        block_of_group[group_of_obs] = block_of_obs
        free_share = len(problem.free) / max(problem.n_data_rows, 1)
        problem.relinearise_readings(x)
        for _ in range(SCALE_PASSES):
            # The scales settle at this x first (the predictions do not change with them: only the whitening and
            # the elimination are computed again), then the fit at them; a pass whose scales settled at once ends.
            # Each update moves a scale about two thirds of the way (the shrinkage and the elimination pull it
            # back): from the second update on, the rest of the way is taken too (Aitken's extrapolation).
            before, updated = None, False
            for _ in range(SCALE_UPDATES):
                r = problem.residuals(x)[: problem.n_data_rows]
                leverage = problem.readings.leverage(problem.n_data_rows)
                used = problem.included[obs_of_row]
                total = np.bincount(group_of_row, r**2)
                dof = np.bincount(group_of_row, used * (1.0 - leverage - free_share))
                pooled = np.bincount(block_of_group, total) / np.maximum(np.bincount(block_of_group, dof), 1e-9)
                own = (total + SCALE_PRIOR_DOF * pooled[block_of_group]) / (np.maximum(dof, 0.0) + SCALE_PRIOR_DOF)
                step = 0.5 * np.log(np.where(dof >= FRAME_SCALE_DOF, own, pooled[block_of_group]))
                if np.max(np.abs(step)) < SCALE_SETTLED:
                    break
                updated, move = True, step
                if before is not None:
                    shrink = np.clip(np.divide(step, before, out=np.zeros_like(step), where=before != 0), 0.0, 0.8)
                    move = step / (1.0 - shrink)
                before = step
                problem.obs_scale = np.maximum(problem.obs_scale * np.exp(move)[group_of_obs], MIN_SCALE)
            if not updated:
                break  # settled at this fit: it is the fit at its scales
            x = self.run(x, None, near=True)
        return x

    def best_start(self, starts: list[Start]) -> np.ndarray:
        """The lowest-cost solution: the last one's, or one from the best few of `starts` (by their cost
        before the full solve)."""
        best = self.last
        for start in sorted(starts, key=lambda s: s.cost)[:SOLVED_STARTS]:
            self.run(start.x, None)
            if self.last.cost < best.cost:
                best, self.start = self.last, start.label
        self.starts += len(starts)
        self.last = best
        return best.x


RICHER_MARGIN = 0.02  # a richer mode's held-out error this much lower (and beyond 2 standard errors) is a warning
SCALE_PASSES = 6  # refits at most while the observations' scales settle against the readings' rounding
SCALE_UPDATES = 12  # updates of the scales at one fit at most
NEAR_DAMPING = 1e-7  # the first step's damping from a nearby solution: nearly Gauss-Newton
SCALE_SETTLED = 0.02  # a scale that changed less than 2% has settled
SCALE_PRIOR_DOF = 20.0  # a configuration's own scatter weighs as this many rows more of its sensor's pooled one
# A configuration's observations of a sensor get a scale of their own only with this many degrees of freedom (a
# board's 24 vertices); fewer (a tracker's two bodies) keep the sensor's: weights fitted to a few rows each follow
# their noise, and the reported standard deviations come out a quarter too small (tests/test_pose6d.py).
FRAME_SCALE_DOF = 24.0
# The least scale of the declared noise: with scatter far below it (exact simulated pixels) the corrections'
# linearisation error, not the noise, would set the weights.
MIN_SCALE = 0.1


def cross_validate(
    profile: Profile, data: Dataset, fit: Callable[[Dataset], Fit], folds: int, robust: bool, seed: int
) -> Figures:
    """Pooled held-out figures: every configuration predicted by a calibration (`fit` of the other folds) that did
    not see it."""
    parts = []
    for train_idx, test_idx in kfold_splits(data, folds, seed):
        if len(test_idx) == 0 or len(train_idx) == 0:
            continue
        result = fit(data.select(train_idx))
        test = data.select(test_idx)
        keep = inliers(profile, test, result.p, result.sigmas) if robust else None
        parts.append((test, _predict(profile, test, result.p), keep))
    return sensor_figures(profile, parts)[0]


def error_clusters(profile: Profile, data: Dataset) -> np.ndarray | None:
    """Configurations whose observations share joint-reading errors, as one label per configuration.

    Observations of one configuration share its joint readings' errors (encoder quantisation,
    backlash), and so do configurations that repeat the target chain's readings (a NAO stance seen
    in three head postures). A target no joint moves relative to the sensor's chain (a board on the
    table seen by a camera on the flange) repeats no readings: each configuration is its own cluster.
    None when every observation stands alone (one per configuration, no repeated target-side
    readings): then the errors are independent.
    """
    sensor_joints = {profile.frames[f].joint for s in data.sensors for f in profile.chain(profile.sensors[s].frame)}
    target_joints = set()
    for t in np.unique(data.target):
        target_joints |= {profile.frames[f].joint for f in profile.chain(profile.targets[t].frame)}
    cols = sorted(j for j in target_joints - sensor_joints if j >= 0)
    if cols:
        key = np.column_stack([np.round(np.nan_to_num(data.joints[:, cols]), 9), np.zeros(data.n_configurations)])
        first_target = np.zeros(data.n_configurations, int)
        first_target[data.cfg[::-1]] = data.target[::-1]
        key[:, -1] = first_target
        _, label = np.unique(key, axis=0, return_inverse=True)
        label = label.ravel()
    else:
        label = np.arange(data.n_configurations)
    if len(np.unique(label)) == data.n_observations:
        return None
    return label


def _figures(
    profile: Profile, train: Dataset, fit: Fit, p_base: np.ndarray, test: Dataset | None, robust: bool
) -> tuple[dict[str, Figures], dict[str, dict[str, Figures]]]:
    """Before/after on the training data, and on the held-out data: pooled, and per sensor."""
    keep = fit.problem.included
    figs, each = {}, {}
    runs = [("before", train, p_base, keep), ("after", train, fit.p, keep)]
    if test is not None:
        test_keep = inliers(profile, test, fit.p, fit.sigmas) if robust else None
        runs += [("holdout_before", test, p_base, test_keep), ("holdout_after", test, fit.p, test_keep)]
    for name, data, p, k in runs:
        figs[name], per = sensor_figures(profile, [(data, _predict(profile, data, p), k)])
        for sensor, f in per.items():
            each.setdefault(sensor, {})[name] = f
    return figs, (each if len(each) > 1 else {})


def _predict(profile: Profile, data: Dataset, p: np.ndarray) -> np.ndarray:
    return Problem(profile, data, [], p, noise_model=False).predict(p)


def _result(
    profile: Profile,
    data: Dataset,
    train: Dataset,
    mode: Mode,
    fit: Fit,
    p_base: np.ndarray,
    figs: dict[str, Figures],
    each: dict[str, dict[str, Figures]],
    solver: SolverReport,
    frames: dict[str, list[int]],
    choice: ModelChoice | None = None,
) -> Calibration:
    """`choice`: what mode `auto` chose (`mode`, which it names AUTO); the calibration says so in a note, and leaves
    out the richer mode a noise test would name (the choice compared it already)."""
    problem = fit.problem
    r, J = problem.residuals_jacobian(fit.p[problem.free])
    # Errors the readings share, where the fit did not eliminate them: a sandwich clustered by configuration.
    clusters = error_clusters(profile, train) if problem.readings is None else None
    rows = None
    if clusters is not None:
        rows = np.concatenate([np.repeat(clusters[train.cfg[b.obs]], b.dim) for b in problem.blocks])
    rep = report(J, r, fit.sigma, rows)
    std_of = {i: (None if rep.std is None else float(rep.std[k])) for k, i in enumerate(problem.free)}
    ties = {t.follower: t for t in mode.ties}
    dep_note = {d.fixed: d.describe(profile) for d in fit.dependencies}
    params = []
    for i in range(len(profile.parameters)):
        estimated, std, note = i in std_of, std_of.get(i), dep_note.get(i)
        tie = ties.get(i)
        if tie is not None and tie.leader in std_of:
            estimated, std = True, std_of[tie.leader]
            note = note or f"tied: {'-' if tie.sign < 0 else ''}{profile.label(tie.leader)}"
        params.append(parameter_estimate(profile, i, fit.p, p_base, estimated=estimated, std=std, note=note))
    pred = problem.predict(fit.p)
    outliers = []
    for k in np.flatnonzero(~problem.included):
        dim = profile.sensors[train.sensor[k]].dim
        error = float(np.linalg.norm(pred[k, :dim] - train.measured[k, :dim]))
        line = None if train.lines is None else int(train.lines[k])
        sigmas = None if fit.verdict is None else float(fit.verdict.sigmas[k])
        frame = int(train.frame_ids[train.cfg[k]])
        outliers.append(Outlier(frame, line, error, profile.sensors[train.sensor[k]].unit, sigmas))
    nuisance = frozenset(registration_params(profile, train.sensors))
    return Calibration(
        robot=profile.name,
        mode=mode.name if choice is None else AUTO,
        method=solver.method,
        created=datetime.now(UTC).isoformat(timespec="seconds"),
        source=data.source,
        parameters=params,
        figures=figs,
        solver=solver,
        identifiability=identifiability_report(profile, rep, problem.free, fit.dependencies),
        outliers=outliers,
        diagnostics=_chosen(choice)
        + diagnose(
            profile,
            observed_mode(profile, train, mode),
            fit,
            rep,
            figs,
            each,
            solver,
            outliers,
            nuisance,
            [observed_mode(profile, train, m) for m in profile.modes.values()] if choice is None else [],
        ),
        frames=frames,
        sensor_figures=each,
        covariance=_covariance(profile, problem, rep.covariance),
        choice=choice,
    )


def _chosen(choice: ModelChoice | None) -> list[Diagnostic]:
    """What mode `auto` chose and each candidate's cross-validated figure, as a note (none for a named mode)."""
    if choice is None:
        return []
    return [Diagnostic(Severity.INFO, "model-choice", choice.describe(), mode=choice.picked.mode)]


def _covariance(profile: Profile, problem: Problem, cov: np.ndarray | None) -> Covariance | None:
    """The free parameters' covariance over every estimated parameter (a tie's follower moves as its leader)."""
    if cov is None:
        return None
    estimated = np.flatnonzero(np.any(problem.A != 0, axis=1))
    A = problem.A[estimated]
    return Covariance.of(profile, estimated.tolist(), A @ cov @ A.T)
