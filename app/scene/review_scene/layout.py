"""Where a review scene's things stand in viser's z-up world: the robot turned upright and facing +x
(`display_rotation`), the old copy on the left and the new one on the right, seen from the front (or both in one
place: the overlay), each copy's label above the robot or just above the selected frame's marks, and how far the
robot's bodies reach (the cameras stay out of them)."""

from __future__ import annotations

import numpy as np

from calib_core import Profile
from calib_core.model import forward

from ..review import frame_bounds_m
from .marks import Marks
from .nodes import Nodes

SIDES = ("old", "new")
LABELS = {"old": "old calibration", "new": "new calibration", "live": "live: active calibration"}
# In the overlay both copies stand in one place and one label names both (two labels would stack).
OVERLAY_LABELS = {"old": "old calibration (translucent)", "new": "old calibration (translucent) and new calibration"}
LABEL_LIFT_M = 0.08  # the old label's lift above the robot in the overlay, where both labels would coincide
BODY_PAD = 0.2  # the bodies reach this share of the robot's size past its frame origins (the camera stays out)


def display_rotation(profile: Profile) -> np.ndarray:
    """R_world_base: the robot upright in viser's z-up world, facing +x.

    Profiles do not say which way is up (Robonaut's chest frame has y down, NAO's torso z up), but
    a robot's head sits above its base: up is the base axis nearest the direction from the base to
    the data sensor at zero joint angles (or the first other sensor on the robot when the data come
    from an external device, like the Motoman's laser tracker); forward is the base x axis (y if x is
    up). A robot with no sensor of its own keeps its base axes."""
    on_robot = [
        s.frame for s in profile.sensors if not any(profile.frames[f].registration for f in profile.chain(s.frame))
    ]
    data_frame = profile.sensors[profile.data.sensor].frame
    if not on_robot:
        return np.eye(3)
    frame = data_frame if data_frame in on_robot else on_robot[0]
    poses = forward(profile, profile.nominal(), np.zeros((1, len(profile.joints))), frames=[frame])
    v = poses.t[frame][0]
    k = int(np.argmax(np.abs(v)))
    up = np.zeros(3)
    up[k] = 1.0 if v[k] >= 0 else -1.0
    ahead = np.eye(3)[1 if k == 0 else 0]
    return np.stack([ahead, np.cross(up, ahead), up])


class Layout:
    """The robot shown's place in the world, read with the scene's nodes (where each copy's root and marks group
    stand now) and marks (the selected frame's, and their size)."""

    def __init__(self, nodes: Nodes, marks: Marks) -> None:
        self.nodes = nodes
        self.marks = marks
        self.R = np.eye(3)  # the review copies' base turned upright in the world
        self.separation_m = 0.0
        self.label_z_m = 0.0
        self.centre_m = np.zeros(3)
        self.extent_m = np.zeros((2, 3))  # the robot's world box at the nominal model, zero joint angles
        self.body_pad_m = 0.0  # how far its bodies reach past its frame origins

    def place(self, profile: Profile, bounds_m: np.ndarray) -> None:
        """Where the copies of `profile` go, its frame origins within `bounds_m` (base frame, m) over what is shown:
        apart by their width and a quarter of the robot, the labels above, the centre between them."""
        R = display_rotation(profile)
        corners = box_corners(bounds_m) @ R.T  # world, before the side offsets
        low, high = corners.min(axis=0), corners.max(axis=0)
        span = high - low
        self.separation_m = float(span[1] + 0.25 * max(span.max(), 0.2))
        self.label_z_m = float(high[2] + 0.1 * max(span[2], 0.2))
        self.centre_m = (low + high) / 2
        self.R = R
        zero = np.zeros((1, len(profile.joints)))
        self.extent_m = bounding_box(box_corners(frame_bounds_m(profile, profile.nominal(), zero)) @ R.T)
        self.body_pad_m = BODY_PAD * float(span.max()) + self.marks.size.ring_m

    def root_position(self, side: str, *, apart: bool) -> tuple[float, float, float]:
        """Where a copy's root stands: side by side along the world y (old on the left, new on the right, seen from
        the front), or both in one place (the overlay, a review of one side); the live copy stands where the old
        one does."""
        half = self.separation_m / 2 if apart else 0.0
        return (0.0, -float(self.centre_m[1]) + (half if side == "new" else -half), 0.0)

    def label_position(self, side: str, *, at_marks: bool, overlay: bool) -> tuple[float, float, float]:
        """Where a copy's label goes (relative to its root): just above the selected frame's marks, where the
        camera looks ("frame it"), or above the robot; in the overlay the old one higher (both would coincide)."""
        marks = self.marks.of_frame(f"/review/{side}/base/frame")
        if at_marks and len(marks):
            world = self.marks_world(side, marks, relative=True)
            lift = 1.2 * self.marks.size.ring_m if overlay and side == "old" else 0.0
            top = float(world[:, 2].max()) + 0.8 * self.marks.size.ring_m + lift
            x, y = (world[:, :2].min(axis=0) + world[:, :2].max(axis=0)) / 2
            return float(x), float(y), top
        lift = LABEL_LIFT_M if overlay and side == "old" else 0.0
        return float(self.centre_m[0]), 0.0, self.label_z_m + lift

    def marks_world(self, side: str, points_m: np.ndarray, *, relative: bool = False) -> np.ndarray:
        """A side's frame marks (base frame, m) in the world, or relative to the side's root."""
        base = f"/review/{side}/base/frame"
        local = points_m + np.asarray(self.nodes[base].position, float)
        root = np.zeros(3) if relative else np.asarray(self.nodes[f"/review/{side}"].position, float)
        return local @ self.R.T + root


def bounding_box(points: np.ndarray) -> np.ndarray:
    """(2, 3) min and max of points (N, 3)."""
    return np.stack([points.min(axis=0), points.max(axis=0)])


def box_corners(bounds_m: np.ndarray) -> np.ndarray:
    """(8, 3) corners of a (2, 3) min/max box."""
    return np.array([[bounds_m[i, 0], bounds_m[j, 1], bounds_m[k, 2]] for i in (0, 1) for j in (0, 1) for k in (0, 1)])
