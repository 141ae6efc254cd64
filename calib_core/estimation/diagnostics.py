"""What a user must read before trusting a calibration, as typed diagnostics: parameters held
because the data cannot separate them, weakly determined groups, rejected outliers, parameters at
their bounds, a solver that did not converge, a held-out error much worse than the training error,
a tracker registration that cannot fit, residuals clearly above a sensor's declared noise, a fit worse
than its start."""

from __future__ import annotations

from collections.abc import Iterable, Sequence

import numpy as np

from ..model.profile import Mode, Profile
from ..units import LENGTH_IN_M
from .calibration import Outlier
from .fit import Fit
from .identifiability import Report, weak_parameters
from .reports import Diagnostic, Severity, SolverReport
from .starts import FAR_ABOVE_NOISE
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
    modes: Sequence[Mode] = (),
) -> list[Diagnostic]:
    """`mode` and `modes` (the profile's others, for `richer_mode`): as these data observe them
    (`calibrate.observed_mode`: the parameters of the other arm of a two-armed robot left out)."""

    def warn(code: str, message: str, parameters: Iterable[str] = ()) -> Diagnostic:
        return Diagnostic(Severity.WARNING, code, message, tuple(parameters))

    free = fit.problem.free
    out = [
        warn("held-fixed", d.describe(profile), [profile.label(d.fixed)])
        for d in fit.dependencies
        if d.remainder is None
    ]
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
        out += [Diagnostic(Severity.INFO, "minimal-set", d.describe(profile), (profile.label(d.fixed),)) for d in left]
    out += [warn("weak", message, names) for names, message in weak_parameters(profile, rep, free, nuisance)]
    if outliers:
        out.append(
            warn(
                "outliers",
                f"{len(outliers)} observations rejected as outliers (frames {_frames(o.frame for o in outliers)}): "
                "each beyond its sensor's outlier limit and predicted neither by a richer model of the robot nor "
                "by its neighbours in joint space or in time (a failed detection, a swapped marker)",
            )
        )
    if fit.verdict is not None and fit.verdict.model_error.any():
        data = fit.problem.data
        kept = np.flatnonzero(fit.verdict.model_error)
        out.append(
            Diagnostic(
                Severity.INFO,
                "model-error",
                f"{len(kept)} observations beyond the outlier limit were kept (frames "
                f"{_frames(int(data.frame_ids[data.cfg[k]]) for k in kept)}): the other observations predict "
                "them, so they are model error (unmodelled geometry or drift), not gross errors; a mode with more "
                "parameters may fit them",
            )
        )
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
                bounded,
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
    out += _noise_excess(profile, mode, modes, fit)
    # Relative to the start's RMS: a start that is the best fit already (a hand-eye registration's) ends a few
    # units in the last place above it, which is no reason to warn.
    if figs["after"].rms > (1 + WORSE_THAN_START) * figs["before"].rms and not _noisy_readings(profile):
        out.append(warn("worse-than-start", "the calibration fits the data worse than its starting point"))
    return out


WORSE_THAN_START = 1e-9


def _noisy_readings(profile: Profile) -> bool:
    """Readings with noise of their own (a reported flange pose): the fit weighs each configuration's error
    shared by its observations, so its plain RMS at the readings as reported may exceed a start's without the
    fit being worse."""
    return any(j.noise > 0 for j in profile.joints)


def _frames(frames: Iterable[int]) -> str:
    """Frame numbers for a message: sorted, at most ten."""
    ids = sorted(set(frames))
    return ", ".join(str(f) for f in ids[:10]) + (" ..." if len(ids) > 10 else "")


def _noise_excess(profile: Profile, mode: Mode, modes: Sequence[Mode], fit: Fit) -> list[Diagnostic]:
    """A sensor whose residuals a chi-square test finds above its declared noise. With thousands of rows the
    test rejects any model of a real robot, so its words follow the size of the excess: within NOISE_WARNING
    (reports.py) times the declared noise, a line of the report that says how much (the estimate fits as well as
    a real robot allows); above it, a warning that says how far above and what a user can do (the profile's mode
    that estimates more, when it has one); far above (FAR_ABOVE_NOISE), it may also be a wrong minimum or data in
    another unit."""
    out = []
    richer_name, richer = richer_mode(profile, mode, modes)
    for test in fit.noise_tests:
        if not test.rejected:
            continue
        if not test.warns:
            out.append(
                Diagnostic(
                    Severity.INFO,
                    "noise-scatter",
                    f"the data scatter {test.factor:.2g} times what '{test.sensor}' declares ({test.describe()}): "
                    "within a fifth of it, as a real robot's close model leaves them; the standard deviations use "
                    "the actual scatter",
                )
            )
            continue
        if test.factor > FAR_ABOVE_NOISE:
            tried = f"{fit.starts} starts were tried" if fit.starts > 1 else "only the start values were tried"
            why = (
                "beyond errors the mode cannot model and a noise figure that is too optimistic, so large a factor may "
                f"be a wrong minimum ({tried}; a closer start, a base calibration, may find a better one) or data in "
                "another unit (data.joint_unit, the measurement's unit): check these before applying it"
                + (f"; {richer}, and may fit what this one cannot" if richer else "")
            )
        else:
            more = f"{richer}, and may fit more" if richer else "a mode with more parameters may fit more"
            why = (
                "errors the mode cannot model (unmodelled geometry, compliance, drift: a real robot has some) or a "
                "noise figure that is too optimistic. The estimate is this mode's best fit and its standard deviations "
                f"use the actual scatter; {more}, or declare the sensor's noise about "
                f"{test.factor:.2g} times larger (it weighs this sensor against the others and sets the outlier limits)"
            )
        out.append(
            Diagnostic(
                Severity.WARNING,
                "noise-excess",
                f"the residuals of '{test.sensor}' are {test.factor:.3g} times the noise it declares "
                f"({test.describe()}): {why}",
                mode=richer_name,
            )
        )
    return out


def richer_mode(profile: Profile, mode: Mode, modes: Sequence[Mode], shown: int = 6) -> tuple[str | None, str]:
    """The smallest of `modes` that estimates all `mode` does and more, for the same sensors: its name, and a
    clause naming what it adds ("mode 'offsets' also estimates shoulder_lift, ..."); (None, "") when there is
    none."""
    mine = set(mode.free)
    richer = [m for m in modes if mine < set(m.free) and m.sensors == mode.sensors]
    if not richer:
        return None, ""
    best = min(richer, key=lambda m: (len(m.free), m.name))
    extra = [profile.label(i) for i in best.free if i not in mine]
    names = ", ".join(extra[:shown]) + (f" and {len(extra) - shown} more" if len(extra) > shown else "")
    return best.name, f"mode '{best.name}' also estimates {names}"


def _registration_misfit(
    profile: Profile, fit: Fit, figs: dict[str, Figures], each: dict[str, dict[str, Figures]]
) -> list[Diagnostic]:
    """A tracker (a point sensor) whose pose was fitted but whose readings the model still misses by centimetres."""
    out = []
    free = set(fit.problem.free)
    for b in fit.problem.blocks:
        frame = profile.frames[b.sensor.frame]
        if b.sensor.dim != 3 or not frame.registration or not {op.param for op in frame.ops} & free:
            continue  # a camera's misfit is in pixels: the noise test speaks for it
        before = each[b.sensor.name]["before"] if each else figs["before"]
        misfit = REGISTRATION_MISFIT_M / LENGTH_IN_M[profile.length_unit]
        if np.isfinite(before.rms) and before.rms > misfit:
            out.append(
                Diagnostic(
                    Severity.WARNING,
                    "registration-misfit",
                    f"with only the tracker's pose fitted the starting model misses the data by {before.rms:.3g} "
                    f"{before.unit} RMS, more than any robot's nominal geometry is off: the data and the profile "
                    "disagree. Likely causes: rows from two tracker set-ups or of the other arm (calibrate each on "
                    "its own: calib solve --where), the joint readings' unit (data.joint_unit), or the measured "
                    "point (a reflector or target far from where the profile puts it)",
                )
            )
    return out
