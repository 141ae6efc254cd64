"""The Levenberg-Marquardt solver's box constraints (a mode's `bounds`)."""

from __future__ import annotations

import numpy as np

from calib_core.estimation.solver import levenberg_marquardt


def linear(A: np.ndarray, b: np.ndarray):
    return lambda x: (A @ x - b, A)


def test_unbounded_solution_is_the_least_squares_one() -> None:
    A, b = np.array([[1.0, 1.0], [1.0, -1.0]]), np.array([3.0, 1.0])
    res = levenberg_marquardt(linear(A, b), np.zeros(2))
    np.testing.assert_allclose(res.x, [2.0, 1.0], atol=1e-8)


def test_a_bound_holds_one_variable_and_the_other_is_optimal_given_it() -> None:
    """min (x0 + x1 - 3)^2 + (x0 - x1 - 1)^2 with x0 <= 1.5 gives (1.5, 1), which is also the free
    optimum (2, 1) clipped; a skewed problem tells the two apart. Tolerances are the solver's: it
    stops when the cost no longer falls by 1e-10 of itself."""
    A, b = np.array([[1.0, 1.0], [1.0, -1.0]]), np.array([3.0, 1.0])
    res = levenberg_marquardt(
        linear(A, b), np.zeros(2), lower=np.array([-np.inf, -np.inf]), upper=np.array([1.5, np.inf])
    )
    np.testing.assert_allclose(res.x, [1.5, 1.0], atol=1e-5)
    # Skewed: the free optimum is (2, 1); with x0 held at 1.5, x1 solves the remaining least squares.
    A = np.array([[1.0, 2.0], [2.0, 1.0], [1.0, 0.0]])
    b = A @ np.array([2.0, 1.0])
    res = levenberg_marquardt(linear(A, b), np.zeros(2), upper=np.array([1.5, np.inf]))
    x1 = (A[:, 1] @ (b - 1.5 * A[:, 0])) / (A[:, 1] @ A[:, 1])
    np.testing.assert_allclose(res.x, [1.5, x1], atol=1e-5)
    assert abs(x1 - 1.0) > 0.1


def test_a_start_outside_the_box_is_moved_in() -> None:
    A, b = np.eye(2), np.array([5.0, -5.0])
    res = levenberg_marquardt(
        linear(A, b), np.array([10.0, 10.0]), lower=np.array([-1.0, -1.0]), upper=np.array([1.0, 1.0])
    )
    np.testing.assert_allclose(res.x, [1.0, -1.0], atol=1e-12)
