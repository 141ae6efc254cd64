"""A robot's calibrations read together: what moved between two of them, what drifts steadily, and which robot
of a team is the odd one out.

Each calibration is an *epoch*: the values of the parameters it estimated and their covariance (display units),
at the time its data were measured. Between two epochs of one robot the parameters both estimated differ by d;
if nothing moved, d is the two estimates' noise, with covariance S = S_a + S_b (independent sessions), and
d' S^-1 d follows a chi-square with as many degrees of freedom as parameters: the congruence test of geodetic
deformation analysis. A change beyond it at level `alpha` is flagged, and localized one parameter at a time
(Baarda's w-test on the difference, each named parameter freed before the next is looked for) until what is left
passes the test.

Why with the whole covariance: a calibration's parameters are correlated. A NAO's hip, knee and ankle pitch
offsets trade off: each alone is known to 0.1-0.3 deg, their combination the camera sees to 0.01 deg. A knee that
moves alone moves that combination, and the test sees it at the combination's precision, where each value read
against its own standard deviation would not. The parameter named is the one whose move alone explains the change
best; correlated parameters moving together in a way the data cannot tell apart are, by construction, not seen.

A trend is the same idea over several epochs: v_k = mu + sum_j e_j r_j (t_k - t_mean) + noise_k (covariance S_k),
fitted by generalized least squares, parameters taken in one at a time (the largest chi-square reduction, tested at
level `alpha` with a Sidak correction over the candidates) while the reduction is significant. Its rate is per
day. The residual chi-square of the final model says whether the rest is noise (steady) or jumps as well.

Robots of one profile are compared per parameter: each robot's value against the others' mean, read against its
own standard deviation, the others' and the spread between robots the others show (a team's NAOs differ in their
offsets: that is not a fault), a Sidak correction over every robot and parameter tested.
"""

from __future__ import annotations

import itertools
import math
from dataclasses import dataclass, field
from datetime import datetime

import numpy as np

from .calibration import Calibration
from .chi_square import survival, upper_quantile

DRIFT_LEVEL = 0.01  # the false-alarm rate: of a history (its changes and trends), of two epochs compared, of a team
DAY_S = 86400.0
MOVED_SHOWN = 3.0  # a parameter "moved" (the page plots it) this many standard deviations or more
_MAX_NAMED = 8  # parameters named for one change or trend at most: beyond, the change is not a few parameters'


@dataclass
class Epoch:
    """One calibration as the history reads it: what it estimated, with its covariance (display units)."""

    id: str
    time: datetime  # when its data were measured
    mode: str
    names: list[str]  # the parameters it estimated, its covariance's order
    values: np.ndarray  # (k,) display units
    covariance: np.ndarray  # (k, k) display units; diagonal when the file kept only standard deviations
    units: dict[str, str]
    correlated: bool = True  # False: the file kept standard deviations only, read as uncorrelated

    @classmethod
    def of(cls, cal: Calibration, id: str, time: datetime) -> Epoch:
        """The calibration's estimated parameters with their covariance (the standard deviations alone for a file
        written before covariances were kept)."""
        est = {p.name: p for p in cal.parameters}
        if cal.covariance is not None and cal.covariance.parameters:
            names = list(cal.covariance.parameters)
            cov = np.asarray(cal.covariance.matrix, float).reshape(len(names), len(names))
        else:
            names = [p.name for p in cal.parameters if p.estimated and p.std is not None]
            cov = np.diag([float(est[n].std) ** 2 for n in names])
        values = np.array([est[n].value for n in names], float)
        units = {p.name: p.unit for p in cal.parameters}
        return cls(id, time, cal.mode, names, values, cov, units, cal.covariance is not None)

    def block(self, names: list[str]) -> tuple[np.ndarray, np.ndarray]:
        """Values and covariance of `names` (each one this epoch estimated)."""
        idx = [self.names.index(n) for n in names]
        return self.values[idx], self.covariance[np.ix_(idx, idx)]

    def sd(self, name: str) -> float:
        k = self.names.index(name)
        return math.sqrt(max(float(self.covariance[k, k]), 0.0))


def _precision(cov: np.ndarray) -> np.ndarray:
    """The inverse of a covariance; directions it leaves (numerically) unknown get no weight."""
    w, v = np.linalg.eigh(0.5 * (cov + cov.T))
    keep = w > max(float(w.max(initial=0.0)), 0.0) * 1e-12
    return (v[:, keep] / w[keep]) @ v[:, keep].T


def _rank(cov: np.ndarray) -> int:
    w = np.linalg.eigvalsh(0.5 * (cov + cov.T))
    return int(np.sum(w > max(float(w.max(initial=0.0)), 0.0) * 1e-12))


# --- two epochs ---------------------------------------------------------------------------------------------
@dataclass
class Moved:
    """A parameter named for a change: its move (display units) and standard deviation if it alone moved with
    the others named before it."""

    parameter: str
    unit: str
    change: float
    sd: float

    @property
    def z(self) -> float:
        return self.change / self.sd if self.sd > 0 else math.inf


@dataclass
class Step:
    """The change from one epoch to the next."""

    before: str
    after: str
    days: float
    parameters: int  # compared: those both estimated
    chi2: float
    p: float
    flagged: bool
    moved: list[Moved] = field(default_factory=list)
    beyond_trends: bool = False  # tested beyond the change the history's trends explain

    @property
    def sentence(self) -> str:
        trends = " and the trends" if self.beyond_trends else ""
        if not self.flagged:
            return (
                f"{self.before} -> {self.after}: within what both calibrations' uncertainty{trends} explain "
                f"({self.parameters} parameters compared, p = {self.p:.2g})"
            )
        named = ", ".join(f"{m.parameter} {m.change:+.3g} {m.unit} ({abs(m.z):.1f} sd)" for m in self.moved)
        return (
            f"{self.before} -> {self.after}: changed beyond what both calibrations' uncertainty{trends} explain "
            f"(p = {self.p:.2g}): {named}"
        )


def compare_epochs(a: Epoch, b: Epoch, alpha: float = DRIFT_LEVEL, expected: dict[str, float] | None = None) -> Step:
    """The congruence test of `b` against `a` over the parameters both estimated, and the parameters that moved.
    `expected`: parameter -> the change a trend explains (display units), taken off before the test."""
    names = [n for n in a.names if n in b.names]
    va, sa = a.block(names)
    vb, sb = b.block(names)
    d, cov = vb - va, sa + sb
    d -= np.array([(expected or {}).get(n, 0.0) for n in names])
    days = (b.time - a.time).total_seconds() / DAY_S
    dof = _rank(cov)
    if dof == 0:
        return Step(a.id, b.id, days, 0, 0.0, 1.0, False)
    W = _precision(cov)
    chi2 = float(d @ W @ d)
    p = survival(dof, chi2)
    step = Step(a.id, b.id, days, len(names), chi2, p, p < alpha, beyond_trends=bool(expected))
    if step.flagged:
        step.moved = _localize(d, W, names, dof, alpha, a.units)
    return step


def _localize(d: np.ndarray, W: np.ndarray, names: list[str], dof: int, alpha: float, units: dict) -> list[Moved]:
    """Baarda's w-test, one parameter at a time: the one whose move best explains what is left, until the rest
    passes the congruence test."""
    named: list[int] = []
    while len(named) < min(_MAX_NAMED, len(names)):
        P = _freed(W, named)
        rest = dof - len(named)
        if rest <= 0 or survival(rest, float(d @ P @ d)) >= alpha:
            break
        diag = np.diag(P)
        w = np.where(diag > 1e-300, (P @ d) / np.sqrt(np.maximum(diag, 1e-300)), 0.0)
        w[named] = 0.0
        named.append(int(np.argmax(np.abs(w))))
    if not named:
        return []
    E = np.eye(len(names))[:, named]
    info = E.T @ W @ E
    cov = np.linalg.pinv(info)
    change = cov @ (E.T @ W @ d)
    return [
        Moved(names[j], units.get(names[j], ""), float(c), math.sqrt(max(float(s), 0.0)))
        for j, c, s in zip(named, change, np.diag(cov), strict=True)
    ]


def _freed(W: np.ndarray, named: list[int]) -> np.ndarray:
    """The precision of what the parameters `named` cannot explain: W - W E (E' W E)^-1 E' W."""
    if not named:
        return W
    WE = W[:, named]
    return W - WE @ np.linalg.pinv(WE[named]) @ WE.T


# --- several epochs -----------------------------------------------------------------------------------------
@dataclass
class Trend:
    """A parameter moving steadily: its rate per day and the rate's standard deviation."""

    parameter: str
    unit: str
    rate_per_day: float
    sd: float
    days: float  # from the first epoch to the last
    calibrations: int
    steady: bool  # the rest of the history is noise (else it jumps as well)

    @property
    def z(self) -> float:
        return self.rate_per_day / self.sd if self.sd > 0 else math.inf

    @property
    def sentence(self) -> str:
        tail = "" if self.steady else " (with jumps besides: see the changes)"
        return (
            f"{self.parameter}: {self.rate_per_day:+.3g} {self.unit} a day over {self.days:.3g} days "
            f"({self.calibrations} calibrations; +/- {self.sd:.2g}){tail}"
        )


@dataclass
class Point:
    """One epoch's value of a parameter: as estimated, and held (the others at the history's values)."""

    calibration: str
    time: datetime
    value: float
    sd: float
    held: float | None  # the value if the other compared parameters were at what the history fits for them
    held_sd: float | None


@dataclass
class Series:
    parameter: str
    unit: str
    points: list[Point]
    moved_sd: float  # how far it moved, standard deviations: the largest of its trend, its changes, first to last
    trend: Trend | None


@dataclass
class Drift:
    """A robot's history read together."""

    epochs: list[str]  # calibration ids, oldest data first
    compared: list[str]  # the parameters every epoch estimated (what the trends read)
    steps: list[Step]
    trends: list[Trend]
    series: list[Series]  # most moved first
    steady_chi2: float | None  # the final trend model's residual chi-square and its degrees of freedom
    steady_dof: int | None
    alpha: float

    @property
    def flagged(self) -> list[Step]:
        return [s for s in self.steps if s.flagged]


def find_drift(epochs: list[Epoch], alpha: float = DRIFT_LEVEL) -> Drift:
    """Steady trends over all epochs, then each change from one epoch to the next beyond what the trends explain
    (a drifting joint is named once, with its rate, not at every step), each parameter's series. `alpha` is the
    history's: half for its trend search, half for its changes together (Sidak over them), so a history in which
    nothing moved shows a flag at most that often."""
    epochs = sorted(epochs, key=lambda e: e.time)
    shared = [n for n in epochs[0].names if all(n in e.names for e in epochs[1:])] if epochs else []
    trends: list[Trend] = []
    fitted: list[np.ndarray] = []
    chi2 = dof = None
    if shared and len(epochs) >= 2:
        fit = _TrendFit(epochs, shared)
        named = fit.select(alpha / 2) if len(epochs) >= 3 and fit.span_days > 0 else []
        chi2, dof, fitted, rates = fit.solve(named)
        steady = dof <= 0 or survival(dof, chi2) >= alpha
        units = epochs[0].units
        trends = [
            Trend(shared[j], units.get(shared[j], ""), r, s, fit.span_days, len(epochs), steady)
            for j, (r, s) in zip(named, rates, strict=True)
        ]
    steps = []
    each = _sidak(alpha / 2, len(epochs) - 1)
    for a, b in itertools.pairwise(epochs):
        days = (b.time - a.time).total_seconds() / DAY_S
        steps.append(compare_epochs(a, b, each, {t.parameter: t.rate_per_day * days for t in trends} or None))
    series = _series(epochs, shared, fitted, steps, trends)
    return Drift([e.id for e in epochs], shared, steps, trends, series, chi2, dof, alpha)


class _TrendFit:
    """v_k = mu + sum_j e_j r_j t_k + noise_k by generalized least squares, whitened: rows L_k' v_k with
    L_k L_k' = S_k^-1 (t_k: days from the epochs' mean time)."""

    def __init__(self, epochs: list[Epoch], shared: list[str]) -> None:
        self.k = len(shared)
        t = np.array([e.time.timestamp() for e in epochs]) / DAY_S
        self.t = t - t.mean()
        self.span_days = float(t.max() - t.min())
        blocks = [e.block(shared) for e in epochs]
        self.values = [v for v, _ in blocks]
        self.precisions = [_precision(s) for _, s in blocks]
        self.roots = [_root(w) for w in self.precisions]
        self.y = np.concatenate([L.T @ v for L, (v, _) in zip(self.roots, blocks, strict=True)])
        self.mu = np.vstack([L.T for L in self.roots])  # the columns of mu
        self.ramp = np.vstack([L.T * tk for L, tk in zip(self.roots, self.t, strict=True)])  # column j: r_j
        self.rows = int(sum(_rank(s) for _, s in blocks))

    def design(self, named: list[int]) -> np.ndarray:
        return np.hstack([self.mu, self.ramp[:, named]])

    def select(self, alpha: float) -> list[int]:
        """Trend parameters taken in one at a time while the best one's chi-square reduction is significant."""
        named: list[int] = []
        while len(named) < min(_MAX_NAMED, self.k):
            A = self.design(named)
            Q = _basis(A)
            r = self.y - Q @ (Q.T @ self.y)
            C = self.ramp - Q @ (Q.T @ self.ramp)  # each candidate's column beyond the current model
            norms = np.einsum("ij,ij->j", C, C)
            gain = np.where(norms > 1e-18 * max(norms.max(), 1e-300), (C.T @ r) ** 2 / np.maximum(norms, 1e-300), 0)
            gain[named] = 0.0
            j = int(np.argmax(gain))
            if gain[j] <= upper_quantile(1.0, _sidak(alpha, self.k - len(named))):
                break
            named.append(j)
        return named

    def solve(self, named: list[int]) -> tuple[float, int, list[np.ndarray], list[tuple[float, float]]]:
        """Residual chi-square, its degrees of freedom, each epoch's fitted values and the rates (per day, sd)."""
        A = self.design(named)
        x, *_ = np.linalg.lstsq(A, self.y, rcond=None)
        resid = self.y - A @ x
        cov = np.linalg.pinv(A.T @ A)
        mu, r = x[: self.k], x[self.k :]
        fitted = [mu + np.bincount(named, weights=r * tk, minlength=self.k) for tk in self.t]
        rates = [(float(v), math.sqrt(max(float(cov[self.k + i, self.k + i]), 0.0))) for i, v in enumerate(r)]
        dof = self.rows - int(np.linalg.matrix_rank(A))
        return float(resid @ resid), dof, fitted, rates


def _sidak(alpha: float, tests: int) -> float:
    """Each of `tests` independent tests' level for a family-wise level `alpha`."""
    return 1.0 - (1.0 - alpha) ** (1.0 / max(tests, 1))


def _root(W: np.ndarray) -> np.ndarray:
    """L with L L' = W (W positive semi-definite)."""
    w, v = np.linalg.eigh(0.5 * (W + W.T))
    return v * np.sqrt(np.clip(w, 0.0, None))


def _basis(A: np.ndarray) -> np.ndarray:
    """An orthonormal basis of A's columns (rank-revealing: dependent columns dropped)."""
    U, s, _ = np.linalg.svd(A, full_matrices=False)
    return U[:, s > s.max(initial=0.0) * 1e-10]


def _series(
    epochs: list[Epoch], shared: list[str], fitted: list[np.ndarray], steps: list[Step], trends: list[Trend]
) -> list[Series]:
    held: dict[str, list[tuple[float, float]]] = {}
    if fitted:
        for e, f in zip(epochs, fitted, strict=True):
            v, s = e.block(shared)
            W = _precision(s)
            wd = np.maximum(np.diag(W), 1e-300)
            h = f + (W @ (v - f)) / wd
            for n, hv, w in zip(shared, h, wd, strict=True):
                held.setdefault(n, []).append((float(hv), 1.0 / math.sqrt(w)))
    names = list(dict.fromkeys(n for e in epochs for n in e.names))
    by_trend = {t.parameter: t for t in trends}
    out = []
    for n in names:
        points = []
        for e in epochs:
            if n not in e.names:
                continue
            k = len(points)
            hv, hs = held[n][k] if n in held else (None, None)
            points.append(Point(e.id, e.time, float(e.values[e.names.index(n)]), e.sd(n), hv, hs))
        moved = [abs(m.z) for s in steps for m in s.moved if m.parameter == n]
        if n in by_trend:
            moved.append(abs(by_trend[n].z))
        if len(points) >= 2:
            a, b = points[0], points[-1]
            if a.held is not None and b.held is not None:
                moved.append(abs(b.held - a.held) / max(math.hypot(a.held_sd, b.held_sd), 1e-300))
            else:
                moved.append(abs(b.value - a.value) / max(math.hypot(a.sd, b.sd), 1e-300))
        unit = epochs[-1].units.get(n, "")
        out.append(Series(n, unit, points, max(moved, default=0.0), by_trend.get(n)))
    return sorted(out, key=lambda s: -s.moved_sd)


# --- robots of one profile ----------------------------------------------------------------------------------
@dataclass
class Standing:
    """One robot's value of a parameter beside the others'."""

    robot: str
    value: float
    sd: float
    z: float  # how far from the others' mean, in the standard deviation of that difference


@dataclass
class OddOne:
    robot: str
    parameter: str
    unit: str
    value: float
    others_mean: float
    others_spread: float  # the standard deviation of the difference it was read against
    z: float

    @property
    def sentence(self) -> str:
        return (
            f"{self.robot}: {self.parameter} {self.value:.4g} {self.unit} where the others have "
            f"{self.others_mean:.4g} (+/- {self.others_spread:.2g}): {abs(self.z):.1f} sd off"
        )


@dataclass
class Column:
    parameter: str
    unit: str
    robots: list[Standing]
    odd: str | None


@dataclass
class Team:
    robots: list[str]
    parameters: list[Column]  # the most off first
    odd: list[OddOne]
    alpha: float


def compare_team(members: dict[str, Epoch], alpha: float = DRIFT_LEVEL) -> Team:
    """Each parameter estimated by three or more of the robots: every robot against the mean of the others, read
    against its own variance, the others' mean's and the spread between robots the others show, flagged beyond
    the Sidak-corrected level over every robot and parameter tested.

    The spread between robots (a team's NAOs differ in their offsets: that is not a fault) is estimated from the
    others by the method of moments (their variance less what their own uncertainty explains), the parameter's own
    or, if larger, that pooled over the parameters of its unit: four robots that happen to agree on one parameter
    cannot say how far apart robots lie in it, a dozen parameters of four robots can."""
    robots = sorted(members)
    names = list(dict.fromkeys(n for r in robots for n in members[r].names))
    columns: dict[str, tuple[list[str], np.ndarray, np.ndarray]] = {}
    for n in names:
        have = [r for r in robots if n in members[r].names]
        if len(have) >= 3:
            v = np.array([members[r].values[members[r].names.index(n)] for r in have])
            columns[n] = (have, v, np.array([members[r].sd(n) ** 2 for r in have]))
    unit = {n: next(members[r].units.get(n, "") for r in columns[n][0]) for n in columns}

    def spread2(robot: str, group: str) -> float:
        """The spread between robots other than `robot` in the parameters of unit `group`, squared."""
        excess = []
        for n, (have, v, s2) in columns.items():
            o = np.array([r != robot for r in have])
            if unit[n] == group and o.sum() >= 2:
                excess.append(max(float(np.var(v[o], ddof=1)) - float(s2[o].mean()), 0.0))
        return float(np.mean(excess)) if excess else 0.0

    pooled = {(r, g): spread2(r, g) for r in robots for g in set(unit.values())}
    rows = []
    for n, (have, v, s2) in columns.items():
        standings = []
        for i, r in enumerate(have):
            o = np.arange(len(have)) != i
            m = len(have) - 1
            own = max(float(np.var(v[o], ddof=1)) - float(s2[o].mean()), 0.0)
            var = s2[i] + max(own, pooled[r, unit[n]]) * (1.0 + 1.0 / m) + float(s2[o].mean()) / m
            mean = float(v[o].mean())
            z = (v[i] - mean) / math.sqrt(var) if var > 0 else 0.0
            standings.append((Standing(r, float(v[i]), math.sqrt(s2[i]), float(z)), mean, math.sqrt(var)))
        rows.append((n, standings))
    tests = sum(len(s) for _, s in rows)
    limit = upper_quantile(1.0, _sidak(alpha, tests)) if tests else math.inf
    columns, odd = [], []
    for n, standings in rows:
        unit = members[standings[0][0].robot].units.get(n, "")
        worst, mean, spread = max(standings, key=lambda x: abs(x[0].z))
        flagged = worst.z**2 > limit
        if flagged:
            odd.append(OddOne(worst.robot, n, unit, worst.value, mean, spread, worst.z))
        columns.append(Column(n, unit, [s for s, *_ in standings], worst.robot if flagged else None))
    columns.sort(key=lambda c: -max(abs(s.z) for s in c.robots))
    odd.sort(key=lambda o: -abs(o.z))
    return Team(robots, columns, odd, alpha)
