"""Drawing configurations a model of the robot predicts in view (`Visibility`): uniform draws inside the joint
limits, or the profile's stance structure (`simulation.sampling: {kind: stances}`; NAO: a leg lifted into a
stance, the head in its postures aimed at that foot's board).

The simulator draws its sessions with its hidden truth; the planner and a random replay draw with the model
the robot believes in. The draws come from the caller's random stream, so a seed gives the same
configurations whoever draws them.
"""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np

from ..errors import Cancelled, InputError
from ..model.kinematics import forward, sensor_points, target_points, to_sensor
from .visibility import Visibility

STANCE_BATCH = 32  # stances drawn and checked at once
AHEAD_ROWS = 4096  # `Sampler.uniform` checks at most so many draws at once (its batches of up to 64 draws 64 at a time)
AIM_STEPS = 121  # the head angles a stance is aimed from (`Sampler._aim`)
AIM_COARSE = 10  # every so many of them tried first


class Sampler:
    """Configurations that `view` predicts in view, drawn from `rng`."""

    def __init__(self, view: Visibility, rng: np.random.Generator) -> None:
        self.view = view
        self.rng = rng

    def configurations(
        self, n: int | None = None, *, should_stop: Callable[[], bool] | None = None
    ) -> tuple[np.ndarray, np.ndarray]:
        """Joint readings (N, n_joints) and, per configuration, the target it shows (N,): the profile's
        stance structure, else `n` (default 100) uniform draws. `should_stop`: asked before each batch drawn
        (thousands of NAO's take a minute); Cancelled once it says yes."""
        stop = should_stop or (lambda: False)
        sampling = self.view.profile.simulation.get("sampling", {"kind": "uniform"})
        if sampling.get("kind") == "stances":
            return self._stances(sampling, n, stop)
        return self.uniform(n or 100, stop)

    def uniform(self, n: int, stop: Callable[[], bool] = lambda: False) -> tuple[np.ndarray, np.ndarray]:
        """`n` configurations drawn uniformly inside the joint limits whose data-format target is in view: batches of
        max(4 n, 64) until one brings those found to n. Where few are in view (a wrist camera sees its board in 2 of
        1000 draws of the hand-eye arm) the batches are drawn and checked 1, 2, 4 ... at a time (at most AHEAD_ROWS
        draws), each call of `sees` costing far more than its rows; the random stream is then put back after the
        batch that found enough, so that the draws and what the stream gives next are those of one batch at a
        time."""
        prof = self.view.profile
        lo, hi = prof.joint_limits()
        target = prof.data.target if prof.data.target is not None else 0
        size = max(4 * n, 64)  # a batch: drawn until one brings the configurations found to n, at most 200
        found: list[np.ndarray] = []
        drawn: list[np.ndarray] = []
        done, ahead = 0, 1
        while done < 200 and len(found) < n:
            if stop():
                raise Cancelled("the draw was cancelled")
            k = min(ahead, 200 - done, max(1, AHEAD_ROWS // size))
            state = self.rng.bit_generator.state
            q = self.rng.uniform(lo, hi, (k * size, len(lo)))
            ok = self.view.sees(q, np.full(len(q), target))
            reached = np.flatnonzero(len(found) + np.cumsum(ok.reshape(k, size).sum(axis=1)) >= n)
            used = k if not len(reached) else int(reached[0]) + 1
            if used < k:  # the stream goes on after the batch that found enough, as if drawn one at a time
                self.rng.bit_generator.state = state
                self.rng.uniform(lo, hi, (used * size, len(lo)))
            drawn.append(q[: used * size])
            found += list(q[: used * size][ok[: used * size]])
            done, ahead = done + used, 2 * ahead
        if len(found) < n:
            raise InputError(
                f"found only {len(found)} visible configurations of the {n} asked: ask for fewer"
                + self.view.too_small(np.concatenate(drawn), target)
            )
        return np.array(found[:n]), np.full(n, target)

    def _stances(
        self, sampling: dict, n: int | None, stop: Callable[[], bool] = lambda: False
    ) -> tuple[np.ndarray, np.ndarray]:
        prof = self.view.profile
        postures = int(sampling.get("postures", 3))
        per_target = int(sampling.get("stances_per_target", 24))
        if n is not None:
            per_target = max(1, math.ceil(n / (postures * len(sampling["stance"]))))
        batch = STANCE_BATCH
        qs, targets = [], []
        for tname, ranges in sampling["stance"].items():
            ti = prof.target(tname)
            got = 0
            for _ in range(per_target * 200 // batch + 1):
                if got == per_target:
                    break
                if stop():
                    raise Cancelled("the draw was cancelled")
                stances, seen = self._stance_batch(sampling, ranges, ti, batch, postures)
                whole = seen.reshape(batch, postures).all(axis=1)
                for b in np.flatnonzero(whole)[: per_target - got]:
                    qs += list(stances[b * postures : (b + 1) * postures])
                    targets += [ti] * postures
                    got += 1
            if got < per_target:
                raise InputError(
                    f"found only {got} visible stances for {tname} of the {per_target} needed: "
                    "ask for fewer configurations or another seed"
                )
        return np.array(qs), np.array(targets)

    def stance_frames(self, batches: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Frames of the profile's stance structure, each on its own (a planner picks among them): per
        target, `batches` x STANCE_BATCH stances in the stance ranges, each in the head postures, aimed at the
        board. The visible ones: readings (N, n_joints), targets (N,) and each frame's stance id (N,)."""
        prof = self.view.profile
        sampling = prof.simulation["sampling"]
        postures = int(sampling.get("postures", 3))
        batch = STANCE_BATCH
        qs, targets, ids = [], [], []
        for tname, ranges in sampling["stance"].items():
            ti = prof.target(tname)
            for _ in range(batches):
                stances, seen = self._stance_batch(sampling, ranges, ti, batch, postures)
                qs.append(stances[seen])
                targets.append(np.full(int(seen.sum()), ti))
                ids.append(len(ids) * batch + np.flatnonzero(seen) // postures)
        return np.concatenate(qs), np.concatenate(targets), np.concatenate(ids)

    def _stance_batch(
        self, sampling: dict, ranges: dict, target: int, batch: int, postures: int
    ) -> tuple[np.ndarray, np.ndarray]:
        """`batch` stances in `ranges`, each in `postures` head postures aimed at the target: the
        configurations (batch * postures, n_joints), stance b's postures in rows b * postures ..., and
        whether each is visible."""
        prof = self.view.profile
        lo, hi = prof.joint_limits()
        look = prof.joint(sampling["look_at"])
        post = prof.joint(sampling["posture_joint"])
        p_lo, p_hi = (math.radians(v) for v in sampling["posture_range"])
        q = np.zeros((batch, len(lo)))
        for jname, (a, b) in ranges.items():
            j = prof.joint(jname)
            q[:, j] = self.rng.uniform(max(math.radians(a), lo[j]), min(math.radians(b), hi[j]), batch)
        pitches = np.linspace(p_lo, p_hi, postures) + self.rng.uniform(-0.02, 0.02, (batch, postures))
        stances = np.repeat(q, postures, axis=0)
        stances[:, post] = np.clip(pitches.ravel(), lo[post], hi[post])
        stances[:, look] = self._aim(stances, look, target)
        stances[:, look] += self.rng.uniform(-0.05, 0.05, len(stances))
        stances[:, look] = np.clip(stances[:, look], lo[look], hi[look])
        return stances, self.view.sees(stances, np.full(len(stances), target))

    def _aim(self, q: np.ndarray, joint: int, target: int) -> np.ndarray:
        """For each configuration (row of q), the angle of `joint` that puts the target's centre in the
        image's centre column: of AIM_STEPS angles over the joint's range (within +-1.2 rad), the best. The
        centre's distance from that column falls and rises once as the joint turns (where the target is behind
        the camera it is infinite), so every AIM_COARSE-th angle is tried first and then the angles within
        AIM_COARSE of the best of those: the same angle as trying all of them, for a quarter of the cost."""
        lo, hi = self.view.profile.joint_limits()
        angles = np.linspace(max(lo[joint], -1.2), min(hi[joint], 1.2), AIM_STEPS)
        coarse = np.arange(0, AIM_STEPS, AIM_COARSE)
        cost = self._off_centre(q, joint, target, np.broadcast_to(angles[coarse], (len(q), len(coarse))))
        if cost is None:
            return np.zeros(len(q))
        best = coarse[np.argmin(cost, axis=1)]
        near = np.clip(best[:, None] + np.arange(-AIM_COARSE, AIM_COARSE + 1), 0, AIM_STEPS - 1)
        cost = self._off_centre(q, joint, target, angles[near])
        assert cost is not None
        return angles[near[np.arange(len(q)), np.argmin(cost, axis=1)]]

    def _off_centre(self, q: np.ndarray, joint: int, target: int, angles: np.ndarray) -> np.ndarray | None:
        """How far (px) from the image's centre column the target's centre is with `joint` at each of the
        angles (N, K) of each configuration (row of q): (N, K), infinite out of view; None for a sensor
        without an image."""
        prof, p = self.view.profile, self.view.p
        k = angles.shape[1]
        qs = np.repeat(q, k, axis=0)
        qs[:, joint] = angles.ravel()
        sensor = prof.sensors[prof.data.sensor]
        tf = prof.targets[target].frame
        if any(op.joint == joint for f in prof.chain(tf) for op in prof.frames[f].ops):
            x = sensor_points(prof, p, qs, np.full(len(qs), target), center_only=True)
        else:  # only the sensor turns: the target's centre once per row, the sensor's chain per angle
            centre = target_points(prof, p, target).mean(axis=0, keepdims=True)
            at_target = forward(prof, p, q, frames=[tf])
            poses = forward(prof, p, qs, frames=[sensor.frame])
            poses.R[tf] = np.repeat(at_target.R[tf], k, axis=0)  # the target's pose per angle
            poses.t[tf] = np.repeat(at_target.t[tf], k, axis=0)
            x = to_sensor(poses, tf, sensor.frame, np.arange(len(qs)), np.repeat(centre, len(qs), axis=0))[1]
        uv = sensor.project(p, x)
        if uv is None or sensor.image is None:
            return None
        cost = np.where(np.isfinite(uv[:, 0]), np.abs(uv[:, 0] - sensor.image[0] / 2), np.inf)
        return cost.reshape(len(q), k)
