"""What one solve found: the estimate, the problem it was found on, and how the solver got there."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from .identifiability import Dependency
from .outliers import OutlierVerdict
from .problem import Problem
from .reports import NoiseTest
from .solver import SolveStatus


@dataclass
class Fit:
    problem: Problem
    p: np.ndarray
    dependencies: list[Dependency]
    iterations: int
    evaluations: int
    seconds: float
    status: SolveStatus
    cost_history: list[float]
    sigma: float  # scale of the whitened residuals at the solution
    sigmas: dict[int, float]  # per sensor (profile index): the scale of its whitened residuals
    verdict: OutlierVerdict | None = None  # the robust pass's flagged observations, sorted (None: no robust pass)
    noise_tests: list[NoiseTest] = field(default_factory=list)  # per sensor, its residuals against its declared noise
    starts: int = 1  # start vectors tried (calib_core.estimation.starts)
    start: str = "the start values"  # the one whose solution was kept
    # The dependencies found among the mode's free parameters at the start values (before a minimal set's), and
    # what they were found on: those parameters and the data rows' Jacobian there (`fit_parameters`' `near`).
    found: tuple[list[int], np.ndarray, list[Dependency]] | None = None
