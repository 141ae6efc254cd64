"""The chi-square tail and quantiles calib_core computes itself (to start without SciPy) agree with SciPy's."""

import numpy as np
import pytest
from scipy.special import chdtrc, chdtri

from calib_core.estimation.chi_square import survival, upper_quantile

DOFS = [0.3, 1, 2, 3, 5.5, 12, 84, 1000, 20000]


@pytest.mark.parametrize("dof", DOFS)
def test_survival_matches_scipy(dof):
    x = dof * np.array([1e-3, 0.1, 0.5, 0.9, 1.0, 1.1, 1.5, 2.0, 3.0, 10.0])
    ours = np.array([survival(dof, v) for v in x])
    ref = chdtrc(dof, x)
    tol = 1e-12 if dof <= 1000 else 1e-9
    kept = ref > 1e-280
    np.testing.assert_allclose(ours[kept], ref[kept], rtol=tol)
    assert survival(dof, 0.0) == 1.0


@pytest.mark.parametrize("dof", DOFS)
def test_quantile_matches_scipy(dof):
    for tail in [1e-6, 1e-4, 0.001, 0.05, 0.5, 0.9, 0.9999]:
        assert upper_quantile(dof, tail) == pytest.approx(chdtri(dof, tail), rel=1e-10)


def test_bad_arguments_are_refused():
    with pytest.raises(ValueError, match="degrees of freedom"):
        survival(0, 1.0)
    with pytest.raises(ValueError, match="tail probability"):
        upper_quantile(3, 1.0)
