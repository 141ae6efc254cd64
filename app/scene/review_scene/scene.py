"""The Review scene in viser: the robot twice, side by side, as the old and the new calibration see it.

    /review/old                    root: placed in the world (left copy; the overlay puts both at 0)
        label                      "old calibration"
        base                       the robot's base frame, turned upright (layout.display_rotation)
            robot/...              URDF at the old calibration's parameters (copies.py)
            ghost/...              the same, translucent: shown instead of `robot` in the overlay (built
                                   when the overlay is first asked for: a third copy costs the browser)
            frame                  the selected frame's marks, lifted toward the camera (marks.py)
                measured           its measurements: hollow red rings facing the camera
                predicted          its predictions: smaller filled dots, blue (green on the new side)
                lines              prediction -> measurement, one segment per point
            all/measured|predicted|lines   every frame at once, smaller: sent at load, toggled by show_all
    /review/new                    the same, right copy, green (no ghost)
    /live                          Observe: one copy driven by the live joint stream, in the left place

Each side's URDF is generated from that side's parameters (`Review.urdf`), so both copies take the same joint
readings and still differ where the calibrations differ. The scene keeps its own registry of the nodes it made
(nodes.py: viser has no public listing) and reports it through `state()`. This module is the scene's
selection: what it shows (a robot, a review and its selected frame, the overlay, every frame, the live view,
the magnification) and, from that, where each node stands and whether it is visible; the robot's copies
(copies.py), the marks (marks.py), where things stand in the world (layout.py) and where the cameras go
(camera.py) are its parts.

Readable at a glance: a measurement is a ring and a prediction a smaller dot inside it, so a good
calibration's dot shows inside its ring instead of being covered by a mark of the same size; a sphere
fixture (drawn by the URDF at the prediction) shows inside the ring, its dot lifted onto the sphere's
front; the new side's marks sit a hair nearer the camera than the old side's, so in the overlay and in
"all frames" coinciding marks do not flicker (z-fighting). Each copy's label sits above the selected
frame's marks. The marks are drawn over the bodies (static/viser_marks.js, in the iframe's page): a hand in
front of its board does not hide them.

An instrument, as in RViz: selecting a frame, the overlay and "all frames" leave every browser's camera where the
operator put it; `frame_marks` ("frame it") brings it onto the selected frame's marks (camera.py). Millimetre
residuals show at a magnification (`set_magnify`, as the 2-D view's): a measurement is drawn at
prediction + k (measurement - prediction), and the copies' labels say k.

A scene draws on a target: one browser's viser client (the desk: each viewer's own scene, app/scene/viewers.py;
viser sends client-scoped nodes to that browser only) or the server (every browser).

One robot at a time: when the robot shown changes (a review, the built-in robot, or the live view of
another robot), everything shown for the previous one is removed from viser (re-adding a node under the
same name would keep the old children, so a Robonaut arm would stay inside a NAO scene) and the target's
browsers' cameras are framed on the new robot (app/scene/framing.py): the copies' extents at the nominal model and
zero joint angles, and as they stand at the selected frame with its marks, where the layout puts them side by side
(camera.robot_view).
"""

from __future__ import annotations

import io
import threading
from pathlib import Path
from typing import Protocol, TypedDict

import numpy as np

from calib_core import Profile, load_profile
from calib_core.io import to_urdf
from calib_core.vision import Sighting

from ..framing import CameraState, ClientFraming, Target
from ..review import Review, frame_bounds_m, live_geometry
from ..robot_copy import quaternion
from .camera import marks_view, robot_view
from .copies import GENERATED, Copies, CopyState
from .layout import LABELS, OVERLAY_LABELS, SIDES, Layout, box_corners, display_rotation
from .marks import ALL_SCALE, MAGNIFY_MAX, PARTS, SIDE_COLOR, Marks, MarkSize, mark_size
from .nodes import Nodes, NodeState


class SceneState(TypedDict):
    """`ReviewScene.state`: what the scene shows (for the tests and the API)."""

    camera: CameraState
    robot: str | None
    index: int | None
    overlay: bool
    all: bool
    live: bool
    magnify: float
    nodes: dict[str, NodeState]
    urdf: dict[str, CopyState]


class LookLike(Protocol):
    """What show_live needs of a driver's look (app.drivers.Look)."""

    readings_rad: np.ndarray
    sightings: list[Sighting]


class ReviewScene:
    def __init__(self, target: Target, urdf_path: Path | None = None) -> None:
        """`target`: the scene of one browser (a viser client: a viewer's own scene) or of every browser (the
        server); `urdf_path`: a built-in robot's URDF to show (at zero joint angles) before any review."""
        self.target = target
        self.robot: str | None = None
        self.review: Review | None = None
        self.index: int | None = None
        self.overlay = False
        self.all = False
        self.live = False
        self.magnify = 1.0  # the residuals drawn this many times their length
        self._lock = threading.RLock()
        self.nodes = Nodes(target)
        self.marks = Marks(self.nodes)
        self.copies = Copies(self.nodes)
        self.layout = Layout(self.nodes, self.marks)
        self._profile: Profile | None = None
        self._live_robot: str | None = None
        self.camera = ClientFraming(target)
        if urdf_path is not None:
            import yourdfpy

            text = Path(urdf_path).read_text(encoding="utf-8")
            self.set_robot(urdf_path, yourdfpy.URDF.load(io.StringIO(text), build_scene_graph=False).robot.name)

    # --- loading --------------------------------------------------------------------------------
    def set_robot(self, urdf_path: Path, robot: str) -> None:
        """Show built-in robot `robot` from a URDF file on both copies at zero joint angles, no frame."""
        self.show_robot(load_profile(robot), Path(urdf_path).read_text(encoding="utf-8"))

    def show_robot(self, profile: Profile, urdf_text: str | None = None) -> None:
        """Show a robot on both copies at zero joint angles, no frame: from a URDF document, or the
        profile's own at the nominal model."""
        with self._lock:
            if self._show_robot(profile, urdf_text):
                self._reframe()

    def _show_robot(self, profile: Profile, urdf_text: str | None) -> bool:
        """show_robot without framing the cameras; True if the robot shown changed."""
        if urdf_text is None or GENERATED in urdf_text:  # a generated frame tree: drawn with bodies instead
            urdf_text = to_urdf(profile, profile.nominal(), bodies=True)
        text = urdf_text
        zero = np.zeros(len(profile.joints))
        switched = self._switch(profile)
        self.review = None
        self.index = None
        self._setup(profile, frame_bounds_m(profile, profile.nominal(), zero[None]))
        for side in SIDES:
            self.copies.ensure_side(profile, side, text, overlay=self.overlay)
            self.copies[side].pose(zero)
        self.live = False
        self._refresh()
        return switched

    def load(self, review: Review) -> None:
        """Show a review: both copies, every frame's points (sent once, shown by show_all), and
        its first frame selected."""
        with self._lock:
            switched = self._switch(review.profile)
            self._setup(review.profile, review.bounds_m)
            self.review = review
            self.index = None
            for side in review.sides:
                self.copies.ensure_side(review.profile, side, review.urdf[side], overlay=self.overlay)
            self.marks.show_all_frames(review, self.magnify)
            self.live = False
            if len(review.indices):
                self.select(int(review.indices[0]))
            else:
                self._refresh()
            if switched:
                self._reframe()

    # --- interaction ----------------------------------------------------------------------------
    def select(self, index: int) -> None:
        """Show frame `index` (its frame number): both URDF configurations and the frame's marks; the cameras stay
        where they are."""
        with self._lock:
            if self.review is None:
                raise ValueError("no review is loaded: load(review) first")
            geometry = self.review.frame_geometry(index)  # NotFound naming the frames for a bad index
            with self.target.atomic():
                for side in self.review.sides:
                    self.copies[side].pose(geometry.joints_rad)
                    self.marks.show_frame(f"/review/{side}/base/frame", geometry, side, self.magnify)
                if self.overlay:
                    self.copies["ghost"].pose(geometry.joints_rad)
                self.index = int(index)
                self.live = False
                self._refresh()

    def set_magnify(self, k: float) -> None:
        """Draw each measurement at prediction + k (measurement - prediction) (k >= 1), every frame's too."""
        if not (np.isfinite(k) and 1 <= k <= MAGNIFY_MAX):
            raise ValueError(f"magnify: {k} is not a factor from 1 to {MAGNIFY_MAX:g}")
        with self._lock:
            self.magnify = float(k)
            if self.review is None:
                return
            with self.target.atomic():
                self.marks.show_all_frames(self.review, self.magnify)
                if self.index is not None:
                    geometry = self.review.frame_geometry(self.index)
                    for side in self.review.sides:
                        self.marks.show_frame(f"/review/{side}/base/frame", geometry, side, self.magnify)
                self._refresh()

    def frame_marks(self) -> None:
        """The page's "frame it": every browser's camera onto the selected frame's marks and labels on the copies
        shown (camera.marks_view). Without a selected frame (or live, or every frame shown): the robot."""
        with self._lock:
            view = None
            if not (self.live or self.all or self.review is None or self.index is None):
                view = marks_view(self.layout, self.review, self.index, overlay=self.overlay)
            if view is None:
                self._reframe()
            else:
                self.camera.frame(view)

    def show_all(self, on: bool) -> None:
        """Every frame's points at once (on), or the selected frame's only."""
        with self._lock:
            self.all = bool(on)
            self._refresh()

    def set_overlay(self, on: bool) -> None:
        """Both copies in one place, the old one translucent (on), or side by side."""
        with self._lock:
            if on and "old" in self.copies:
                self.copies.ensure_ghost()
            self.overlay = bool(on)
            self._refresh()

    def show_live(self, profile: Profile, look: LookLike, p: np.ndarray) -> None:
        """Observe: the robot at its live readings through calibration p, the live detection (red)
        and the prediction (blue) of every sensor's sighting, in place of the review copies until the next select
        or load."""
        geometry = live_geometry(profile, p, look.readings_rad, look.sightings)
        text = to_urdf(profile, p, bodies=True)
        with self._lock:
            # Another robot: it replaces the one shown (and its review), and the cameras frame it live.
            switched = self.robot != profile.name and self._show_robot(profile, None)
            if self._live_robot != profile.name:
                self._live_robot = profile.name
                R = display_rotation(profile)
                bounds = frame_bounds_m(profile, p, np.zeros((1, len(profile.joints))))
                top = float((box_corners(bounds) @ R.T)[:, 2].max())
                self.nodes.frame("/live", visible=False)
                self.nodes.frame("/live/base", wxyz=quaternion(R))
                self.nodes.label("/live/label", LABELS["live"], (0.0, 0.0, top + 0.1))
                self.marks.add_group("/live/base/frame", SIDE_COLOR["old"], mark_size(profile), "frame", R)
            copy = self.copies.ensure("live", "/live/base/robot", profile, text, None)
            with self.target.atomic():
                copy.pose(geometry.joints_rad)
                self.marks.show_frame("/live/base/frame", geometry, "old", 1.0)
                self.live = True
                self._refresh()
            if switched:
                self._reframe()

    def hide_live(self) -> None:
        """Back to the review copies."""
        with self._lock:
            self.live = False
            self._refresh()

    # --- tests and the API ----------------------------------------------------------------------
    def state(self) -> SceneState:
        """{robot, index, overlay, all, live, magnify, nodes, urdf, camera}. nodes: {name: {kind ("frame", "points",
        "lines", "label"), visible, shown (it and its ancestors visible), position, wxyz (relative to
        its parent), and color + points (N, 3) / segments (N, 2, 3) of what it really holds, or text}};
        urdf: {copy ("old", "ghost", "new", "live"): {root, node (the URDF's nodes hang under it), shown,
        joints: {name: rad}, looks: {node: {link, what, faces}} (a URDF robot's own visuals)}}; camera: the
        framing of the robot shown and each browser's camera (app.scene.framing.ClientFraming.state)."""
        with self._lock:
            return {
                "camera": self.camera.state(),
                "robot": self.robot,
                "index": self.index,
                "overlay": self.overlay,
                "all": self.all,
                "live": self.live,
                "magnify": self.magnify,
                "nodes": self.nodes.state(),
                "urdf": self.copies.state(),
            }

    # --- building blocks ------------------------------------------------------------------------
    def _setup(self, profile: Profile, bounds_m: np.ndarray) -> None:
        """Roots, labels and empty point nodes for a robot; where the copies go; the camera."""
        self._profile = profile
        self.robot = profile.name
        self.marks.size = size = mark_size(profile)
        self.layout.place(profile, bounds_m)
        R, centre_m = self.layout.R, self.layout.centre_m
        for side in SIDES:
            root = f"/review/{side}"
            self.nodes.frame(root)
            self.nodes.frame(f"{root}/base", wxyz=quaternion(R))
            self.nodes.label(f"{root}/label", LABELS[side], (float(centre_m[0]), 0.0, self.layout.label_z_m))
            for group in ("frame", "all"):
                # Every frame at once: smaller marks, or they hide the robot.
                scale = 1.0 if group == "frame" else ALL_SCALE
                m = MarkSize(scale * size.ring_m, scale * size.dot_m, size.lift_m)
                self.marks.add_group(f"{root}/base/{group}", SIDE_COLOR[side], m, group, R, nearer=side == "new")

    def _switch(self, profile: Profile) -> bool:
        """Before showing `profile`: if it is another robot than the one shown, remove everything shown
        for that one: every URDF copy with all its nodes, and the live view (hidden until show_live builds
        it for the new robot); the points and labels are made anew by _setup. True if switched."""
        if self.robot == profile.name and self._profile is not None:
            return False
        self.copies.drop_all()
        if "/live" in self.nodes:
            self.nodes["/live"].visible = False
            for name in [n for n in self.nodes.counts if n.startswith("/live/")]:
                self.marks.update_points(name, np.zeros((0, 3)))
        self._live_robot = None
        self.marks.now.clear()
        self.review = None
        self.index = None
        self.live = False
        return True

    def _refresh(self) -> None:
        """Positions and visibility from the flags: roots side by side along the world y (old on
        the left, new on the right, seen from the front) or overlaid with the old copy's ghost;
        the selected frame's points or every frame's; the review copies or the live one."""
        nodes = self.nodes
        if "/review/old" not in nodes:
            return
        has_new = self.review is None or "new" in self.review.sides
        apart = has_new and not self.overlay
        nodes["/review/old"].position = self.layout.root_position("old", apart=apart)
        nodes["/review/new"].position = self.layout.root_position("new", apart=apart)
        nodes["/review/old"].visible = not self.live
        nodes["/review/new"].visible = has_new and not self.live
        if "/live" in nodes:
            nodes["/live"].position = self.layout.root_position("live", apart=apart)
            nodes["/live"].visible = self.live
        if "/review/old/base/ghost" in nodes:
            nodes["/review/old/base/robot"].visible = not self.overlay
            nodes["/review/old/base/ghost"].visible = self.overlay
        framed = self.review is not None and self.index is not None
        for side in SIDES:
            text = (OVERLAY_LABELS if self.overlay else LABELS)[side] + self._magnify_text()
            label = nodes[f"/review/{side}/label"]
            label.text = text  # type: ignore[attr-defined]
            label.position = self.layout.label_position(side, at_marks=framed and not self.all, overlay=self.overlay)
            label.visible = not (self.overlay and has_new and side == "old")
        for side in SIDES:
            for part in PARTS:
                for group, on in (("frame", framed and not self.all), ("all", self.review is not None and self.all)):
                    name = f"/review/{side}/base/{group}/{part}"
                    nodes[name].visible = on and nodes.counts[name] > 0
        if "/live/base/frame/measured" in nodes:
            for part in PARTS:
                name = f"/live/base/frame/{part}"
                nodes[name].visible = nodes.counts[name] > 0

    def _reframe(self) -> None:
        """Every browser's camera on the copies shown (camera.robot_view)."""
        self.camera.frame(robot_view(self.layout, self.review, self.index, live=self.live, overlay=self.overlay))

    def _magnify_text(self) -> str:
        """What a label adds when the residuals are drawn longer than they are."""
        return "" if self.magnify == 1 else f" · residuals x{self.magnify:g}"
