"""The typed parts of a calibration result: how the solver stopped, what the data determine, and
every diagnostic with its severity. Each reads and writes the JSON of the calibration file; files
written before these types existed (free-text status, a list of warning sentences) still load."""

from __future__ import annotations

from dataclasses import asdict, dataclass, field
from enum import Enum
from typing import Any

from .solver import SolveStatus
from .validation import Figures


class Severity(Enum):
    INFO = "info"  # worth knowing, needs nothing
    WARNING = "warning"  # read it before applying: the result may be wrong or weaker than it looks


@dataclass(frozen=True)
class Diagnostic:
    """One finding about a calibration: `code` for programs (`not-converged`, `held-fixed`, `weak`,
    `outliers`, `model-error`, `at-bound`, `holdout-worse`, `registration-misfit`, `noise-excess`,
    `worse-than-start`, `minimal-set`, `model-choice`), `message` for people, `parameters` the ones it is about
    (labels)."""

    severity: Severity
    code: str
    message: str
    parameters: tuple[str, ...] = ()
    # For a program: a mode of the profile that may fit what this one cannot (noise-excess, richer-predicts), or
    # the one `auto` chose (model-choice).
    mode: str | None = None

    def to_dict(self) -> dict[str, Any]:
        return {
            "severity": self.severity.value,
            "code": self.code,
            "message": self.message,
            "parameters": list(self.parameters),
            "mode": self.mode,
        }

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> Diagnostic:
        parameters = tuple(str(p) for p in d.get("parameters", []))
        mode = d.get("mode")
        return cls(
            Severity(d["severity"]), str(d["code"]), str(d["message"]), parameters, None if mode is None else str(mode)
        )


# The kinds of diagnostic in the order a reader should meet them: those that change whether to apply first
# (the fit is wrong, or worse than it looks), then what is weak, then what the mode holds by design.
DECISION_ORDER = (
    "model-choice",  # a note, after every warning: what `auto` chose and why
    "not-converged",
    "worse-than-start",
    "registration-misfit",
    "noise-excess",
    "holdout-worse",
    "at-bound",
    "outliers",
    "weak",
    "model-error",
    "held-fixed",
    "minimal-set",
)
# What the parameters of a kind's several diagnostics are, on its one line (followed by their names).
_GROUP_TITLES = {
    "weak": "weakly determined by these data (the data fix combinations of them, not each one)",
    "held-fixed": "held at their base values (the data cannot tell each from others)",
    "minimal-set": "left out of the minimal parameter set",
}


@dataclass(frozen=True)
class DiagnosticGroup:
    """The diagnostics of one kind and severity: one line (`title`, the parameters named) and each one's
    message on demand."""

    severity: Severity
    code: str
    title: str
    parameters: tuple[str, ...]
    messages: tuple[str, ...]

    def to_dict(self) -> dict[str, Any]:
        return {
            "severity": self.severity.value,
            "code": self.code,
            "title": self.title,
            "parameters": list(self.parameters),
            "messages": list(self.messages),
        }


def group_diagnostics(diagnostics: list[Diagnostic]) -> list[DiagnosticGroup]:
    """One group per (severity, code): warnings before notes, each in DECISION_ORDER (unknown kinds after the
    known ones). A kind with one diagnostic is titled by its message; with several, by what their parameters
    are and their names (a kind without a title: its first message and how many more)."""
    groups: dict[tuple[Severity, str], list[Diagnostic]] = {}
    for d in diagnostics:
        groups.setdefault((d.severity, d.code), []).append(d)

    def rank(key: tuple[Severity, str]) -> tuple[int, int]:
        severity, code = key
        order = DECISION_ORDER.index(code) if code in DECISION_ORDER else len(DECISION_ORDER)
        return (0 if severity is Severity.WARNING else 1, order)

    out = []
    for key in sorted(groups, key=rank):
        items = groups[key]
        parameters = tuple(dict.fromkeys(p for d in items for p in d.parameters))
        if len(items) == 1:
            title = items[0].message
        elif parameters and key[1] in _GROUP_TITLES:
            title = f"{len(parameters)} parameters {_GROUP_TITLES[key[1]]}: {', '.join(parameters)}"
        else:
            title = f"{items[0].message} (and {len(items) - 1} more of this kind)"
        out.append(DiagnosticGroup(key[0], key[1], title, parameters, tuple(d.message for d in items)))
    return out


# Residuals within this many times a sensor's declared noise are said, not warned of: a chi-square test of thousands
# of rows rejects any real robot's model at 1.1 (the NAO's full calibration on its board corners), and a warning on
# every calibration teaches people to ignore warnings.
NOISE_WARNING = 1.2


@dataclass(frozen=True)
class NoiseTest:
    """One sensor's residuals against its declared noise (calib_core.estimation.noise_test)."""

    sensor: str
    factor: float  # residual RMS over the declared noise (of the whitened residuals, per row)
    rows: int  # the included rows tested
    dof: float  # degrees of freedom: the rows less the sensor's share of the free parameters
    p_value: float  # the chance of a sum of squares this large if the declared noise were right
    level: float  # the test rejects the declared noise below this p-value

    @property
    def rejected(self) -> bool:
        return self.p_value < self.level

    @property
    def warns(self) -> bool:
        """Rejected by more than a real robot's close model leaves (NOISE_WARNING): worth a warning, not a line."""
        return self.rejected and self.factor > NOISE_WARNING

    def describe(self) -> str:
        """The test in words, for a message."""
        p = f"p = {self.p_value:.1g}" if self.p_value > 0 else "p < 1e-300"
        return (
            f"a chi-square test of its {self.rows} residual rows ({self.dof:.0f} degrees of freedom) rejects the "
            f"declared noise at the {self.level:.1%} level, {p}"
        )

    def to_dict(self) -> dict[str, Any]:
        return asdict(self) | {"rejected": self.rejected}

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> NoiseTest:
        return cls(
            str(d["sensor"]),
            float(d["factor"]),
            int(d["rows"]),
            float(d["dof"]),
            float(d["p_value"]),
            float(d["level"]),
        )


@dataclass
class SolverReport:
    """How the estimate was computed and why the solver stopped (a converged minimum, or a limit).

    `converged` is the solver's own criterion: it stopped at a minimum, not at a limit of work. Whether
    that minimum fits the data as well as the sensors' declared noise says is `fits_noise` (a chi-square
    test per sensor, `noise_tests`): a converged solve far above the noise is a wrong minimum or a model
    that misses something, and carries a `noise-excess` warning."""

    method: str  # "lm" or "nelder-mead"
    status: SolveStatus
    iterations: int
    evaluations: int
    solve_seconds: float  # the solver's own time (identifiability, solves), not file I/O
    robust: bool = True
    cost_history: list[float] = field(default_factory=list)
    sigma: float | None = None  # scale of the whitened residuals at the solution
    folds: int = 0  # k of the k-fold cross-validation (0: none)
    cv_seconds: float | None = None
    minimal: bool = False  # a minimal identifiable parameter set, without the mode's priors
    noise_tests: list[NoiseTest] = field(default_factory=list)  # per sensor (none in files before them)
    starts: int = 1  # start vectors tried (calib_core.estimation.starts)
    start: str = "the start values"  # the one whose solution was kept

    @property
    def converged(self) -> bool:
        return self.status.converged

    @property
    def fits_noise(self) -> bool | None:
        """Whether no sensor's residuals are clearly above its declared noise (None: not tested)."""
        return None if not self.noise_tests else not any(t.rejected for t in self.noise_tests)

    def to_dict(self) -> dict[str, Any]:
        d = asdict(self)
        d.update(status=self.status.code, message=self.status.value, converged=self.converged)
        d.update(noise_tests=[t.to_dict() for t in self.noise_tests], fits_noise=self.fits_noise)
        return d

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> SolverReport:
        return cls(
            method=str(d.get("method", "lm")),
            status=SolveStatus.from_code(str(d["status"])),
            iterations=int(d["iterations"]),
            evaluations=int(d.get("evaluations", d["iterations"])),
            solve_seconds=float(d["solve_seconds"]),
            robust=bool(d.get("robust", True)),
            cost_history=[float(c) for c in d.get("cost_history", [])],
            sigma=None if d.get("sigma") is None else float(d["sigma"]),
            folds=int(d.get("folds", 0)),
            cv_seconds=None if d.get("cv_seconds") is None else float(d["cv_seconds"]),
            minimal=bool(d.get("minimal", False)),
            noise_tests=[NoiseTest.from_dict(t) for t in d.get("noise_tests", [])],
            starts=int(d.get("starts", 1)),
            start=str(d.get("start", "the start values")),
        )


@dataclass(frozen=True)
class HeldParameter:
    """A parameter the data cannot separate from others, held at its base value."""

    parameter: str
    message: str


@dataclass(frozen=True)
class Correlation:
    a: str
    b: str
    rho: float


@dataclass
class IdentifiabilityReport:
    """What the data determine, computed on the Jacobian of the noise-weighted residuals with
    unit-length columns: singular values, rank, condition, the observability index O1, the held
    parameters, strongly correlated pairs and each parameter's variance inflation."""

    free: list[str]
    held_fixed: list[HeldParameter] = field(default_factory=list)
    singular_values: list[float] = field(default_factory=list)
    rank: int = 0
    condition: float | None = None
    o1: float | None = None
    correlations: list[Correlation] = field(default_factory=list)
    inflation: dict[str, float] = field(default_factory=dict)

    def to_dict(self) -> dict[str, Any]:
        d = asdict(self)
        d["note"] = "computed on the Jacobian of the noise-weighted residuals with unit-length columns"
        return d

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> IdentifiabilityReport:
        held = [
            HeldParameter(h, "held at its base value") if isinstance(h, str) else HeldParameter(**h)
            for h in d.get("held_fixed", [])
        ]
        return cls(
            free=[str(n) for n in d.get("free", [])],
            held_fixed=held,
            singular_values=[float(v) for v in d.get("singular_values", [])],
            rank=int(d.get("rank", 0)),
            condition=None if d.get("condition") is None else float(d["condition"]),
            o1=None if d.get("o1") is None else float(d["o1"]),
            correlations=[Correlation(**c) for c in d.get("correlations", [])],
            inflation={str(k): float(v) for k, v in d.get("inflation", {}).items()},
        )


@dataclass(frozen=True)
class Candidate:
    """One model `auto` compared (calib_core.estimation.model_choice): a mode of the profile, its priors' standard
    deviations times `prior_scale` (None: the mode has no priors), and how it predicted the configurations its
    cross-validation held out. `score`: their mean squared error per row, weighed by the sensors' declared noise
    (several sensors: the geometric mean over them, weighed by their rows); `figures`: the same errors in the
    sensors' units. `refused`: why it was not compared (it cannot be fitted on these data), else None."""

    mode: str
    prior_scale: float | None
    score: float | None = None
    figures: Figures | None = None
    refused: str | None = None

    @property
    def name(self) -> str:
        """The mode and its priors' scale, as a report names it: `origins (priors x1/8)`."""
        return self.mode if self.prior_scale is None else f"{self.mode} (priors {_scale(self.prior_scale)})"

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> Candidate:
        scale, score, figs = d.get("prior_scale"), d.get("score"), d.get("figures")
        return cls(
            str(d["mode"]),
            None if scale is None else float(scale),
            None if score is None else float(score),
            None if figs is None else Figures(**figs),
            None if d.get("refused") is None else str(d["refused"]),
        )


@dataclass
class ModelChoice:
    """What mode `auto` chose and why: every candidate's cross-validated figures, `chosen` the index of the one
    with the lowest score. Each of `shuffles` shuffles of the training configurations is cut into `folds` parts,
    each part predicted by every candidate fitted on the rest; compared on the `compared` observations of the
    `held_out` predicted that every competitive candidate's fit explains (calib_core.estimation.model_choice)."""

    candidates: list[Candidate]
    chosen: int
    folds: int
    shuffles: int
    compared: int
    held_out: int
    seconds: float

    @property
    def picked(self) -> Candidate:
        return self.candidates[self.chosen]

    def describe(self) -> str:
        """The choice in a sentence, and every candidate's cross-validated RMS, each mode's prior scales together."""
        by_mode: dict[str, list[Candidate]] = {}
        for c in self.candidates:
            by_mode.setdefault(c.mode, []).append(c)
        each = []
        for mode, group in by_mode.items():
            if group[0].refused is not None and len(group) == 1:
                each.append(f"{mode}: not compared ({group[0].refused})")
                continue
            scales = [_scale(c.prior_scale) for c in group if c.prior_scale is not None]
            what = f"{mode} with priors {', '.join(scales)}" if scales else mode
            each.append(f"{what}: {', '.join(_figure(c) for c in group)}")
        shuffles = f", {self.shuffles} shuffles" if self.shuffles > 1 else ""
        left = self.held_out - self.compared
        left = f", {left} that a competitive candidate's fit cannot explain left out" if left else ""
        return (
            f"auto chose mode {self.picked.name}: it predicts the training configurations it did not see best, "
            f"{_figure(self.picked)} RMS ({self.folds}-fold cross-validation{shuffles}, {self.compared} predicted "
            f"observations{left}). Each candidate: {'; '.join(each)}"
        )

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> ModelChoice:
        counts = {k: int(d[k]) for k in ("chosen", "folds", "shuffles", "compared", "held_out")}
        return cls([Candidate.from_dict(c) for c in d["candidates"]], **counts, seconds=float(d["seconds"]))


def _scale(scale: float) -> str:
    """A prior scale as a report writes it: x1/8, x1, x4."""
    return f"x1/{1 / scale:g}" if scale < 1 else f"x{scale:g}"


def _figure(c: Candidate) -> str:
    """A candidate's cross-validated RMS with its unit (a metre profile's in mm), a pose's rotation too."""
    if c.figures is None:
        return f"not compared ({c.refused})"
    f = c.figures
    scale, unit = (1000.0, "mm") if f.unit == "m" else (1.0, f.unit)
    rotation = "" if f.rms_rotation_deg is None else f" / {f.rms_rotation_deg:.3g} deg"
    return f"{f.rms * scale:.4g} {unit}{rotation}"
