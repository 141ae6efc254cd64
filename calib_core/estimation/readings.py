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
from operator import itemgetter

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
        # The data rows no correction moves: the elimination leaves them as they are.
        moved = np.zeros(len(Jq), bool)
        for c in clusters:
            moved[c.rows] = True
        self._unmoved = np.flatnonzero(~moved)
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
        keys = _keys(profile, data, [steps[i][0] for i in params])
        moved = np.stack(
            [np.bincount(row_cfg, weights=column != 0, minlength=data.n_configurations) > 0 for column in Jq.T], axis=1
        )
        variables: dict[tuple, list[int]] = {}
        for c, k in zip(*(a.tolist() for a in np.nonzero(moved)), strict=True):
            variables.setdefault((k, keys[c][k]), []).append(c)
        obs_of_cfg = np.bincount(data.cfg, minlength=data.n_configurations).tolist()
        if all(len(cfgs) == 1 and obs_of_cfg[cfgs[0]] == 1 for cfgs in variables.values()):
            return None  # every reading's rounding is one observation's (a moved configuration has one at least)
        group = _components(data.n_configurations, variables.values())
        label = group.tolist()  # Python ints: looked up once per correction
        members: dict[int, list[tuple[int, list[int]]]] = {}
        for (k, _), cfgs in variables.items():
            members.setdefault(label[cfgs[0]], []).append((k, cfgs))
        clusters = []
        rows_of = np.argsort(group[row_cfg], kind="stable")
        bounds = np.searchsorted(group[row_cfg][rows_of], np.arange(group.max() + 2))
        for g, vs in members.items():
            rows = rows_of[bounds[g] : bounds[g + 1]]
            reads = np.zeros((data.n_configurations, len(vs)), bool)  # the configurations each correction moves
            for j, (_, cfgs) in enumerate(vs):
                reads[cfgs, j] = True
            mask = reads[row_cfg[rows]]
            std = np.array([steps[params[k]][1] for k, _ in vs])
            clusters.append(_Cluster(rows, np.array([k for k, _ in vs]), mask, std))
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

    def project(
        self, r: np.ndarray, J: np.ndarray | None = None, gap: int = 0
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
        """The data rows r (and their Jacobian J) with every cluster's corrections eliminated, and the
        corrections' rows (module doc). The Jacobian comes whole: the data rows, `gap` rows of zeros (the priors',
        for the caller to fill), then the corrections' rows."""
        r_out = r.copy()
        extra = np.zeros(self.n)
        J_out = None
        if J is not None:
            n_data = len(r)
            J_out = np.empty((n_data + gap + self.n, J.shape[1]))
            J_out[self._unmoved] = J[self._unmoved]
            J_out[n_data : n_data + gap] = 0.0
            J_extra = J_out[n_data + gap :]
        for g, (top, bottom) in zip(self._groups, self._Q, strict=True):
            rg = r[g.rows]
            coef = np.einsum("bmv,bm->bv", top, rg)
            r_out[g.rows] = rg - np.einsum("bmv,bv->bm", top, coef)
            extra[g.extra] = -np.einsum("buv,bv->bu", bottom, coef)
            if J_out is not None:
                Jg = np.take(J, g.rows, axis=0)  # (B, m, columns)
                C = top.transpose(0, 2, 1) @ Jg
                Jg -= top @ C
                J_out[g.rows] = Jg
                J_extra[g.extra] = -(bottom @ C)
        return r_out, extra, J_out


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
    """The clusters stacked by shape (a NAO's stances are alike: one LAPACK call for all their QRs, one product for
    all their projections, instead of a few small ones per stance). `width`: the offsets' Jacobian's columns."""
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


def _keys(profile: Profile, data: Dataset, joints: list[int]) -> list[list[tuple]]:
    """Per configuration and quantised joint: what its rounding is shared by, the readings of the joints on its
    side of the chain (the target's joints the sensor's chain lacks, or the sensor's): the same readings are the
    same rounding (a stance seen in several head postures)."""
    first_target = np.zeros(data.n_configurations, int)
    first_target[data.cfg[::-1]] = data.target[::-1]
    first_sensor = np.zeros(data.n_configurations, int)
    first_sensor[data.cfg[::-1]] = data.sensor[::-1]
    q = np.round(np.nan_to_num(data.joints), 9).tolist()
    # Per (target, sensor): each joint's owner (None: the configuration itself) and the readings that are its key.
    keyed: dict[tuple[int, int], list[tuple[tuple | None, Callable[[list[float]], tuple]]]] = {}
    out = []
    for c, (t, s) in enumerate(zip(first_target.tolist(), first_sensor.tolist(), strict=True)):
        if (t, s) not in keyed:
            target = {profile.frames[f].joint for f in profile.chain(profile.targets[t].frame)} - {-1}
            sensor = {profile.frames[f].joint for f in profile.chain(profile.sensors[s].frame)} - {-1}
            keyed[(t, s)] = []
            for j in joints:
                if j in target - sensor:
                    keyed[(t, s)].append((("target", t), _picker(sorted(target - sensor))))
                elif j in sensor - target:
                    keyed[(t, s)].append((("sensor", s), _picker(sorted(sensor - target))))
                else:
                    keyed[(t, s)].append((None, _picker([])))
        row = q[c]
        out.append([(("configuration", c) if who is None else who, pick(row)) for who, pick in keyed[(t, s)]])
    return out


def _picker(side: list[int]) -> Callable[[list[float]], tuple]:
    """The readings of `side` from a configuration's list of readings, as a tuple."""
    if len(side) > 1:
        return itemgetter(*side)
    if side:
        return lambda row, j=side[0]: (row[j],)
    return lambda row: ()


def _components(n: int, links) -> np.ndarray:
    """Connected components of n items joined by the item lists in `links`: a label per item."""
    parent = list(range(n))

    def root(i: int) -> int:
        while parent[i] != i:
            parent[i] = parent[parent[i]]
            i = parent[i]
        return i

    for items in links:
        first = root(items[0])
        for i in items[1:]:
            parent[root(i)] = first
    return np.array([root(i) for i in range(n)])
