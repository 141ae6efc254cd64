"""What a look at a target gave, and a session of them as a dataset: the finders' results
(`calib_core.vision.finders`, seeded by the kinematic prediction of the robot's believed calibration)
become rows of the pinned data formats. The same types serve the simulated robot and a real one.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from ..dataset import Dataset
from ..frame_status import FrameStatus
from ..model.kinematics import sensor_points, target_points
from ..model.profile import Profile

# A detector's own record of a look (its votes, inliers, residual, why it found nothing): JSON as the detector
# gives it, kept with the frame and shown as it came; its keys differ from one detector to another.
Detail = dict[str, Any]


@dataclass
class Sighting:
    """What one sensor's look at a target gave: measured rows, or why there are none."""

    sensor: int  # the sensor that looked (its index in the profile)
    target: int
    status: FrameStatus  # measured or not found
    reason: str
    measured: np.ndarray | None  # (K, dim): a sensor-frame point (profile length unit) or pixels
    points: np.ndarray  # (K, 3) the observed points in the target frame (NaN: the calibrated point)
    vertices: np.ndarray  # (K,) vertex ids, -1 for a single point
    detail: Detail = field(default_factory=dict)  # the detector's own figures (votes, inliers, ...)


@dataclass
class Capture:
    """One configuration looked at through the cameras (simulated, or a bag's images)."""

    frame: int
    readings: np.ndarray  # (n_joints,) rad: what the robot reports (quantised)
    sighting: Sighting
    images: dict[str, np.ndarray]  # "left", "right" (stereo) or "image" (a camera)


def predicted_points(
    profile: Profile, p: np.ndarray, q: np.ndarray, target: int, sensor: int | None = None
) -> np.ndarray:
    """The target's points (K, 3) in a sensor's frame (default: the data sensor's), for one configuration q (rad)."""
    k = len(target_points(profile, p, target))
    return sensor_points(profile, p, q[None], np.array([target]), sensor=sensor)[0, :k]


def dataset_from_captures(profile: Profile, captures: list[Capture], source: str) -> Dataset:
    """The dataset of the measured captures (frames whose detector found nothing are left out); `source`:
    where they come from (the Dataset's)."""
    got = [c for c in captures if c.sighting.measured is not None]
    if not got:
        raise ValueError("no capture was measured")
    counts = [len(c.sighting.measured) for c in got]  # type: ignore[arg-type]
    return Dataset(
        robot=profile.name,
        frame_ids=np.array([c.frame for c in got]),
        joints=np.array([c.readings for c in got]),
        cfg=np.repeat(np.arange(len(got)), counts),
        target=np.repeat([c.sighting.target for c in got], counts),
        point=np.concatenate([c.sighting.points for c in got]),
        vertex=np.concatenate([c.sighting.vertices for c in got]),
        measured=np.concatenate([c.sighting.measured for c in got]),  # type: ignore[misc]
        sensor=np.repeat([c.sighting.sensor for c in got], counts),
        source=source,
    )
