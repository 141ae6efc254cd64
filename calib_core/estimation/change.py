"""How far a calibration's own uncertainty moves a frame's predictions: the band a review's change is read
against.

A calibration's estimate is uncertain (its covariance Sigma), and the uncertainty moves all the points of a
frame together: two calibrations of the same robot from independent sessions differ on a frame by far
more than its points' noise over sqrt(points). Observation k's prediction has the covariance
G_k Sigma G_k^T (G_k its prediction Jacobian, position axes). A frame's band is the RMS over its
observations of how far that moves the prediction, sqrt(mean_k trace(G_k Sigma G_k^T)): a frame's mean
error cannot change by more than its predictions move (triangle inequality), so a change within a few
bands is what the uncertainty alone explains.
"""

from __future__ import annotations

import numpy as np

from ..dataset import Dataset
from ..model.profile import Profile
from .calibration import Covariance
from .problem import Problem


def frame_band(profile: Profile, data: Dataset, p: np.ndarray, covariance: Covariance) -> np.ndarray:
    """Per configuration of `data` (N,): the RMS over its observations of the standard deviation of where
    calibration `p` with `covariance` predicts them (the sensors' units); 0 without an observation."""
    indices, cov = covariance.internal(profile)
    variance = np.zeros(data.n_configurations)
    if not indices or data.n_observations == 0:
        return variance
    problem = Problem(profile, data, indices, p, noise_model=False)
    _, J = problem.residuals_jacobian(problem.x0)
    for b in problem.blocks:
        G = J[b.rows].reshape(-1, b.dim, len(indices))[:, : b.dim - b.sensor.rotation_axes]
        np.add.at(variance, data.cfg[b.obs], np.einsum("kan,nm,kam->k", G, cov, G))
    counts = np.bincount(data.cfg, minlength=data.n_configurations)
    return np.sqrt(np.maximum(variance, 0.0) / np.maximum(counts, 1))
