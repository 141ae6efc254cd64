"""The calibration result: one object that the CLI, the API and the page all show, and its JSON file.

It holds every parameter's value with its unit (estimated ones with their standard deviation), the
error figures before and after (training, held-out, cross-validated; per sensor when several
measured), how the solver stopped and whether it converged, the identifiability report, the outliers
and every diagnostic with its severity. Values are in display units (deg, the profile's length
unit, px), the units a person reads and a file stores.
"""

from __future__ import annotations

import json
import math
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from ..errors import InputError
from ..files import write_atomic
from ..model.profile import Profile
from .reports import (
    Diagnostic,
    DiagnosticGroup,
    IdentifiabilityReport,
    ModelChoice,
    Severity,
    SolverReport,
    group_diagnostics,
)
from .validation import Figures

FORMAT = "calib-calibration/1"


@dataclass
class ParameterEstimate:
    name: str
    label: str
    unit: str
    value: float
    base: float
    nominal: float
    estimated: bool
    std: float | None = None
    note: str | None = None


@dataclass
class Outlier:
    """A rejected observation: its frame and CSV line, its error at the fit (the sensor's unit) and
    why it was rejected (`sigmas`: how far the best prediction from the other observations misses
    it, in robust sigmas; None in files written before it was recorded)."""

    frame: int
    line: int | None
    error: float
    unit: str
    sigmas: float | None = None


@dataclass
class Covariance:
    """The estimate's covariance over its estimated parameters (a tie's follower as its leader), display units:
    what a review propagates to the predictions (`calib_core.estimation.change`)."""

    parameters: list[str]
    matrix: list[list[float]]

    @classmethod
    def of(cls, profile: Profile, indices: list[int], cov: np.ndarray) -> Covariance:
        """From a covariance `cov` of parameters `indices`, internal units."""
        scale = np.array([profile.to_display(i, 1.0) for i in indices])
        display = np.nan_to_num(cov * np.outer(scale, scale))
        return cls([profile.parameters[i].name for i in indices], display.tolist())

    def internal(self, profile: Profile) -> tuple[list[int], np.ndarray]:
        """(parameter indices, covariance in internal units)."""
        indices = [profile.param(name) for name in self.parameters]
        scale = np.array([profile.from_display(i, 1.0) for i in indices])
        return indices, np.asarray(self.matrix, float).reshape(len(indices), len(indices)) * np.outer(scale, scale)


@dataclass
class Calibration:
    robot: str
    mode: str
    method: str
    created: str
    source: str
    parameters: list[ParameterEstimate]
    figures: dict[str, Figures]  # before, after, holdout_before, holdout_after, cv_after
    solver: SolverReport
    identifiability: IdentifiabilityReport
    outliers: list[Outlier] = field(default_factory=list)
    diagnostics: list[Diagnostic] = field(default_factory=list)
    frames: dict[str, list[int]] = field(default_factory=dict)
    sensor_figures: dict[str, dict[str, Figures]] = field(default_factory=dict)  # several sensors: each one's
    covariance: Covariance | None = None  # None: a file written before it was kept
    choice: ModelChoice | None = None  # mode `auto`: what it chose and why (None: a named mode)
    format: str = FORMAT

    @property
    def converged(self) -> bool:
        return self.solver.converged

    @property
    def warnings(self) -> list[str]:
        """The sentences of the diagnostics to read before applying."""
        return [d.message for d in self.diagnostics if d.severity is Severity.WARNING]

    def diagnostic_groups(self) -> list[DiagnosticGroup]:
        """The diagnostics one line per kind, those that change whether to apply it first."""
        return group_diagnostics(self.diagnostics)

    # --- values -----------------------------------------------------------------------------------
    def values(self) -> dict[str, float]:
        """Every parameter's value, display units."""
        return {p.name: p.value for p in self.parameters}

    def params(self, profile: Profile) -> np.ndarray:
        """The full parameter vector in internal units for `profile`."""
        if profile.name != self.robot:
            raise InputError(f"calibration is for robot '{self.robot}', not '{profile.name}'")
        return profile.params_from_display(self.values())

    # --- files ------------------------------------------------------------------------------------
    def to_dict(self) -> dict[str, Any]:
        d = asdict(self)
        d["figures"] = {k: v.to_dict() for k, v in self.figures.items()}
        d["sensor_figures"] = {n: {k: v.to_dict() for k, v in f.items()} for n, f in self.sensor_figures.items()}
        d["solver"] = self.solver.to_dict()
        d["identifiability"] = self.identifiability.to_dict()
        d["diagnostics"] = [x.to_dict() for x in self.diagnostics]
        d["warnings"] = self.warnings
        d["converged"] = self.converged
        d["fits_noise"] = self.solver.fits_noise
        d["solve_seconds"] = self.solver.solve_seconds
        d["iterations"] = self.solver.iterations
        return _finite(d)

    def save(self, path: str | Path) -> None:
        """Write atomically: a reader sees the old file or the new one, never half of one."""
        write_atomic(Path(path), json.dumps(self.to_dict(), indent=2) + "\n")

    @classmethod
    def from_dict(cls, d: dict[str, Any], source: str = "<calibration>") -> Calibration:
        try:
            if d.get("format") != FORMAT:
                raise InputError(
                    f"not a calibration file (format is {d.get('format')!r}, expected {FORMAT!r})",
                    file=source,
                )
            params = []
            for i, p in enumerate(d["parameters"]):
                if not isinstance(p["name"], str):  # a list or null would surface later as a TypeError
                    raise InputError(f"parameters[{i}].name: expected a string, got {p['name']!r}", file=source)
                for key in ("value", "base", "nominal"):
                    if not isinstance(p[key], int | float) or not math.isfinite(p[key]):
                        raise InputError(f"parameters[{i}].{key}: expected a finite number", file=source)
                params.append(ParameterEstimate(**p))
            return cls(
                robot=str(d["robot"]),
                mode=str(d["mode"]),
                method=str(d.get("method", "lm")),
                created=str(d.get("created", "")),
                source=str(d.get("source", "")),
                parameters=params,
                figures={k: Figures(**v) for k, v in d.get("figures", {}).items()},
                solver=SolverReport.from_dict(d["solver"]),
                identifiability=IdentifiabilityReport.from_dict(d.get("identifiability", {})),
                outliers=[Outlier(**o) for o in d.get("outliers", [])],
                diagnostics=_diagnostics(d),
                frames=dict(d.get("frames", {})),
                sensor_figures={
                    n: {k: Figures(**v) for k, v in f.items()} for n, f in d.get("sensor_figures", {}).items()
                },
                covariance=None if d.get("covariance") is None else Covariance(**d["covariance"]),
                choice=None if d.get("choice") is None else ModelChoice.from_dict(d["choice"]),
            )
        except InputError:
            raise
        except KeyError as exc:
            raise InputError(f"calibration file lacks the field {exc}", file=source) from None
        except (TypeError, ValueError, AttributeError, OverflowError) as exc:
            raise InputError(f"calibration file is malformed ({exc})", file=source) from None

    @classmethod
    def load(cls, path: str | Path) -> Calibration:
        name = str(path)
        try:
            text = Path(path).read_text(encoding="utf-8")
        except FileNotFoundError:
            raise InputError("calibration file does not exist", file=name) from None
        except (OSError, UnicodeDecodeError) as exc:
            raise InputError(f"calibration file cannot be read ({exc.__class__.__name__})", file=name) from None
        try:
            d = json.loads(text)
        except json.JSONDecodeError as exc:
            raise InputError(f"not valid JSON ({exc.msg})", file=name, line=exc.lineno) from None
        if not isinstance(d, dict):
            raise InputError("a calibration file must hold a JSON object", file=name)
        return cls.from_dict(d, name)

    # --- people -----------------------------------------------------------------------------------
    def summary(self, verbose: bool = False) -> str:
        """A few lines for a terminal: figures, solver, the diagnostics one line per kind (`verbose`: and each
        diagnostic of a kind that has several under its line)."""
        f = self.figures
        lines = [f"{self.robot} {self.mode} calibration ({self.method}) on {f['after'].n} observations"]
        if self.choice is not None:
            c = self.choice
            lines.append(
                f"  chosen: {c.picked.name}, the least {c.folds}-fold cross-validated error of {len(c.candidates)} "
                f"candidates ({c.seconds:.1f} s)"
            )
        lines.append(f"  before: {f['before']}")
        lines.append(f"  after:  {f['after']}")
        if "holdout_after" in f:
            lines.append(f"  held out before: {f['holdout_before']}")
            lines.append(f"  held out after:  {f['holdout_after']}")
        if "cv_after" in f:
            lines.append(f"  {self.solver.folds}-fold cross-validated: {f['cv_after']}")
        for name, sf in self.sensor_figures.items():
            held = f", held out {sf['holdout_after']}" if "holdout_after" in sf else ""
            lines.append(f"  {name}: before {sf['before']}; after {sf['after']}{held}")
        s = self.solver
        outcome = s.status.value if s.converged else f"DID NOT CONVERGE: {s.status.value}"
        above = [t for t in s.noise_tests if t.warns]
        if above:
            worst = max(above, key=lambda t: t.factor)
            outcome += f"; residuals {worst.factor:.3g} times the noise '{worst.sensor}' declares"
        work = f"{s.iterations} iterations, {s.evaluations} evaluations, {s.solve_seconds * 1e3:.1f} ms"
        if s.starts > 1:
            work += f", {s.starts} starts (kept: {s.start})"
        lines.append(f"  solver: {work} ({outcome})")
        for g in self.diagnostic_groups():
            lines.append(f"  {g.severity.value}: {g.title}")
            if verbose and len(g.messages) > 1:
                lines += [f"    - {m}" for m in g.messages]
        return "\n".join(lines)


def parameter_estimate(
    profile: Profile,
    i: int,
    p: np.ndarray,
    p_base: np.ndarray,
    *,
    estimated: bool,
    std: float | None = None,
    note: str | None = None,
) -> ParameterEstimate:
    """Parameter i of full parameters p (internal units) as the file holds it: display units."""
    return ParameterEstimate(
        name=profile.parameters[i].name,
        label=profile.label(i),
        unit=profile.unit(i),
        value=profile.to_display(i, p[i]),
        base=profile.to_display(i, p_base[i]),
        nominal=profile.to_display(i, profile.nominal()[i]),
        estimated=estimated,
        std=None if std is None else abs(profile.to_display(i, std)),
        note=note,
    )


def _diagnostics(d: dict[str, Any]) -> list[Diagnostic]:
    """The file's diagnostics; a file written before they were typed has warning sentences only."""
    if "diagnostics" in d:
        return [Diagnostic.from_dict(x) for x in d["diagnostics"]]
    return [Diagnostic(Severity.WARNING, "warning", str(w)) for w in d.get("warnings", [])]


def _finite(obj: Any) -> Any:
    """JSON has no NaN or infinity: write them as null."""
    if isinstance(obj, float):
        return obj if math.isfinite(obj) else None
    if isinstance(obj, dict):
        return {k: _finite(v) for k, v in obj.items()}
    if isinstance(obj, list | tuple):
        return [_finite(v) for v in obj]
    if isinstance(obj, np.generic):
        return _finite(obj.item())
    return obj
