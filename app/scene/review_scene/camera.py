"""Where a review scene puts the browsers' cameras (app/scene/framing.py moves them). An instrument, as in RViz:
selecting a frame, the overlay and "all frames" leave every camera where the operator put it; the cameras move
when the robot shown changes (`robot_view`: onto its copies) and at the page's "frame it" (`marks_view`: onto the
selected frame's marks, side by side from far enough, a narrow field of view, that both copies are seen from
nearly the same direction, and never inside a body)."""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from ..framing import DEFAULT_FOV_RAD, Framing, framing, leave_box
from ..review import Review, frame_bounds_m
from .layout import SIDES, Layout, bounding_box, box_corners

FRAME_VIEW_SHARE = 0.15  # "frame it" spans at least this share of the robot's size
SAME_VIEW_DEG = 5.0  # "frame it": the side-by-side copies seen from directions at most this far apart


def robot_view(layout: Layout, review: Review | None, index: int | None, *, live: bool, overlay: bool) -> Framing:
    """The live copy, or the review's two side by side (or overlaid), each where the layout puts it: its extent at
    the nominal model and zero joint angles, as it stands at the selected frame with that frame's marks (a robot
    known by its flange pose is all at its base at zero readings: its reading places the flange, and the board is
    where the marks are), and its label; at the default field of view. A review of one side is framed with the
    other's place too, showing the same: its first calibration puts the new copy there, the camera left as it is."""
    nodes = layout.nodes
    if live:
        places = {"/live": (np.asarray(nodes["/live"].position, float), None)}
    else:
        places = {f"/review/{s}": (np.array(layout.root_position(s, apart=not overlay)), s) for s in SIDES}
    points = []
    for root, (at, side) in places.items():
        points += [layout.extent_m + at, np.asarray(nodes[f"{root}/label"].position, float)[None] + at]
        if side is not None and review is not None and index is not None:
            points.append(_at_frame(layout, review, index, side if side in review.sides else "old") + at)
    return framing(bounding_box(np.concatenate(points)), fov_rad=DEFAULT_FOV_RAD)


def _at_frame(layout: Layout, review: Review, index: int, side: str) -> np.ndarray:
    """(8, 3) the corners of a copy's box at the selected frame, relative to its root in the world: its frame
    origins and the frame's marks."""
    geometry = review.frame_geometry(index)
    marks = (geometry.measured_m[side], geometry.predicted_m[side])
    return (
        box_corners(frame_bounds_m(review.profile, review.sides[side].p, geometry.joints_rad[None], marks)) @ layout.R.T
    )


def marks_view(layout: Layout, review: Review, index: int, *, overlay: bool) -> Framing | None:
    """ "Frame it": the selected frame's marks and labels on the copies shown, from the front. Side by side, from
    far enough (the field of view narrowed to fit) that the two copies are seen from directions at most
    SAME_VIEW_DEG apart (from nearby, one is seen from its left and the other from its right: they look posed
    differently); never inside the robot's bodies (the overlay's translucent copy). None: no marks to frame."""
    nodes = layout.nodes
    shown = [s for s in SIDES if nodes[f"/review/{s}"].visible]
    points = []
    for side in shown:
        marks = layout.marks.of_frame(f"/review/{side}/base/frame")
        if len(marks):
            label = nodes[f"/review/{side}/label"].position + nodes[f"/review/{side}"].position
            points += [layout.marks_world(side, marks), np.asarray(label, float)[None]]
    if not points:
        return None
    robot = float(np.linalg.norm(layout.extent_m[1] - layout.extent_m[0])) / 2
    f = framing(bounding_box(np.concatenate(points)), min_radius_m=FRAME_VIEW_SHARE * robot)
    apart_m = 0.0 if len(shown) < 2 or overlay else layout.separation_m
    same_view_m = 1.1 * apart_m / 2 / np.tan(np.radians(SAME_VIEW_DEG) / 2)  # a tenth to spare: seen from above
    bodies = [_bodies_box(layout, review, index, side) for side in shown]
    outside_m = leave_box(f.look_at, f.direction, bounding_box(np.concatenate(bodies)))
    return replace(f, distance_m=max(same_view_m, outside_m, 1e-3))


def _bodies_box(layout: Layout, review: Review, index: int, side: str) -> np.ndarray:
    """(2, 3) world box of a copy's bodies at the selected frame: its frame origins, padded."""
    joints = review.frame_geometry(index).joints_rad
    bounds = frame_bounds_m(review.profile, review.sides[side].p, joints[None])
    box = bounding_box(box_corners(bounds) @ layout.R.T + np.asarray(layout.nodes[f"/review/{side}"].position, float))
    return box + np.array([[-1.0], [1.0]]) * layout.body_pad_m
