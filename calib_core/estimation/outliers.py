"""Robust scales and outliers: which observations a calibration leaves out as gross errors (a failed
detection, a misread marker), each sensor by its own spread.

Residuals here are whitened (unit variance when the noise model holds), one observation `dim` rows.
"""

from __future__ import annotations

import numpy as np
from scipy.stats import chi2

from ..dataset import Dataset
from ..model.profile import Profile
from ..sensors import Sensor
from .problem import Problem
from .solver import block_norms_sq

OUTLIER_QUANTILE = 0.9999


def robust_sigma(r: np.ndarray, dim: int) -> float:
    """Scale of whitened residual blocks from their median norm (|r|^2 ~ sigma^2 chi2(dim))."""
    norms = np.sqrt(block_norms_sq(r, dim))
    norms = norms[norms > 0]
    if len(norms) == 0:
        return 1.0
    return float(np.median(norms) / np.sqrt(chi2.ppf(0.5, dim)))


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
    return declared if declared is not None else float(np.sqrt(chi2.ppf(OUTLIER_QUANTILE, sensor.dim)))


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
    r = problem.residuals(np.zeros(0))
    keep = np.ones(data.n_observations, bool)
    for b in problem.blocks:
        if b.index in sigmas:
            norms = np.sqrt(block_norms_sq(r[b.rows], b.dim))
            keep[b.obs] = norms <= sigmas[b.index] * outlier_limit(b.sensor)
    return keep
