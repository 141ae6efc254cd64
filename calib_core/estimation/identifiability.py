"""Identifiability and uncertainty: which parameter directions the data determine, and how well.

All of it works on the Jacobian of the whitened residuals with its columns scaled to unit length, so
that metres, degrees and pixels compare. Taking the columns in the mode's order, the kept ones are a
set of parameters that the data determine; every other column is a combination of those (to
round-off), and is named with that combination so that a user reads which parameters move together.

A column that is round-off itself (a reflector on the last joint's axis leaves that joint's column
near 1e-16 of the others) is not scaled up: scaled to unit length, round-off looks like a direction
of its own, and the pseudo-inverse would report the parameter as determined. Such a column is zero,
relative to the largest column and to the noise (`zero_columns`).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..model.profile import Profile
from .reports import Correlation, HeldParameter, IdentifiabilityReport

# A unit column whose part outside the span of the kept columns is shorter than this is a
# combination of them: exact structural dependence shows up near 1e-12; on a real robot, readings
# that barely move (the Motoman's E axis, jittering by 0.01 deg) leave a remainder near 1e-5, which
# no data can turn into an estimate (its standard deviation would be inflated 10^4 times).
DEPENDENCE_TOLERANCE = 1e-4
# The minimal parameter set keeps a parameter while its unit column has more than this outside the
# span of the ones kept before it: the structural cut, as FIGAROH's base parameters. A looser cut
# (0.05: no parameter inflated 20 times, the "weak" warning) held parameters that are off nominal
# and was worse on held-out data (benchmarks/minimal_set.py).
MINIMAL_TOLERANCE = DEPENDENCE_TOLERANCE
CORRELATION_LISTED = 0.9  # pairs listed in the report
INFLATION_WARNING = 20.0  # sd inflated this much by the others (VIF 400): warned about
# A column shorter than this share of the longest is round-off (1e-17 to 1e-13 here), not an effect:
# the weakest real effect in the built-in profiles, a camera's focal length (per px) next to joint
# angles (per rad), is 2e-5 of the longest.
ZERO_RELATIVE = 1e-9
# ... and so is one whose whole effect over all the data, per internal unit (m, rad, px) of the
# parameter, is below this many noise standard deviations (the columns are whitened).
ZERO_WHITENED = 1e-9


@dataclass
class Dependency:
    """Parameter `fixed` moves with others: changing it by 1 (display unit) and each of `partners`
    by its coefficient (display units) leaves every prediction unchanged."""

    fixed: int
    partners: dict[int, float]
    # Outside the minimal parameter set (not a strict dependence): the share of its unit column that
    # the kept parameters do not reproduce.
    remainder: float | None = None

    def describe(self, profile: Profile) -> str:
        terms = sorted(self.partners.items(), key=lambda kv: -abs(kv[1]))[:4]
        name = profile.label(self.fixed)
        if not terms:
            why = ""
            if _turns_a_joint(profile, self.fixed):  # the target on its axis, or a motion no sensor measures
                why = " (turning that joint moves nothing these sensors measure: a target on its axis?)"
            return f"{name} has no effect on any prediction with these data{why}: held at its base value"
        others = " and ".join(profile.label(i) for i, _ in terms)
        change = ", ".join(f"{c:+.3g} {profile.unit(i)} on {profile.label(i)}".replace("  ", " ") for i, c in terms)
        if self.remainder is not None:
            return (
                f"{name} is left out of the minimal parameter set: all but {self.remainder:.1%} of its effect on "
                f"these data is that of {others} (+1 {profile.unit(self.fixed)} on {name} with {change} nearly "
                f"cancels): {name} held at its base value"
            )
        return (
            f"{name} and {others} cannot be told apart by these data "
            f"(+1 {profile.unit(self.fixed)} on {name} with {change} changes no prediction): "
            f"{name} held at its base value"
        )


@dataclass
class Report:
    singular_values: list[float]  # of the column-scaled Jacobian, largest first
    rank: int
    condition: float
    o1: float  # observability index O1 = (prod s_i)^(1/n) / sqrt(m) (Borm & Menq)
    dependencies: list[Dependency] = field(default_factory=list)
    std: np.ndarray | None = None  # per free parameter, internal units
    inflation: np.ndarray | None = None  # sd / sd if the other parameters were known (sqrt of VIF)
    correlation: np.ndarray | None = None
    covariance: np.ndarray | None = None  # of the free parameters, internal units (0 where the data say nothing)


def _turns_a_joint(profile: Profile, index: int) -> bool:
    """Whether the parameter is the offset of a revolute joint (a rotation a joint drives)."""
    return any(op.param == index and op.kind == "r" and op.joint >= 0 for f in profile.frames for op in f.ops)


def zero_columns(J: np.ndarray) -> np.ndarray:
    """Columns of the whitened Jacobian that are round-off, not an effect on any prediction (bool)."""
    norms = np.linalg.norm(J, axis=0)
    return norms <= max(ZERO_RELATIVE * norms.max(initial=0.0), ZERO_WHITENED)


def column_scales(J: np.ndarray) -> np.ndarray:
    """Each column's norm, or 1 for a zero column (so that its round-off stays round-off)."""
    return np.where(zero_columns(J), 1.0, np.linalg.norm(J, axis=0))


def find_dependencies(profile: Profile, J: np.ndarray, free: list[int]) -> list[Dependency]:
    """Free parameters whose Jacobian column earlier columns reproduce, with the combination.

    Columns are taken in the mode's order and kept when they add a direction the kept ones lack
    (Gram-Schmidt on unit columns), so which parameter of a dependent set is held is the profile
    author's choice (the later one), the same on every dataset.
    """
    if J.shape[1] == 0:
        return []
    scale = column_scales(J)
    Js = J / scale
    zero = zero_columns(J)
    # Usually every column adds a direction: one QR says so (each |R_kk| is what column k adds to all before it;
    # with fewer rows than columns some column cannot).
    tall = J.shape[0] >= J.shape[1]
    if tall and not zero.any() and np.all(np.abs(np.diag(np.linalg.qr(Js, mode="r"))) > DEPENDENCE_TOLERANCE):
        return []
    basis = np.zeros((J.shape[0], 0))
    keep: list[int] = []
    out = []
    for k in range(J.shape[1]):
        c = Js[:, k]
        rest = c - basis @ (basis.T @ c)
        rest -= basis @ (basis.T @ rest)  # twice is enough (Kahan)
        if not zero[k] and np.linalg.norm(rest) > DEPENDENCE_TOLERANCE:
            basis = np.column_stack([basis, rest / np.linalg.norm(rest)])
            keep.append(k)
            continue
        out.append(Dependency(free[k], {} if zero[k] else _partners(profile, Js, scale, free, k, keep)[0]))
    return out


def minimal_set(
    profile: Profile, J: np.ndarray, free: list[int], first: frozenset[int] = frozenset()
) -> list[Dependency]:
    """The free parameters outside a minimal identifiable set, each with the combination nearest to it.

    QR with column pivoting (Businger & Golub) of the unit-scaled whitened Jacobian picks one column
    after another, each time the one with the most effect the chosen ones lack, and stops where the
    best remaining one has less than MINIMAL_TOLERANCE of its unit length outside their span. `first`
    (a tracker's registration: a nuisance every calibration must fit) are chosen before any other.
    Run it on the columns `find_dependencies` keeps, so that of an exactly dependent set the profile
    author's choice is held.
    """
    if J.shape[1] == 0:
        return []
    scale = column_scales(J)
    Js = J / scale
    zero = zero_columns(J)
    forced = [k for k in range(len(free)) if free[k] in first and not zero[k]]
    rest = [k for k in range(len(free)) if free[k] not in first and not zero[k]]
    A = Js[:, rest]
    if forced:
        Q, _ = np.linalg.qr(Js[:, forced])
        A = A - Q @ (Q.T @ A)
    keep = list(forced)
    if rest:
        import scipy.linalg  # only here: NumPy has no pivoted QR, and SciPy slows every start

        _, R, pivots = scipy.linalg.qr(A, mode="economic", pivoting=True)
        diag = np.abs(np.diag(R))
        chosen = int(np.sum(diag > MINIMAL_TOLERANCE))  # of unit columns: no relative scale
        keep += [rest[i] for i in pivots[:chosen]]
    keep.sort()  # the mode's order, so that the partners read as in find_dependencies
    out = []
    for k in range(len(free)):
        if k in keep:
            continue
        if zero[k]:
            out.append(Dependency(free[k], {}))
            continue
        partners, remainder = _partners(profile, Js, scale, free, k, keep)
        exact = remainder <= DEPENDENCE_TOLERANCE
        out.append(Dependency(free[k], partners, None if exact else remainder))
    return out


def _partners(
    profile: Profile, Js: np.ndarray, scale: np.ndarray, free: list[int], k: int, keep: list[int]
) -> tuple[dict[int, float], float]:
    """The change of the kept parameters that best cancels +1 (display unit) on parameter k, and the
    share of k's unit column they leave (0 for a strict dependence)."""
    if not keep:
        return {}, 1.0
    c = Js[:, k]
    coef, *_ = np.linalg.lstsq(Js[:, keep], c, rcond=None)
    partners: dict[int, float] = {}
    for a, j in zip(coef, keep, strict=True):
        if abs(a) > 1e-3:
            # J_k / s_k = sum a J_j / s_j, so +1 on p_k and -a s_k / s_j on p_j cancel.
            delta = -a * scale[k] / scale[j]
            partners[free[j]] = (
                delta * _display_per_internal(profile, free[j]) / _display_per_internal(profile, free[k])
            )
    return partners, float(np.linalg.norm(c - Js[:, keep] @ coef))


def _display_per_internal(profile: Profile, index: int) -> float:
    return profile.to_display(index, 1.0)


def report(J: np.ndarray, r: np.ndarray, sigma: float, clusters: np.ndarray | None = None) -> Report:
    """Singular values, rank, condition, O1 and the covariance of the estimate at the solution.

    J, r: Jacobian and residuals of the whitened problem (data rows first, then priors) in the
    free parameters; sigma: the residuals' estimated scale. The covariance is sigma^2 (J^T J)^-1
    when each configuration gives one observation. When a configuration gives several (the 24
    vertices of a board), their errors share that configuration's joint-reading errors and are not
    independent: then the cluster-robust (sandwich) covariance, clustered by shared readings, is used.
    `clusters`: the configuration of each data row.
    """
    m, n = J.shape
    if n == 0:
        return Report([], 0, 1.0, 0.0)
    scale = column_scales(J)
    Js = J / scale
    s = np.linalg.svd(Js, compute_uv=False)
    rank = int(np.sum(s > DEPENDENCE_TOLERANCE * s[0]))
    condition = float(s[0] / s[-1]) if s[-1] > 0 else float("inf")
    o1 = float(np.exp(np.mean(np.log(np.maximum(s, 1e-300)))) / np.sqrt(m))
    bread = np.linalg.pinv(Js.T @ Js, rcond=1e-12, hermitian=True)
    if clusters is not None:
        # CR2 (Bell & McCaffrey): each cluster's residuals are scaled by (I - H_gg)^(-1/2) to undo
        # the cluster's own pull on the fit, H_gg = J_g B J_g^T the cluster's block of the hat
        # matrix. Plain clustered sandwiches underestimate with a few dozen clusters.
        rows = len(clusters)
        w, V = np.linalg.eigh(bread)
        root = (V * np.sqrt(np.maximum(w, 0.0))) @ V.T  # B^(1/2)
        meat = np.zeros((n, n))
        labels = np.unique(clusters)
        for label in labels:
            sel = clusters == label
            Jg, rg = Js[:rows][sel], r[:rows][sel]
            U, S, _ = np.linalg.svd(Jg @ root, full_matrices=False)
            shrink = 1.0 / np.sqrt(np.maximum(1.0 - S**2, 1e-6)) - 1.0
            adjusted = rg + U @ (shrink * (U.T @ rg))
            score = Jg.T @ adjusted
            meat += np.outer(score, score)
        cov_scaled = bread @ meat @ bread
    else:
        cov_scaled = sigma**2 * bread
    cov = cov_scaled / np.outer(scale, scale)
    std = np.sqrt(np.maximum(np.diag(cov), 0.0))
    std[zero_columns(J)] = np.inf  # the data say nothing about it (the pseudo-inverse would say 0)
    with np.errstate(invalid="ignore", divide="ignore"):
        corr = cov / np.outer(std, std)
    # With unit columns, (J^T J)^-1_ii is the variance inflation factor of parameter i.
    inflation = np.sqrt(np.maximum(np.diag(bread), 1.0))
    return Report(
        s.tolist(),
        rank,
        condition,
        o1,
        std=std,
        correlation=np.nan_to_num(corr),
        inflation=inflation,
        covariance=cov,
    )


def strong_correlations(profile: Profile, corr: np.ndarray, free: list[int]) -> list[Correlation]:
    out = []
    for a in range(len(free)):
        for b in range(a + 1, len(free)):
            if abs(corr[a, b]) >= CORRELATION_LISTED:
                out.append(Correlation(profile.label(free[a]), profile.label(free[b]), float(corr[a, b])))
    return sorted(out, key=lambda c: -abs(c.rho))


def identifiability_report(
    profile: Profile, rep: Report, free: list[int], dependencies: list[Dependency]
) -> IdentifiabilityReport:
    """The report a calibration carries, by parameter name."""
    names = [profile.parameters[i].name for i in free]
    return IdentifiabilityReport(
        free=names,
        held_fixed=[HeldParameter(profile.parameters[d.fixed].name, d.describe(profile)) for d in dependencies],
        singular_values=rep.singular_values,
        rank=rep.rank,
        condition=rep.condition,
        o1=rep.o1,
        correlations=[] if rep.correlation is None else strong_correlations(profile, rep.correlation, free),
        inflation={} if rep.inflation is None else {n: float(v) for n, v in zip(names, rep.inflation, strict=True)},
    )


def weak_parameters(
    profile: Profile, rep: Report, free: list[int], nuisance: frozenset[int] = frozenset()
) -> list[tuple[list[str], str]]:
    """One warning per group of parameters the data determine only in combination: (their labels, the message).

    A parameter is weak when the others mimic more than 99.75% of its effect (its standard
    deviation is at least INFLATION_WARNING times what it would be alone); weak parameters that
    trade off against each other (|correlation| >= 0.8) form one group. `nuisance` parameters (a
    tracker's registration, which nobody applies to the robot) are not warned about.
    """
    if rep.inflation is None or rep.correlation is None:
        return []
    weak = [k for k in np.argsort(-rep.inflation) if rep.inflation[k] >= INFLATION_WARNING and free[k] not in nuisance]
    group = {k: k for k in weak}

    def root(k: int) -> int:
        while group[k] != k:
            k = group[k]
        return k

    for a in weak:
        for b in weak:
            if a < b and abs(rep.correlation[a, b]) >= 0.8:
                group[root(b)] = root(a)
    out = []
    for head in dict.fromkeys(root(k) for k in weak):
        members = [k for k in weak if root(k) == head]
        names = ", ".join(profile.label(free[k]) for k in members)
        lo, hi = min(rep.inflation[members]), max(rep.inflation[members])
        spread = f"{hi:.0f}x" if round(lo) == round(hi) else f"{lo:.0f}-{hi:.0f}x"
        a = members[0]
        b = max((j for j in range(len(free)) if j != a), key=lambda j: abs(rep.correlation[a, j]))
        out.append(
            (
                [profile.label(free[k]) for k in members],
                f"{names}: weakly determined by these data (standard deviation {spread} what it would be if the "
                f"other parameters were known); {profile.label(free[a])} trades off against {profile.label(free[b])} "
                f"(correlation {rep.correlation[a, b]:+.2f}): the data fix a combination of them, not each one; "
                "more varied configurations separate them",
            )
        )
    return out
