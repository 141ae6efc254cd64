"""Shared by the tests of exact Jacobians: every column against central finite differences."""

from __future__ import annotations

import math

import numpy as np

from calib_core import Problem


def perturbed(profile, rng: np.random.Generator) -> np.ndarray:
    """Nominal parameters moved at random (so that zero values and zero-angle paths are exercised)."""
    p = profile.nominal().copy()
    for i, prm in enumerate(profile.parameters):
        scale = {"angle": math.radians(3.0), "length": 2.0, "px": 5.0, "scalar": 0.01}[prm.kind]
        p[i] += rng.uniform(-scale, scale)
    return p


def check_jacobian(problem: Problem, names: list[str], rel: float = 1e-6) -> int:
    """Every column of the exact Jacobian against central differences; returns the non-zero columns."""
    x0 = problem.x0.copy()
    _, J = problem.residuals_jacobian(x0)
    nonzero = 0
    bad = []
    for k in range(len(x0)):
        h = 1e-5 * max(1.0, abs(x0[k]))
        e = np.zeros_like(x0)
        e[k] = h
        fd = (problem.residuals(x0 + e) - problem.residuals(x0 - e)) / (2 * h)
        scale = np.linalg.norm(fd)
        err = np.linalg.norm(J[:, k] - fd)
        if scale == 0.0:
            if np.linalg.norm(J[:, k]) != 0.0:
                bad.append((names[k], "FD column is zero but J is not", float(np.linalg.norm(J[:, k]))))
            continue
        nonzero += 1
        if err > rel * scale:
            bad.append((names[k], float(err / scale)))
    assert not bad, bad
    return nonzero
