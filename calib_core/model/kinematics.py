"""Forward kinematics of a profile's frame tree, batched over configurations, with exact derivatives.

Poses are kept as R (N, 3, 3) and t (N, 3): `T_base_frame` for every frame and configuration. For the
Jacobian, every recorded op keeps its axis `w` and pivot `o` in the base frame. Moving an op's value by dv
moves everything after it by a rotation about (w, o) or a translation along w, so a point P fixed
beyond the op moves by dP = w x (P - o) dv (rotation) or w dv (translation). Seen from a sensor that
hangs off the same tree, a shared op moves both and cancels; an op only on the sensor's side moves
the point the other way. That is the whole chain rule; no finite differences.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from .profile import Op, Profile


@dataclass
class Poses:
    """Base-frame poses of every frame for N configurations, plus the recorded ops' axes and pivots: a column
    per recorded op id, in ascending order (those of frames not computed are left unset)."""

    R: list[np.ndarray]  # per frame (N, 3, 3): T_base_frame rotation
    t: list[np.ndarray]  # per frame (N, 3)
    w: np.ndarray  # (N, 3, number of recorded ops): each op's axis in the base frame
    o: np.ndarray  # (N, 3, number of recorded ops): each op's pivot in the base frame


def op_ids(profile: Profile) -> list[tuple[int, int]]:
    """(frame, position) of every op, in a fixed order; an op's id is its index in this list."""
    return profile.op_ids


_EYE = np.eye(3)
_ZERO = np.zeros(3)


def axis_angle(axis: np.ndarray, angle: np.ndarray | float) -> np.ndarray:
    """Rodrigues: the rotation by `angle` about unit `axis`; (N, 3, 3) for an array of angles."""
    K = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
    a = np.asarray(angle, dtype=float)
    s = np.sin(a)[..., None, None]
    c = np.cos(a)[..., None, None]
    return _EYE + s * K + (1 - c) * (K @ K)


def _principal(axis: int, angle: np.ndarray) -> np.ndarray:
    """Rotations (N, 3, 3) about a principal axis, faster than Rodrigues."""
    c, s = np.cos(angle), np.sin(angle)
    i, j = {0: (1, 2), 1: (2, 0), 2: (0, 1)}[axis]
    out = np.zeros((len(angle), 3, 3))
    out[:, axis, axis] = 1.0
    out[:, i, i] = c
    out[:, j, j] = c
    out[:, i, j] = -s
    out[:, j, i] = s
    return out


def _rotation(op: Op, angle: float) -> np.ndarray:
    if op.axis is None:
        return axis_angle(op.vector, angle)
    c, s = math.cos(angle), math.sin(angle)
    if op.axis == 0:
        return np.array([[1.0, 0, 0], [0, c, -s], [0, s, c]])
    if op.axis == 1:
        return np.array([[c, 0, s], [0, 1.0, 0], [-s, 0, c]])
    return np.array([[c, -s, 0], [s, c, 0], [0, 0, 1.0]])


def forward(
    profile: Profile,
    p: np.ndarray,
    q: np.ndarray,
    *,
    frames: list[int] | None = None,
    record: set[int] | None = None,
    skip: set[int] | None = None,
) -> Poses:
    """Poses of `frames` (default all) and their ancestors for joint readings q (N, n_joints), rad.

    `record`: op ids whose axis and pivot to keep (for the Jacobian), written in place into `Poses.w` and `Poses.o`:
    a group of observations takes its ops' columns as they are, where a dictionary of them, stacked anew for each
    Jacobian, took 0.06 of its 0.84 ms (TALOS's origins). `skip`: op ids known to be identities (a zero value that
    is not estimated), left out for speed; none of them is in `record`. Runs of ops that no joint drives are the same
    for every configuration: they are composed as one 3 x 3 rotation and offset (C_R, C_t) and applied to the batch
    once.
    """
    n = q.shape[0]
    wanted = set(range(len(profile.frames))) if frames is None else {a for f in frames for a in profile.chain(f)}
    record = record or set()
    skip = skip or set()
    R: list[np.ndarray] = [None] * len(profile.frames)  # type: ignore[list-item]
    t: list[np.ndarray] = [None] * len(profile.frames)  # type: ignore[list-item]
    column = {i: c for c, i in enumerate(sorted(record))}
    w = np.empty((n, 3, len(column)))
    o = np.empty((n, 3, len(column)))
    op_id = 0
    for f, frame in enumerate(profile.frames):
        if f not in wanted:
            op_id += len(frame.ops)
            continue
        if frame.parent < 0:
            Rf, tf = np.broadcast_to(_EYE, (n, 3, 3)), np.zeros((n, 3))
        else:
            Rf, tf = R[frame.parent], t[frame.parent]
        C_R, C_t = _EYE, _ZERO  # pending constant transform after (Rf, tf)
        # The constant ops to record: their columns, axes and pivots after (Rf, tf).
        pending: list[tuple[int, np.ndarray, np.ndarray]] = []
        for op in frame.ops:
            i = op_id
            op_id += 1
            if i in skip:
                continue
            if op.joint < 0:
                axis = op.vector if C_R is _EYE else C_R @ op.vector  # a URDF origin's x, y, z come before its turns
                if i in record:
                    pending.append((column[i], axis, C_t))
                value = float(p[op.param])
                if op.kind == "t":
                    C_t = C_t + value * axis
                else:
                    C_R = _rotation(op, value) if C_R is _EYE else C_R @ _rotation(op, value)
                continue
            if pending:
                _record(Rf, tf, pending, w, o)
            if C_t is not _ZERO:
                tf = tf + _times(Rf, C_t)
            if C_R is not _EYE:
                Rf = _times(Rf, C_R)
            C_R, C_t, pending = _EYE, _ZERO, []
            value = p[op.param] + q[:, op.joint]
            axis = Rf[:, :, op.axis] if op.axis is not None else Rf @ op.vector
            if i in record:
                w[:, :, column[i]], o[:, :, column[i]] = axis, tf
            if op.kind == "t":
                tf = tf + value[:, None] * axis
            elif op.axis is not None:
                Rf = Rf @ _principal(op.axis, value)
            else:
                Rf = Rf @ axis_angle(op.vector, value)
        if pending:
            _record(Rf, tf, pending, w, o)
        R[f] = Rf if C_R is _EYE else _times(Rf, C_R)
        t[f] = tf if C_t is _ZERO else tf + _times(Rf, C_t)
    return Poses(R, t, w, o)


def _times(R: np.ndarray, M: np.ndarray) -> np.ndarray:
    """R @ M of a batch of rotations R (N, 3, 3) and one constant M (3, 3) or (3,), as one product of the stacked
    rows: the same numbers as the batched product, which calls BLAS once per configuration and took ten times
    as long (a tenth of drawing a plan's candidates)."""
    return (R.reshape(-1, 3) @ M).reshape(R.shape[:2] + M.shape[1:])


def _record(
    Rf: np.ndarray, tf: np.ndarray, ops: list[tuple[int, np.ndarray, np.ndarray]], w: np.ndarray, o: np.ndarray
) -> None:
    """The base-frame axes and pivots of a run of constant ops (`ops`: each op's column in w and o, its axis and
    its pivot after (Rf, tf)), all in one product: one at a time, they took half the kinematics of a Jacobian of
    a URDF's origins. The run's recorded ops are consecutive among the recorded ones (a joint's op ends a run, a
    skipped op is not recorded), so their columns are one slice."""
    k = len(ops)
    local = np.array([a for _, a, _ in ops] + [c for _, _, c in ops]).T  # (3, 2k): the axes, then the pivots
    base = (np.ascontiguousarray(Rf).reshape(-1, 3) @ local).reshape(len(tf), 3, 2 * k)
    columns = slice(ops[0][0], ops[0][0] + k)
    w[:, :, columns] = base[:, :, :k]
    np.add(base[:, :, k:], tf[:, :, None], out=o[:, :, columns])


def transform(R: np.ndarray, t: np.ndarray) -> np.ndarray:
    """(N, 4, 4) homogeneous matrices from R (N, 3, 3) and t (N, 3)."""
    T = np.zeros((R.shape[0], 4, 4))
    T[:, :3, :3] = R
    T[:, :3, 3] = t
    T[:, 3, 3] = 1.0
    return T


def ancestors_ops(profile: Profile, frame: int) -> set[int]:
    """Op ids on the path from the base to `frame`."""
    ids = op_ids(profile)
    chain = set(profile.chain(frame))
    return {i for i, (f, _) in enumerate(ids) if f in chain}


def op_signs(profile: Profile, target_frame: int, sensor_frame: int) -> dict[int, float]:
    """+1 for ops only on the target's side, -1 for ops only on the sensor's side (shared ops cancel)."""
    t_ops = ancestors_ops(profile, target_frame)
    s_ops = ancestors_ops(profile, sensor_frame)
    return {i: 1.0 for i in t_ops - s_ops} | {i: -1.0 for i in s_ops - t_ops}


def target_points(profile: Profile, p: np.ndarray, target: int) -> np.ndarray:
    """The points (K, 3) of a target in its frame: a board's grid, fixed points (markers, the frame's
    origin) or the calibrated point."""
    t = profile.targets[target]
    if t.grid is not None:
        return t.grid
    if t.points is not None:
        return t.points
    assert t.point_params is not None
    return p[list(t.point_params)][None]


def to_sensor(
    poses: Poses, target_frame: int, sensor_frame: int, cfg: np.ndarray, local: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Points `local` (n, 3) of a target frame, one per configuration cfg (n,): in the base frame
    (P_base), in the sensor frame (x_sensor), and the rotations R_base_sensor, R_base_target."""
    R_base_target = poses.R[target_frame][cfg]
    P_base = (R_base_target @ local[:, :, None])[:, :, 0] + poses.t[target_frame][cfg]
    R_base_sensor = poses.R[sensor_frame][cfg]
    x_sensor = ((P_base - poses.t[sensor_frame][cfg])[:, None, :] @ R_base_sensor)[:, 0, :]
    return P_base, x_sensor, R_base_sensor, R_base_target


def sensor_points(
    profile: Profile,
    p: np.ndarray,
    q: np.ndarray,
    targets: np.ndarray,
    *,
    sensor: int | None = None,
    center_only: bool = False,
) -> np.ndarray:
    """Each configuration's target points in a sensor's frame (default: the data format's sensor):
    (N, K, 3), or (N, 3) of their centre with `center_only`. Rows whose target has fewer points
    than K are zero-padded."""
    frame = profile.sensors[profile.data.sensor if sensor is None else sensor].frame
    used = sorted(set(np.asarray(targets).tolist()))
    poses = forward(profile, p, q, frames=sorted({profile.targets[t].frame for t in used} | {frame}))
    K = 1 if center_only else max(len(target_points(profile, p, t)) for t in used)
    out = np.zeros((len(q), K, 3))
    for t in used:
        rows = np.flatnonzero(targets == t)
        pts = target_points(profile, p, t)
        pts = pts.mean(axis=0, keepdims=True) if center_only else pts
        cfg = np.repeat(rows, len(pts))
        local = np.tile(pts, (len(rows), 1))
        x = to_sensor(poses, profile.targets[t].frame, frame, cfg, local)[1]
        out[rows, : len(pts)] = x.reshape(len(rows), len(pts), 3)
    return out[:, 0] if center_only else out
