"""The typed parts of a calibration result: how the solver stopped, what the data determine, and
every diagnostic with its severity. Each reads and writes the JSON of the calibration file; files
written before these types existed (free-text status, a list of warning sentences) still load."""

from __future__ import annotations

from dataclasses import asdict, dataclass, field
from enum import Enum
from typing import Any

from .solver import SolveStatus


class Severity(Enum):
    INFO = "info"  # worth knowing, needs nothing
    WARNING = "warning"  # read it before applying: the result may be wrong or weaker than it looks


@dataclass(frozen=True)
class Diagnostic:
    """One finding about a calibration: `code` for programs (`not-converged`, `held-fixed`, `weak`,
    `outliers`, `model-error`, `at-bound`, `holdout-worse`, `registration-misfit`, `noise-excess`,
    `worse-than-start`, `minimal-set`), `message` for people."""

    severity: Severity
    code: str
    message: str

    def to_dict(self) -> dict[str, str]:
        return {"severity": self.severity.value, "code": self.code, "message": self.message}

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> Diagnostic:
        return cls(Severity(d["severity"]), str(d["code"]), str(d["message"]))


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
