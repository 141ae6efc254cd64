"""The rounding of the joint readings as errors in the variables, for observations that share a reading.

A joint's reading is rounded to its encoder step: the physical angle is offset + reading + d, d uniform over
one step (variance step^2 / 12). When a configuration gives one observation, d is noise on that observation
alone and folds into its covariance (`Problem._reading_covariance`). When it gives many (a board's 24
vertices), they all share d: folding it into each vertex's covariance as if it were independent weighs it
24 times too little, and the offsets of joints that d moves alike (a leg's three pitch joints) are told apart
worse than the data allow. Here each reading's d is a nuisance variable with a Gaussian prior of std
step / sqrt(12), shared by every observation of the configurations that read the same values on its chain
(a NAO stance seen in three head postures), and eliminated exactly: with U the whitened d(error)/d(d) of a
cluster of observations (the offset's column, at the base model) and M = [U; diag(1 / std)],

    min_d |r - U d|^2 + |d / std|^2 = |P [r; 0]|^2,  P = I - Q Q^T,  Q = orth(M),

so each cluster's whitened rows r become the first rows of P [r; 0] (one row per observation, as before, so
a robust loss still acts per observation) and its corrections add one row each; with U fixed, P is constant
and the Jacobian is P [J; 0] exactly. The cost is r^T (Sigma + U S U^T)^-1 r: the generalised least squares of
the whole configuration, whose covariance (J^T P J)^-1 accounts for the shared rounding. U is taken at the base
model, then again at each solution the fit reaches (`relinearise`): with pixel noise far below a reading step's
effect, U's error at a model a few degrees off would outweigh the noise and bias the offsets.

A reading may also carry noise of its own (`Joint.noise`: a controller's reported flange pose, read as the six
joints of calib_core.model.flange_pose): its variance adds to the rounding's in the prior, and the same
elimination keeps the image's corners from absorbing it.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from ..dataset import Dataset
from ..model.profile import Profile


@dataclass
class _Cluster:
    rows: np.ndarray  # data rows of the residual vector
    joints: np.ndarray  # (v,) each correction's column of the offsets' Jacobian
    mask: np.ndarray  # (len(rows), v) the rows each correction moves
    std: np.ndarray  # (v,) each correction's prior std, internal units


class ReadingErrors:
    """The nuisance corrections of a problem's quantised joint readings, eliminated cluster by cluster."""

    def __init__(self, clusters: list[_Cluster], params: list[int], Jq: np.ndarray) -> None:
        self.clusters = clusters
        self.params = params  # the quantised joints' offsets
        self.Jq = Jq  # (data rows, len(params)) unweighted d(error)/d(offset), at the model of `relinearise`
        self.n = sum(len(c.std) for c in clusters)  # corrections: one residual row each
        self._groups = _groups(clusters, len(params))
        self._key: tuple | None = None
        self._Q: list[tuple[np.ndarray, np.ndarray]] = []

    def relinearise(self, Jq: np.ndarray) -> None:
        """The corrections' effect at another model (the fit so far): a reading's error moves the prediction
        as the offset does where the robot is, not where the nominal model puts it."""
        self.Jq = Jq
        self._key = None

    @classmethod
    def of(
        cls, profile: Profile, data: Dataset, row_cfg: np.ndarray, offset_jacobian: Callable[[list[int]], np.ndarray]
    ) -> ReadingErrors | None:
        """The corrections of `data`'s quantised readings, or None when no reading is shared by more than one
        observation (then folding its rounding into each observation's covariance is exact). `row_cfg`: the
        configuration of each data row; `offset_jacobian(params)`: the unweighted data rows' Jacobian with
        respect to those joint offsets at the base model."""
        steps = quantised_offsets(profile)
        if not steps or len(row_cfg) == 0:
            return None
        params = list(steps)
        Jq = offset_jacobian(params)
        n_cfg = data.n_configurations
        moved = np.zeros((n_cfg, len(params)), bool)  # the configurations whose rows a joint's offset moves
        rows, columns = np.nonzero(Jq)
        moved[row_cfg[rows], columns] = True
        # Each correction is a quantised joint's reading shared by the configurations with the same key (`_keys`), in
        # the order of its first (configuration, joint) moved.
        cfg_of, joint_of = np.nonzero(moved)
        keys = np.column_stack([joint_of, _keys(profile, data, [steps[i][0] for i in params])[cfg_of, joint_of]])
        variable, first = _first_seen(keys)  # of each (configuration, joint) moved; each correction's first
        joint_of_variable = joint_of[first]
        obs_of_cfg = np.bincount(data.cfg, minlength=n_cfg)
        if len(first) == len(variable) and np.all(obs_of_cfg[cfg_of] == 1):
            return None  # every reading's rounding is one observation's (a moved configuration has one at least)
        group = _components(n_cfg, cfg_of, variable)
        # The clusters in the order of their first correction, each one's corrections in their order.
        cluster_of_variable = group[cfg_of[first]]
        _, first_variable = np.unique(cluster_of_variable, return_index=True)
        labels = cluster_of_variable[np.sort(first_variable)]
        variables_of = np.argsort(cluster_of_variable, kind="stable")
        variable_bounds = np.searchsorted(cluster_of_variable[variables_of], np.arange(n_cfg + 1))
        position = np.empty(len(first), int)  # of each correction in its cluster
        pairs_of = np.argsort(cluster_of_variable[variable], kind="stable")
        pair_bounds = np.searchsorted(cluster_of_variable[variable][pairs_of], np.arange(n_cfg + 1))
        rows_of = np.argsort(group[row_cfg], kind="stable")
        row_bounds = np.searchsorted(group[row_cfg][rows_of], np.arange(n_cfg + 1))
        std_of_joint = np.array([steps[i][1] for i in params])
        clusters = []
        for g in labels.tolist():
            rows = rows_of[row_bounds[g] : row_bounds[g + 1]]
            vs = variables_of[variable_bounds[g] : variable_bounds[g + 1]]
            position[vs] = np.arange(len(vs))
            pairs = pairs_of[pair_bounds[g] : pair_bounds[g + 1]]
            reads = np.zeros((n_cfg, len(vs)), bool)  # the configurations each correction moves
            reads[cfg_of[pairs], position[variable[pairs]]] = True
            joints = joint_of_variable[vs]
            clusters.append(_Cluster(rows, joints, reads[row_cfg[rows]], std_of_joint[joints]))
        return cls(clusters, params, Jq)

    def prepare(self, weigh: Callable[[np.ndarray], np.ndarray], key: tuple) -> None:
        """Each cluster's Q for the data rows' current whitening (`weigh(J)`: data rows weighed as the
        residuals are, by the noise model, the scale and the observations left out); recomputed when `key`
        (what the whitening depends on) changes.

        Q = M L^-T with L L^T = M^T M = U^T U + diag(1 / std^2) (Cholesky): the prior's diagonal keeps M's columns
        well apart (a NAO stance's M has a condition number about 14), so this Q is orthonormal to within rounding
        and spans what Householder's would, at a third of the time (Householder's QR of the stacked M passed over
        it several times)."""
        if key == self._key:
            return
        Jw = weigh(self.Jq).ravel()
        self._Q = []
        for g in self._groups:
            U = Jw[g.entries] * g.mask  # (B, m, v)
            v = U.shape[2]
            gram = U.transpose(0, 2, 1) @ U
            gram[:, np.arange(v), np.arange(v)] += g.std**-2
            L_inv_T = np.linalg.inv(np.linalg.cholesky(gram)).transpose(0, 2, 1)
            self._Q.append((U @ L_inv_T, L_inv_T / g.std[:, :, None]))
        self._key = key

    def leverage(self, n_rows: int) -> np.ndarray:
        """(n_rows,) each data row's share of the corrections' fit (the diagonal of Q Q^T on the data rows):
        what the elimination takes from its variance."""
        out = np.zeros(n_rows)
        for g, (top, _) in zip(self._groups, self._Q, strict=True):
            out[g.rows] = np.sum(top**2, axis=2)
        return out

    def project(self, r: np.ndarray, J: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
        """The data rows r with every cluster's corrections eliminated, and the corrections' rows (module doc).
        `J`: the data rows' Jacobian in its first len(r) rows, eliminated in place, the corrections' rows written
        into its last `n` rows."""
        r_out = r.copy()
        extra = np.zeros(self.n)
        J_extra = None if J is None else J[len(J) - self.n :]
        for g, (top, bottom) in zip(self._groups, self._Q, strict=True):
            rg = r[g.rows]
            coef = np.einsum("bmv,bm->bv", top, rg)
            r_out[g.rows] = rg - np.einsum("bmv,bv->bm", top, coef)
            extra[g.extra] = -np.einsum("buv,bv->bu", bottom, coef)
            if J is not None and J_extra is not None:
                Jg = np.take(J, g.rows, axis=0)  # (B, m, columns)
                C = top.transpose(0, 2, 1) @ Jg
                Jg -= top @ C
                J[g.rows] = Jg
                J_extra[g.extra] = -(bottom @ C)
        return r_out, extra


def quantised_offsets(profile: Profile) -> dict[int, tuple[int, float]]:
    """The offsets of the joints whose readings carry a rounding (or noise): offset parameter -> (joint, the
    reading's standard deviation)."""
    return {
        op.param: (op.joint, profile.joints[op.joint].reading_sd)
        for f in profile.frames
        for op in f.ops
        if op.joint >= 0 and profile.joints[op.joint].reading_sd > 0
    }


@dataclass
class _Group:
    """Clusters of the same shape stacked (B of them), eliminated together."""

    rows: np.ndarray  # (B, m) data rows
    entries: np.ndarray  # (B, m, v) U's entries in the flattened offsets' Jacobian: row * its width + joint
    mask: np.ndarray  # (B, m, v)
    std: np.ndarray  # (B, v)
    extra: np.ndarray  # (B, v) the corrections' rows among `ReadingErrors.n`


def _groups(clusters: list[_Cluster], width: int) -> list[_Group]:
    """The clusters stacked by shape (a NAO's stances are alike: one LAPACK call for all their factorisations, one
    product for all their projections, instead of a few small ones per stance). `width`: the offsets' Jacobian's
    columns."""
    starts = np.cumsum([0] + [len(c.std) for c in clusters])
    by_shape: dict[tuple[int, int], list[int]] = {}
    for i, c in enumerate(clusters):
        by_shape.setdefault(c.mask.shape, []).append(i)
    out = []
    for members in by_shape.values():
        rows = np.stack([clusters[i].rows for i in members])
        joints = np.stack([clusters[i].joints for i in members])
        out.append(
            _Group(
                rows,
                rows[:, :, None] * width + joints[:, None, :],
                np.stack([clusters[i].mask for i in members]).astype(float),
                np.stack([clusters[i].std for i in members]),
                np.stack([np.arange(starts[i], starts[i + 1]) for i in members]),
            )
        )
    return out


def _keys(profile: Profile, data: Dataset, joints: list[int]) -> np.ndarray:
    """Per configuration and quantised joint, what its rounding is shared by, as a row of numbers (N, len(joints),
    3 + W): the owner's kind (0 the target, 1 the sensor, 2 the configuration alone), the owner (target, sensor or
    configuration), how many readings follow and the readings of the joints on its side of the chain (the target's
    joints the sensor's chain lacks, or the sensor's), zero-padded: the same readings are the same rounding (a
    stance seen in several head postures)."""
    n_cfg = data.n_configurations
    first_target = np.zeros(n_cfg, int)
    first_target[data.cfg[::-1]] = data.target[::-1]
    first_sensor = np.zeros(n_cfg, int)
    first_sensor[data.cfg[::-1]] = data.sensor[::-1]
    q = np.round(np.nan_to_num(data.joints), 9) + 0.0  # -0.0 reads as 0.0
    # Per (target, sensor): each joint's owner's kind and the joints whose readings are its key.
    sides: dict[tuple[int, int], list[tuple[int, list[int]]]] = {}
    for t, s in set(zip(first_target.tolist(), first_sensor.tolist(), strict=True)):
        target = {profile.frames[f].joint for f in profile.chain(profile.targets[t].frame)} - {-1}
        sensor = {profile.frames[f].joint for f in profile.chain(profile.sensors[s].frame)} - {-1}
        own_target, own_sensor = sorted(target - sensor), sorted(sensor - target)
        sides[(t, s)] = [
            (0, own_target) if j in own_target else (1, own_sensor) if j in own_sensor else (2, []) for j in joints
        ]
    width = max((len(side) for owners in sides.values() for _, side in owners), default=0)
    out = np.zeros((n_cfg, len(joints), 3 + width))
    for (t, s), owners in sides.items():
        cfgs = np.flatnonzero((first_target == t) & (first_sensor == s))
        for k, (kind, side) in enumerate(owners):
            out[cfgs, k, 0] = kind
            out[cfgs, k, 1] = (t, s, cfgs)[kind]
            out[cfgs, k, 2] = len(side)
            out[cfgs, k, 3 : 3 + len(side)] = q[np.ix_(cfgs, side)]
    return out


def _first_seen(rows: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Equal rows numbered in the order each first appears: the number of every row, and where each number's first
    row is."""
    order = np.lexsort(rows.T[::-1])  # stable: equal rows keep their order
    ordered = rows[order]
    new = np.ones(len(rows), bool)
    new[1:] = np.any(ordered[1:] != ordered[:-1], axis=1)
    sorted_id = np.cumsum(new) - 1
    first = order[new]  # each distinct row's first appearance, in sorted order
    rank = np.empty(len(first), int)
    rank[np.argsort(first)] = np.arange(len(first))
    number = np.empty(len(rows), int)
    number[order] = rank[sorted_id]
    return number, np.sort(first)


def _components(n: int, item_of: np.ndarray, link_of: np.ndarray) -> np.ndarray:
    """Connected components of n items joined by links (`item_of[i]` is in link `link_of[i]`): a label per item, the
    least item of its component."""
    label = np.arange(n)
    while True:
        least = np.full(link_of.max(initial=-1) + 1, n)
        np.minimum.at(least, link_of, label[item_of])
        spread = label.copy()
        np.minimum.at(spread, item_of, least[link_of])
        if np.array_equal(spread, label):
            return label
        label = spread
