"""Mode `auto`: the data choose the model, among the profile's modes and the strength of their priors.

A profile's modes are a ladder of models (a URDF's `offsets`, then `origins`, which frees every joint origin
with a prior towards the URDF), and a prior's width is a guess made before any data: on FIGAROH's real data
(docs/peers.md) the UR10e predicts its held-out poses best with `origins`' priors 8 times narrower than the
import's 5 mm / 1 deg, TALOS with them 16 times wider. Which one a robot's data support is what cross-validation
measures: every candidate, a mode with its priors' standard deviations times one of PRIOR_SCALES (a mode without
priors as it is), is fitted as `calibrate` fits it (short of the last digits: `fit_parameters`' `precise`) on
part of the training configurations and predicts the rest (FOLDS parts; SHUFFLES shuffles of them when the
configurations are few), and the one that predicts them best is chosen. Only the training data take part: the
configurations held out of the calibration never reach the choice.
A part's candidates are fitted one after another, each from the estimate of the one before it (the modes in the
profile's order, a mode's priors from the narrowest), and a candidate of the same parameters takes the dependencies
the one before it found (`fit_parameters`' `near`): on FIGAROH's data the same choices and held-out figures in
60-75% of the CPU time (benchmarks/fit_speed.py).

The candidates are compared on the observations that every competitive candidate's fit explains (within its
sensors' outlier limits; competitive: within COMPETITIVE times the best mean squared error on what most of them
explain). A misread marker, or a configuration a weakly determined candidate predicts wildly, would otherwise
weigh on the comparison as heavily as on a plain least-squares fit; measured on FIGAROH's data this picks
better models than comparing every observation (held out: TALOS 0.749 against 0.781 mm, the UR10e 3.716 against
3.742 mm, TIAGo's random splits 4.173 against 4.181 mm), and a hopeless candidate (a mode of the registration
alone) does not get to say what counts. Comparing on what the leading candidate alone explains was no better
(TALOS 0.760 mm): TALOS's held-out error is flat in the priors' width from x1 to x16 (0.747 to 0.757 mm), so
which of those is chosen follows small changes of the rule. Errors are weighed by
each sensor's declared noise (a pose's position against its rotation, as the fit weighs them); with several
sensors the score is the geometric mean of their mean squared errors, weighed by their rows, so that no sensor's
declared noise sets its weight against the others'.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import replace

import numpy as np

from ..dataset import Dataset
from ..errors import Cancelled, InputError
from ..model.profile import Mode, Profile
from .fit import Fit
from .outliers import explained
from .problem import Problem
from .reports import Candidate, ModelChoice
from .validation import Figures, configuration_groups, kfold_splits, sensor_figures

# A prior's standard deviations times these: from 16 times narrower (nearly the mode without those parameters)
# to 16 times wider (nearly no prior), by factors of 2 (the held-out error changes by a few percent between two).
PRIOR_SCALES = (1 / 16, 1 / 8, 1 / 4, 1 / 2, 1.0, 2.0, 4.0, 8.0, 16.0)
FOLDS = 5
# Fewer configurations than FEW_CONFIGURATIONS are cut into folds SHUFFLES times: there one 5-fold cut's choice
# moves most from another's, and each solve is quick.
SHUFFLES = 2
FEW_CONFIGURATIONS = 100
COMPETITIVE = 2.0  # a candidate within this many times the best mean squared error has a say in what is compared


def candidates(profile: Profile, data: Dataset) -> list[tuple[Candidate, Mode | None]]:
    """Every candidate in the order a report lists them (the profile's modes, each prior scale from the narrowest),
    with the mode to fit; a mode that fits other sensors than these data's is listed as refused (no mode)."""
    out: list[tuple[Candidate, Mode | None]] = []
    for mode in profile.modes.values():
        if mode.sensors is not None and not set(data.sensors) <= set(mode.sensors):
            names = ", ".join(profile.sensors[s].name for s in mode.sensors)
            out.append((Candidate(mode.name, None, refused=f"it fits {names} only"), None))
        elif not mode.priors:
            out.append((Candidate(mode.name, None), mode))
        else:
            for scale in PRIOR_SCALES:
                priors = {i: sigma * scale for i, sigma in mode.priors.items()}
                out.append((Candidate(mode.name, scale), replace(mode, priors=priors)))
    return out


def choose(
    profile: Profile,
    train: Dataset,
    fit: Callable[[Dataset, Mode, Fit | None], Fit],
    *,
    robust: bool = True,
    seed: int = 0,
    should_stop: Callable[[], bool] | None = None,
) -> tuple[Mode, ModelChoice]:
    """The candidate (`candidates`) that predicts the training configurations it did not see best (the least
    `_score`), and the choice with every candidate's figures. `fit(data, mode, near)`: the calibration's fit of a
    mode on data (it raises InputError for a mode it cannot fit on them: that candidate is refused), `near` the fit
    of the candidate before it on the same data (`fit_parameters`: started from its estimate)."""
    start = time.perf_counter()
    listed = candidates(profile, train)
    groups = len(np.unique(configuration_groups(train)))
    folds, shuffles = min(FOLDS, groups), SHUFFLES if groups < FEW_CONFIGURATIONS else 1
    if folds < 2:
        raise InputError("mode 'auto' needs at least 2 distinct training configurations to cross-validate on")
    refused = {k: c.refused for k, (c, m) in enumerate(listed) if m is None}
    parts: dict[int, list[tuple[Dataset, np.ndarray, np.ndarray, np.ndarray]]] = {k: [] for k in range(len(listed))}
    for repeat in range(shuffles):
        for train_idx, test_idx in kfold_splits(train, folds, seed + repeat):
            part, test = train.select(train_idx), train.select(test_idx)
            near: Fit | None = None  # the part's last fit
            for k, (_, mode) in enumerate(listed):
                if k in refused or mode is None:
                    continue
                if should_stop is not None and should_stop():
                    raise Cancelled("mode 'auto' stopped while cross-validating")
                try:
                    near = fit(part, mode, near)
                except InputError as exc:
                    refused[k] = exc.message
                    continue
                parts[k].append((test, *_errors(profile, test, near, robust)))
    compared = [k for k in range(len(listed)) if k not in refused]
    if not compared:
        raise InputError(
            "mode 'auto' can fit none of the profile's modes on parts of these training data: "
            + "; ".join(f"{listed[k][0].name}: {why}" for k, why in refused.items())
        )
    keep = _compared(parts, compared)
    out = []
    for k, (c, _) in enumerate(listed):
        if k in refused:
            out.append(replace(c, refused=refused[k]))
            continue
        out.append(replace(c, score=_score(parts[k], keep), figures=_figures(profile, parts[k], keep)))
    chosen = min(compared, key=lambda k: out[k].score)
    choice = ModelChoice(out, chosen, folds, shuffles, int(keep.sum()), len(keep), time.perf_counter() - start)
    mode = listed[chosen][1]
    assert mode is not None
    return mode, choice


def _compared(
    parts: dict[int, list[tuple[Dataset, np.ndarray, np.ndarray, np.ndarray]]], compared: list[int]
) -> np.ndarray:
    """The observations the candidates are compared on (the module's doc): those every competitive candidate's
    fit explains, a candidate competitive when its mean squared error on what most candidates explain is within
    COMPETITIVE times the best one's."""
    explained = {k: np.concatenate([p[3] for p in parts[k]]) for k in compared}
    most = 2 * np.sum(list(explained.values()), axis=0) > len(compared)
    if not most.any():
        most[:] = True
    rough = {k: _score(parts[k], most) for k in compared}
    best = min(rough.values())
    keep = np.logical_and.reduce([explained[k] for k in compared if rough[k] <= COMPETITIVE * best])
    return keep if keep.any() else most


def _errors(profile: Profile, test: Dataset, fit: Fit, robust: bool) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A fit's predictions of the held-out observations, their squared errors per row weighed by the declared noise
    (M,), and which of them the fit explains (M,: within its sensors' outlier limits; all without the robust pass)."""
    problem = Problem(profile, test, [], fit.p)
    r = problem.residuals(np.zeros(0))
    squared = np.zeros(test.n_observations)
    for b in problem.blocks:
        squared[b.obs] = np.mean(r[b.rows].reshape(-1, b.dim) ** 2, axis=1)
    keep = explained(problem, r, fit.sigmas) if robust else np.ones(test.n_observations, bool)
    return problem.predict(fit.p), squared, keep


def _score(parts: list[tuple[Dataset, np.ndarray, np.ndarray, np.ndarray]], keep: np.ndarray) -> float:
    """The mean squared error per row of the compared observations (`keep`, over the parts in order), weighed
    by the declared noise; several sensors: the geometric mean of theirs, weighed by their rows."""
    sensor = np.concatenate([test.sensor for test, *_ in parts])
    squared = np.concatenate([p[2] for p in parts])
    logs, weights = [], []
    for s in np.unique(sensor[keep]):
        mine = keep & (sensor == s)
        logs.append(np.log(np.mean(squared[mine])))
        weights.append(float(mine.sum()))
    return float(np.exp(np.average(logs, weights=weights)))


def _figures(
    profile: Profile, parts: list[tuple[Dataset, np.ndarray, np.ndarray, np.ndarray]], keep: np.ndarray
) -> Figures:
    """The compared observations' errors in the sensors' units, pooled as a calibration's figures are."""
    pieces, at = [], 0
    for test, predicted, _, _ in parts:
        pieces.append((test, predicted, keep[at : at + test.n_observations]))
        at += test.n_observations
    return sensor_figures(profile, pieces)[0]
