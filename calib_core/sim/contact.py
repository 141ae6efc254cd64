"""Configurations in contact: for plane constraints, where the robot touches each plane with its
target (a probe tip on a table), found on the true robot.

A random configuration inside the joint limits is pulled onto the plane by Gauss-Newton steps of
minimum norm in joint space (the plane distance's gradient by the joints is its Jacobian by the
joint offsets, which move exactly as the readings do); one that leaves the limits less the margin
on the way, or does not reach the plane, is drawn again.
"""

from __future__ import annotations

import math

import numpy as np

from ..dataset import Dataset
from ..errors import InputError
from ..estimation.problem import Problem
from ..model.profile import Profile

MARGIN_RAD = math.radians(1.0)  # kept clear of every joint limit, as a real robot's replay does
CONTACT_TOLERANCE = 1e-9  # profile length unit: in contact


def contacts(
    prof: Profile, p_true: np.ndarray, rng: np.random.Generator, per_plane: int
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Configurations (N, n_joints) in which the true robot (parameters p_true) touches each plane
    sensor with the sampling's target, `per_plane` each; their targets (N,) and the plane of each (N,)."""
    sampling = prof.simulation.get("sampling", {})
    target = prof.target(str(sampling["target"])) if "target" in sampling else (prof.data.target or 0)
    planes = [i for i, s in enumerate(prof.sensors) if s.kind == "plane"]
    if not planes:
        raise InputError(f"robot '{prof.name}' has no plane sensor to be in contact with")
    qs, targets, sensors = [], [], []
    for s in planes:
        found = _on_plane(prof, p_true, rng, target, s, per_plane)
        qs.append(found)
        targets += [target] * per_plane
        sensors += [s] * per_plane
    return np.concatenate(qs), np.array(targets), np.array(sensors)


def _on_plane(
    prof: Profile, p_true: np.ndarray, rng: np.random.Generator, target: int, sensor: int, n: int
) -> np.ndarray:
    lo, hi = prof.joint_limits()
    lo, hi = lo + MARGIN_RAD, hi - MARGIN_RAD
    moving = sorted(prof.joints_between(target, sensor))
    drives = [(op.param, op.joint) for f in prof.frames for op in f.ops if op.joint in moving]
    params = sorted({p for p, _ in drives})
    # d(reading of joint j) = d(offset of each op it drives): the joint's column sums those columns.
    to_joint = np.zeros((len(params), len(prof.joints)))
    for param, joint in drives:
        to_joint[params.index(param), joint] = 1.0
    found: list[np.ndarray] = []
    for _ in range(50):
        q = rng.uniform(lo, hi, (4 * n, len(lo)))
        for _ in range(30):
            r, J = _distance(prof, p_true, q, target, sensor, params)
            if np.max(np.abs(r)) < CONTACT_TOLERANCE:
                break
            Jq = J @ to_joint  # (N, n_joints)
            q -= Jq * (r / np.maximum(np.sum(Jq**2, axis=1), 1e-300))[:, None]
        r, _ = _distance(prof, p_true, q, target, sensor, params)
        ok = (np.abs(r) < 1e-6) & np.all((q >= lo) & (q <= hi), axis=1)
        found += list(q[ok])
        if len(found) >= n:
            return np.array(found[:n])
    raise InputError(f"found only {len(found)} configurations touching '{prof.sensors[sensor].name}' of the {n} asked")


def _distance(
    prof: Profile, p_true: np.ndarray, q: np.ndarray, target: int, sensor: int, params: list[int]
) -> tuple[np.ndarray, np.ndarray]:
    """The plane distance of the target in each configuration (N,) and its Jacobian by `params` (N, k)."""
    n = len(q)
    data = Dataset(
        robot=prof.name,
        frame_ids=np.arange(1, n + 1),
        joints=q,
        cfg=np.arange(n),
        target=np.full(n, target),
        point=np.full((n, 3), np.nan),
        vertex=np.full(n, -1),
        measured=np.zeros((n, 1)),
        sensor=np.full(n, sensor),
    )
    problem = Problem(prof, data, params, p_true, noise_model=False)
    r, J = problem.residuals_jacobian(problem.x0)
    return r, J
