"""The calibration problem: residuals of a dataset as a function of the free parameters, and their
exact Jacobian.

The free vector x holds the estimated parameters (leaders of ties only). The full parameter vector
is p = p_fixed + A x, where A has a 1 for each estimated parameter and the tie's sign for each
follower. Residuals are W (prediction - measurement), one block of `dim` rows per observation, where W is the
sensor's noise model whitening (so each row has about unit variance), followed by one row per prior
(times `prior_scale`, the scale of the whitened residuals, so that a prior weighs as a MAP term).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..dataset import Dataset
from ..model.kinematics import forward, op_ids, op_signs
from ..model.profile import Profile, Tie
from ..sensors.measurement import dimension, intrinsic_params, predict, whitening


@dataclass
class _Group:
    """The observations of one target: the same chain, so one vectorised evaluation."""

    obs: np.ndarray  # observation indices
    target: int
    signs: dict[int, float]
    ops: list[int]  # recorded op ids with a non-zero sign
    B_ops: np.ndarray  # (K, n_free): d(op value)/dx
    B_point: np.ndarray | None  # (3, n_free): d(target point)/dx
    rotation: np.ndarray  # (K,) 1.0 for a rotation op, 0.0 for a translation
    per_cfg: int  # > 0: the observations are runs of this length, one run per configuration
    cfgs: np.ndarray  # the configuration of each run
    sign: np.ndarray  # (K,) +1 target side, -1 sensor side


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
        noise_model: bool | np.ndarray | float = True,
    ) -> None:
        """`noise_model`: True to weigh by the sensor's noise model, False for none, or the
        whitening of an earlier Problem on the same data (it depends on the data only)."""
        self.profile = profile
        self.data = data
        self.free = list(free)
        self.sensor = profile.sensors[profile.data.sensor]
        self.dim = dimension(self.sensor)
        n = len(profile.parameters)
        A = np.zeros((n, len(self.free)))
        for k, i in enumerate(self.free):
            A[i, k] = 1.0
        for tie in ties:
            if tie.leader in self.free:
                A[tie.follower, self.free.index(tie.leader)] = tie.sign
        self.A = A
        affected = np.flatnonzero(np.any(A != 0, axis=1))
        self.p_fixed = p_base.copy()
        self.p_fixed[affected] = 0.0
        self.x0 = p_base[self.free].copy()
        self.priors = {i: s for i, s in (priors or {}).items() if A[i].any()}
        self.prior_mean = profile.nominal() if prior_mean is None else prior_mean
        self.prior_scale = 1.0

        ids = op_ids(profile)
        all_ops = [profile.frames[f].ops[k] for f, k in ids]
        affected_set = set(affected.tolist())
        self._op = all_ops
        # Ops that no joint drives and no estimate moves are identities when their value is zero.
        self._constant = [
            (i, op.param) for i, op in enumerate(all_ops) if op.joint < 0 and op.param not in affected_set
        ]
        self.record = {i for i, op in enumerate(all_ops) if op.param in affected_set}
        self.frames = sorted({profile.targets[t].frame for t in np.unique(data.target)} | {self.sensor.frame})
        self.intrinsics = intrinsic_params(self.sensor)
        self.B_intr = A[self.intrinsics] if self.intrinsics else np.zeros((0, len(self.free)))
        self.groups = []
        for t in np.unique(data.target):
            target = profile.targets[t]
            obs = np.flatnonzero(data.target == t)
            cfgs, counts = np.unique(data.cfg[obs], return_counts=True)
            runs = bool(np.all(np.diff(data.cfg[obs]) >= 0) and np.all(counts == counts[0]))
            signs = op_signs(profile, target.frame, self.sensor.frame)
            ops = sorted(i for i in self.record if signs.get(i, 0.0) != 0.0)
            self.groups.append(
                _Group(
                    obs=obs,
                    target=int(t),
                    signs=signs,
                    ops=ops,
                    B_ops=A[[all_ops[i].param for i in ops]] if ops else np.zeros((0, len(self.free))),
                    B_point=A[list(target.point_params)] if target.point_params else None,
                    rotation=np.array([1.0 if all_ops[i].kind == "r" else 0.0 for i in ops]),
                    sign=np.array([signs[i] for i in ops]),
                    per_cfg=int(counts[0]) if runs else 0,
                    cfgs=cfgs,
                )
            )
        self.n_data_rows = data.n_observations * self.dim
        self.included = np.ones(data.n_observations, bool)  # False: an outlier, left out
        self._q = np.nan_to_num(data.joints)  # joints a row does not need do not matter
        if noise_model is True:
            self.W = whitening(self.sensor, p_base, data.measured, self._reading_covariance(p_base))
        else:
            self.W = 1.0 if noise_model is False else noise_model

    def _reading_covariance(self, p: np.ndarray) -> np.ndarray | None:
        """(M, dim, dim): what rounding each joint reading to its encoder step adds to a measurement.

        A reading's rounding error is uniform over one step (variance step^2 / 12) and moves the
        prediction like the joint's offset does, so its Jacobian is the offset's column.
        """
        steps = {op.param: self.profile.joints[op.joint].resolution for op in self._op if op.joint >= 0}
        steps = {k: v for k, v in steps.items() if v > 0}
        if not steps:
            return None
        probe = Problem(self.profile, self.data, list(steps), p, noise_model=False)
        _, J = probe.residuals_jacobian(probe.x0)
        Jq = J.reshape(-1, self.dim, len(steps)) * np.sqrt(np.array(list(steps.values())) ** 2 / 12.0)
        return Jq @ Jq.transpose(0, 2, 1)

    # --- parameters -----------------------------------------------------------------------------
    def params(self, x: np.ndarray) -> np.ndarray:
        return self.p_fixed + self.A @ x

    # --- evaluation -----------------------------------------------------------------------------
    def predict(self, p: np.ndarray) -> np.ndarray:
        """Predicted measurements (M, dim) for full parameters p."""
        return self._evaluate(p, jacobian=False)[0]

    def residuals(self, x: np.ndarray) -> np.ndarray:
        p = self.params(x)
        pred, _ = self._evaluate(p, jacobian=False)
        return self._with_priors(self._whiten(pred - self.data.measured).ravel(), p)

    def residuals_jacobian(self, x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        p = self.params(x)
        pred, J = self._evaluate(p, jacobian=True)
        assert J is not None
        r = self._with_priors(self._whiten(pred - self.data.measured).ravel(), p)
        J3 = J.reshape(-1, self.dim, len(self.free)) * self.included[:, None, None]
        J = (self.W @ J3 if isinstance(self.W, np.ndarray) else J3 * self.W).reshape(J.shape)
        if self.priors:
            Jp = np.zeros((len(self.priors), len(self.free)))
            for k, (i, s) in enumerate(self.priors.items()):
                Jp[k] = self.prior_scale * self.A[i] / s
            J = np.vstack([J, Jp])
        return r, J

    def raw_residuals(self, x: np.ndarray) -> np.ndarray:
        """Prediction - measurement (M * dim), unweighted: the distances the papers report."""
        pred, _ = self._evaluate(self.params(x), jacobian=False)
        return ((pred - self.data.measured) * self.included[:, None]).ravel()

    def _whiten(self, e: np.ndarray) -> np.ndarray:
        e = e * self.included[:, None]
        return (self.W @ e[:, :, None])[:, :, 0] if isinstance(self.W, np.ndarray) else e * self.W

    def _with_priors(self, r: np.ndarray, p: np.ndarray) -> np.ndarray:
        if not self.priors:
            return r
        prior = [self.prior_scale * (p[i] - self.prior_mean[i]) / s for i, s in self.priors.items()]
        return np.concatenate([r, prior])

    def sensor_points(self, p: np.ndarray) -> np.ndarray:
        """Each observed point in the sensor frame (M, 3), for visibility checks and rendering."""
        poses = forward(self.profile, p, self._joints(), frames=self.frames, skip=self._skip(p))
        out = np.empty((self.data.n_observations, 3))
        for g in self.groups:
            out[g.obs] = self._points(p, poses, g)[1]
        return out

    def _skip(self, p: np.ndarray) -> set[int]:
        return {i for i, k in self._constant if p[k] == 0.0}

    def _joints(self) -> np.ndarray:
        return self._q

    def _points(self, p: np.ndarray, poses, g: _Group) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Base-frame points P, sensor-frame points x, the sensor rotation and the target rotation."""
        target = self.profile.targets[g.target]
        cfg = self.data.cfg[g.obs]
        local = self.data.point[g.obs]
        if target.point_params is not None:
            local = np.broadcast_to(p[list(target.point_params)], local.shape)
        elif target.points is not None:  # fixed points (markers, the frame's origin) by vertex id
            local = target.points[np.maximum(self.data.vertex[g.obs], 0)]
        Rt = poses.R[target.frame][cfg]
        P = (Rt @ local[:, :, None])[:, :, 0] + poses.t[target.frame][cfg]
        Rs = poses.R[self.sensor.frame][cfg]
        x = ((P - poses.t[self.sensor.frame][cfg])[:, None, :] @ Rs)[:, 0, :]
        return P, x, Rs, Rt

    def _twists(self, poses, g: _Group) -> np.ndarray:
        """(N, 6, K): per configuration, the (w, v) twist of each of the group's ops, signed."""
        W = np.stack([poses.w[i] for i in g.ops], axis=2)
        pivots = np.stack([poses.o[i] for i in g.ops], axis=2)
        v = np.where(g.rotation, np.cross(pivots, W, axis=1), W)
        return np.concatenate([W * g.rotation, v], axis=1) * g.sign

    def _evaluate(self, p: np.ndarray, jacobian: bool) -> tuple[np.ndarray, np.ndarray | None]:
        poses = forward(
            self.profile,
            p,
            self._joints(),
            frames=self.frames,
            record=self.record if jacobian else None,
            skip=self._skip(p),
        )
        M = self.data.n_observations
        pred = np.empty((M, self.dim))
        J = np.zeros((M, self.dim, len(self.free))) if jacobian else None
        for g in self.groups:
            P, x, Rs, Rt = self._points(p, poses, g)
            h, dh_dx, dh_dint = predict(self.sensor, p, x, derivatives=jacobian)
            pred[g.obs] = h
            if not jacobian:
                continue
            assert J is not None and dh_dx is not None and dh_dint is not None
            G = dh_dx @ Rs.transpose(0, 2, 1)  # d(pred)/d(P in the base frame)
            Jg = np.zeros((len(g.obs), self.dim, len(self.free)))
            if g.ops:
                # Each op moves the point by a twist: dP = w x P + v with v = o x w (rotation) or
                # dP = w (translation). Build the twists per configuration, then one batched product.
                xi = self._twists(poses, g)  # (N, 6, K)
                skew = np.zeros((len(P), 3, 3))
                skew[:, 0, 1], skew[:, 0, 2], skew[:, 1, 2] = P[:, 2], -P[:, 1], P[:, 0]
                skew[:, 1, 0], skew[:, 2, 0], skew[:, 2, 1] = -P[:, 2], P[:, 1], -P[:, 0]
                H = np.concatenate([G @ skew, G], axis=2)  # d(pred)/d(w, v): w x P = -[P]x w
                if g.per_cfg:  # observations come in equal runs per configuration: one product each
                    c = g.per_cfg
                    dpred = (H.reshape(-1, c * self.dim, 6) @ xi[g.cfgs]).reshape(len(P), self.dim, -1)
                else:
                    dpred = H @ xi[self.data.cfg[g.obs]]
                Jg += dpred @ g.B_ops
            if g.B_point is not None:
                Jg += (G @ Rt) @ g.B_point
            if self.intrinsics:
                Jg += dh_dint @ self.B_intr
            J[g.obs] = Jg
        return pred, (None if J is None else J.reshape(M * self.dim, len(self.free)))
