"""Solvers: Levenberg-Marquardt with the exact Jacobian and a robust loss per observation, and the
Robonaut paper's Nelder-Mead search on the sum of distances as the baseline.

The robust loss acts on whole observations (a 3-D point, a pixel), not on single coordinates: with
z = |r_b|^2 / s^2 the Cauchy loss s^2 log(1 + z) gives each observation the weight 1 / (1 + z).
Each LM step solves the reweighted normal equations (iteratively reweighted least squares) and is
accepted only if the robust cost falls, so it converges to a stationary point of the robust cost.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass, field
from enum import Enum

import numpy as np

from ..errors import Cancelled


class SolveStatus(Enum):
    """Why a solver stopped; the value is the sentence shown to people."""

    GRADIENT_VANISHED = "gradient vanished"
    STEP_TOLERANCE = "step below tolerance"
    COST_TOLERANCE = "cost change below tolerance"
    NO_FURTHER_DECREASE = "no step can reduce the cost further"
    SIMPLEX_TOLERANCE = "simplex below tolerance"
    MAX_ITERATIONS = "maximum iterations reached"
    MAX_EVALUATIONS = "maximum evaluations reached"

    @property
    def converged(self) -> bool:
        """Whether the solver reached a minimum (to its tolerances), rather than a limit of work."""
        return self not in (SolveStatus.MAX_ITERATIONS, SolveStatus.MAX_EVALUATIONS)

    @property
    def code(self) -> str:
        return self.name.lower()

    @classmethod
    def from_code(cls, code: str) -> SolveStatus:
        """From a code (`max_iterations`) or, for calibration files written before codes, the text."""
        for status in cls:
            if code in (status.code, status.value):
                return status
        legacy = {
            "converged (no step can reduce the cost further)": cls.NO_FURTHER_DECREASE,
            "Optimization terminated successfully.": cls.SIMPLEX_TOLERANCE,
            "Maximum number of function evaluations has been exceeded.": cls.MAX_EVALUATIONS,
            "Maximum number of iterations has been exceeded.": cls.MAX_ITERATIONS,
        }
        if code in legacy:
            return legacy[code]
        raise ValueError(f"unknown solver status {code!r}")


@dataclass
class SolveResult:
    x: np.ndarray
    cost: float
    iterations: int
    evaluations: int
    seconds: float
    status: SolveStatus
    cost_history: list[float] = field(default_factory=list)


@dataclass
class Robust:
    """Cauchy loss on observation blocks: each segment (rows, dim, scale) is a sensor's data rows,
    observations of `dim` rows each, with its own scale. Rows outside every segment (priors) are
    plain least squares."""

    segments: list[tuple[slice, int, float]]

    def weights(self, r: np.ndarray) -> np.ndarray:
        """Per-row IRLS weights."""
        w = np.ones_like(r)
        for rows, dim, scale in self.segments:
            z = block_norms_sq(r[rows], dim) / scale**2
            w[rows] = np.repeat(1.0 / (1.0 + z), dim)
        return w

    def cost(self, r: np.ndarray) -> float:
        plain = np.ones(len(r), bool)
        total = 0.0
        for rows, dim, scale in self.segments:
            total += scale**2 * float(np.sum(np.log1p(block_norms_sq(r[rows], dim) / scale**2)))
            plain[rows] = False
        return 0.5 * (total + float(r[plain] @ r[plain]))


def block_norms_sq(r: np.ndarray, dim: int) -> np.ndarray:
    return np.sum(r.reshape(-1, dim) ** 2, axis=1)


Progress = Callable[[int, float], None]


def levenberg_marquardt(
    fun_jac: Callable[[np.ndarray], tuple[np.ndarray, np.ndarray]],
    x0: np.ndarray,
    *,
    fun: Callable[[np.ndarray], np.ndarray] | None = None,
    initial: tuple[np.ndarray, np.ndarray] | None = None,
    robust: Robust | None = None,
    max_iterations: int = 100,
    xtol: float = 1e-10,
    ftol: float = 1e-10,
    progress: Progress | None = None,
    should_stop: Callable[[], bool] | None = None,
    lower: np.ndarray | None = None,
    upper: np.ndarray | None = None,
    damping: float = 1e-3,
) -> SolveResult:
    """Minimise 0.5 |r(x)|^2 (or the robust cost) by Levenberg-Marquardt with Marquardt scaling,
    within the box [lower, upper] when given: a variable at a bound that the gradient pushes
    outward leaves the step's system, and every step is projected into the box. `fun`: the
    residuals alone (cheaper than with the Jacobian), for the trials after a rejected step. `damping`: the first
    step's (relative to the Hessian's diagonal); a start at a nearby solution (the same problem weighed anew)
    takes nearly Gauss-Newton steps at once."""
    start = time.perf_counter()
    lo = np.full(len(x0), -np.inf) if lower is None else np.asarray(lower, float)
    hi = np.full(len(x0), np.inf) if upper is None else np.asarray(upper, float)

    def cost_of(r: np.ndarray) -> float:
        return robust.cost(r) if robust else 0.5 * float(r @ r)

    x = np.clip(x0.astype(float), lo, hi)
    r, J = initial if initial is not None and np.array_equal(x, x0) else fun_jac(x)
    evaluations = 1
    cost = cost_of(r)
    history = [cost]
    lam = damping
    nu = 2.0
    status = SolveStatus.MAX_ITERATIONS
    iteration = 0
    for iteration in range(1, max_iterations + 1):
        if should_stop is not None and should_stop():
            raise Cancelled()
        w = robust.weights(r) if robust else None
        Jw = J * w[:, None] if w is not None else J
        H = Jw.T @ J
        g = Jw.T @ r
        diag = np.maximum(np.diag(H), 1e-12 * max(1.0, float(np.max(np.diag(H), initial=0.0))))
        held = ((x <= lo) & (g > 0)) | ((x >= hi) & (g < 0))  # at a bound, pushed outward
        if np.max(np.abs(np.where(held, 0.0, g)), initial=0.0) <= 1e-14 * max(1.0, cost):
            status = SolveStatus.GRADIENT_VANISHED
            break
        # Near the solution nearly every step is accepted, so the first trial point gets its
        # Jacobian at once (an accepted step saves a residual evaluation); after a rejection most
        # trials are rejected too (at the solution, all of them), so they get residuals only.
        accepted = False
        J_new: np.ndarray | None = None
        tries = 0
        while True:
            try:
                dx = _box_step(H + lam * np.diag(diag), g, x, lo, hi, held)
            except np.linalg.LinAlgError:
                lam *= nu
                nu *= 2.0
                continue
            predicted = -(g @ dx) - 0.5 * dx @ H @ dx
            if np.linalg.norm(dx) <= xtol * (np.linalg.norm(x) + xtol) or predicted <= ftol * cost:
                break
            if tries == 0 or fun is None:
                r_new, J_new = fun_jac(x + dx)
            else:
                r_new, J_new = fun(x + dx), None
            tries += 1
            evaluations += 1
            cost_new = cost_of(r_new)
            rho = (cost - cost_new) / predicted if predicted > 0 else -1.0
            if rho > 0:
                accepted = True
                break
            lam *= nu
            nu *= 2.0
            if lam > 1e16:
                break
        if not accepted:
            status = SolveStatus.NO_FURTHER_DECREASE
            break
        if J_new is None:
            r_new, J_new = fun_jac(x + dx)
            evaluations += 1
        reduction = cost - cost_new
        x, r, J, cost = x + dx, r_new, J_new, cost_new
        lam *= max(1.0 / 3.0, 1.0 - (2.0 * rho - 1.0) ** 3)
        nu = 2.0
        history.append(cost)
        if progress is not None:
            progress(iteration, cost)
        if np.linalg.norm(dx) <= xtol * (np.linalg.norm(x) + xtol):
            status = SolveStatus.STEP_TOLERANCE
            break
        if reduction <= ftol * max(cost, 1e-300):
            status = SolveStatus.COST_TOLERANCE
            break
    return SolveResult(x, cost, iteration, evaluations, time.perf_counter() - start, status, history)


def _box_step(
    A: np.ndarray, g: np.ndarray, x: np.ndarray, lo: np.ndarray, hi: np.ndarray, held: np.ndarray
) -> np.ndarray:
    """The damped step -A^-1 g inside the box: a variable whose step would leave the box stops at
    its bound and the others are solved again with it fixed (a held one does not move at all)."""
    if not held.any():  # the usual case: the whole system, and no bound in the way
        dx = _solve_positive(A, -g)
        if np.all((x + dx >= lo) & (x + dx <= hi)):
            return dx
    fixed = held.copy()
    dx = np.zeros_like(x)
    while True:
        free = ~fixed
        rhs = -(g[free] + A[np.ix_(free, fixed)] @ dx[fixed])
        dx[free] = _solve_positive(A[np.ix_(free, free)], rhs) if free.any() else 0.0
        out = free & ((x + dx < lo) | (x + dx > hi))
        if not out.any():
            return dx
        dx[out] = np.clip(x + dx, lo, hi)[out] - x[out]
        fixed |= out


def nelder_mead(
    fun: Callable[[np.ndarray], np.ndarray],
    x0: np.ndarray,
    segments: list[tuple[slice, int]],
    *,
    max_evaluations: int = 200_000,
    should_stop: Callable[[], bool] | None = None,
) -> SolveResult:
    """The paper's baseline: Nelder-Mead on the sum of observation distances |r_b|; `segments`:
    each sensor's rows of fun(x) and the rows of one observation."""
    start = time.perf_counter()
    history: list[float] = []

    def objective(x: np.ndarray) -> float:
        r = fun(x)
        value = float(sum(np.sum(np.sqrt(block_norms_sq(r[rows], dim))) for rows, dim in segments))
        if not history or value < history[-1]:
            history.append(value)
        return value

    def callback(_x: np.ndarray) -> None:
        if should_stop is not None and should_stop():
            raise Cancelled()

    # Initial simplex steps of ~1 unit on lengths and ~1 deg on angles would ignore scale; step 5%
    # of each value, or 0.02 where the value is zero (2 cm / 1.1 deg), as Matlab's fminsearch does.
    simplex = [x0]
    for k in range(len(x0)):
        e = x0.copy()
        e[k] = x0[k] * 1.05 if x0[k] != 0 else 0.02
        simplex.append(e)
    import scipy.optimize  # the paper's simplex only: the solver's own LM needs none of it (a faster start)

    res = scipy.optimize.minimize(
        objective,
        x0,
        method="Nelder-Mead",
        callback=callback,
        options={
            "maxfev": max_evaluations,
            "xatol": 1e-6,
            "fatol": 1e-9,
            "initial_simplex": np.array(simplex),
            "adaptive": True,
        },
    )
    return SolveResult(
        res.x,
        float(res.fun),
        int(res.nit),
        int(res.nfev),
        time.perf_counter() - start,
        SolveStatus.SIMPLEX_TOLERANCE if res.success else SolveStatus.MAX_EVALUATIONS,
        history,
    )


def _solve_positive(A: np.ndarray, b: np.ndarray) -> np.ndarray:
    """A^-1 b for a symmetric positive definite A, by Cholesky: np.linalg.LinAlgError when A is not
    (the damping then grows). NumPy's, not SciPy's: importing scipy.linalg would slow every start."""
    L = np.linalg.cholesky(A)
    return np.linalg.solve(L.T, np.linalg.solve(L, b))
