"""The calibration problem: residuals of a dataset as a function of the free parameters, and their
exact Jacobian, for any number of sensors.

The free vector x holds the estimated parameters (leaders of ties only). The full parameter vector
is p = p_fixed + A x, where A has a 1 for each estimated parameter and the tie's sign for each
follower. The residual vector stacks one block per sensor (`SensorBlock`: a tracker's 3-D points,
a camera's pixels, a plane's distances, a tracked body's poses), each observation `dim` rows of W e with
e the sensor's error (prediction - measurement; for a pose's orientation the rotation between them) and W
the sensor's noise-model whitening (so each row has about unit variance), followed by one row
per prior (times `prior_scale`, the scale of the whitened residuals, so that a prior weighs as a MAP
term).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from ..dataset import Dataset
from ..model.kinematics import Poses, forward, op_ids, op_signs, to_sensor
from ..model.profile import Profile, Tie
from ..sensors import Sensor
from .readings import ReadingErrors, quantised_offsets


@dataclass
class SensorBlock:
    """The observations of one sensor and their rows in the residual vector."""

    sensor: Sensor
    index: int  # the sensor's index in the profile
    obs: np.ndarray | slice  # its observations: indices, ascending (a slice when they are one run)
    rows: slice  # its rows in the residual vector: len(obs) * dim
    W: np.ndarray | float  # whitening of its observations by the noise model: (n, dim, dim) or a scalar
    B_direct: np.ndarray  # (k, n_free): d(the sensor's direct parameters)/dx
    scale: float = 1.0  # the scatter of its whitened residuals, as estimated: they are divided by it

    @property
    def dim(self) -> int:
        return self.sensor.dim


@dataclass
class _Group:
    """The observations of one target by one sensor: the same chain, so one vectorised evaluation."""

    block: SensorBlock
    obs: np.ndarray  # observation indices
    pos: np.ndarray | slice  # their positions in the block (a slice when they are one run)
    target: int
    ops: list[int]  # recorded op ids with a non-zero sign
    columns: np.ndarray | slice  # their columns in the recorded axes and pivots (`Poses.w`; a slice when one run)
    B_ops: np.ndarray  # (K, n_free): d(op value)/dx
    B_point: np.ndarray | None  # (3, n_free): d(target point)/dx
    rotation: np.ndarray  # (K,) 1.0 for a rotation op, 0.0 for a translation
    translation: np.ndarray | None  # (K,) True for a translation op; None when there is none
    per_cfg: int  # > 0: the observations are runs of this length, one run per configuration
    cfgs: np.ndarray  # the configuration of each run
    sign: np.ndarray  # (K,) +1 target side, -1 sensor side
    local: np.ndarray | None  # (n, 3) the points in the target's frame (`local_points`); None: calibrated, from p


class Problem:
    def __init__(
        self,
        profile: Profile,
        data: Dataset,
        free: list[int],
        p_base: np.ndarray,
        ties: tuple[Tie, ...] = (),
        priors: dict[int, float] | None = None,
        prior_mean: np.ndarray | None = None,
        noise_model: bool | Sequence[np.ndarray | float] = True,
        readings: bool = False,
        probes: dict[tuple[int, ...], Problem] | None = None,
        rounding_jacobian: np.ndarray | None = None,
    ) -> None:
        """`noise_model`: True to weigh by the sensors' noise models, False for none, or the
        `weights` of an earlier Problem on the same data (they depend on the data only). `readings`: with a
        noise model, the rounding of readings that several observations share as errors in the variables
        (`ReadingErrors`: its rows follow the priors'), the weights then the sensors' noise alone. `probes`: the
        `probes` of an earlier Problem on the same data, shared (`_offset_jacobian`). `rounding_jacobian`: the quantised
        joints' offsets' Jacobian to weigh the readings' rounding with (`_reading_covariance`), taken near p already
        (a fit's `readings.Jq`), instead of at p."""
        self.profile = profile
        self.data = data
        self.free = list(free)
        n = len(profile.parameters)
        A = np.zeros((n, len(self.free)))
        for k, i in enumerate(self.free):
            A[i, k] = 1.0
        for tie in ties:
            if tie.leader in self.free:
                A[tie.follower, self.free.index(tie.leader)] = tie.sign
        self.A = A
        affected = np.flatnonzero(np.any(A != 0, axis=1))
        # The kinematics' Jacobian (`_jacobian`) has a column per free parameter and, with the readings' corrections,
        # one more per quantised joint's offset without a column of its own (a full calibration's head joints): the
        # corrections take the offsets' columns from the evaluations the fit makes anyway (`_offset_jacobian`).
        self._column = {i: k for k, i in enumerate(self.free) if np.count_nonzero(A[:, k]) == 1}
        quantised = list(quantised_offsets(profile)) if readings and noise_model is not False else []
        shadow = [i for i in quantised if i not in self._column]
        self._column |= {i: len(self.free) + k for k, i in enumerate(shadow)}
        self._B = np.hstack([A, np.eye(n)[:, shadow]])  # d(parameters)/d(the Jacobian's columns)
        self.p_fixed = p_base.copy()
        self.p_fixed[affected] = 0.0
        self.x0 = p_base[self.free].copy()
        self.priors = {i: s for i, s in (priors or {}).items() if A[i].any()}
        self.prior_mean = profile.nominal() if prior_mean is None else prior_mean
        self.prior_scale = 1.0

        ids = op_ids(profile)
        self._op = [profile.frames[f].ops[k] for f, k in ids]
        affected_set = set(affected.tolist())
        # Ops that no joint drives and no estimate moves are identities when their value is zero.
        self._constant = [
            (i, op.param) for i, op in enumerate(self._op) if op.joint < 0 and op.param not in affected_set
        ]
        self.record = {i for i, op in enumerate(self._op) if op.param in affected_set or op.param in shadow}
        self.blocks = self._blocks()
        self.n_data_rows = self.blocks[-1].rows.stop if self.blocks else 0
        self.frames = sorted(
            {profile.targets[t].frame for t in np.unique(data.target)} | {b.sensor.frame for b in self.blocks}
        )
        self.groups = [g for b in self.blocks for g in self._groups(b, p_base)]
        self.included = np.ones(data.n_observations, bool)  # False: an outlier, left out
        # Each observation's scatter relative to its sensor's (estimated where a configuration's observations
        # show it: `_Passes.reading_scales`); its whitened residual is divided by it and its block's scale.
        self.obs_scale = np.ones(data.n_observations)
        self._last_prediction: tuple[bytes, np.ndarray] | None = None  # (p's bytes, predictions): see `_predicted`
        self._last_jacobian: tuple[bytes, np.ndarray] | None = None  # (p's bytes, `_jacobian`'s)
        self.probes: dict[tuple[int, ...], Problem] = {} if probes is None else probes  # see `_offset_jacobian`
        self._q = np.nan_to_num(data.joints)  # joints a row does not need do not matter
        self.readings: ReadingErrors | None = None
        if readings and noise_model is not False:
            row_cfg = np.concatenate([np.repeat(data.cfg[b.obs], b.dim) for b in self.blocks])
            self.readings = ReadingErrors.of(
                profile, data, row_cfg, lambda params: self._offset_jacobian(params, p_base)
            )
        if noise_model is True:
            extra = None if self.readings is not None else self._reading_covariance(p_base, rounding_jacobian)
            for b in self.blocks:
                measured = data.measured[b.obs, : b.dim]
                b.W = b.sensor.whitening(p_base, measured, None if extra is None else extra[b.index])
        elif noise_model is not False:
            for b, W in zip(self.blocks, noise_model, strict=True):
                b.W = W

    def _blocks(self) -> list[SensorBlock]:
        """One block per sensor of the data, in the profile's order, its rows after the previous one's."""
        out: list[SensorBlock] = []
        start = 0
        for s in self.data.sensors:
            sensor = self.profile.sensors[s]
            obs = np.flatnonzero(self.data.sensor == s)
            direct = list(sensor.direct_params())
            B_direct = self._B[direct] if direct else np.zeros((0, self._B.shape[1]))
            rows = slice(start, start + len(obs) * sensor.dim)
            out.append(SensorBlock(sensor, s, _run(obs), rows, 1.0, B_direct))
            start = rows.stop
        return out

    def _groups(self, block: SensorBlock, p: np.ndarray) -> list[_Group]:
        data, profile = self.data, self.profile
        out = []
        in_block = np.arange(data.n_observations)[block.obs]
        position = np.empty(data.n_observations, int)
        position[in_block] = np.arange(len(in_block))
        recorded = sorted(self.record)  # the columns of `Poses.w` and `Poses.o`
        for t in np.unique(data.target[in_block]):
            target = profile.targets[t]
            obs = in_block[data.target[in_block] == t]
            cfgs, counts = np.unique(data.cfg[obs], return_counts=True)
            runs = bool(np.all(np.diff(data.cfg[obs]) >= 0) and np.all(counts == counts[0]))
            signs = op_signs(profile, target.frame, block.sensor.frame)
            ops = sorted(i for i in self.record if signs.get(i, 0.0) != 0.0)
            rotation = np.array([1.0 if self._op[i].kind == "r" else 0.0 for i in ops])
            out.append(
                _Group(
                    block=block,
                    obs=obs,
                    pos=_run(position[obs]),
                    target=int(t),
                    ops=ops,
                    columns=_run(np.searchsorted(recorded, ops)),
                    B_ops=self._B[[self._op[i].param for i in ops]] if ops else np.zeros((0, self._B.shape[1])),
                    B_point=self._B[list(target.point_params)] if target.point_params else None,
                    rotation=rotation,
                    translation=rotation == 0.0 if np.any(rotation == 0.0) else None,
                    sign=np.array([signs[i] for i in ops]),
                    per_cfg=int(counts[0]) if runs else 0,
                    cfgs=cfgs,
                    local=None if target.point_params is not None else local_points(profile, data, obs, int(t), p),
                )
            )
        return out

    def _offset_jacobian(self, params: list[int], p: np.ndarray) -> np.ndarray:
        """The data rows' unweighted Jacobian with respect to the parameters `params` (joint offsets) at p: the
        columns of this problem's own (`_jacobian`: the readings' corrections take them from the evaluation the fit
        makes there anyway), else from a problem that computes it (made once, then moved to each p)."""
        columns = [self._column.get(i) for i in params]
        if all(k is not None for k in columns):
            return self._jacobian(p)[1][:, columns]
        probe = self.probes.get(tuple(params))
        if probe is None:
            probe = self.probes[tuple(params)] = Problem(self.profile, self.data, params, p, noise_model=False)
        probe.p_fixed = p - probe.A @ p[probe.free]
        return probe.residuals_jacobian(p[probe.free])[1][: probe.n_data_rows]

    def relinearise_readings(self, x: np.ndarray) -> None:
        """The readings' corrections (`ReadingErrors`) linearised at the parameters x."""
        if self.readings is not None:
            self.readings.relinearise(self._offset_jacobian(self.readings.params, self.params(x)))

    def _reading_covariance(self, p: np.ndarray, J: np.ndarray | None = None) -> dict[int, np.ndarray] | None:
        """Per sensor, (n, dim, dim): what each joint reading's error adds to a measurement.

        A reading's rounding error is uniform over one step (variance step^2 / 12), plus the reading's own noise
        where the profile declares one (`Joint.reading_sd`); it moves the prediction like the joint's offset
        does, so its Jacobian is the offset's column.
        """
        steps = {op.param: self.profile.joints[op.joint].reading_sd for op in self._op if op.joint >= 0}
        steps = {k: v for k, v in steps.items() if v > 0}
        if not steps:
            return None
        if J is None or J.shape[1] != len(steps):
            J = self._offset_jacobian(list(steps), p)
        scale = np.array(list(steps.values()))
        out = {}
        for b in self.blocks:
            Jq = J[b.rows].reshape(-1, b.dim, len(steps)) * scale
            out[b.index] = Jq @ Jq.transpose(0, 2, 1)
        return out

    # --- parameters -----------------------------------------------------------------------------
    def params(self, x: np.ndarray) -> np.ndarray:
        return self.p_fixed + self.A @ x

    @property
    def weights(self) -> list[np.ndarray | float]:
        """Each block's whitening, to build another Problem on the same data without recomputing it."""
        return [b.W for b in self.blocks]

    # --- evaluation -----------------------------------------------------------------------------
    def predict(self, p: np.ndarray) -> np.ndarray:
        """Predicted measurements (M, width of data.measured) for full parameters p; NaN in the
        columns an observation's sensor does not have."""
        return self._evaluate(p, jacobian=False)[0]

    @property
    def reading_rows(self) -> slice:
        """The rows of the readings' corrections (`ReadingErrors`), after the priors' (empty without)."""
        start = self.n_data_rows + len(self.priors)
        return slice(start, start + (0 if self.readings is None else self.readings.n))

    def residuals(self, x: np.ndarray) -> np.ndarray:
        p = self.params(x)
        r = self._whitened(self._predicted(p))
        if self.readings is None:
            return self._with_priors(r, p)
        self._prepare_readings()
        r, extra = self.readings.project(r)
        return np.concatenate([self._with_priors(r, p), extra])

    def residuals_jacobian(self, x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        p = self.params(x)
        pred, J_raw = self._jacobian(p)
        J_raw = J_raw[:, : len(self.free)]
        r = self._with_priors(self._whitened(pred), p)
        n_data = self.n_data_rows
        # The data rows, the priors' and the readings' corrections' (`reading_rows`), filled in place.
        J = np.empty((self.reading_rows.stop, len(self.free)))
        self._weighed(J_raw, out=J[:n_data])
        if self.readings is not None:
            self._prepare_readings()
            r_data, extra = self.readings.project(r[:n_data], J)
            r = np.concatenate([r_data, r[n_data:], extra])
        for k, (i, s) in enumerate(self.priors.items()):
            J[n_data + k] = self.prior_scale * self.A[i] / s
        return r, J

    def _jacobian(self, p: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The predictions and the data rows' unweighted Jacobian at p (a column per free parameter, then one per
        quantised joint's offset that has none of its own: see `__init__`), those of the last evaluation if at the
        same p: the same parameters weighed anew (the scales settling) and the readings' corrections taken where the
        fit stands need no kinematics again."""
        key = p.tobytes()
        if self._last_jacobian is not None and self._last_jacobian[0] == key:
            return self._predicted(p), self._last_jacobian[1]
        pred, J = self._evaluate(p, jacobian=True)
        assert J is not None
        self._last_prediction, self._last_jacobian = (key, pred), (key, J)
        return pred, J

    def share_predictions(self, other: Problem) -> None:
        """Take the last predictions of `other`, a problem on the same data: where this one is evaluated at the same
        parameters (a fit's noise test at its estimate), they are not computed again."""
        self._last_prediction = other._last_prediction

    def _predicted(self, p: np.ndarray) -> np.ndarray:
        """The predictions at p, those of the last evaluation if at the same p: the residuals at one fit under
        other weights (the scales settling) need no kinematics again."""
        key = p.tobytes()
        if self._last_prediction is None or self._last_prediction[0] != key:
            self._last_prediction = (key, self._evaluate(p, jacobian=False)[0])
        return self._last_prediction[1]

    def _weighed(self, J: np.ndarray, out: np.ndarray | None = None) -> np.ndarray:
        """Data rows of an unweighted Jacobian (any number of columns) weighed as the residuals are: by each
        block's whitening and scale, the observations left out zero (into `out` when given)."""
        weighed = np.empty(J.shape) if out is None else out
        for b in self.blocks:
            J3 = J[b.rows].reshape(-1, b.dim, J.shape[1])
            out = weighed[b.rows].reshape(J3.shape)  # views of contiguous rows: written in place
            w = self.included[b.obs] / (b.scale * self.obs_scale[b.obs])
            if isinstance(b.W, np.ndarray):  # scale the (n, dim, dim) whitening, not the wide Jacobian
                np.matmul(b.W * w[:, None, None], J3, out=out)
            else:
                np.multiply(J3, (w * b.W)[:, None, None], out=out)
        return weighed

    def _prepare_readings(self) -> None:
        """The readings' elimination for the current whitening (it changes with the scales and the
        observations left out)."""
        assert self.readings is not None
        key = (self.included.tobytes(), self.obs_scale.tobytes(), tuple(b.scale for b in self.blocks))
        self.readings.prepare(self._weighed, key)

    def raw_residuals(self, x: np.ndarray) -> np.ndarray:
        """Prediction - measurement, unweighted, block after block: the distances the papers report."""
        pred, _ = self._evaluate(self.params(x), jacobian=False)
        return np.concatenate([self._errors(pred, b).ravel() for b in self.blocks])

    def block_rows(self, r: np.ndarray) -> list[np.ndarray]:
        """The data rows of a residual vector, one array per block."""
        return [r[b.rows] for b in self.blocks]

    def _errors(self, pred: np.ndarray, b: SensorBlock) -> np.ndarray:
        e = b.sensor.error(pred[b.obs, : b.dim], self.data.measured[b.obs, : b.dim])
        return e * self.included[b.obs, None]

    def _whitened(self, pred: np.ndarray) -> np.ndarray:
        parts = []
        for b in self.blocks:
            e = self._errors(pred, b) / (b.scale * self.obs_scale[b.obs, None])
            parts.append(((b.W @ e[:, :, None])[:, :, 0] if isinstance(b.W, np.ndarray) else e * b.W).ravel())
        return np.concatenate(parts) if parts else np.zeros(0)

    def _with_priors(self, r: np.ndarray, p: np.ndarray) -> np.ndarray:
        if not self.priors:
            return r
        prior = [self.prior_scale * (p[i] - self.prior_mean[i]) / s for i, s in self.priors.items()]
        return np.concatenate([r, prior])

    def sensor_points(self, p: np.ndarray) -> np.ndarray:
        """Each observed point in its sensor's frame (M, 3), for visibility checks and rendering."""
        poses = forward(self.profile, p, self._q, frames=self.frames, skip=self._skip(p))
        out = np.empty((self.data.n_observations, 3))
        for g in self.groups:
            out[g.obs] = self._points(p, poses, g)[1]
        return out

    def _skip(self, p: np.ndarray) -> set[int]:
        return {i for i, k in self._constant if p[k] == 0.0}

    def _points(self, p: np.ndarray, poses: Poses, g: _Group) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Base-frame points P, sensor-frame points x (n, 3), the sensor rotation and the target rotation: per
        observation (n, 3, 3), or per configuration (N, 3, 3) for a group in runs per configuration (`_times`)."""
        local = local_points(self.profile, self.data, g.obs, g.target, p) if g.local is None else g.local
        target, sensor = self.profile.targets[g.target].frame, g.block.sensor.frame
        if not g.per_cfg:
            return to_sensor(poses, target, sensor, self.data.cfg[g.obs], local)
        # A board's vertices seen in one configuration share its poses: one product per configuration.
        Rt, Rs = poses.R[target][g.cfgs], poses.R[sensor][g.cfgs]
        P = local.reshape(len(g.cfgs), g.per_cfg, 3) @ Rt.transpose(0, 2, 1) + poses.t[target][g.cfgs][:, None, :]
        x = (P - poses.t[sensor][g.cfgs][:, None, :]) @ Rs
        return P.reshape(-1, 3), x.reshape(-1, 3), Rs, Rt

    @staticmethod
    def _times(g: _Group, a: np.ndarray, R: np.ndarray) -> np.ndarray:
        """a (n, rows, 3) times rotations R as `_points` gives them: per observation, or per configuration."""
        if g.per_cfg:
            return (a.reshape(len(R), -1, a.shape[2]) @ R).reshape(a.shape[0], a.shape[1], R.shape[2])
        return a @ R

    @staticmethod
    def _twists(poses: Poses, g: _Group) -> np.ndarray:
        """(N, 6, K): per configuration, the (w, v) twist of each of the group's ops, signed: (w, o x w) for a
        rotation, (0, w) for a translation. Written in place from the recorded columns, the cross product a component
        at a time as np.cross computes it (the same numbers, without its moving of axes and copies): stacked, crossed
        and concatenated anew, they took 0.14 of a Jacobian's 0.84 ms (TALOS's origins), 0.06 now."""
        W, o = poses.w[:, :, g.columns], poses.o[:, :, g.columns]
        xi = np.empty((len(W), 6, W.shape[2]))
        product = np.empty((len(W), W.shape[2]))
        for k, (a, b) in enumerate(((1, 2), (2, 0), (0, 1))):  # v_k = o_a w_b - o_b w_a
            np.multiply(o[:, a], W[:, b], out=xi[:, 3 + k])
            np.multiply(o[:, b], W[:, a], out=product)
            xi[:, 3 + k] -= product
        if g.translation is None:
            xi[:, :3] = W
        else:
            np.multiply(W, g.rotation, out=xi[:, :3])
            np.copyto(xi[:, 3:], W, where=g.translation)
        xi *= g.sign
        return xi

    def _evaluate(self, p: np.ndarray, jacobian: bool) -> tuple[np.ndarray, np.ndarray | None]:
        poses = forward(
            self.profile, p, self._q, frames=self.frames, record=self.record if jacobian else None, skip=self._skip(p)
        )
        pred = np.full(self.data.measured.shape, np.nan)
        F = self._B.shape[1]
        J = np.zeros((self.n_data_rows, F)) if jacobian else None
        for g in self.groups:
            dim, sensor = g.block.dim, g.block.sensor
            P, x, Rs, Rt = self._points(p, poses, g)
            Rs_T = Rs.transpose(0, 2, 1)
            rotation = None
            if sensor.rotation_axes:  # the target's orientation, sensor frame, per observation
                rotation = Rs_T @ Rt if not g.per_cfg else np.repeat(Rs_T @ Rt, g.per_cfg, axis=0)
            h, dh_dx, dh_direct, dh_drot = sensor.predict_pose(p, x, rotation, derivatives=jacobian)
            pred[g.obs, :dim] = h
            if J is None:
                continue
            assert dh_dx is not None and dh_direct is not None
            G = self._times(g, dh_dx, Rs_T)  # d(pred)/d(P in the base frame)
            n, k = len(g.obs), len(g.block.B_direct)
            if g.ops:
                # Each op moves the point by a twist: dP = w x P + v with v = o x w (rotation) or
                # dP = w (translation). Build the twists per configuration, then one batched product, the sensor's
                # own parameters (their d/dx the same everywhere) in the same product.
                xi = self._twists(poses, g)  # (N, 6, K)
                skew = np.zeros((len(P), 3, 3))
                skew[:, 0, 1], skew[:, 0, 2], skew[:, 1, 2] = P[:, 2], -P[:, 1], P[:, 0]
                skew[:, 1, 0], skew[:, 2, 0], skew[:, 2, 1] = -P[:, 2], P[:, 1], -P[:, 0]
                turn = G @ skew  # d(pred)/d(w): w x P = -[P]x w
                if dh_drot is not None:  # w turns the target frame by Rs^T w about the sensor's axes
                    turn += self._times(g, dh_drot, Rs_T)
                H = np.concatenate([turn, G] + ([dh_direct] if k else []), axis=2)  # d(pred)/d(w, v, direct)
                # The twists taken to the free parameters first, per configuration (K ops -> F free, K >> F).
                xi_free = xi @ g.B_ops  # (N, 6, F)
                if g.per_cfg:  # observations come in equal runs per configuration: one product each
                    D = xi_free[g.cfgs]
                    H = H.reshape(-1, g.per_cfg * dim, 6 + k)
                else:
                    D = xi_free[self.data.cfg[g.obs]]
                if k:
                    D = np.concatenate([D, np.broadcast_to(g.block.B_direct, (len(D), k, F))], axis=1)
                Jg = (H @ D).reshape(n, dim, F)
            elif k:
                Jg = (dh_direct.reshape(-1, k) @ g.block.B_direct).reshape(n, dim, F)
            else:
                Jg = np.zeros((n, dim, F))
            if g.B_point is not None:
                Jg += self._times(g, G, Rt) @ g.B_point
            E = sensor.error_jacobian(h, self.data.measured[g.obs, :dim])
            if E is not None:
                Jg = E @ Jg
            J[g.block.rows].reshape(-1, dim, F)[g.pos] = Jg
        return pred, J


def local_points(profile: Profile, data: Dataset, obs: np.ndarray | slice, target: int, p: np.ndarray) -> np.ndarray:
    """The points (n, 3) observations `obs` of `target` saw, in the target's frame: the calibrated point, a
    fixed point (a marker, the frame's origin) by vertex id, or the row's own point; a board's vertex where the
    row gives none (the CSV names only the vertex: row k // cols, column k % cols)."""
    t = profile.targets[target]
    local = data.point[obs]
    if t.point_params is not None:
        return np.broadcast_to(p[list(t.point_params)], local.shape)
    if t.points is not None:
        return t.points[np.maximum(data.vertex[obs], 0)]
    if t.grid is not None:
        vertex = data.vertex[obs]
        return np.where(np.isnan(local) & (vertex >= 0)[:, None], t.grid[np.maximum(vertex, 0)], local)
    return local


def _run(index: np.ndarray) -> np.ndarray | slice:
    """A slice for ascending consecutive indices (a view, not a copy, when indexing), else the indices."""
    if len(index) and index[-1] - index[0] == len(index) - 1 and np.all(np.diff(index) == 1):
        return slice(int(index[0]), int(index[-1]) + 1)
    return index
