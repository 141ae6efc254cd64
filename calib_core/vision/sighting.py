"""From camera images to measurements, the way a real head does it: the detectors are seeded by the
kinematic prediction of the robot's current (believed) calibration, and their results become rows
of the pinned data formats. The same functions serve the simulated robot and a real one.

- Robonaut: stereo depth -> BallFinder -> the sphere's centre in the eye frame (one 3-D point).
- NAO: the lower camera's image -> sandal board detector -> the 24 vertices in px, each with its
  identity (the 180-degree symmetry of the grid resolved by the prediction).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..dataset import Dataset
from ..frame_status import FrameStatus
from ..model.kinematics import sensor_points, target_points
from ..model.profile import Profile
from ..units import length_factor
from .ballfinder import find_sphere
from .sandal_board import detect_board
from .stereo import StereoHead


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
    detail: dict = field(default_factory=dict)  # the detector's own figures (votes, inliers, ...)


@dataclass
class Capture:
    """One configuration looked at through the cameras (simulated, or a bag's images)."""

    frame: int
    readings: np.ndarray  # (n_joints,) rad: what the robot reports (quantised)
    sighting: Sighting
    images: dict[str, np.ndarray]  # "left", "right" (stereo) or "image" (a camera)


def predicted_points(profile: Profile, p: np.ndarray, q: np.ndarray, target: int) -> np.ndarray:
    """The target's points (K, 3) in the data sensor's frame, for one configuration q (rad)."""
    k = len(target_points(profile, p, target))
    return sensor_points(profile, p, q[None], np.array([target]))[0, :k]


def sight_fixture(
    profile: Profile, p_believed: np.ndarray, q: np.ndarray, depth_m: np.ndarray, head: StereoHead
) -> Sighting:
    """The BallFinder on a depth map, seeded by where the believed kinematics put the fixture."""
    target = profile.data.target if profile.data.target is not None else 0
    radius = profile.targets[target].radius
    if radius is None:
        raise ValueError(f"target '{profile.targets[target].name}' has no radius: not a sphere")
    to_m = length_factor(profile.length_unit, "m")
    seed_m = (predicted_points(profile, p_believed, q, target)[0] @ head.R_frame_optical) * to_m
    found = find_sphere(depth_m, head.fx_px, head.fy_px, head.cx_px, head.cy_px, radius * to_m, seed_m)
    detail = found.to_json()
    points = np.full((1, 3), np.nan)
    if not found.found or found.center_m is None:
        return Sighting(
            profile.data.sensor, target, FrameStatus.NOT_FOUND, found.reason, None, points, np.array([-1]), detail
        )
    measured = (head.R_frame_optical @ found.center_m) / to_m
    return Sighting(
        profile.data.sensor, target, FrameStatus.MEASURED, "ok", measured[None], points, np.array([-1]), detail
    )


def sight_board(profile: Profile, p_believed: np.ndarray, q: np.ndarray, target: int, image: np.ndarray) -> Sighting:
    """The sandal board detector, its vertex identities taken from the believed kinematics."""
    s = profile.data.sensor
    sensor = profile.sensors[s]
    board = profile.targets[target]
    assert board.grid is not None and board.grid_shape is not None
    rows, cols = board.grid_shape
    expected = sensor.predict(p_believed, predicted_points(profile, p_believed, q, target))[0]
    found = detect_board(image, cols, rows, predicted=expected)
    vertices = np.arange(rows * cols)
    detail = {"found": found.found, "reason": found.reason, "residual_px": found.residual_px}
    if not found.found or found.corners is None:
        return Sighting(s, target, FrameStatus.NOT_FOUND, found.reason, None, board.grid, vertices, detail)
    return Sighting(
        s, target, FrameStatus.MEASURED, "ok", np.asarray(found.corners, float), board.grid, vertices, detail
    )


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
