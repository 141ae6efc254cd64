"""Mode `auto`'s rule of choice against others, on FIGAROH's real data (docs/peers.md, "Where auto is behind").

For each robot's splits (calib_core.io.figaroh_data), mode `auto`'s cross-validation is run once and every
candidate's cross-validated squared errors recorded, with each candidate's held-out error when fitted on the whole
training part; each rule then picks a candidate per split from the records alone, and its pooled held-out RMS
(mm) is printed. About 2 minutes.

    .venv/bin/python benchmarks/choice_rules.py
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from calib_core import load_profile
from calib_core.estimation import calibrate as calibration
from calib_core.estimation import model_choice
from calib_core.estimation.problem import Problem
from calib_core.io.figaroh_data import ROBOTS, PoseErrors, pooled, pose_errors, splits

FOLDER = Path(__file__).resolve().parents[1] / "sample_sessions" / "figaroh"
CASES = (("tiago", False), ("talos", False), ("ur10e-pose", False))


@dataclass
class Split:
    """One split's record: per candidate (in `candidates`' order, None where refused) the squared errors of the
    observations its cross-validation predicted, their configurations (per part), what the desk compares, the
    desk's scores, and the held-out errors of the candidate fitted on the whole training part."""

    squared: list[np.ndarray | None]
    cfgs: list[np.ndarray]
    keep: np.ndarray
    scores: list[float | None]
    held: list[PoseErrors | None]

    @property
    def ks(self) -> list[int]:
        return [k for k, s in enumerate(self.scores) if s is not None]

    def per_configuration(self, k: int, keep: np.ndarray) -> np.ndarray:
        """Candidate k's kept squared errors summed per (part, configuration)."""
        sums, at = [], 0
        for cfg in self.cfgs:
            _, inv = np.unique(cfg, return_inverse=True)
            sums.append(np.bincount(inv, (self.squared[k] * keep)[at : at + len(cfg)]))
            at += len(cfg)
        return np.concatenate(sums)


def record(robot: str, sessions: bool) -> list[Split]:
    profile = load_profile(FOLDER / ROBOTS[robot].profile)
    seen: dict = {}
    compared = model_choice._compared

    def spy(parts, ks):  # the parts the desk's choice scores, and what it compares
        seen["parts"], seen["keep"] = parts, compared(parts, ks)
        return seen["keep"]

    model_choice._compared = spy
    out = []
    try:
        for train, heldout in splits(profile, FOLDER, robot, sessions):

            def fit(part, mode, near=None, precise=True):
                return calibration._fit_mode(profile, part, mode, None, "lm", True, None, near, precise)

            def candidate(part, mode, near=None):  # as `calibrate` fits auto's candidates
                return fit(part, mode, near, precise=False)

            _, choice = model_choice.choose(profile, train, candidate)
            listed = model_choice.candidates(profile, train)
            squared, held = [], []
            for k, ((_, mode), c) in enumerate(zip(listed, choice.candidates, strict=True)):
                if mode is None or c.refused:
                    squared.append(None)
                    held.append(None)
                    continue
                squared.append(np.concatenate([p[2] for p in seen["parts"][k]]))
                p = fit(train, mode).p
                held.append(
                    pose_errors(profile, heldout, Problem(profile, heldout, [], p, noise_model=False).predict(p))
                )
            k0 = next(k for k in range(len(listed)) if squared[k] is not None)
            cfgs = [p[0].cfg for p in seen["parts"][k0]]
            out.append(Split(squared, cfgs, seen["keep"], [c.score for c in choice.candidates], held))
    finally:
        model_choice._compared = compared
    return out


def least(split: Split, keep: np.ndarray) -> int:
    return min(split.ks, key=lambda k: float(np.mean(split.squared[k][keep])))


def narrowest_within_se(split: Split, keep: np.ndarray) -> int:
    """The first candidate (the modes in order, priors from the narrowest) within one standard error of the best,
    the error of the difference paired by configuration."""
    best = least(split, keep)
    n, base = keep.sum(), split.per_configuration(best, keep)
    for k in split.ks:
        d = split.per_configuration(k, keep) - base
        if d.sum() / n <= np.sqrt(len(d)) * np.std(d, ddof=1) / n:
            return k
    return best


def capped(split: Split) -> int:
    cap = 4.0 * min(s for s in split.scores if s is not None)
    return min(split.ks, key=lambda k: float(np.mean(np.minimum(split.squared[k], cap))))


RULES: dict[str, Callable[[Split], int]] = {
    "the desk's (least score on what every competitive candidate explains)": lambda s: least(s, s.keep),
    "every observation compared": lambda s: least(s, np.ones_like(s.keep)),
    "every observation, the narrowest within one standard error": lambda s: narrowest_within_se(
        s, np.ones_like(s.keep)
    ),
    "the desk's comparison, the narrowest within one standard error": lambda s: narrowest_within_se(s, s.keep),
    "squared errors capped at 4 times the best score, none left out": capped,
}


def _cell(e: PoseErrors) -> str:
    deg = e.rms_deg()
    return f"{e.rms_mm():.3f}" + ("" if deg is None else f" / {deg:.3f} deg")


def main() -> None:
    records = {case: record(*case) for case in CASES}
    print("| rule | " + " | ".join(robot for robot, _ in CASES) + " |")
    print("|---|" + "---|" * len(CASES))
    for name, rule in RULES.items():
        cells = [_cell(pooled([s.held[rule(s)] for s in records[case]])) for case in CASES]
        print(f"| {name} | " + " | ".join(cells) + " |")


if __name__ == "__main__":
    main()
