"""Several starts for the poses nobody measured, when the first solution stays far above the noise.

A six-parameter pose that a mode estimates and no closed form starts (a camera's mount in the room,
a board's place on the flange) starts where the profile puts it, which may be a quarter turn off.
From there least squares can settle in a wrong minimum, tens or thousands of pixels off, that the
solver's own criteria call converged. When the first solution's residuals are more than
FAR_ABOVE_NOISE times a sensor's declared noise, each such pose is turned through the 23 other
rotations that map a cube onto itself (every orientation lies within 63 deg of one of them), its
translation re-fitted with everything else at its start; the SOLVED_STARTS turns whose re-fit fits
best are solved in full, and the lowest final cost of all wins. A camera or board on a registration
frame starts from the hand-eye equations in closed form (`camera_registration`): the other closed forms,
each also with the images whose board pose agrees better flipped flipped, are more starts of the list
(`closed_form_starts`).
"""

from __future__ import annotations

import itertools
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from ..model.profile import Profile
from .camera_registration import camera_starts, is_camera
from .handeye import zyx_angles
from .noise_test import sensor_scatter
from .problem import Problem
from .registration import registration_params
from .solver import levenberg_marquardt

# Residuals this many times a sensor's declared noise: beyond what a real robot's model error leaves
# in the built-in profiles' real data (Motoman: 0.9-6 with the tracker cube subsets and the cameras,
# 29-31 on the Aug 2019 tracker file, whose registration is fitted in closed form), and what a pose
# started a quarter turn off leaves (60 to thousands on a simulated hand-eye arm at 0.3 px).
FAR_ABOVE_NOISE = 10.0
SOLVED_STARTS = 5  # turned starts solved in full, the best by their re-fitted cost
REFIT_ITERATIONS = 10  # of the translation's re-fit: it only has to bring the target back into view
POSE_STEPS = (("t", 0), ("t", 1), ("t", 2), ("r", 2), ("r", 1), ("r", 0))  # x, y, z, yaw, pitch, roll


@dataclass(frozen=True)
class Start:
    """A start vector of the free parameters and how it was made."""

    label: str
    x: np.ndarray
    cost: float = 0.0  # before the full solve, to pick the few solved (0: solved in any case)


def far_above_noise(problem: Problem, r: np.ndarray) -> bool:
    """Whether some sensor's residuals `r` (as `Problem.residuals` gives them) are more than FAR_ABOVE_NOISE
    times its declared noise."""
    scatter = sensor_scatter(problem, r, len(problem.free))
    return any(total > FAR_ABOVE_NOISE**2 * max(dof, 1.0) for total, _, dof in scatter.values())


def unknown_poses(profile: Profile, free: list[int], settled: frozenset[int]) -> list[tuple[str, list[int]]]:
    """The frames no joint drives whose whole pose (x, y, z, yaw, pitch, roll: a urdf-style frame or a
    registration) is in `free`, none of it `settled` (fitted in closed form, as a tracker's registration
    is, or kept within bounds by the mode): each frame's name and the positions of its six parameters in
    `free`."""
    out = []
    position = {i: k for k, i in enumerate(free)}
    for frame in profile.frames:
        ops = frame.ops
        if frame.joint >= 0 or tuple((op.kind, op.axis) for op in ops) != POSE_STEPS:
            continue
        params = [op.param for op in ops]
        if all(i in position and i not in settled for i in params):
            out.append((frame.name, [position[i] for i in params]))
    return out


def cube_turns() -> list[tuple[str, np.ndarray]]:
    """The 23 rotations other than the identity that map a cube onto itself, each with its description."""
    from scipy.spatial.transform import Rotation  # here, not at the top: SciPy slows every start

    out = []
    for perm in itertools.permutations(range(3)):
        for signs in itertools.product((1.0, -1.0), repeat=3):
            G = np.zeros((3, 3))
            G[range(3), perm] = signs
            if np.linalg.det(G) < 0 or np.allclose(G, np.eye(3)):
                continue
            rotvec = Rotation.from_matrix(G).as_rotvec()
            angle = np.linalg.norm(rotvec)
            axis = rotvec / angle
            axis /= np.min(np.abs(axis[np.abs(axis) > 1e-9]))
            about = ", ".join(str(round(a)) for a in axis)
            out.append((f"turned {np.degrees(angle):.0f} deg about ({about})", G))
    return out


def turned_starts(
    problem: Problem,
    x0: np.ndarray,
    poses: list[tuple[str, list[int]]],
    should_stop: Callable[[], bool] | None = None,
) -> list[Start]:
    """From `x0`: each pose turned in its own frame through `cube_turns`, its translation re-fitted."""
    if not poses:
        return []
    from scipy.spatial.transform import Rotation  # here, not at the top: SciPy slows every start

    out = []
    for name, positions in poses:
        yaw, pitch, roll = x0[positions[3:]]
        R = Rotation.from_euler("ZYX", [yaw, pitch, roll]).as_matrix()
        for label, G in cube_turns():
            x = x0.copy()
            x[positions[3:]] = zyx_angles(R @ G)
            x, cost = refit(problem, x, positions[:3], should_stop)
            out.append(Start(f"{name} {label}", x, cost))
    return out


def refit(
    problem: Problem, x: np.ndarray, positions: list[int], should_stop: Callable[[], bool] | None = None
) -> tuple[np.ndarray, float]:
    """`x` with the free parameters at `positions` fitted to the data, every other one held; and the cost."""
    sub = Problem(
        problem.profile,
        problem.data,
        [problem.free[k] for k in positions],
        problem.params(x),
        noise_model=problem.weights,
    )
    res = levenberg_marquardt(
        sub.residuals_jacobian, sub.x0, fun=sub.residuals, max_iterations=REFIT_ITERATIONS, should_stop=should_stop
    )
    out = x.copy()
    out[positions] = res.x
    return out, res.cost


def closed_form_starts(problem: Problem) -> list[Start]:
    """For each camera of the problem whose (or whose board's) registration it estimates: the closed-form
    starts other than the best, which the start values hold (`camera_starts`), the rest of the start as is."""
    prof, data = problem.profile, problem.data
    p = problem.params(problem.x0)
    out = []
    for s in data.sensors:
        own = data.of_sensor(s)
        params = set(registration_params(prof, [s], np.unique(own.target).tolist()))
        if not is_camera(prof, s) or not params or not params <= set(problem.free):
            continue
        for start in camera_starts(prof, own, p)[1:]:
            out.append(Start(f"{start.label} (closed form)", start.p[problem.free], start.cost))
    return out
