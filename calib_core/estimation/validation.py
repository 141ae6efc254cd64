"""Error figures and data splits: before/after, held-out and k-fold cross-validation.

Errors are Euclidean distances between prediction and measurement per observation (cm for a 3-D
point, px for a pixel, the distance from a plane, a pose's position, its rotation apart in deg), the figure
the papers report; with several
sensors, per sensor, and pooled over those that measure in one unit. Splits keep whole configurations together, and
repeated configurations (the same joint readings) on one side, so a held-out figure never tests a
configuration that was also trained on.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np

from ..dataset import Dataset
from ..errors import InputError
from ..model.profile import Profile


@dataclass
class Figures:
    n: int  # observations
    mean: float
    rms: float
    max: float
    median: float
    unit: str
    rms_axes: list[float]  # per measurement coordinate (x, y, z or u, v; a pose's position)
    excluded: int = 0  # observations left out as outliers (failed detections)
    rms_rotation_deg: float | None = None  # a pose's orientation error (its rotation angle); None: no pose

    def to_dict(self) -> dict:
        return asdict(self)

    def __str__(self) -> str:
        scale, unit = (1000.0, "mm") if self.unit == "m" else (1.0, self.unit)  # a metre profile reads in mm
        out = f"mean {self.mean * scale:.3f} {unit}, RMS {self.rms * scale:.3f}, max {self.max * scale:.3f}"
        if self.rms_rotation_deg is not None:
            out += f", rotation RMS {self.rms_rotation_deg:.4f} deg"
        out += f" (n={self.n}"
        return out + (f", {self.excluded} outliers left out)" if self.excluded else ")")


def figures(
    pred: np.ndarray, measured: np.ndarray, unit: str, keep: np.ndarray | None = None, rotation_axes: int = 0
) -> Figures:
    """Distances of the observations in `keep` (default all); the others count as excluded. The last
    `rotation_axes` columns of the difference are a rotation vector (rad, a pose's): its angle is reported
    apart (`rms_rotation_deg`), the distance is the rest's."""
    excluded = 0
    if keep is not None:
        excluded = int(np.sum(~keep))
        pred, measured = pred[keep], measured[keep]
    e = pred - measured
    rotation = None
    if rotation_axes:
        e, angle = e[:, :-rotation_axes], np.linalg.norm(e[:, -rotation_axes:], axis=1)
        rotation = float(np.degrees(np.sqrt(np.mean(angle**2)))) if len(angle) else float("nan")
    d = np.linalg.norm(e, axis=1)
    if len(d) == 0:
        return Figures(0, float("nan"), float("nan"), float("nan"), float("nan"), unit, [], excluded, rotation)
    return Figures(
        len(d),
        float(d.mean()),
        float(np.sqrt(np.mean(d**2))),
        float(d.max()),
        float(np.median(d)),
        unit,
        np.sqrt(np.mean(e**2, axis=0)).tolist(),
        excluded,
        rotation,
    )


def sensor_figures(
    profile: Profile, parts: list[tuple[Dataset, np.ndarray, np.ndarray | None]]
) -> tuple[Figures, dict[str, Figures]]:
    """The figures pooled over the sensors that measure in the first sensor's unit, and each
    sensor's (by name), of (data, prediction, observations kept) parts: the prediction (M, width)
    as Problem.predict gives it, the kept ones a bool mask or None for all."""
    errors: dict[int, list[np.ndarray]] = {}
    kept: dict[int, list[np.ndarray]] = {}
    for data, pred, keep in parts:
        k = np.ones(data.n_observations, bool) if keep is None else keep
        for s in data.sensors:
            sel = data.sensor == s
            sensor = profile.sensors[s]
            errors.setdefault(s, []).append(sensor.error(pred[sel, : sensor.dim], data.measured[sel, : sensor.dim]))
            kept.setdefault(s, []).append(k[sel])
    each, pooled_e, pooled_k = {}, [], []
    unit = profile.sensors[min(errors)].unit
    for s in sorted(errors):
        sensor = profile.sensors[s]
        e, k = np.concatenate(errors[s]), np.concatenate(kept[s])
        each[sensor.name] = figures(e, np.zeros_like(e), sensor.unit, k, sensor.rotation_axes)
        if sensor.unit == unit:
            pooled_e.append(e[:, : sensor.dim - sensor.rotation_axes])
            pooled_k.append(k)
    if len(each) == 1:
        return next(iter(each.values())), each
    if len({e.shape[1] for e in pooled_e}) > 1:  # several kinds: the distances, no per-axis figures
        pooled_e = [np.linalg.norm(e, axis=1, keepdims=True) for e in pooled_e]
    d = np.concatenate(pooled_e)
    return figures(d, np.zeros_like(d), unit, np.concatenate(pooled_k)), each


MAX_HOLDOUT = 0.9  # a held-out share leaves at least a tenth of the configurations to fit on


def check_share(share: float, what: str = "held-out share") -> None:
    """The one rule for a held-out share (library, command line, API): between 0 and MAX_HOLDOUT."""
    if not 0.0 <= share <= MAX_HOLDOUT:
        raise InputError(f"{what} {share} must be between 0 and {MAX_HOLDOUT}")


REPEAT_TOLERANCE_RAD = 0.01  # readings this close on every joint: the same commanded configuration


def configuration_groups(data: Dataset, tolerance_rad: float = REPEAT_TOLERANCE_RAD) -> np.ndarray:
    """A group id per configuration: repeats of one configuration (every joint reading within
    `tolerance_rad`, transitively) share one, so a held-out set never has a twin in training. Groups are
    numbered in the order of their first configuration.

    Exact repeats are merged first and the near pairs found with a k-d tree (max-norm), so time and memory
    grow with the configurations and their near pairs, not with their square (96,000 configurations: 4 s and
    tens of MB; pairwise blocks took minutes and 2.7 GB)."""
    from scipy.sparse import coo_matrix  # only where a share is held out: a plain solve starts without them
    from scipy.sparse.csgraph import connected_components
    from scipy.spatial import cKDTree

    q = np.nan_to_num(data.joints)
    n = len(q)
    if n == 0:
        return np.zeros(0, int)
    distinct, same = np.unique(q, axis=0, return_inverse=True)
    same = same.ravel()
    varied = distinct[:, np.ptp(distinct, axis=0) > 0]  # a joint that never moves only slows the tree down
    pairs = cKDTree(varied).query_pairs(tolerance_rad, p=np.inf, output_type="ndarray")
    m = len(distinct)
    graph = coo_matrix((np.ones(len(pairs)), (pairs[:, 0], pairs[:, 1])), shape=(m, m))
    _, component = connected_components(graph, directed=False)
    label = component[same]
    first = np.full(label.max() + 1, n)
    np.minimum.at(first, label, np.arange(n))
    rank = np.empty_like(first)
    rank[np.argsort(first)] = np.arange(len(first))
    return rank[label]


def holdout_split(data: Dataset, share: float, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """Configuration indices (train, test) with about `share` of the configurations held out."""
    groups = configuration_groups(data)
    ids = np.unique(groups)
    rng = np.random.default_rng(seed)
    rng.shuffle(ids)
    n_test = round(share * len(ids))
    test_ids = set(ids[:n_test].tolist())
    test = np.array([g in test_ids for g in groups])
    return np.flatnonzero(~test), np.flatnonzero(test)


def kfold_splits(data: Dataset, k: int, seed: int = 0) -> list[tuple[np.ndarray, np.ndarray]]:
    groups = configuration_groups(data)
    ids = np.unique(groups)
    rng = np.random.default_rng(seed)
    rng.shuffle(ids)
    fold_of = {int(g): i % k for i, g in enumerate(ids)}
    fold = np.array([fold_of[int(g)] for g in groups])
    return [(np.flatnonzero(fold != i), np.flatnonzero(fold == i)) for i in range(k)]
