"""The review's marks in the 3-D scene: each measurement a red ring facing the camera, each prediction a smaller
dot in its side's colour (blue the old calibration and Observe's live view, green the new one), and a residual
line from the prediction to the measurement.

A group of marks (`<copy>/base/frame`: the selected frame's; `<copy>/base/all`: every frame's, smaller) holds
the three parts as viser nodes under one frame, lifted toward the camera: onto a sphere fixture's front, where the
URDF's sphere would hide them, or off a board, which would cut the rings. The marks are sized to the target
(`mark_size`): a ring just outside the sphere, or about half a board's grid step (neighbouring corners' rings do
not touch). Millimetre residuals show at a magnification: a measurement is drawn at
prediction + k (measurement - prediction) (`magnified`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from calib_core import Profile
from calib_core.units import length_factor

from ..framing import FRONT
from ..review import FrameGeometry, Review
from .nodes import Nodes

PARTS = ("measured", "predicted", "lines")
RED = (255, 0, 0)
SIDE_COLOR = {"old": (0, 0, 255), "new": (0, 200, 0)}
DEFAULT_RING_M = 0.01  # a measurement's ring (diameter) when the target says nothing of its size
DOT_PER_RING = 0.22  # a prediction's dot, as a share of the ring's diameter (viser draws it about twice that)
RING_LINE = 0.05  # a ring's line thickness, as a share of its diameter
RESIDUAL_LINE = 0.25  # a residual line's thickness, as a share of the dot
RING_SEGMENTS = {"frame": 20, "all": 8}  # segments per ring
ALL_SCALE = 0.5  # mark size of the all-frames view, relative to the one-frame view
NEW_NEARER = 0.15  # the new side's marks nearer the camera than the old side's, in dots
MAGNIFY_MAX = 1000.0  # the largest factor the residuals are drawn at


@dataclass(frozen=True)
class MarkSize:
    """How a robot's marks are drawn (m): the ring's and the dot's diameters, and how far the marks are lifted
    toward the camera (onto a sphere fixture's front, where the URDF's sphere would hide them)."""

    ring_m: float
    dot_m: float
    lift_m: float


class Marks:
    """The scene's groups of marks, in its node registry: what each group's rings are (about the origin, facing the
    camera) and the selected frame's marks as drawn (base frame, m: the labels stand above them, "frame it" frames
    them)."""

    def __init__(self, nodes: Nodes) -> None:
        self.nodes = nodes
        self.size = MarkSize(DEFAULT_RING_M, DOT_PER_RING * DEFAULT_RING_M, 0.0)  # the robot shown's
        self._rings: dict[str, np.ndarray] = {}  # a marks group -> its ring's segments about the origin
        self.now: dict[str, np.ndarray] = {}  # a frame group -> its marks now (base frame, m)

    def of_frame(self, base: str) -> np.ndarray:
        """(N, 3) the marks a frame group shows now (base frame, m)."""
        return self.now.get(base, np.zeros((0, 3)))

    def add_group(
        self,
        base: str,
        color: tuple[int, int, int],
        size: MarkSize,
        group: str,
        R_world_base: np.ndarray,
        *,
        nearer: bool = False,
    ) -> None:
        """A group's red measurement rings, coloured prediction dots (float32: float16 would hide millimetre
        residuals) and residual lines, empty and hidden (viser gets one placeholder each). The group's node
        is lifted toward the camera (`size.lift_m`, and a little more for the `nearer` side); its rings face
        the camera's direction (R_world_base: the base's turn in the world)."""
        lift = size.lift_m + (NEW_NEARER * size.dot_m if nearer else 0.0)
        toward = R_world_base.T @ FRONT  # the view direction in the base frame
        self.nodes.frame(base)
        self.nodes[base].position = tuple(float(v) for v in lift * toward)
        self._rings[base] = _ring(toward, R_world_base.T[:, 2], size.ring_m / 2, RING_SEGMENTS[group])
        self._add_segments(f"{base}/measured", RED, RING_LINE * size.ring_m)
        self.nodes[f"{base}/predicted"] = self.nodes.target.scene.add_point_cloud(
            f"{base}/predicted",
            np.zeros((1, 3), np.float32),
            np.array(color, np.uint8),
            point_size=size.dot_m,
            point_shape="circle",
            precision="float32",
            point_shading="flat",
            visible=False,
        )
        self._add_segments(f"{base}/lines", color, RESIDUAL_LINE * size.dot_m)
        for part in PARTS:
            self.nodes.counts[f"{base}/{part}"] = 0
        self.nodes.centres[f"{base}/measured"] = np.zeros((0, 3))

    def show_frame(self, base: str, geometry: FrameGeometry, side: str, k: float) -> None:
        """A frame's marks on one side, each measurement drawn at prediction + k (measurement - prediction)."""
        predicted = geometry.predicted_m[side]
        got = np.isfinite(geometry.measured_m[side]).all(axis=1)
        measured = np.full_like(predicted, np.nan)
        measured[got] = magnified(predicted[got], geometry.measured_m[side][got], k)
        marks = np.concatenate([predicted, measured[got]])
        self.now[base] = marks[np.isfinite(marks).all(axis=1)]
        self.update_points(f"{base}/predicted", predicted)
        self.update_points(f"{base}/measured", measured[got])
        self.update_lines(f"{base}/lines", predicted[got], measured[got])

    def show_all_frames(self, review: Review, k: float) -> None:
        """Every frame's marks (hidden until the scene shows every frame), the residuals magnified k times."""
        for side in review.sides:
            measured, predicted = review.all_points(side)
            shown = magnified(predicted, measured, k)
            base = f"/review/{side}/base/all"
            self.update_points(f"{base}/measured", shown)
            self.update_points(f"{base}/predicted", predicted)
            self.update_lines(f"{base}/lines", predicted, shown)

    def update_points(self, name: str, points: np.ndarray) -> None:
        """New points for a cloud (or centres for a group's rings); an empty one keeps its old points (viser
        needs one) and is hidden."""
        group = name.rsplit("/", 1)[0]
        if name.endswith("/measured") and group in self._rings:
            centres = np.asarray(points, float).reshape(-1, 3)
            self.nodes.centres[name] = centres
            if len(centres):
                rings = centres[:, None, None, :] + self._rings[group][None]
                self.nodes[name].points = rings.reshape(-1, 2, 3).astype(np.float32)  # type: ignore[attr-defined]
        elif len(points):
            self.nodes[name].points = np.asarray(points, np.float32)  # type: ignore[attr-defined]
        self.nodes.counts[name] = len(points)

    def update_lines(self, name: str, start: np.ndarray, end: np.ndarray) -> None:
        if len(start):
            self.nodes[name].points = np.stack([start, end], axis=1).astype(np.float32)  # type: ignore[attr-defined]
        self.nodes.counts[name] = len(start)

    def _add_segments(self, name: str, color: tuple[int, int, int], thickness_m: float) -> None:
        """An empty, hidden line-segments node (one placeholder segment)."""
        self.nodes[name] = self.nodes.target.scene.add_line_segments(
            name, np.zeros((1, 2, 3), np.float32), np.array(color, np.uint8), thickness=thickness_m, visible=False
        )


def mark_size(profile: Profile) -> MarkSize:
    """Marks sized to the target: a ring just outside a sphere fixture (the URDF draws the sphere at the
    prediction: it shows inside the ring, the dot lifted onto its front), or about half a board's grid step
    (neighbouring corners' rings do not touch), lifted off the board."""
    to_m = length_factor(profile.length_unit, "m")
    target = profile.targets[profile.data.target if profile.data.target is not None else 0]
    if target.radius is not None:
        r = target.radius * to_m
        return MarkSize(2.8 * r, 0.5 * r, 1.05 * r)
    ring = DEFAULT_RING_M
    if target.grid is not None and len(target.grid) > 1:
        ring = 0.45 * float(np.linalg.norm(target.grid[1] - target.grid[0])) * to_m
    return MarkSize(ring, DOT_PER_RING * ring, 0.6 * ring)  # lifted off a board, which would cut the rings


def magnified(predicted_m: np.ndarray, measured_m: np.ndarray, k: float) -> np.ndarray:
    """Where a measurement is drawn: prediction + k (measurement - prediction) (the measurement without a
    prediction)."""
    return np.where(np.isfinite(predicted_m), predicted_m + k * (measured_m - predicted_m), measured_m)


def _ring(toward: np.ndarray, up: np.ndarray, radius_m: float, n: int) -> np.ndarray:
    """(n, 2, 3) segments of a circle of `radius_m` about the origin, in the plane facing `toward` (unit)."""
    side = np.cross(up, toward)
    if np.linalg.norm(side) < 1e-9:
        side = np.cross(np.eye(3)[int(np.argmin(np.abs(toward)))], toward)
    side /= np.linalg.norm(side)
    rise = np.cross(toward, side)
    angles = np.linspace(0.0, 2 * np.pi, n + 1)
    circle = radius_m * (np.cos(angles)[:, None] * side + np.sin(angles)[:, None] * rise)
    return np.stack([circle[:-1], circle[1:]], axis=1)
