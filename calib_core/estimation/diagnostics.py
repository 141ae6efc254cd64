"""What a user must read before trusting a calibration, as typed diagnostics: parameters held
because the data cannot separate them, weakly determined groups, rejected outliers, parameters at
their bounds, a solver that did not converge, a held-out error much worse than the training error,
a tracker registration that cannot fit, a fit worse than its start."""

from __future__ import annotations

import numpy as np

from ..model.profile import Mode, Profile
from ..units import LENGTH_IN_M
from .calibration import Outlier
from .fit import Fit
from .identifiability import Report, weak_parameters
from .reports import Diagnostic, Severity, SolverReport
from .validation import Figures

# No robot's nominal model is this far off once the tracker's pose is fitted; rows from two tracker
# set-ups (or the wrong arm) are.
REGISTRATION_MISFIT_M = 0.05
HOLDOUT_WORSE = 1.5  # held-out RMS this many times the training RMS: the calibration may not generalise


def diagnose(
    profile: Profile,
    mode: Mode,
    fit: Fit,
    rep: Report,
    figs: dict[str, Figures],
    each: dict[str, dict[str, Figures]],
    solver: SolverReport,
    outliers: list[Outlier],
    nuisance: frozenset[int],
) -> list[Diagnostic]:
    def warn(code: str, message: str) -> Diagnostic:
        return Diagnostic(Severity.WARNING, code, message)

    free = fit.problem.free
    out = [warn("held-fixed", d.describe(profile)) for d in fit.dependencies if d.remainder is None]
    if solver.minimal:
        left = [d for d in fit.dependencies if d.remainder is not None]
        n_mode = len(free) + len(fit.dependencies)
        out.append(
            Diagnostic(
                Severity.INFO,
                "minimal-set",
                f"minimal parameter set: {len(free)} of the mode's {n_mode} parameters estimated (QR with column "
                f"pivoting of these data, no priors), {len(left)} more held than the data strictly require",
            )
        )
        out += [Diagnostic(Severity.INFO, "minimal-set", d.describe(profile)) for d in left]
    out += [warn("weak", w) for w in weak_parameters(profile, rep, free, nuisance)]
    if outliers:
        frames = sorted({o.frame for o in outliers})
        shown = ", ".join(str(f) for f in frames[:10]) + (" ..." if len(frames) > 10 else "")
        out.append(warn("outliers", f"{len(outliers)} observations rejected as outliers (frames {shown})"))
    nominal = profile.nominal()
    bounded = [
        profile.label(i) for i in free if i in mode.bounds and abs(fit.p[i] - nominal[i]) >= mode.bounds[i] * (1 - 1e-9)
    ]
    if bounded:
        out.append(
            warn(
                "at-bound",
                f"{', '.join(bounded)} stopped at the bound the profile allows: the data push further than a "
                "physical error would (a wrong nominal value, or data from another set-up?)",
            )
        )
    if not solver.converged:
        out.append(
            warn(
                "not-converged",
                f"the solver did not converge ({solver.status.value} after {solver.iterations} iterations): the "
                "result may be far from the best fit; start from a closer calibration (a base) or check the data",
            )
        )
    unit = figs["after"].unit
    if "holdout_after" in figs and figs["holdout_after"].rms > HOLDOUT_WORSE * figs["after"].rms:
        out.append(
            warn(
                "holdout-worse",
                f"held-out RMS {figs['holdout_after'].rms:.3g} {unit} is much worse than training RMS "
                f"{figs['after'].rms:.3g} {unit}: the calibration may not generalise "
                "(too few or too similar configurations)",
            )
        )
    out += _registration_misfit(profile, fit, figs, each)
    if figs["after"].rms > figs["before"].rms:
        out.append(warn("worse-than-start", "the calibration fits the data worse than its starting point"))
    return out


def _registration_misfit(
    profile: Profile, fit: Fit, figs: dict[str, Figures], each: dict[str, dict[str, Figures]]
) -> list[Diagnostic]:
    """A tracker whose pose was fitted but whose readings the model still misses by centimetres."""
    out = []
    free = set(fit.problem.free)
    for b in fit.problem.blocks:
        frame = profile.frames[b.sensor.frame]
        if not frame.registration or not {op.param for op in frame.ops} & free:
            continue
        before = each[b.sensor.name]["before"] if each else figs["before"]
        misfit = REGISTRATION_MISFIT_M / LENGTH_IN_M[profile.length_unit]
        if np.isfinite(before.rms) and before.rms > misfit:
            out.append(
                Diagnostic(
                    Severity.WARNING,
                    "registration-misfit",
                    f"with only the registration fitted the model is {before.rms:.3g} {before.unit} RMS off: are "
                    "these rows from one tracker set-up and the arm the data say? Calibrate each set-up on its own "
                    "(calib solve --where)",
                )
            )
    return out
