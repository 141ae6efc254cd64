"""The Review scene in viser: the robot twice, side by side, as the old and the new calibration see it.

    /review/old                    root: placed in the world (left copy; the overlay puts both at 0)
        label                      "old calibration"
        base                       the robot's base frame, turned upright (display_rotation)
            robot/...              URDF at the old calibration's parameters (app/scene/robot_copy.py)
            ghost/...              the same, translucent: shown instead of `robot` in the overlay (built
                                   when the overlay is first asked for: a third copy costs the browser)
            frame                  the selected frame's marks, lifted toward the camera (`_Marks`)
                measured           its measurements: hollow red rings facing the camera
                predicted          its predictions: smaller filled dots, blue (green on the new side)
                lines              prediction -> measurement, one segment per point
            all/measured|predicted|lines   every frame at once, smaller: sent at load, toggled by show_all
    /review/new                    the same, right copy, green (no ghost)
    /live                          Observe: one copy driven by the live joint stream, in the left place

Each side's URDF is generated from that side's parameters (`Review.urdf`), so both copies take the
same joint readings and still differ where the calibrations differ. A robot made from a URDF file is drawn
with that URDF's own visuals (app/scene/robot_look.py: meshes, primitives) under each copy's link frames, in place of
the generated bodies of those links; they are sent once per copy and move with the links. The scene keeps its
own registry of the nodes it made (viser has no public listing) and reports it through `state()`.

Readable at a glance: a measurement is a ring and a prediction a smaller dot inside it, so a good
calibration's dot shows inside its ring instead of being covered by a mark of the same size; a sphere
fixture (drawn by the URDF at the prediction) shows inside the ring, its dot lifted onto the sphere's
front; the new side's marks sit a hair nearer the camera than the old side's, so in the overlay and in
"all frames" coinciding marks do not flicker (z-fighting). Each copy's label sits above the selected
frame's marks. The marks are drawn over the bodies (static/viser_marks.js, in the iframe's page): a hand in
front of its board does not hide them.

An instrument, as in RViz: selecting a frame, the overlay and "all frames" leave every browser's camera where the
operator put it; `frame_marks` ("frame it") brings it onto the selected frame's marks, side by side from far
enough (a narrow field of view) that both copies are seen from nearly the same direction, and never inside a
body. Millimetre residuals show at a magnification (`set_magnify`, as the 2-D view's): a measurement is drawn at
prediction + k (measurement - prediction), and the copies' labels say k.

A scene draws on a target: one browser's viser client (the desk: each viewer's own scene, app/scene/viewers.py;
viser sends client-scoped nodes to that browser only) or the server (every browser).

One robot at a time: when the robot shown changes (a review, the built-in robot, or the live view of
another robot), everything shown for the previous one is removed from viser (re-adding a node under the
same name would keep the old children, so a Robonaut arm would stay inside a NAO scene) and the target's
browsers' cameras are framed on the new robot (app/scene/framing.py): the copies' extents at the nominal model and
zero joint angles, where the layout puts them.
"""

from __future__ import annotations

import io
import threading
from dataclasses import dataclass, replace
from pathlib import Path
from typing import TYPE_CHECKING, Any, Protocol

import numpy as np
import viser

from calib_core import Profile, load_profile
from calib_core.io import to_urdf
from calib_core.model import forward
from calib_core.units import length_factor
from calib_core.vision import Sighting

from ..validation import MAGNIFY_MAX
from .framing import DEFAULT_FOV_RAD, FRONT, ClientFraming, Target, framing, leave_box
from .review import FrameGeometry, Review, frame_bounds_m, live_geometry
from .robot_copy import RobotCopy, quaternion
from .robot_look import LinkVisual, link_visuals, robot_look, without_bodies

if TYPE_CHECKING:  # loaded with the first robot drawn (with trimesh, half a second): not at the desk's start
    import yourdfpy

SIDES = ("old", "new")
PARTS = ("measured", "predicted", "lines")
RED = (255, 0, 0)
SIDE_COLOR = {"old": (0, 0, 255), "new": (0, 200, 0)}
LABELS = {"old": "old calibration", "new": "new calibration", "live": "live: active calibration"}
# In the overlay both copies stand in one place and one label names both (two labels would stack).
OVERLAY_LABELS = {"old": "old calibration (translucent)", "new": "old calibration (translucent) and new calibration"}
GHOST_RGBA = (0.45, 0.55, 1.0, 0.35)  # the old copy in the overlay: translucent, tinted like its points
DEFAULT_RING_M = 0.01  # a measurement's ring (diameter) when the target says nothing of its size
DOT_PER_RING = 0.22  # a prediction's dot, as a share of the ring's diameter (viser draws it about twice that)
RING_LINE = 0.05  # a ring's line thickness, as a share of its diameter
RESIDUAL_LINE = 0.25  # a residual line's thickness, as a share of the dot
RING_SEGMENTS = {"frame": 20, "all": 8}  # segments per ring
ALL_SCALE = 0.5  # mark size of the all-frames view, relative to the one-frame view
NEW_NEARER = 0.15  # the new side's marks nearer the camera than the old side's, in dots
LABEL_LIFT_M = 0.08  # the old label's lift above the robot in the overlay, where both labels would coincide
GENERATED = "Generated by calib_core.urdf"  # the comment of a URDF made by to_urdf (the built-in robots')
FRAME_VIEW_SHARE = 0.15  # "frame it" spans at least this share of the robot's size
SAME_VIEW_DEG = 5.0  # "frame it": the side-by-side copies seen from directions at most this far apart
BODY_PAD = 0.2  # the bodies reach this share of the robot's size past its frame origins (the camera stays out)


class LookLike(Protocol):
    """What show_live needs of a driver's look (app.drivers.Look)."""

    readings_rad: np.ndarray
    sightings: list[Sighting]


@dataclass
class _Copy:
    """One URDF copy: its document, its model (the URDF shown: the profile's frame tree, without the simple
    bodies of links drawn with their own visuals) and its frames and visuals in viser (app/scene/robot_copy.py).

    `root` is the slot's frame (kept, its visibility is the copy's); the URDF's nodes hang under `node`, a
    child named once per build (`root`/u<n>), removed with the copy: viser's buffer merges the removal of
    a name with its re-creation, so a rebuilt copy under the same names could keep the old one's nodes."""

    text: str
    profile: Profile
    urdf: yourdfpy.URDF
    robot: RobotCopy
    root: str
    node: viser.FrameHandle
    joint_order: list[int]  # the profile joint index of each URDF actuated joint
    joint_unit: np.ndarray  # per URDF actuated joint: its reading's unit in the URDF's (a prismatic one's, in m)
    looks: dict[str, LinkVisual]  # the robot's own visuals (app/scene/robot_look.py): viser node -> visual


@dataclass(frozen=True)
class _Marks:
    """How a robot's marks are drawn (m): the ring's and the dot's diameters, and how far the marks are lifted
    toward the camera (onto a sphere fixture's front, where the URDF's sphere would hide them)."""

    ring_m: float
    dot_m: float
    lift_m: float


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


def configure(server: viser.ViserServer) -> None:
    """The viser client as the page embeds it, for every browser: no share button (it would tunnel the scene
    through an external service), the (empty) control panel minimised so the scene gets the room, and the
    default lights without shadows: their shadows (three cascades) draw the scene three more times per frame,
    which a software-rendered browser pays for in the latency of every change (a frame step's marks wait for
    the frame that shows them). A hemisphere light instead of viser's environment map: prefiltering the map's
    image cost such a browser 1.2-1.9 s of CPU at every scene it opened (benchmarks/scene_open.py), for much
    the same look."""
    server.gui.configure_theme(show_share_button=False)
    server.gui.main_panel.minimize()
    server.scene.configure_default_lights(cast_shadow=False)
    server.scene.configure_environment_map(hdri=None)
    server.scene.add_light_hemisphere(
        "/lights/sky", sky_color=(255, 255, 255), ground_color=(120, 120, 130), intensity=1.5
    )


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
        self._nodes: dict[str, viser.SceneNodeHandle] = {}
        self._counts: dict[str, int] = {}  # points or segments node -> how many it really holds
        self._rings: dict[str, np.ndarray] = {}  # a marks group -> its ring's segments about the origin
        self._centres: dict[str, np.ndarray] = {}  # a group's rings node -> the measurements it rings
        self._frame_marks: dict[str, np.ndarray] = {}  # a frame group -> its marks now (base frame, m)
        self._R = np.eye(3)  # the review copies' base turned upright in the world
        self._marks = _Marks(DEFAULT_RING_M, DOT_PER_RING * DEFAULT_RING_M, 0.0)
        self._copies: dict[str, _Copy] = {}
        self._builds = 0  # URDF copies built: names each build's node
        self._profile: Profile | None = None
        self._separation_m = 0.0
        self._label_z_m = 0.0
        self._centre_m = np.zeros(3)
        self._live_robot: str | None = None
        self._extent_m = np.zeros((2, 3))  # the robot's world box at the nominal model, zero joint angles
        self._body_pad_m = 0.0  # how far its bodies reach past its frame origins
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
            self._ensure_side(profile, side, text)
            self._set_joints(self._copies[side], zero)
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
                self._ensure_side(review.profile, side, review.urdf[side])
            self._show_all_frames(review)
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
                    self._set_joints(self._copies[side], geometry.joints_rad)
                    self._show_frame(f"/review/{side}/base/frame", geometry, side, self.magnify)
                if self.overlay:
                    self._set_joints(self._copies["ghost"], geometry.joints_rad)
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
                self._show_all_frames(self.review)
                if self.index is not None:
                    geometry = self.review.frame_geometry(self.index)
                    for side in self.review.sides:
                        self._show_frame(f"/review/{side}/base/frame", geometry, side, self.magnify)
                self._refresh()

    def frame_marks(self) -> None:
        """The page's "frame it": every browser's camera onto the selected frame's marks and labels on the copies
        shown, from the front. Side by side, from far enough (the field of view narrowed to fit) that the two copies are
        seen from directions at most SAME_VIEW_DEG apart (from nearby, one is seen from its left and the other
        from its right: they look posed differently); never inside the robot's bodies (the overlay's translucent
        copy). Without a selected frame (or live, or every frame shown): the robot."""
        with self._lock:
            shown = [s for s in SIDES if self._nodes[f"/review/{s}"].visible]
            points = []
            for side in shown:
                marks = self._frame_marks.get(f"/review/{side}/base/frame", np.zeros((0, 3)))
                if len(marks):
                    label = self._nodes[f"/review/{side}/label"].position + self._nodes[f"/review/{side}"].position
                    points += [self._marks_world(side, marks), np.asarray(label, float)[None]]
            if self.live or self.all or self.review is None or self.index is None or not points:
                self._reframe()
                return
            robot = float(np.linalg.norm(self._extent_m[1] - self._extent_m[0])) / 2
            f = framing(_box(np.concatenate(points)), min_radius_m=FRAME_VIEW_SHARE * robot)
            apart_m = 0.0 if len(shown) < 2 or self.overlay else self._separation_m
            same_view_m = 1.1 * apart_m / 2 / np.tan(np.radians(SAME_VIEW_DEG) / 2)  # a tenth to spare: seen from above
            bodies = [self._bodies_box(side) for side in shown]
            outside_m = leave_box(f.look_at, f.direction, _box(np.concatenate(bodies)))
            self.camera.frame(replace(f, distance_m=max(same_view_m, outside_m, 1e-3)))

    def show_all(self, on: bool) -> None:
        """Every frame's points at once (on), or the selected frame's only."""
        with self._lock:
            self.all = bool(on)
            self._refresh()

    def set_overlay(self, on: bool) -> None:
        """Both copies in one place, the old one translucent (on), or side by side."""
        with self._lock:
            if on and "old" in self._copies:
                self._ensure_ghost()
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
                top = float((_corners(bounds) @ R.T)[:, 2].max())
                self._frame("/live", visible=False)
                self._frame("/live/base", wxyz=quaternion(R))
                self._label("/live/label", LABELS["live"], (0.0, 0.0, top + 0.1))
                self._add_parts("/live/base/frame", SIDE_COLOR["old"], _marks(profile), "frame", R)
            copy = self._ensure_copy("live", "/live/base/robot", profile, text, None)
            with self.target.atomic():
                self._set_joints(copy, geometry.joints_rad)
                self._show_frame("/live/base/frame", geometry, "old", 1.0)
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
    def state(self) -> dict[str, Any]:
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
                "nodes": {name: self._node_state(name, h) for name, h in self._nodes.items()},
                "urdf": {
                    slot: {
                        "root": c.root,
                        "node": c.node.name,
                        "shown": self._shown(c.root),
                        "joints": dict(zip(c.robot.joint_names, map(float, c.robot.cfg), strict=True)),
                        "looks": {
                            name: {"link": v.link, "what": v.what, "faces": len(v.faces)} for name, v in c.looks.items()
                        },
                    }
                    for slot, c in self._copies.items()
                },
            }

    # --- building blocks ------------------------------------------------------------------------
    def _setup(self, profile: Profile, bounds_m: np.ndarray) -> None:
        """Roots, labels and empty point nodes for a robot; where the copies go; the camera."""
        self._profile = profile
        self.robot = profile.name
        R = display_rotation(profile)
        corners = _corners(bounds_m) @ R.T  # world, before the side offsets
        low, high = corners.min(axis=0), corners.max(axis=0)
        span = high - low
        self._separation_m = float(span[1] + 0.25 * max(span.max(), 0.2))
        self._label_z_m = float(high[2] + 0.1 * max(span[2], 0.2))
        self._centre_m = (low + high) / 2
        self._R = R
        self._marks = marks = _marks(profile)
        for side in SIDES:
            root = f"/review/{side}"
            self._frame(root)
            self._frame(f"{root}/base", wxyz=quaternion(R))
            self._label(f"{root}/label", LABELS[side], (float(self._centre_m[0]), 0.0, self._label_z_m))
            for group in ("frame", "all"):
                # Every frame at once: smaller marks, or they hide the robot.
                scale = 1.0 if group == "frame" else ALL_SCALE
                m = _Marks(scale * marks.ring_m, scale * marks.dot_m, marks.lift_m)
                self._add_parts(f"{root}/base/{group}", SIDE_COLOR[side], m, group, R, nearer=side == "new")
        zero = np.zeros((1, len(profile.joints)))
        self._extent_m = _box(_corners(frame_bounds_m(profile, profile.nominal(), zero)) @ R.T)
        self._body_pad_m = BODY_PAD * float(span.max()) + marks.ring_m

    def _switch(self, profile: Profile) -> bool:
        """Before showing `profile`: if it is another robot than the one shown, remove everything shown
        for that one: every URDF copy with all its nodes, and the live view (hidden until show_live builds
        it for the new robot); the points and labels are made anew by _setup. True if switched."""
        if self.robot == profile.name and self._profile is not None:
            return False
        for slot in list(self._copies):
            self._drop_copy(slot)
        if "/live" in self._nodes:
            self._nodes["/live"].visible = False
            for name in [n for n in self._counts if n.startswith("/live/")]:
                self._update_points(name, np.zeros((0, 3)))
        self._live_robot = None
        self._frame_marks.clear()
        self.review = None
        self.index = None
        self.live = False
        return True

    def _reframe(self) -> None:
        """Every browser's camera on the copies shown, each its nominal extent where the layout puts it, and
        their labels, at the default field of view."""
        roots = (
            ["/live"]
            if self.live
            else ["/review/old"] + (["/review/new"] if self._nodes["/review/new"].visible else [])
        )
        boxes = [self._extent_m + np.asarray(self._nodes[r].position, float) for r in roots]
        labels = [np.asarray(self._nodes[f"{r}/label"].position, float) + self._nodes[r].position for r in roots]
        box = _box(np.concatenate([*boxes, np.array(labels)]))
        self.camera.frame(framing(box, fov_rad=DEFAULT_FOV_RAD))

    def _ensure_side(self, profile: Profile, side: str, text: str) -> None:
        self._ensure_copy(side, f"/review/{side}/base/robot", profile, text, None)
        if side == "old":
            ghost = self._copies.get("ghost")
            if self.overlay:
                self._ensure_ghost()
            elif ghost is not None and ghost.text != text:
                self._drop_copy("ghost")  # built again when the overlay is next asked for

    def _ensure_ghost(self) -> _Copy:
        """The old copy's translucent twin, at the old copy's joints."""
        old = self._copies["old"]
        ghost = self._ensure_copy("ghost", "/review/old/base/ghost", old.profile, old.text, GHOST_RGBA)
        ghost.robot.update_cfg(old.robot.cfg)
        return ghost

    def _ensure_copy(
        self, slot: str, root: str, profile: Profile, text: str, rgba: tuple[float, float, float, float] | None
    ) -> _Copy:
        """The URDF copy in `slot`, rebuilt only when its document changed."""
        current = self._copies.get(slot)
        if current is not None and current.text == text:
            return current
        look = robot_look(profile) if GENERATED in text else None  # a URDF robot's own visuals
        shown = text if look is None else without_bodies(text, look.links)
        import yourdfpy

        urdf = yourdfpy.URDF.load(io.StringIO(shown), build_scene_graph=False, load_meshes=False)
        bodies, _ = link_visuals(urdf, Path.cwd())  # a generated frame tree's bodies: simple shapes, no files
        if not bodies and not (look and look.visuals):
            raise ValueError(f"the URDF of the '{slot}' copy has no visual geometry to show")
        self._frame(root)
        if current is not None:
            self._drop_copy(slot)
        self._builds += 1
        node = self.target.scene.add_frame(f"{root}/u{self._builds}", show_axes=False)
        robot = RobotCopy(self.target, urdf, node.name)
        robot.add_visuals(bodies, "body", rgba)
        looks = {} if look is None else robot.add_visuals(look.visuals, "look", rgba)
        order = [profile.joint(name) for name in robot.joint_names]
        to_m = length_factor(profile.length_unit, "m")
        unit = np.array([to_m if profile.joints[j].prismatic else 1.0 for j in order])
        self._copies[slot] = _Copy(text, profile, urdf, robot, root, node, order, unit, looks)
        return self._copies[slot]

    def _drop_copy(self, slot: str) -> None:
        """Remove a copy's URDF from viser: its build node and every node under it."""
        self._copies.pop(slot).node.remove()

    def _set_joints(self, copy: _Copy, q_rad: np.ndarray) -> None:
        """Drive a copy with readings in the profile's joint order (rad, a prismatic joint's in its length unit)."""
        copy.robot.update_cfg(np.asarray(q_rad, float)[copy.joint_order] * copy.joint_unit)

    def _show_all_frames(self, review: Review) -> None:
        """Every frame's marks (hidden until show_all), the residuals magnified."""
        for side in review.sides:
            measured, predicted = review.all_points(side)
            shown = _magnified(predicted, measured, self.magnify)
            base = f"/review/{side}/base/all"
            self._update_points(f"{base}/measured", shown)
            self._update_points(f"{base}/predicted", predicted)
            self._update_lines(f"{base}/lines", predicted, shown)

    def _show_frame(self, base: str, geometry: FrameGeometry, side: str, k: float) -> None:
        """A frame's marks on one side, each measurement drawn at prediction + k (measurement - prediction)."""
        predicted = geometry.predicted_m[side]
        got = np.isfinite(geometry.measured_m[side]).all(axis=1)
        measured = np.full_like(predicted, np.nan)
        measured[got] = _magnified(predicted[got], geometry.measured_m[side][got], k)
        marks = np.concatenate([predicted, measured[got]])
        self._frame_marks[base] = marks[np.isfinite(marks).all(axis=1)]
        self._update_points(f"{base}/predicted", predicted)
        self._update_points(f"{base}/measured", measured[got])
        self._update_lines(f"{base}/lines", predicted[got], measured[got])

    def _refresh(self) -> None:
        """Positions and visibility from the flags: roots side by side along the world y (old on
        the left, new on the right, seen from the front) or overlaid with the old copy's ghost;
        the selected frame's points or every frame's; the review copies or the live one."""
        if "/review/old" not in self._nodes:
            return
        has_new = self.review is None or "new" in self.review.sides
        half = 0.0 if self.overlay or not has_new else self._separation_m / 2
        y0 = -float(self._centre_m[1])
        self._nodes["/review/old"].position = (0.0, y0 - half, 0.0)
        self._nodes["/review/new"].position = (0.0, y0 + half, 0.0)
        self._nodes["/review/old"].visible = not self.live
        self._nodes["/review/new"].visible = has_new and not self.live
        if "/live" in self._nodes:
            self._nodes["/live"].position = (0.0, y0 - half, 0.0)
            self._nodes["/live"].visible = self.live
        if "/review/old/base/ghost" in self._nodes:
            self._nodes["/review/old/base/robot"].visible = not self.overlay
            self._nodes["/review/old/base/ghost"].visible = self.overlay
        framed = self.review is not None and self.index is not None
        for side in SIDES:
            text = (OVERLAY_LABELS if self.overlay else LABELS)[side] + self._magnify_text()
            label = self._nodes[f"/review/{side}/label"]
            label.text = text  # type: ignore[attr-defined]
            label.position = self._label_position(side, framed and not self.all)
            label.visible = not (self.overlay and has_new and side == "old")
        for side in SIDES:
            for part in PARTS:
                for group, on in (("frame", framed and not self.all), ("all", self.review is not None and self.all)):
                    name = f"/review/{side}/base/{group}/{part}"
                    self._nodes[name].visible = on and self._counts[name] > 0
        if "/live/base/frame/measured" in self._nodes:
            for part in PARTS:
                name = f"/live/base/frame/{part}"
                self._nodes[name].visible = self._counts[name] > 0

    def _bodies_box(self, side: str) -> np.ndarray:
        """(2, 3) world box of a copy's bodies at the selected frame: its frame origins, padded."""
        assert self.review is not None and self.index is not None
        joints = self.review.frame_geometry(self.index).joints_rad
        bounds = frame_bounds_m(self.review.profile, self.review.sides[side].p, joints[None])
        box = _box(_corners(bounds) @ self._R.T + np.asarray(self._nodes[f"/review/{side}"].position, float))
        return box + np.array([[-1.0], [1.0]]) * self._body_pad_m

    def _magnify_text(self) -> str:
        """What a label adds when the residuals are drawn longer than they are."""
        return "" if self.magnify == 1 else f" · residuals x{self.magnify:g}"

    def _label_position(self, side: str, at_marks: bool) -> tuple[float, float, float]:
        """Where a copy's label goes (relative to its root): just above the selected frame's marks, where the
        camera looks ("frame it"), or above the robot; in the overlay the old one higher (both would coincide)."""
        marks = self._frame_marks.get(f"/review/{side}/base/frame", np.zeros((0, 3)))
        if at_marks and len(marks):
            world = self._marks_world(side, marks, relative=True)
            lift = 1.2 * self._marks.ring_m if self.overlay and side == "old" else 0.0
            top = float(world[:, 2].max()) + 0.8 * self._marks.ring_m + lift
            x, y = (world[:, :2].min(axis=0) + world[:, :2].max(axis=0)) / 2
            return float(x), float(y), top
        lift = LABEL_LIFT_M if self.overlay and side == "old" else 0.0
        return float(self._centre_m[0]), 0.0, self._label_z_m + lift

    def _marks_world(self, side: str, points_m: np.ndarray, *, relative: bool = False) -> np.ndarray:
        """A side's frame marks (base frame, m) in the world, or relative to the side's root."""
        base = f"/review/{side}/base/frame"
        local = points_m + np.asarray(self._nodes[base].position, float)
        root = np.zeros(3) if relative else np.asarray(self._nodes[f"/review/{side}"].position, float)
        return local @ self._R.T + root

    # --- nodes ----------------------------------------------------------------------------------
    def _frame(self, name: str, *, wxyz: tuple[float, ...] = (1.0, 0.0, 0.0, 0.0), visible: bool = True) -> None:
        if name in self._nodes:
            self._nodes[name].wxyz = wxyz  # type: ignore[assignment]
            return
        self._nodes[name] = self.target.scene.add_frame(name, show_axes=False, wxyz=wxyz, visible=visible)

    def _label(self, name: str, text: str, position: tuple[float, float, float]) -> None:
        if name not in self._nodes:
            self._nodes[name] = self.target.scene.add_label(name, text, anchor="bottom-center")
        self._nodes[name].text = text  # type: ignore[attr-defined]
        self._nodes[name].position = position

    def _add_parts(
        self,
        base: str,
        color: tuple[int, int, int],
        marks: _Marks,
        group: str,
        R_world_base: np.ndarray,
        *,
        nearer: bool = False,
    ) -> None:
        """A group's red measurement rings, coloured prediction dots (float32: float16 would hide millimetre
        residuals) and residual lines, empty and hidden (viser gets one placeholder each). The group's node
        is lifted toward the camera (`marks.lift_m`, and a little more for the `nearer` side); its rings face
        the camera's direction (R_world_base: the base's turn in the world)."""
        lift = marks.lift_m + (NEW_NEARER * marks.dot_m if nearer else 0.0)
        toward = R_world_base.T @ FRONT  # the view direction in the base frame
        self._frame(base)
        self._nodes[base].position = tuple(float(v) for v in lift * toward)
        self._rings[base] = _ring(toward, R_world_base.T[:, 2], marks.ring_m / 2, RING_SEGMENTS[group])
        self._add_segments(f"{base}/measured", RED, RING_LINE * marks.ring_m)
        self._nodes[f"{base}/predicted"] = self.target.scene.add_point_cloud(
            f"{base}/predicted",
            np.zeros((1, 3), np.float32),
            np.array(color, np.uint8),
            point_size=marks.dot_m,
            point_shape="circle",
            precision="float32",
            point_shading="flat",
            visible=False,
        )
        self._add_segments(f"{base}/lines", color, RESIDUAL_LINE * marks.dot_m)
        for part in PARTS:
            self._counts[f"{base}/{part}"] = 0
        self._centres[f"{base}/measured"] = np.zeros((0, 3))

    def _add_segments(self, name: str, color: tuple[int, int, int], thickness_m: float) -> None:
        """An empty, hidden line-segments node (one placeholder segment)."""
        self._nodes[name] = self.target.scene.add_line_segments(
            name, np.zeros((1, 2, 3), np.float32), np.array(color, np.uint8), thickness=thickness_m, visible=False
        )

    def _update_points(self, name: str, points: np.ndarray) -> None:
        """New points for a cloud (or centres for a group's rings); an empty one keeps its old points (viser
        needs one) and is hidden."""
        group = name.rsplit("/", 1)[0]
        if name.endswith("/measured") and group in self._rings:
            centres = np.asarray(points, float).reshape(-1, 3)
            self._centres[name] = centres
            if len(centres):
                rings = centres[:, None, None, :] + self._rings[group][None]
                self._nodes[name].points = rings.reshape(-1, 2, 3).astype(np.float32)  # type: ignore[attr-defined]
        elif len(points):
            self._nodes[name].points = np.asarray(points, np.float32)  # type: ignore[attr-defined]
        self._counts[name] = len(points)

    def _update_lines(self, name: str, start: np.ndarray, end: np.ndarray) -> None:
        if len(start):
            self._nodes[name].points = np.stack([start, end], axis=1).astype(np.float32)  # type: ignore[attr-defined]
        self._counts[name] = len(start)

    def _shown(self, name: str) -> bool:
        parts = name.split("/")
        return all(
            self._nodes[p].visible for k in range(2, len(parts) + 1) if (p := "/".join(parts[:k])) in self._nodes
        )

    def _node_state(self, name: str, h: viser.SceneNodeHandle) -> dict[str, Any]:
        out: dict[str, Any] = {
            "visible": bool(h.visible),
            "shown": self._shown(name),
            "position": [float(v) for v in h.position],
            "wxyz": [float(v) for v in h.wxyz],
        }
        if name in self._centres:  # a group's measurement rings: their centres
            held = self._centres[name][: self._counts[name]].tolist()
            out |= {"kind": "rings", "color": [int(v) for v in np.asarray(h.colors).reshape(-1, 3)[0]], "points": held}
        elif isinstance(h, viser.PointCloudHandle | viser.LineSegmentsHandle):
            kind, key = ("points", "points") if isinstance(h, viser.PointCloudHandle) else ("lines", "segments")
            held = h.points[: self._counts[name]].astype(float).tolist()
            out |= {"kind": kind, "color": [int(v) for v in np.asarray(h.colors).reshape(-1, 3)[0]], key: held}
        elif isinstance(h, viser.LabelHandle):
            out |= {"kind": "label", "text": h.text}
        else:
            out |= {"kind": "frame"}
        return out


def _magnified(predicted_m: np.ndarray, measured_m: np.ndarray, k: float) -> np.ndarray:
    """Where a measurement is drawn: prediction + k (measurement - prediction) (the measurement without a
    prediction)."""
    return np.where(np.isfinite(predicted_m), predicted_m + k * (measured_m - predicted_m), measured_m)


def _box(points: np.ndarray) -> np.ndarray:
    """(2, 3) min and max of points (N, 3)."""
    return np.stack([points.min(axis=0), points.max(axis=0)])


def _corners(bounds_m: np.ndarray) -> np.ndarray:
    """(8, 3) corners of a (2, 3) min/max box."""
    return np.array([[bounds_m[i, 0], bounds_m[j, 1], bounds_m[k, 2]] for i in (0, 1) for j in (0, 1) for k in (0, 1)])


def _marks(profile: Profile) -> _Marks:
    """Marks sized to the target: a ring just outside a sphere fixture (the URDF draws the sphere at the
    prediction: it shows inside the ring, the dot lifted onto its front), or about half a board's grid step
    (neighbouring corners' rings do not touch), lifted off the board."""
    to_m = length_factor(profile.length_unit, "m")
    target = profile.targets[profile.data.target if profile.data.target is not None else 0]
    if target.radius is not None:
        r = target.radius * to_m
        return _Marks(2.8 * r, 0.5 * r, 1.05 * r)
    ring = DEFAULT_RING_M
    if target.grid is not None and len(target.grid) > 1:
        ring = 0.45 * float(np.linalg.norm(target.grid[1] - target.grid[0])) * to_m
    return _Marks(ring, DOT_PER_RING * ring, 0.6 * ring)  # lifted off a board, which would cut the rings


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
