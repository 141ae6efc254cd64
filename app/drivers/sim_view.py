"""What a simulated robot served to the desk from another process shows (`calib sim-ros2`, `calib sim-naoqi`): where
it stands at the start, and what its camera sees of the target in view."""

from __future__ import annotations

import math

import numpy as np

from calib_core import Profile
from calib_core.sim import SimulatedRobot
from calib_core.vision import Sampler, Visibility, found_targets


def home(profile: Profile, sim: SimulatedRobot) -> np.ndarray:
    """A start with the target in view, inside the limits less a degree."""
    lo, hi = profile.joint_limits()
    qs, _ = Sampler(Visibility(profile, sim.true_params), np.random.default_rng(99)).configurations(4)
    margin = math.radians(1.0)
    return np.clip(qs[0], lo + margin, hi - margin) if len(qs) else (lo + hi) / 2


def render_in_view(profile: Profile, sim: SimulatedRobot, q: np.ndarray) -> list[np.ndarray]:
    """The image(s) of true configuration q, drawn by the finder of the target in view (NAO: the left or right
    foot's board; Robonaut: the sphere in its hand, the stereo head's pair), one per image role of the sensor."""
    found = found_targets(profile, profile.data.sensor)
    if len(found) > 1:
        found = [t for t in Visibility(profile, sim.true_params).targets_in_view(q) if t in found] or found
    images, _ = sim.render(q, found[0])
    sensor = profile.sensors[profile.data.sensor]
    return [np.ascontiguousarray(images[role], dtype=np.uint8) for role in sensor.image_roles]
