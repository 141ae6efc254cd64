"""Planning the configurations of a calibration, and predicting its accuracy before the robot moves.

The linearised calibration at the base model (nominal, or the robot's calibration) tells how well a
set of configurations determines the parameters: each configuration c adds its whitened Jacobian's
information J_c^T J_c (the sensor's noise model at that configuration: a stereo head's depth noise
grows with z^2, along the view ray only; a pixel's is the same everywhere; plus the rounding of the
joint readings, which a configuration's observations share), and the covariance of the estimate is
C = (sum_c J_c^T J_c + priors)^-1 over the mode's identifiable (minimal) parameter set.

From C follows the predicted error of the calibrated model anywhere in the workspace: at an
observation with prediction Jacobian G (measurement units per parameter), the error covariance is
G C G^T, so its expected size is sqrt(trace(G C G^T)) (cm, px). Over a set of workspace
configurations E (random visible ones, the same kind the held-out check draws), the mean of
trace(G C G^T) is trace(C A) with A = mean G^T G: the task-space (I- or V-optimal) criterion this
planner minimises. It predicts the held-out error directly; D-optimality (max log det of the
information, FIGAROH's choice, and Sun & Hollerbach's O1) weighs every parameter direction alike,
whatever its effect on what the user measures, and O3/O4 look at one singular value only
(benchmarks/planning.py compares them on held-out error against the simulator's truth).
A robot whose calibration is its joint offsets, stored on it and used in every pose (the NAO: its mode says
`plan: offsets`), is planned with A restricted to the offsets instead, the sum of their variances (A-optimal):
the error over a NAO camera's workspace hardly depends on how a leg's three pitch offsets share their sum, and
the robot's walking does (benchmarks/nao_offsets.py: the knee's std 0.14 -> 0.115 deg at 60 frames).

The search: candidates inside the joint limits less the safety margin and predicted visible with the
base model (`Visibility`: field of view, the arm hiding the sphere, a board's obliquity);
greedy selection with rank-k updates of C (Sherman-Morrison-Woodbury; k the rows of one
configuration, a board's 48 compressed to at most the parameter count by QR), then Fedorov exchange
passes that swap a chosen configuration for a candidate while the criterion falls. Uniform draws are
sparse where the best configurations lie (near the sensor, at the edge of what it sees), so a plan from
drawn candidates then draws more about the configurations it chose (REFINE_DEG on every joint) and
exchanges again: a local refinement, about 8% off the predicted error of a 32-configuration Robonaut plan.
The choosing and exchanging is selection.py's. A plan of a few hundred configurations takes seconds
(benchmarks/plan_speed.py): `plan` reports where it is after each step (`progress`: each configuration chosen,
each one reconsidered by an exchange) and stops when its caller asks (`should_stop`, checked at each step: it
raises Cancelled).
The workspace the error is averaged over is not the plan's candidates (which keep wider margins) but
configurations the sensor sees with the usual margin, the kind a held-out check draws (`workspace`).
"""

from __future__ import annotations

import itertools
import math
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Literal

import numpy as np

from ..dataset import Dataset
from ..errors import Cancelled, InputError
from ..model.kinematics import sensor_points
from ..model.profile import Profile
from ..vision.finders import finder_for, found_targets
from ..vision.sampling import Sampler
from ..vision.visibility import MIN_SPHERE_SHARE, Visibility
from .calibrate import observed_mode
from .identifiability import find_dependencies, minimal_set
from .problem import Problem
from .registration import registration_params
from .selection import Selection, inverse

Criterion = Literal["task", "offsets", "d", "random"]
CRITERIA: tuple[str, ...] = ("task", "offsets", "d", "random")

JOINT_MARGIN_DEG = 1.0  # kept clear of every revolute joint's limits (the drivers' default safety margin)
JOINT_MARGIN_M = 0.001  # kept clear of every prismatic joint's limits (the drivers' default)
# Kept clear of the image border by candidates and the workspace: more than the dry run's 10 px, since a
# model error of a few cm (a robot never calibrated) moves what the sensor sees. A finder may ask for more
# (`plan_margins`: a stereo head's sphere).
VIEW_MARGIN_PX = 40.0
CHECK_BATCH = 32  # candidates checked for visibility at once (the check is vectorised)
# Candidate configurations drawn (uniform sampling; the costly visibility check is lazy and batched): the
# predicted error of a 32-configuration Robonaut plan falls 5% from 6000 to 16000.
CANDIDATES = 16000
# Within a seed's neighbourhood (`Around`) fewer do: on the sample arm (docs/handeye.md) a 12-configuration plan
# from 2000 predicts an error within 3% of one from 16000, in a sixth of the time.
AROUND_CANDIDATES = 2000
# A stance structure (NAO): at least this many batches of 32 stances per target (about 400 visible frames,
# each of 48 rows: as much information per candidate as 16 of the 3-row uniform ones), more for a larger count.
STANCE_BATCHES = 12
STANCE_CANDIDATES = 400
MAX_STANCE_BATCHES = 200
# Where uniform draws see the target this rarely (a wrist camera and a board on the table: 0.25% of the sample arm's
# configurations; Robonaut's sphere 11%, the Motoman's tracker all), each later draw takes half its configurations
# near those already seen, this far on every joint: the sample arm's 16000 candidates in about 4 s, where fifty
# uniform draws of 16000 found about 1100, most of a 14.5-s plan (benchmarks/handeye_plan.py).
SPARSE_SHARE = 0.02
SPARSE_SPREAD_DEG = 10.0
WORKSPACE = 300  # configurations the predicted workspace error is averaged over
# Candidates linearised at once by `design`: its memory (a board's 84 rows each: 16000 at once took 0.6 GB more).
DESIGN_CHUNK = 2000
EXCHANGE_PASSES = 2
# Local refinement (module doc): candidates drawn about each chosen configuration, with this spread on every
# joint, then one exchange pass. On Robonaut full (32 configurations, seeds 0-3) the expected held-out error
# of the frames the true robot shows fell from 0.090 to 0.088 cm with 5 deg, 0.086 with 8 deg, 0.085 with
# 12 deg; the planner's own prediction from 0.085 to 0.078.
REFINE_DRAWS = 24
REFINE_DEG = 12.0
REFINE_PASSES = 1
REFINE_CHUNK = 100  # chosen configurations whose draws are checked and added at once
# An information matrix (scaled by a typical configuration's) whose smallest eigenvalue is below this share
# of its largest leaves a parameter direction undetermined: no finite prediction.
UNDETERMINED = 1e-10
# An eigenvalue of a configuration's information below this share of its largest is round-off (`_whitened`).
EIGEN_ROUND_OFF = 1e-13
# Information every parameter starts with, relative to one typical configuration's: it only keeps the
# greedy start (fewer configurations than parameters) finite; its effect on a plan's figures is below 1e-5.
REGULARISATION = 1e-6


@dataclass
class ParameterStd:
    name: str
    unit: str
    std: float  # predicted standard deviation, display unit


@dataclass
class AccuracyPrediction:
    """What a set of configurations predicts about its calibration, from the noise model alone."""

    n: int  # configurations
    unit: str  # of the workspace error (the measurement's unit: cm, px, m)
    mean: float  # mean over the workspace of each point's expected error sqrt(trace(G C G^T))
    rms: float
    max: float
    parameters: list[ParameterStd]  # the estimated (identifiable) parameters
    held: list[str]  # parameters of the mode held at their base value (not identifiable)

    @property
    def determined(self) -> bool:
        """Whether the configurations determine every estimated parameter (else the figures are inf)."""
        return math.isfinite(self.mean)

    def to_dict(self) -> dict:
        """JSON-ready: None for an undetermined (infinite) figure."""

        def finite(v: float) -> float | None:
            return v if math.isfinite(v) else None

        return {
            "n": self.n,
            "unit": self.unit,
            "mean": finite(self.mean),
            "rms": finite(self.rms),
            "max": finite(self.max),
            "parameters": [{"name": p.name, "unit": p.unit, "std": finite(p.std)} for p in self.parameters],
            "held": list(self.held),
        }

    def __str__(self) -> str:
        if not self.determined:
            return f"{self.n} configurations do not determine every parameter: no prediction of the error"
        return (
            f"predicted error over the workspace: mean {self.mean:.3g} {self.unit}, RMS {self.rms:.3g}, "
            f"max {self.max:.3g} ({self.n} configurations)"
        )


@dataclass
class Plan:
    """N configurations to measure (rad, the profile's joint order) and the target each shows."""

    q: np.ndarray
    targets: np.ndarray
    criterion: str
    predicted: AccuracyPrediction
    history: list[float] = field(default_factory=list)  # predicted mean error after each greedy pick
    candidates: int = 0
    seconds: float = 0.0


@dataclass(frozen=True)
class PlanProgress:
    """Where a plan is (plan's `progress`): its stage, the steps of that stage done and to do, and the share
    of the whole plan's work done, estimated from the steps (each costs about one search of the candidates)."""

    stage: str  # "drawing" candidates, "choosing" the configurations, "exchanging", "refining" (module doc)
    done: int
    total: int
    fraction: float


# The share of a plan's work before its first choice (drawing the candidates, the linearised calibration):
# about 2 s of a 300-configuration Robonaut plan's 40.
DRAWING_SHARE = 0.05


class _Pace:
    """Reports a plan's steps to `progress` and raises Cancelled at a step once `should_stop` says so.
    `stages`: (name, steps, weight) in order; the weights share the work after drawing."""

    def __init__(
        self,
        progress: Callable[[PlanProgress], None] | None,
        should_stop: Callable[[], bool] | None,
        stages: list[tuple[str, int, float]],
    ) -> None:
        self.progress, self.should_stop = progress, should_stop
        weight = sum(w for _, _, w in stages) or 1.0
        self.stages: dict[str, tuple[int, float, float]] = {}  # name: steps, share before it, its share
        before = DRAWING_SHARE
        for name, steps, w in stages:
            share = (1.0 - DRAWING_SHARE) * w / weight
            self.stages[name] = (max(steps, 1), before, share)
            before += share

    def __call__(self, stage: str, done: int = 0) -> None:
        if self.should_stop is not None and self.should_stop():
            raise Cancelled("the plan was cancelled")
        if self.progress is None:
            return
        if stage == "drawing":
            self.progress(PlanProgress(stage, done, 1, DRAWING_SHARE * done))
            return
        steps, before, share = self.stages[stage]
        done = min(done, steps)
        self.progress(PlanProgress(stage, done, steps, before + share * done / steps))


@dataclass
class Design:
    """The linearised calibration over a pool of candidate configurations (module doc)."""

    profile: Profile
    free: list[int]  # the identifiable parameters (columns)
    held: list[int]
    L: np.ndarray  # (N, k, n) each candidate's information factor: L^T L = J_c^T J_c
    A: np.ndarray  # (n, n) mean G^T G over the workspace observations
    G: np.ndarray  # (W, dim, n) the workspace observations' prediction Jacobians
    prior: np.ndarray  # (n, n) information from the mode's priors
    scale: np.ndarray  # (n,) a typical configuration's information per parameter (for the regularisation)
    q: np.ndarray  # (N, n_joints) rad
    targets: np.ndarray  # (N,)
    unit: str
    p: np.ndarray  # the base model it is linearised at
    ties: tuple
    isotropic: bool = False

    def start(self, regularise: bool = True) -> np.ndarray:
        """The information before any configuration: the priors (and the regularisation)."""
        return self.prior + (REGULARISATION * np.diag(self.scale) if regularise else 0.0)

    def information(self, rows: np.ndarray) -> np.ndarray:
        L = self.L[rows].reshape(-1, self.L.shape[2])
        return L.T @ L

    def factors(self, q: np.ndarray, targets: np.ndarray) -> np.ndarray:
        """Information factors (N, k, n) of configurations outside the pool (frames measured already)."""
        data = _dataset(self.profile, self.p, q, targets)
        problem = Problem(self.profile, data, self.free, self.p, self.ties, noise_model=False)
        _, J = problem.residuals_jacobian(problem.x0)
        return _compress(_whitened(problem, J[: problem.n_data_rows], self.p, self.isotropic))

    def extend(self, q: np.ndarray, targets: np.ndarray) -> None:
        """More candidates in the pool (after the ones it has, so chosen indices stay valid)."""
        L = self.factors(q, targets)
        k = max(L.shape[1], self.L.shape[1])
        pad = [((0, 0), (0, k - x.shape[1]), (0, 0)) for x in (self.L, L)]
        self.L = np.concatenate([np.pad(self.L, pad[0]), np.pad(L, pad[1])])
        self.q = np.concatenate([self.q, q])
        self.targets = np.concatenate([self.targets, targets])

    def predict(self, M: np.ndarray, n: int) -> AccuracyPrediction:
        """The prediction from an information matrix M over the free parameters (inf where the
        configurations do not determine them all)."""
        unit_scale = 1.0 / np.sqrt(self.scale)
        eig = np.linalg.eigvalsh(M * unit_scale[:, None] * unit_scale[None, :])
        if len(eig) and eig[0] <= UNDETERMINED * max(eig[-1], 1e-300):
            per_obs, std = np.full(len(self.G), np.inf), np.full(len(self.free), np.inf)
        else:
            C = inverse(M)
            per_obs = _expected_errors(self.G, C)
            std = np.sqrt(np.maximum(np.diag(C), 0.0))
        prof = self.profile
        params = [
            ParameterStd(prof.parameters[i].name, prof.unit(i), abs(prof.to_display(i, s)))
            for i, s in zip(self.free, std, strict=True)
        ]
        return AccuracyPrediction(
            n,
            self.unit,
            float(per_obs.mean()),
            float(np.sqrt(np.mean(per_obs**2))),
            float(per_obs.max()),
            params,
            [prof.parameters[i].name for i in self.held],
        )


@dataclass(frozen=True)
class Around:
    """A neighbourhood a plan keeps to: every joint within `spread_rad` of `q_rad` (the seed of a first plan
    for unknown poses: calib_core.estimation.plan_seed)."""

    q_rad: np.ndarray
    spread_rad: float


def _limits_less_margin(
    profile: Profile, margin_deg: float, around: Around | None = None
) -> tuple[np.ndarray, np.ndarray]:
    """The joint limits less the margin, and within the neighbourhood when one is given."""
    lo, hi = profile.limits_less_margin(margin_deg, JOINT_MARGIN_M)
    if around is None:
        return lo, hi
    return np.maximum(lo, around.q_rad - around.spread_rad), np.minimum(hi, around.q_rad + around.spread_rad)


def within_margin(
    profile: Profile, q: np.ndarray, margin_deg: float = JOINT_MARGIN_DEG, around: Around | None = None
) -> np.ndarray:
    """Whether each configuration (N, n_joints) rad lies inside the joint limits less the margin (and the
    neighbourhood, when given) (N,)."""
    lo, hi = _limits_less_margin(profile, margin_deg, around)
    return np.all((q >= lo - 1e-12) & (q <= hi + 1e-12), axis=1)


def candidates(
    profile: Profile,
    p_base: np.ndarray,
    *,
    seed: int = 0,
    count: int | None = None,
    margin_deg: float = JOINT_MARGIN_DEG,
    occlusion: bool = True,
    view_margin_px: float = VIEW_MARGIN_PX,
    obliquity_margin_deg: float = 0.0,
    should_stop: Callable[[], bool] | None = None,
    around: Around | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Configurations (N, n_joints) rad and their targets (N,): inside the joint limits less the margin
    (and `around`'s neighbourhood, when given) and predicted visible with the base model. A profile with a
    stance structure (NAO: a leg lifted, the head in its postures aimed at the board) gives that structure's
    frames; any other, uniform draws (where they rarely see the target, half of each later draw near what the
    earlier ones saw: SPARSE_SHARE). `count`: about how many (default: CANDIDATES, a stance structure
    STANCE_CANDIDATES). `occlusion=False`: without the costly check that the arm leaves a stereo head's sphere in
    view (`CandidateView` makes it for the configurations a plan picks). `view_margin_px`: kept clear of
    the image border; `obliquity_margin_deg`: a board seen this much less obliquely than its finder's limit.
    `should_stop`: asked before each batch drawn; Cancelled once it says yes."""

    def check() -> None:
        if should_stop is not None and should_stop():
            raise Cancelled("the draw was cancelled")

    view = Visibility(profile, p_base, margin_px=view_margin_px, obliquity_margin_deg=obliquity_margin_deg)
    sampler = Sampler(view, np.random.default_rng(seed))
    if profile.simulation.get("sampling", {}).get("kind") == "contact":
        raise InputError(f"robot '{profile.name}' is calibrated from contacts with planes: there is nothing to plan")
    if _stances(profile):
        count = STANCE_CANDIDATES if count is None else count
        parts = [sampler.stance_frames(1)[:2] for _ in range(STANCE_BATCHES)]
        while sum(len(p[0]) for p in parts) < count and len(parts) < MAX_STANCE_BATCHES:
            check()
            parts.append(sampler.stance_frames(1)[:2])
        q, targets = np.concatenate([p[0] for p in parts]), np.concatenate([p[1] for p in parts])
    else:
        count = CANDIDATES if count is None else count
        lo, hi = _limits_less_margin(profile, margin_deg, around)
        target = profile.data.target if profile.data.target is not None else (profile.data.target_default or 0)
        found = np.zeros((0, len(lo)))
        sparse = False
        for _ in range(50):
            check()
            draw = sampler.rng.uniform(lo, hi, (count, len(lo)))
            if sparse and len(found):  # half of the draw near what the sensor saw, the other half still anywhere
                near = found[sampler.rng.integers(len(found), size=count // 2)]
                spread = sampler.rng.normal(0.0, math.radians(SPARSE_SPREAD_DEG), near.shape)
                draw[: count // 2] = np.clip(near + spread, lo, hi)
            seen = view.sees(draw, np.full(count, target), occlusion=occlusion)
            sparse = sparse or seen.mean() < SPARSE_SHARE
            found = np.concatenate([found, draw[seen]])
            if len(found) >= count:
                break
        q = found[:count]
        targets = np.full(len(q), target)
    keep = within_margin(profile, q, margin_deg, around)
    if keep.sum() == 0:
        where = "its joint limits" if around is None else f"{math.degrees(around.spread_rad):g} deg of the seed"
        raise InputError(f"no configuration of robot '{profile.name}' is predicted visible within {where}")
    return q[keep], targets[keep]


def workspace(
    profile: Profile,
    p_base: np.ndarray,
    seed: int = 0,
    should_stop: Callable[[], bool] | None = None,
    around: Around | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Where the predicted error is averaged: WORKSPACE configurations the sensor sees with the base model,
    VIEW_MARGIN_PX clear of the border and a stereo head's sphere not hidden by the arm (what a held-out
    check draws), not the plan's candidates, which keep a stereo head's wider margins. `should_stop`: as
    candidates() asks it; `around`: the plan's neighbourhood, where its calibration is used first."""
    return candidates(profile, p_base, seed=seed + 1, count=WORKSPACE, should_stop=should_stop, around=around)


def _stances(profile: Profile) -> bool:
    """Whether the profile's configurations have a stance structure (NAO: a leg lifted, the head's postures)."""
    return profile.simulation.get("sampling", {}).get("kind") == "stances"


def _dataset(profile: Profile, p: np.ndarray, q: np.ndarray, targets: np.ndarray) -> Dataset:
    """The observations of the data format's sensor that configurations q would give with model p,
    noise-free (their predictions): one per point of a grid target, else one per configuration."""
    s = profile.data.sensor
    gridded = np.array([t.grid is not None for t in profile.targets])
    counts = np.array([1 if t.grid is None else len(t.grid) for t in profile.targets])[targets]
    x = sensor_points(profile, p, q, targets)
    k = np.arange(x.shape[1])
    keep = k[None, :] < counts[:, None]
    cfg = np.repeat(np.arange(len(q)), counts)
    vertex = np.where(gridded[targets[cfg]], np.arange(len(cfg)) - np.repeat(np.cumsum(counts) - counts, counts), -1)
    point = np.full((len(cfg), 3), np.nan)
    for t in np.unique(targets):
        grid = profile.targets[t].grid
        rows = targets[cfg] == t
        if grid is not None:
            point[rows] = grid[vertex[rows]]
    return Dataset(
        robot=profile.name,
        frame_ids=np.arange(1, len(q) + 1),
        joints=q,
        cfg=cfg,
        target=targets[cfg],
        point=point,
        vertex=vertex.astype(int),
        measured=profile.sensors[s].predict(p, x[keep])[0],
        sensor=np.full(len(cfg), s),
        source="plan",
    )


def _row_slots(problem: Problem) -> tuple[np.ndarray, np.ndarray, int]:
    """Each data row's configuration and its position among that configuration's rows, and the most rows
    any configuration has."""
    cfg_of_row = np.concatenate([np.repeat(problem.data.cfg[b.obs], b.dim) for b in problem.blocks])
    counts = np.bincount(cfg_of_row, minlength=problem.data.n_configurations)
    order = np.argsort(cfg_of_row, kind="stable")
    slot = np.empty(len(order), int)
    slot[order] = np.arange(len(order)) - np.repeat(np.cumsum(counts) - counts, counts)
    return cfg_of_row, slot, int(counts.max(initial=1))


def _whitened(problem: Problem, J: np.ndarray, p: np.ndarray, isotropic: bool) -> np.ndarray:
    """Each configuration's information J^T C^-1 J as a factor B (N, k, n), B^T B = J^T C^-1 J: J the data rows of
    an unweighted Jacobian that configuration has, C their whole covariance, the sensor's noise model per
    observation (D, block-diagonal) plus what rounding the joint readings to their encoder step adds (U U^T, one
    column per quantised joint), which the observations of one configuration share (a board's 24 vertices move
    together when a reading is off). By Woodbury's identity with D's blocks whitened first, J_d = D^-1/2 J,
    U_d = D^-1/2 U: J^T C^-1 J = J_d^T J_d - J_d^T U_d (I + U_d^T U_d)^-1 U_d^T J_d, whose size is the
    parameters' and the joints', not the rows' (a board's 84: the dense whitening took a third of a hand-eye
    plan); a configuration of fewer rows than parameters is whitened whole, B = L^-1 J_d with L L^T = I + U_d
    U_d^T. `isotropic`: unit covariance instead (the rows themselves, zero-padded)."""
    cfg, slot, r = _row_slots(problem)
    N, n = problem.data.n_configurations, J.shape[1]
    if isotropic:
        Jc = np.zeros((N, r, n))
        Jc[cfg, slot] = J
        return Jc
    profile = problem.profile
    steps = {
        op.param: profile.joints[op.joint].reading_sd
        for f in profile.frames
        for op in f.ops
        if op.joint >= 0 and profile.joints[op.joint].reading_sd > 0
    }
    U = np.zeros((len(J), len(steps)))
    if steps:
        U = _offsets_jacobian(problem, J, list(steps), p) * np.array(list(steps.values()))
    Jd, Ud = np.empty_like(J), np.empty_like(U)
    for b in problem.blocks:
        rows = np.arange(b.rows.start, b.rows.stop).reshape(-1, b.dim)  # (n_obs, dim)
        L = np.linalg.cholesky(b.sensor.covariance(p, problem.data.measured[b.obs, : b.dim]))
        Jd[rows], Ud[rows] = _lower_solve(L, J[rows]), _lower_solve(L, U[rows])
    Jc, Uc = np.zeros((N, r, n)), np.zeros((N, r, len(steps)))  # by configuration, zero-padded
    Jc[cfg, slot], Uc[cfg, slot] = Jd, Ud
    if r <= n:  # few rows (a sphere's 3): whitened whole by the Cholesky factor of I + U_d U_d^T
        cov = np.eye(r) + Uc @ Uc.transpose(0, 2, 1)
        return _lower_solve(np.linalg.cholesky(cov), Jc)
    info = Jc.transpose(0, 2, 1) @ Jc
    if steps:
        JtU = Jc.transpose(0, 2, 1) @ Uc
        inner = np.eye(len(steps)) + Uc.transpose(0, 2, 1) @ Uc
        info -= JtU @ np.linalg.solve(inner, JtU.transpose(0, 2, 1))
    w, V = np.linalg.eigh(0.5 * (info + info.transpose(0, 2, 1)))
    # Directions the configuration does not inform are zero to the eigensolver's round-off (1e-16 of the largest),
    # not below _compress's cut (1e-12 of the largest singular value, 1e-24 of the eigenvalue): made zero here.
    w = np.where(w > EIGEN_ROUND_OFF * w.max(axis=1, keepdims=True), w, 0.0)
    return np.sqrt(w)[:, :, None] * V.transpose(0, 2, 1)


def _offsets_jacobian(problem: Problem, J: np.ndarray, params: list[int], p: np.ndarray) -> np.ndarray:
    """The Jacobian of the data rows (J's, unweighted, at p) with respect to the joint offsets `params`: J's own
    columns where the problem estimates each offset alone (no tie moves another parameter with it) at p itself,
    else a problem's of its own (its kinematics again: a third of a plan's design)."""
    cols = []
    if np.array_equal(problem.params(problem.x0), p):
        for i in params:
            k = problem.free.index(i) if i in problem.free else -1
            if k < 0 or np.count_nonzero(problem.A[:, k]) != 1:
                break
            cols.append(k)
    if len(cols) == len(params):
        return J[:, cols]
    probe = Problem(problem.profile, problem.data, params, p, noise_model=False)
    return probe.residuals_jacobian(probe.x0)[1][: probe.n_data_rows]


def _lower_solve(L: np.ndarray, B: np.ndarray) -> np.ndarray:
    """L^-1 B of a batch, L (N, d, d) lower triangular, B (N, d, m): by forward substitution over the d rows,
    each step over the whole batch (a batched LAPACK solve of 16,000 3 x 3 systems costs ten times more)."""
    X = np.empty(np.broadcast_shapes(L.shape[:-1], B.shape[:-1]) + B.shape[-1:])
    for i in range(L.shape[-1]):
        X[..., i, :] = (B[..., i, :] - np.einsum("...j,...jm->...m", L[..., i, :i], X[..., :i, :])) / L[..., i, i, None]
    return X


def design(
    profile: Profile,
    mode: str,
    p_base: np.ndarray,
    q: np.ndarray,
    targets: np.ndarray,
    *,
    workspace: tuple[np.ndarray, np.ndarray] | None = None,
    isotropic: bool = False,
    seed: int = 0,
) -> Design:
    """The linearised calibration in `mode` at p_base over candidate configurations q (rad) with their
    targets. `workspace`: where the predicted error is averaged (default: WORKSPACE of the candidates);
    `isotropic`: weigh every measurement alike (to show what ignoring the noise model costs)."""
    _, one = np.unique(targets, return_index=True)  # which parameters the data observe: their targets say
    m = observed_mode(profile, _dataset(profile, p_base, q[one], targets[one]), profile.mode(mode))
    parts = []
    for at in range(0, len(q), DESIGN_CHUNK):
        data = _dataset(profile, p_base, q[at : at + DESIGN_CHUNK], targets[at : at + DESIGN_CHUNK])
        problem = Problem(profile, data, list(m.free), p_base, m.ties, m.priors, noise_model=False)
        _, J = problem.residuals_jacobian(problem.x0)
        parts.append(_whitened(problem, J[: problem.n_data_rows], p_base, isotropic))
    rows = max(x.shape[1] for x in parts)
    Jw = np.concatenate([np.pad(x, ((0, 0), (0, rows - x.shape[1]), (0, 0))) for x in parts])
    # Which parameters the data determine is a property of the robot and the workspace: a few hundred
    # configurations show it as well as thousands (and the QR and least squares cost 20 times less).
    some = Jw[:WORKSPACE].reshape(-1, Jw.shape[2])
    deps = find_dependencies(profile, some, problem.free)
    dependent = {d.fixed for d in deps}
    kept = [k for k, i in enumerate(problem.free) if i not in dependent]
    first = frozenset(registration_params(profile, data.sensors))
    deps += minimal_set(profile, some[:, kept], [problem.free[k] for k in kept], first)
    held = sorted({d.fixed for d in deps})
    cols = [k for k, i in enumerate(problem.free) if i not in held]
    free = [problem.free[k] for k in cols]
    Jc = _compress(Jw[:, :, cols])
    prior_rows = J[problem.n_data_rows :][:, cols]
    scale = np.einsum("nki,nki->i", Jc, Jc) / len(q)
    scale = np.where(scale > 0, scale, 1.0)
    if workspace is None:
        pick = np.random.default_rng(seed).permutation(len(q))[:WORKSPACE]
        workspace = (q[pick], targets[pick])
    G, unit = _workspace_jacobians(profile, m.ties, p_base, free, *workspace)
    A = np.einsum("wdi,wdj->ij", G, G) / len(G)
    return Design(
        profile, free, held, Jc, A, G, prior_rows.T @ prior_rows, scale, q, targets, unit, p_base, m.ties, isotropic
    )


def _compress(Jc: np.ndarray) -> np.ndarray:
    """The same information J^T J per configuration in as few rows as its rank (a board's 48 rows move
    only its own leg's parameters and the camera's: 12 of 21): diag(s) V^T of the SVD, zero-padded."""
    if Jc.shape[1] <= 3:
        return Jc
    _, sv, Vt = np.linalg.svd(Jc, full_matrices=False)
    k = max(1, int(np.sum(sv > 1e-12 * sv.max(initial=0.0), axis=1).max(initial=1)))
    return sv[:, :k, None] * Vt[:, :k]


def _workspace_jacobians(
    profile: Profile, ties: tuple, p: np.ndarray, free: list[int], q: np.ndarray, targets: np.ndarray
) -> tuple[np.ndarray, str]:
    """Each workspace observation's prediction Jacobian (W, dim, n), unweighted, and its unit."""
    data = _dataset(profile, p, q, targets)
    problem = Problem(profile, data, free, p, ties, noise_model=False)
    _, J = problem.residuals_jacobian(problem.x0)
    blocks = problem.blocks
    dim = max(b.dim for b in blocks)
    parts = []
    for b in blocks:
        Jb = J[b.rows].reshape(-1, b.dim, len(free))
        parts.append(np.pad(Jb, ((0, 0), (0, dim - b.dim), (0, 0))))
    return np.concatenate(parts), blocks[0].sensor.unit


def plan_margins(profile: Profile) -> tuple[float, float, float]:
    """What a plan's configurations keep clear with the base model: px from the image border, the share
    of a stereo head's sphere outline the arm must leave free, and deg below a board's obliquity limit; more
    than these defaults where the data sensor's finder asks for more (`Finder.plan_margins`: a stereo head's
    sphere; `Finder.plan_obliquity_margin_deg`: the NAO's sandals)."""
    s = profile.data.sensor
    margin_px, share, obliquity_deg = VIEW_MARGIN_PX, MIN_SPHERE_SHARE, 0.0
    for t in found_targets(profile, s):
        finder = finder_for(profile, s, t)
        if finder is None:
            continue
        obliquity_deg = max(obliquity_deg, finder.plan_obliquity_margin_deg)
        if finder.plan_margins is not None:
            margin_px, share = max(margin_px, finder.plan_margins[0]), max(share, finder.plan_margins[1])
    return margin_px, share, obliquity_deg


class CandidateView:
    """Whether the base model predicts candidates visible with a plan's margins (`plan_margins`),
    occlusion by the robot's body included; checked when first asked and remembered. `in_view`: the candidates
    have their targets in view with those margins already (drawn by `candidates`, as `extend`'s are): only what
    hides them is left to check."""

    def __init__(
        self, profile: Profile, p: np.ndarray, q: np.ndarray, targets: np.ndarray, *, in_view: bool = False
    ) -> None:
        margin_px, share, obliquity_deg = plan_margins(profile)
        self.view = Visibility(profile, p, margin_px=margin_px, sphere_share=share, obliquity_margin_deg=obliquity_deg)
        self.q, self.targets = q, targets
        self.in_view = in_view
        self.known = np.full(len(q), -1, np.int8)  # -1: not checked yet, else 0/1

    def extend(self, q: np.ndarray, targets: np.ndarray) -> None:
        """More candidates (as `Design.extend`) in view with the plan's margins, not checked for what hides them."""
        self.q, self.targets = np.concatenate([self.q, q]), np.concatenate([self.targets, targets])
        self.known = np.concatenate([self.known, np.full(len(q), -1, np.int8)])

    def __call__(self, cs: np.ndarray) -> np.ndarray:
        """Whether each candidate (indices) is visible (bool array)."""
        new = cs[self.known[cs] < 0]
        if len(new):
            self._check(new)
        return self.known[cs] == 1

    def first(self, cs: np.ndarray) -> int:
        """The position in cs (indices, best first) of the first candidate visible, -1 if none is. Those not
        checked yet are checked CHECK_BATCH at a time in cs's order, the next ones too: a check's cost is mostly
        its call's (3 ms, 70 us a candidate), and an exchange asks again about nearly the same best candidates."""
        at = 0
        while True:
            known = self.known[cs[at:]]
            ahead = np.flatnonzero(known != 0)
            if not len(ahead):
                return -1
            at += int(ahead[0])
            if known[ahead[0]] == 1:
                return at
            self._check(cs[at:][known[ahead[0] :] < 0][:CHECK_BATCH])

    def _check(self, cs: np.ndarray) -> None:
        q, targets = self.q[cs], self.targets[cs]
        self.known[cs] = self.view.clear(q, targets) if self.in_view else self.view.sees(q, targets)


def plan(
    profile: Profile,
    mode: str,
    n: int,
    p_base: np.ndarray | None = None,
    *,
    seed: int = 0,
    criterion: Criterion = "task",
    margin_deg: float = JOINT_MARGIN_DEG,
    exchange: bool = True,
    isotropic: bool = False,
    pool: tuple[np.ndarray, np.ndarray] | None = None,
    progress: Callable[[PlanProgress], None] | None = None,
    should_stop: Callable[[], bool] | None = None,
    around: Around | None = None,
) -> Plan:
    """N configurations that make a calibration in `mode` as accurate as the noise model predicts it
    can be (module doc), from candidates inside the joint limits less `margin_deg` and predicted
    visible with p_base (default: the nominal model). `criterion`: "task" (the predicted error over
    the workspace), "d" (D-optimal) or "random" (the first N candidates, for comparison). `pool`:
    candidate configurations and targets to choose from instead of drawing them. `progress`: told where
    the plan is after each step (PlanProgress); `should_stop`: asked at each step, and the plan raises
    Cancelled once it says yes. `around`: draw (and refine) only within this neighbourhood of a seed (a first
    plan for unknown poses, whose base model predicts well only near the view it was seeded by)."""
    if criterion not in CRITERIA:
        raise InputError(f"unknown criterion '{criterion}' ({', '.join(CRITERIA)})")
    if n < 1:
        raise InputError(f"--configurations must be at least 1, got {n}")
    start = time.perf_counter()
    p = profile.nominal() if p_base is None else p_base
    profile.mode(mode)  # an unknown mode fails before any sampling
    drawn = pool is None  # a pool given is what to choose from: no refinement beyond it
    refine = drawn and exchange and criterion != "random" and not _stances(profile)
    stages = [("choosing", n, 1.0)]
    if exchange and criterion != "random":
        stages.append(("exchanging", EXCHANGE_PASSES * n, EXCHANGE_PASSES))
    if refine:  # with drawing about each choice and checking what it sees: about as long as choosing
        stages.append(("refining", REFINE_PASSES * n, REFINE_PASSES))
    pace = _Pace(progress, should_stop, stages)
    pace("drawing")
    if pool is None:
        count = max(
            STANCE_CANDIDATES if _stances(profile) else CANDIDATES if around is None else AROUND_CANDIDATES, 3 * n
        )
        pool = candidates(
            profile,
            p,
            seed=seed,
            count=count,
            margin_deg=margin_deg,
            occlusion=False,
            view_margin_px=plan_margins(profile)[0],
            obliquity_margin_deg=plan_margins(profile)[2],
            should_stop=should_stop,
            around=around,
        )
    q, targets = pool
    if n > len(q):
        raise InputError(f"only {len(q)} candidate configurations are predicted visible: ask for at most {len(q)}")
    ws = workspace(profile, p, seed, should_stop, around)
    pace("drawing")
    d = design(profile, mode, p, q, targets, workspace=ws, isotropic=isotropic, seed=seed)
    if criterion == "offsets" and offsets_weights(profile, d.free).any():
        d.A = offsets_weights(profile, d.free)
    pace("drawing", 1)
    admissible = CandidateView(profile, p, q, targets, in_view=drawn)
    history: list[float] = []
    if criterion == "random":
        order = (int(c) for c in np.random.default_rng(seed).permutation(len(q)))
        sel = Selection(d, "task", list(itertools.islice((c for c in order if admissible(np.array([c]))[0]), n)))
        pace("choosing", n)
    else:
        sel = Selection(d, criterion, admissible=admissible.first)
        for k in range(n):
            c = sel.best()
            if c < 0:
                break
            sel.add(c)
            history.append(_mean_error(d, sel.C))
            pace("choosing", k + 1)
        if exchange:
            sel.exchange(EXCHANGE_PASSES, step=lambda k: pace("exchanging", k))
            if refine:
                _refine(profile, d, admissible, sel, margin_deg, seed, pace, around)
    if len(sel.chosen) < n:
        raise InputError(
            f"only {len(sel.chosen)} of the candidate configurations are predicted visible: ask for at most that"
        )
    rows = np.array(sel.chosen)
    predicted = d.predict(d.start(regularise=False) + d.information(rows), n)
    return Plan(d.q[rows], d.targets[rows], criterion, predicted, history, len(q), time.perf_counter() - start)


def offsets_weights(profile: Profile, free: list[int]) -> np.ndarray:
    """The criterion matrix of the sum of the joint offsets' variances (A-optimal on the offsets; zero when
    none is free, and then the plan keeps the task's)."""
    offsets = {op.param for f in profile.frames for op in f.ops if op.joint >= 0}
    return np.diag([1.0 if i in offsets else 0.0 for i in free])


def _refine(
    profile: Profile,
    d: Design,
    visible: CandidateView,
    sel: Selection,
    margin_deg: float,
    seed: int,
    pace: _Pace,
    around: Around | None = None,
) -> None:
    """Local refinement (module doc): REFINE_DRAWS candidates about each chosen configuration, inside the
    limits less the margin and the plan's view margins (occlusion checked when one is about to be chosen),
    then exchange again. The draws are checked and added REFINE_CHUNK chosen configurations at a time, so
    that a cancel is heard between."""
    rng = np.random.default_rng([seed, 2])
    lo, hi = _limits_less_margin(profile, margin_deg, around)
    chosen = np.array(sel.chosen)
    q = np.repeat(d.q[chosen], REFINE_DRAWS, axis=0)
    q = np.clip(q + rng.normal(0.0, math.radians(REFINE_DEG), q.shape), lo, hi)
    targets = np.repeat(d.targets[chosen], REFINE_DRAWS)
    added = False
    for at in range(0, len(q), REFINE_CHUNK * REFINE_DRAWS):
        pace("refining")
        part = slice(at, at + REFINE_CHUNK * REFINE_DRAWS)
        seen = visible.view.sees(q[part], targets[part], occlusion=False)
        if seen.any():
            d.extend(q[part][seen], targets[part][seen])
            visible.extend(q[part][seen], targets[part][seen])
            added = True
    if added:
        sel.exchange(REFINE_PASSES, step=lambda k: pace("refining", k))


def _mean_error(d: Design, C: np.ndarray) -> float:
    return float(np.mean(_expected_errors(d.G, C)))


def _expected_errors(G: np.ndarray, C: np.ndarray) -> np.ndarray:
    """sqrt(trace(G_w C G_w^T)) per workspace observation: its expected error size (W,)."""
    flat = G.reshape(-1, G.shape[2])
    var = np.sum((flat @ C) * flat, axis=1).reshape(G.shape[:2]).sum(axis=1)
    return np.sqrt(np.maximum(var, 0.0))


def predict_accuracy(
    profile: Profile,
    mode: str,
    q: np.ndarray,
    targets: np.ndarray,
    p_base: np.ndarray | None = None,
    *,
    seed: int = 0,
) -> AccuracyPrediction:
    """The predicted standard deviations and workspace error of a calibration in `mode` from
    configurations q (rad) and their targets (a plan, or a session's frames), before they are measured."""
    p = profile.nominal() if p_base is None else p_base
    q = np.asarray(q, dtype=float)
    if len(q) == 0:
        raise InputError("no configurations to predict the accuracy of")
    d = design(profile, mode, p, q, np.asarray(targets, int), workspace=workspace(profile, p, seed), seed=seed)
    return d.predict(d.start(regularise=False) + d.information(np.arange(len(q))), len(q))


class SequentialPlan:
    """Sequential design: the next configuration from what has been measured so far, until the predicted
    error over the workspace reaches a target (capture until good enough).

    `proposal()` gives the candidate that lowers the predicted error most; `measured(True)` adds its
    information, `measured(False)` (not found, skipped) never proposes it again. Frames measured before
    (`q_done`, `targets_done`) count from the start."""

    def __init__(
        self,
        profile: Profile,
        mode: str,
        p_base: np.ndarray | None = None,
        *,
        seed: int = 0,
        margin_deg: float = JOINT_MARGIN_DEG,
        q_done: np.ndarray | None = None,
        targets_done: np.ndarray | None = None,
        admissible: Callable[[np.ndarray], bool] | None = None,
        should_stop: Callable[[], bool] | None = None,
        around: Around | None = None,
    ) -> None:
        """`admissible`: a further check of a configuration (rad) before it is proposed (a driver's limits);
        `should_stop`: asked while drawing and before the linearised calibration (Cancelled once it says yes),
        so that a cancel while the plan starts is heard within a fraction of a second; `around`: as plan()'s."""
        p = profile.nominal() if p_base is None else p_base
        pace = _Pace(None, should_stop, [])
        q, targets = candidates(
            profile,
            p,
            seed=seed,
            margin_deg=margin_deg,
            occlusion=False,
            view_margin_px=plan_margins(profile)[0],
            obliquity_margin_deg=plan_margins(profile)[2],
            should_stop=should_stop,
            around=around,
        )
        ws = workspace(profile, p, seed, should_stop, around)
        pace("drawing")
        self.design = design(profile, mode, p, q, targets, workspace=ws, seed=seed)
        visible = CandidateView(profile, p, q, targets, in_view=True)
        self.rejected: set[int] = set()

        def first(cs: np.ndarray) -> int:
            free = np.flatnonzero([c not in self.rejected for c in cs.tolist()])
            while len(free):
                at = visible.first(cs[free])
                if at < 0:
                    return -1
                if admissible is None or admissible(q[cs[free[at]]]):
                    return int(free[at])
                free = free[at + 1 :]
            return -1

        self.selection = Selection(self.design, "task", admissible=first)
        self.n = 0
        if q_done is not None and len(q_done):
            for L in self.design.factors(np.asarray(q_done, float), np.asarray(targets_done, int)):
                self.selection.add_information(L)
            self.n = len(q_done)
        self._proposed: int | None = None

    def predicted(self) -> AccuracyPrediction:
        sel, d = self.selection, self.design
        return d.predict(d.start(regularise=False) + d.information(np.array(sel.chosen, int)) + sel.extra, self.n)

    def mean_error(self) -> float:
        """The predicted mean error over the workspace (inf while some parameter is not determined)."""
        return self.predicted().mean

    def proposal(self) -> tuple[np.ndarray, int] | None:
        """The next configuration (rad) and its target, or None when no candidate is left."""
        c = self.selection.best()
        if c < 0:
            return None
        self._proposed = c
        return self.design.q[c], int(self.design.targets[c])

    def measured(self, ok: bool) -> None:
        """What became of the last proposal: measured (its information counts) or not."""
        assert self._proposed is not None, "measured() answers a proposal()"
        if ok:
            self.selection.add(self._proposed)
            self.n += 1
        else:
            self.rejected.add(self._proposed)
        self._proposed = None
