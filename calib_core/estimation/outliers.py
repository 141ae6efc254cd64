"""Robust scales and outliers: which observations a calibration leaves out as gross errors (a failed
detection, a misread marker), each sensor by its own spread.

Residuals here are whitened (unit variance when the noise model holds), one observation `dim` rows.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..dataset import Dataset
from ..model.profile import Profile
from ..sensors import Sensor
from .chi_square import upper_quantile
from .problem import Problem
from .solver import block_norms_sq

OUTLIER_QUANTILE = 0.9999


def robust_sigma(r: np.ndarray, dim: int) -> float:
    """Scale of whitened residual blocks from their median norm (|r|^2 ~ sigma^2 chi2(dim))."""
    norms = np.sqrt(block_norms_sq(r, dim))
    norms = norms[norms > 0]
    if len(norms) == 0:
        return 1.0
    return float(np.median(norms) / np.sqrt(upper_quantile(dim, 0.5)))


def pooled_robust_sigma(problem: Problem, r: np.ndarray) -> float:
    """One robust scale for every sensor's whitened rows: each sensor's, weighed by its rows."""
    blocks = [(b.rows.stop - b.rows.start, robust_sigma(r[b.rows], b.dim)) for b in problem.blocks]
    rows = sum(n for n, _ in blocks)
    return float(np.sqrt(sum(n * s**2 for n, s in blocks) / max(rows, 1)))


def outlier_limit(sensor: Sensor) -> float:
    """How many robust sigmas make an outlier: the sensor's declared `noise.outliers`, else the
    99.99% quantile. A detector fails now and then (a misread corner); a laser tracker does not, and
    the heavy tail of a real robot's model error is not an outlier, so its profile sets a wide limit."""
    declared = sensor.outlier_sigmas()
    return declared if declared is not None else float(np.sqrt(upper_quantile(sensor.dim, 1 - OUTLIER_QUANTILE)))


def outliers_of(r: np.ndarray, dim: int, limit: float) -> np.ndarray:
    """Observations beyond `limit` times the residuals' robust spread."""
    norms = np.sqrt(block_norms_sq(r, dim))
    return norms > robust_sigma(r, dim) * limit


def problem_outliers(problem: Problem, r: np.ndarray) -> np.ndarray:
    """(M,) the observations each sensor's robust spread and limit call outliers."""
    out = np.zeros(problem.data.n_observations, bool)
    for b in problem.blocks:
        out[b.obs] = outliers_of(r[b.rows], b.dim, outlier_limit(b.sensor))
    return out


def inliers(profile: Profile, data: Dataset, p: np.ndarray, sigmas: dict[int, float]) -> np.ndarray:
    """(M,) observations that calibration p explains (not failed detections): within each sensor's
    outlier limit of its residual scale at the fit (`sigmas`: sensor index -> scale; a sensor the
    fit did not see keeps every observation)."""
    problem = Problem(profile, data, [], p)
    return explained(problem, problem.residuals(np.zeros(0)), sigmas)


def explained(problem: Problem, r: np.ndarray, sigmas: dict[int, float]) -> np.ndarray:
    """`inliers` of a problem with no free parameter (its calibration p) and its residuals r."""
    keep = np.ones(problem.data.n_observations, bool)
    for b in problem.blocks:
        if b.index in sigmas:
            norms = np.sqrt(block_norms_sq(r[b.rows], b.dim))
            keep[b.obs] = norms <= sigmas[b.index] * outlier_limit(b.sensor)
    return keep


NEIGHBOURS = 4  # configurations nearest in the joints that predict an observation's residual


@dataclass(frozen=True)
class OutlierVerdict:
    """The observations beyond their sensor's outlier limit, sorted: `gross` (isolated errors that no
    smooth model predicts: rejected) and `model_error` (what the other observations predict:
    unmodelled geometry or drift, kept). `sigmas`: how far the best of those predictions misses
    each flagged observation, in robust sigmas of the richer model's residuals (NaN elsewhere)."""

    gross: np.ndarray  # (M,) bool
    model_error: np.ndarray  # (M,) bool
    sigmas: np.ndarray  # (M,) float


def sort_outliers(problem: Problem, x: np.ndarray, flagged: np.ndarray) -> OutlierVerdict:
    """Tell isolated gross errors from systematic model error among the `flagged` observations.

    A failed detection or a swapped marker is isolated: nothing else in the data predicts it. Model
    error is not: it is smooth in the joints or in time. Three predictions of each flagged
    observation's residual, none of which uses the observation itself:
    - a richer model (every parameter the observations depend on, linearised at the fit) fitted to
      the residuals of the unflagged observations: unmodelled geometry;
    - the mean residual of the same sensor and point in the nearest configurations in joint space
      (joint readings in internal units): smooth error that no parameter of the profile describes;
    - the mean of the previous and the next such observation in the data's order: drift (a warming
      robot, a tracker that settles).
    Each misses by a distance measured against the prediction's own uncertainty and the richer
    model's residual scale (a robust sigma per sensor); the observation is a gross error only when
    every prediction misses beyond the sensor's outlier limit.
    """
    M = problem.data.n_observations
    sigmas = np.full(M, np.nan)
    if not flagged.any():
        return OutlierVerdict(flagged.copy(), np.zeros(M, bool), sigmas)
    r, J = _richer_model(problem, x)
    obs_of_row = np.concatenate([np.repeat(np.arange(M)[b.obs], b.dim) for b in problem.blocks])
    clean = ~flagged[obs_of_row]
    # Unit-scaled columns; directions the clean rows cannot determine are dropped (pseudo-inverse).
    norms = np.linalg.norm(J[clean], axis=0)
    cols = norms > 0
    Jc = J[:, cols] / norms[cols]
    U, s, Vt = np.linalg.svd(Jc[clean], full_matrices=False)
    keep = s > s[0] * 1e-8 if len(s) else np.zeros(0, bool)
    U, s, Vt = U[:, keep], s[keep], Vt[keep]
    e = r - Jc @ (Vt.T @ ((U.T @ r[clean]) / s))  # the richer model's residuals; out of its fit where flagged
    P = Jc @ (Vt.T / s)  # its prediction's covariance is sigma^2 P P^T
    inflate = np.sqrt(clean.sum() / max(clean.sum() - len(s), 1))  # the fit's own share of the scatter
    data = problem.data
    q = np.nan_to_num(data.joints)[data.cfg]
    for b in problem.blocks:
        rows = np.arange(b.rows.start, b.rows.stop)
        obs = np.arange(M)[b.obs]
        sigma = robust_sigma(e[rows][clean[rows]], b.dim) * inflate
        E = e[rows].reshape(-1, b.dim)
        same = np.stack([data.target[obs], data.vertex[obs]], axis=1)
        for k in np.flatnonzero(flagged[obs]):
            block_rows = rows[k * b.dim : (k + 1) * b.dim]
            cov = np.eye(b.dim) + P[block_rows] @ P[block_rows].T
            misses = [float(np.sqrt(E[k] @ np.linalg.solve(cov, E[k])))]
            peers = np.flatnonzero(np.all(same == same[k], axis=1))
            peers = peers[peers != k]
            if len(peers):
                nearest = peers[np.argsort(np.linalg.norm(q[obs[peers]] - q[obs[k]], axis=1))[:NEIGHBOURS]]
                before, after = peers[peers < k], peers[peers > k]
                adjacent = np.concatenate([before[-1:], after[:1]])
                for group in (nearest, adjacent):
                    miss = np.linalg.norm(E[k] - E[group].mean(axis=0)) / np.sqrt(1 + 1 / len(group))
                    misses.append(float(miss))
            sigmas[obs[k]] = min(misses) / sigma
    gross = flagged & (sigmas > _limits(problem, M))
    return OutlierVerdict(gross, flagged & ~gross, sigmas)


def _limits(problem: Problem, M: int) -> np.ndarray:
    """(M,) each observation's outlier limit in robust sigmas (its sensor's)."""
    out = np.empty(M)
    for b in problem.blocks:
        out[b.obs] = outlier_limit(b.sensor)
    return out


def _richer_model(problem: Problem, x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Whitened residuals at x of every observation and their Jacobian with respect to every
    parameter of the profile (columns of parameters no observation depends on are zero)."""
    p = problem.params(x)
    rich = Problem(problem.profile, problem.data, list(range(len(p))), p, noise_model=problem.weights)
    for b, mine in zip(rich.blocks, problem.blocks, strict=True):
        b.scale = mine.scale
    r, J = rich.residuals_jacobian(p)
    return r[: rich.n_data_rows], J[: rich.n_data_rows]
