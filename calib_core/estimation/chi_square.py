"""The chi-square distribution's tail and quantiles, for outlier limits and the noise test.

Written here rather than taken from SciPy: importing any part of SciPy costs every `calib` start
about 0.3 s, more than the rest of a small solve. The tail is the regularized upper incomplete gamma
function Q(k/2, x/2), by its power series below the mean and Lentz's continued fraction above it
(Numerical Recipes, 6.2): within 1e-12 of SciPy's (relative) up to a thousand degrees of freedom, 1e-9
at a hundred thousand (tests/test_chi_square.py). The quantile inverts it by Newton steps kept inside
a bracket.
"""

from __future__ import annotations

import math
from functools import lru_cache

_EPS = 1e-16
_MAX_TERMS = 100_000


def survival(dof: float, x: float) -> float:
    """P(X > x) for X chi-square with `dof` (> 0, not necessarily whole) degrees of freedom."""
    if dof <= 0:
        raise ValueError(f"degrees of freedom must be positive, not {dof}")
    if x <= 0:
        return 1.0
    a, z = 0.5 * dof, 0.5 * x
    if z < a + 1.0:
        return max(0.0, 1.0 - _lower_series(a, z))
    return _upper_fraction(a, z)


@lru_cache(maxsize=1024)
def upper_quantile(dof: float, tail: float) -> float:
    """x with P(X > x) = tail (0 < tail < 1): the (1 - tail) quantile, as SciPy's chdtri(dof, tail)."""
    if not 0.0 < tail < 1.0:
        raise ValueError(f"tail probability must be in (0, 1), not {tail}")
    # Wilson-Hilferty: (X / k)^(1/3) is nearly normal with mean 1 - 2/(9k), variance 2/(9k).
    v = 2.0 / (9.0 * dof)
    x = max(dof * (1.0 - v + _normal_upper_quantile(tail) * math.sqrt(v)) ** 3, 1e-300)
    lo, hi = 0.0, math.inf
    for _ in range(200):
        excess = survival(dof, x) - tail  # falls as x grows
        if excess > 0:
            lo = x
        else:
            hi = x
        if excess == 0 or (math.isfinite(hi) and hi - lo <= 1e-15 * hi):
            return x
        density = _density(dof, x)
        x_new = x + excess / density if density > 0 else math.nan
        if not lo < x_new < hi:  # Newton left the bracket: bisect it, in logs while it spans decades
            if not math.isfinite(hi):
                x_new = 2.0 * max(x, lo)
            else:
                x_new = math.sqrt(lo * hi) if 0 < 4 * lo < hi else 0.5 * (lo + hi)
        if abs(x_new - x) <= 1e-15 * x:
            return x_new
        x = x_new
    return x


def _density(dof: float, x: float) -> float:
    a = 0.5 * dof
    return math.exp((a - 1.0) * math.log(0.5 * x) - 0.5 * x - math.lgamma(a)) * 0.5


def _prefactor(a: float, z: float) -> float:
    return math.exp(a * math.log(z) - z - math.lgamma(a))


def _lower_series(a: float, z: float) -> float:
    """P(a, z) by its series, for z < a + 1."""
    term = total = 1.0 / a
    n = a
    for _ in range(_MAX_TERMS):
        n += 1.0
        term *= z / n
        total += term
        if abs(term) < abs(total) * _EPS:
            break
    return total * _prefactor(a, z)


def _upper_fraction(a: float, z: float) -> float:
    """Q(a, z) by its continued fraction (modified Lentz), for z >= a + 1."""
    tiny = 1e-300
    b = z + 1.0 - a
    c = 1.0 / tiny
    d = 1.0 / b
    h = d
    for i in range(1, _MAX_TERMS):
        an = -i * (i - a)
        b += 2.0
        d = an * d + b
        d = tiny if abs(d) < tiny else d
        c = b + an / c
        c = tiny if abs(c) < tiny else c
        d = 1.0 / d
        delta = d * c
        h *= delta
        if abs(delta - 1.0) < _EPS:
            break
    return _prefactor(a, z) * h


def _normal_upper_quantile(p: float) -> float:
    """z with P(Z > z) = p for a standard normal Z, to about 1e-3 (a start for Newton's method only)."""
    q = min(p, 1.0 - p)
    t = math.sqrt(-2.0 * math.log(q))
    z = t - (2.515517 + 0.802853 * t + 0.010328 * t * t) / (1.0 + 1.432788 * t + 0.189269 * t * t + 0.001308 * t**3)
    return z if p < 0.5 else -z
