"""Shared by the tests of 6-D pose measurements: tests/profiles/tracked-arm.yaml's hidden truth and its
poses as a tracker would measure them (the simulator makes no poses: the true model's own prediction,
then Gaussian noise on the position and a random small rotation of the orientation)."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from calib_core import Dataset, Problem, load_profile
from calib_core.model import Profile

PROFILE = Path(__file__).resolve().parent / "profiles" / "tracked-arm.yaml"
# The hidden truth, display units (mm, deg), as changes from the nominal.
TRUTH_CHANGES = {
    "shoulder_lift": 0.3,
    "elbow": -0.25,
    "wrist_1": 0.4,
    "wrist_2": -0.3,
    "tracker.x": 1500.0,
    "tracker.y": -300.0,
    "tracker.z": 400.0,
    "tracker.yaw": 140.0,
    "tracker.pitch": 2.0,
    "tracker.roll": -1.0,
    "tool_body.x": 1.5,
    "tool_body.y": -0.8,
    "tool_body.z": 2.0,
    "tool_body.yaw": 1.0,
    "tool_body.roll": -0.6,
    "forearm_body.y": 1.2,
    "forearm_body.pitch": 0.7,
}
POSITION_MM, ROTATION_DEG = 0.05, 0.02  # the profile's noise, which the measurements get


def tracked_arm() -> Profile:
    return load_profile(PROFILE)


def truth(profile: Profile) -> np.ndarray:
    p = profile.nominal().copy()
    for name, change in TRUTH_CHANGES.items():
        i = profile.param(name)
        p[i] += math.radians(change) if profile.parameters[i].kind == "angle" else change
    return p


def configurations(profile: Profile, n: int, seed: int) -> Dataset:
    """n random configurations within 2.5 rad of home, each seen with both bodies; measured: zeros."""
    rng = np.random.default_rng(seed)
    q = rng.uniform(-2.5, 2.5, (n, len(profile.joints)))
    targets = [profile.targets.index(t) for t in profile.targets]
    k = len(targets)
    return Dataset(
        robot=profile.name,
        frame_ids=np.arange(1, n + 1),
        joints=q,
        cfg=np.repeat(np.arange(n), k),
        target=np.tile(targets, n),
        point=np.zeros((n * k, 3)),
        vertex=np.full(n * k, -1),
        measured=np.zeros((n * k, 6)),
        sensor=np.zeros(n * k, int),
    )


def measure(profile: Profile, data: Dataset, p: np.ndarray, seed: int, scale: float = 1.0) -> Dataset:
    """`data` with the poses that parameters p give, noisy (the profile's noise times `scale`)."""
    rng = np.random.default_rng(seed)
    exact = Problem(profile, data, [], p, noise_model=False).predict(p)
    position = exact[:, :3] + rng.normal(0.0, POSITION_MM * scale, (len(exact), 3))
    turn = Rotation.from_rotvec(rng.normal(0.0, math.radians(ROTATION_DEG) * scale, (len(exact), 3)))
    rotation = (Rotation.from_rotvec(exact[:, 3:6]) * turn).as_rotvec()
    out = Dataset(**{**data.__dict__, "measured": np.hstack([position, rotation])})
    return out
