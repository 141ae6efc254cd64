"""Whether a fit's residuals agree with the noise each sensor declares: a chi-square test per sensor.

If a sensor's declared noise is right and the mode can fit its data, its residuals whitened by the
noise model are (to first order) independent standard normal, less what the fit took from them: their
sum of squares follows a chi-square distribution whose degrees of freedom are the sensor's included
rows less its share of the free parameters (the share of its rows in the data). The test rejects the
declared noise when that sum is beyond the distribution's 1 - NOISE_TEST_LEVEL quantile. It is one-sided:
residuals smaller than declared (a cautious noise figure) are no reason to doubt the fit.

On a real robot the test usually rejects: the model error a mode leaves (unmodelled geometry,
compliance, drift) adds to the noise. The factor (residual RMS over the declared noise) says how much.
"""

from __future__ import annotations

import numpy as np

from .chi_square import survival
from .problem import Problem
from .reports import NoiseTest

NOISE_TEST_LEVEL = 1e-3  # the false alarm rate: a fit with the declared noise is warned about this often


def sensor_scatter(problem: Problem, r: np.ndarray, n_free: int) -> dict[int, tuple[float, int, float]]:
    """Per sensor (profile index): the sum of squares of its residuals whitened by its noise model alone,
    its included rows and their degrees of freedom after a fit of `n_free` parameters. `r`: residuals as
    `Problem.residuals` gives them (divided by each block's scale)."""
    out = {}
    for b in problem.blocks:
        rows_in = int(problem.included[b.obs].sum()) * b.dim
        share = n_free * (b.rows.stop - b.rows.start) / max(problem.n_data_rows, 1)
        out[b.index] = (float(np.sum((r[b.rows] * b.scale) ** 2)), rows_in, rows_in - share)
    return out


def noise_tests(problem: Problem, r: np.ndarray, n_free: int) -> list[NoiseTest]:
    """The test for each sensor of `problem` at residuals `r` after a fit of `n_free` parameters (as
    `sensor_scatter`). A sensor left with no degree of freedom is not tested."""
    scatter = sensor_scatter(problem, r, n_free)
    out = []
    for b in problem.blocks:
        total, rows, dof = scatter[b.index]
        if dof > 0:
            p_value = float(survival(dof, total))
            out.append(NoiseTest(b.sensor.name, float(np.sqrt(total / dof)), rows, dof, p_value, NOISE_TEST_LEVEL))
    return out
