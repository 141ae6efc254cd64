"""Viewers: each browser tab has its own review (session, old and new calibration, selected frame, overlay,
all frames) and its own 3-D scene, so two tabs never move each other.

A viewer is named by an id its page makes (sent as the `X-Viewer` header; a request without one addresses
the default viewer, which scripts and single-viewer clients share). Its scene is a `ReviewScene` over the
viser client of its page's iframe (`/scene/<viewer>/`, app/web/scene_proxy.py), so everything it shows is
client-scoped in viser: another browser never receives it. The viewer keeps what it shows apart from the
scene, so a review can be loaded before its iframe connects and is drawn again on a new client (the iframe
reloaded after a server restart, or viser's client reconnecting).

A viewer other than the default one lives while its iframe is connected: without a connection it is dropped
`linger_s` later (a closed tab; a viewer some request named but no iframe ever connected to), with its review.

Observe's live view is shared: the viewers watching (those that asked for it) get every look of the robot
observed; the others keep their review.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import TypedDict

import numpy as np
import viser

from calib_core import InputError, Profile

from .review import Review
from .review_scene.scene import LookLike, ReviewScene

DEFAULT = "default"
VIEWER_PATTERN = r"^[A-Za-z0-9_-]{1,64}$"
LINGER_S = 5.0  # a viewer without a connected scene is kept this long (viser's client reconnects within it)
MAX_VIEWERS = 64


class TooManyViewers(Exception):
    """More viewers than the desk keeps: close a tab, or wait for closed ones to go."""


class ReviewKey(TypedDict):
    """What a viewer's review is of: the session, the old and the new calibration's ids (None: the nominal model),
    the robot, the sensor reviewed, the sensors the session has observations of and those that take an image."""

    session: str
    old: str | None
    new: str | None
    robot: str
    sensor: str
    sensors: list[str]
    images: list[str]


class ViewerState(TypedDict):
    """A viewer and what it shows (the API's ViewerOut): its review's key fields None while it has none."""

    id: str
    connected: bool
    robot: str | None
    session: str | None
    old: str | None
    new: str | None
    sensor: str | None
    index: int | None
    overlay: bool
    all: bool
    magnify: float
    live: bool


@dataclass(frozen=True)
class Shown:
    """A robot shown without a review (at zero joint angles): its profile and URDF (None: the profile's own)."""

    profile: Profile
    urdf_text: str | None = None


class Viewer:
    """One tab's review and scene. Every method holds the viewer's lock: a request, viser's callback that
    attaches a scene and Observe's live loop may come at once."""

    def __init__(self, viewer_id: str, shown: Shown | None) -> None:
        self.id = viewer_id
        self.lock = threading.RLock()
        self.shown = shown  # the robot shown when no review is loaded
        self.review: Review | None = None
        self.key: ReviewKey | None = None  # what the review is of (None: no review)
        self.index: int | None = None
        self.overlay = False
        self.all = False
        self.magnify = 1.0  # the scene's residuals drawn this many times their length
        self.live = False  # the scene shows Observe's live view
        self.scenes: dict[int, ReviewScene] = {}  # a scene per viser client attached, oldest first
        self.connections: set[int] = set()  # viser clients of this viewer's proxied websockets
        self.idle_since = time.monotonic()  # since when it has no connection

    @property
    def client_id(self) -> int | None:
        """The newest attached viser client still connected (None: none is)."""
        live = [c for c in list(self.scenes) if c in self.connections]
        return live[-1] if live else None

    @property
    def scene(self) -> ReviewScene | None:
        """The scene on that client."""
        client = self.client_id
        return None if client is None else self.scenes.get(client)

    @property
    def robot(self) -> str | None:
        if self.review is not None:
            return self.review.profile.name
        return None if self.shown is None else self.shown.profile.name

    # --- what the viewer shows ----------------------------------------------------------------------
    def show_robot(self, shown: Shown) -> None:
        """Show a robot at zero joint angles unless this one is shown already; a review of another robot is
        closed."""
        with self.lock:
            if self.robot == shown.profile.name:
                return
            self.shown = shown
            self._close_review()
            for scene in self._drawn():
                scene.show_robot(shown.profile, shown.urdf_text)

    def load(self, review: Review, key: ReviewKey) -> None:
        """Show a review, its first frame selected."""
        with self.lock:
            self.review, self.key = review, key
            self.index = int(review.indices[0]) if len(review.indices) else None
            self.live = False
            for scene in self._drawn():
                scene.load(review)

    def select(self, index: int, *, show_all: bool, overlay: bool) -> None:
        """Select frame `index` (its number) with the overlay and all-frames flags."""
        with self.lock:
            review = self.current()
            review.row(index)  # NotFound naming the frames, scene or not
            self.index, self.all, self.overlay, self.live = int(index), bool(show_all), bool(overlay), False
            for scene in self._drawn():
                scene.set_overlay(overlay)
                scene.show_all(show_all)
                scene.select(index)

    def set_magnify(self, k: float) -> None:
        """The scene's residuals drawn k times their length (the review's and every later one's)."""
        with self.lock:
            self.magnify = float(k)
            for scene in self._drawn():
                scene.set_magnify(k)

    def frame_marks(self) -> None:
        """The page's "frame it": the scene's camera onto the selected frame's marks (app/scene/review_scene/camera.py;
        without a review, onto the robot)."""
        with self.lock:
            for scene in self._drawn():
                scene.frame_marks()

    def current(self) -> Review:
        if self.review is None:
            raise InputError("no session is loaded for review (POST /api/review first)")
        return self.review

    def show_live(self, profile: Profile, look: LookLike, p: np.ndarray) -> None:
        """Observe's look, in place of the review until the next select (another robot's replaces it)."""
        with self.lock:
            if self.robot != profile.name:
                self.shown = Shown(profile)
                self._close_review()
            self.live = True
            for scene in self._drawn():
                scene.show_live(profile, look, p)

    def hide_live(self) -> None:
        with self.lock:
            self.live = False
            for scene in self._drawn():
                scene.hide_live()

    def state(self) -> ViewerState:
        with self.lock:
            key = self.key
            return ViewerState(
                id=self.id,
                connected=bool(self.connections),
                robot=self.robot,
                session=None if key is None else key["session"],
                old=None if key is None else key["old"],
                new=None if key is None else key["new"],
                sensor=None if key is None else key["sensor"],
                index=self.index,
                overlay=self.overlay,
                all=self.all,
                magnify=self.magnify,
                live=self.live,
            )

    # --- its browser ----------------------------------------------------------------------------------
    def attach(self, client: viser.ClientHandle) -> None:
        """Draw on this viser client too (a new iframe of this viewer): everything shown, again."""
        with self.lock:
            if client.client_id not in self.connections:
                return  # its websocket closed before viser reported it
            self.scenes = {c: scene for c, scene in self.scenes.items() if c in self.connections}
            scene = ReviewScene(client)
            scene.set_magnify(self.magnify)
            if self.review is not None:
                scene.set_overlay(self.overlay)
                scene.show_all(self.all)
                scene.load(self.review)
                if self.index is not None and self.index != scene.index:
                    scene.select(self.index)
            elif self.shown is not None:
                scene.show_robot(self.shown.profile, self.shown.urdf_text)
            self.scenes[client.client_id] = scene

    def _drawn(self) -> list[ReviewScene]:
        """The scenes of the connected clients (a closed one's wait for the next client). Usually one; after a
        server restart the old iframe's viser client may reconnect beside the new iframe's, in either order, and
        which one the page shows is the browser's business: every one is drawn on."""
        return [scene for c, scene in list(self.scenes.items()) if c in self.connections]

    def _close_review(self) -> None:
        self.review, self.key, self.index, self.live = None, None, None, False


class Viewers:
    """The viewers of the desk by id, the viser client each proxied websocket became, and who watches live."""

    def __init__(
        self, shown: Callable[[], Shown | None], *, linger_s: float = LINGER_S, limit: int = MAX_VIEWERS
    ) -> None:
        """`shown`: what a new viewer shows (the connected robot, or the first one)."""
        self._shown = shown
        self.linger_s = linger_s
        self.limit = limit
        self._lock = threading.Lock()
        self._viewers: dict[str, Viewer] = {}
        self._owner: dict[int, Viewer] = {}  # viser client id -> the viewer its websocket named
        self._watching: set[str] = set()
        self._stop = threading.Event()
        self._sweeper = threading.Thread(target=self._sweep_loop, name="viewers", daemon=True)

    def start(self) -> None:
        self.get(DEFAULT)
        self._sweeper.start()

    def stop(self) -> None:
        self._stop.set()
        if self._sweeper.is_alive():
            self._sweeper.join(timeout=5)

    @property
    def default(self) -> Viewer:
        return self._viewers[DEFAULT]

    def get(self, viewer_id: str | None) -> Viewer:
        """The viewer of this id (None: the default one), made when new (TooManyViewers beyond the limit)."""
        viewer_id = viewer_id or DEFAULT
        viewer = self._known(viewer_id)
        if viewer is not None:
            return viewer
        shown = self._shown()  # read outside the lock: it may read a URDF file
        with self._lock:
            viewer = self._viewers.get(viewer_id)
            if viewer is None:
                if len(self._viewers) >= self.limit:
                    raise TooManyViewers(
                        f"the desk already has {len(self._viewers)} views open: close a tab, or wait for closed "
                        "ones to go"
                    )
                viewer = self._viewers[viewer_id] = Viewer(viewer_id, shown)
            return viewer

    def _known(self, viewer_id: str) -> Viewer | None:
        """A viewer already there; a request naming it keeps it linger_s from now when it has no connection."""
        with self._lock:
            viewer = self._viewers.get(viewer_id)
            if viewer is not None and not viewer.connections:
                viewer.idle_since = time.monotonic()
            return viewer

    def all(self) -> list[Viewer]:
        with self._lock:
            return list(self._viewers.values())

    # --- the scene proxy and viser ------------------------------------------------------------------
    def connected(self, viewer_id: str, client_id: int) -> None:
        """A proxied websocket of this viewer became viser client `client_id`: the viewer draws on it once viser
        reports the client (`client_ready`)."""
        viewer = self.get(viewer_id)
        with self._lock:
            self._owner[client_id] = viewer
            viewer.connections.add(client_id)

    def client_ready(self, client: viser.ClientHandle) -> None:
        """viser's connect callback (after the browser's first camera message): its viewer draws on it."""
        with self._lock:
            viewer = self._owner.get(client.client_id)
        if viewer is not None:
            viewer.attach(client)

    def disconnected(self, client_id: int) -> None:
        """A proxied websocket closed: its viewer no longer draws on that client (and lingers without any).
        Quick, never waiting for a viewer's lock: the proxy calls it as the websocket ends."""
        with self._lock:
            viewer = self._owner.pop(client_id, None)
            if viewer is None:
                return
            viewer.connections.discard(client_id)
            if not viewer.connections:
                viewer.idle_since = time.monotonic()

    def sweep(self) -> list[str]:
        """Drop the viewers (but the default) without a connection for linger_s; their ids."""
        now = time.monotonic()
        with self._lock:
            gone = [
                v.id
                for v in self._viewers.values()
                if v.id != DEFAULT and not v.connections and now - v.idle_since >= self.linger_s
            ]
            for viewer_id in gone:
                del self._viewers[viewer_id]
                self._watching.discard(viewer_id)
        return gone

    def _sweep_loop(self) -> None:
        while not self._stop.wait(min(max(self.linger_s / 4, 0.25), 5.0)):
            self.sweep()

    # --- robots shown -------------------------------------------------------------------------------
    def replace_robot(self, robot: str, shown: Shown | None) -> None:
        """Every viewer showing `robot` (taken off the desk) shows `shown` instead."""
        for viewer in self.all():
            if viewer.robot == robot and shown is not None:
                viewer.show_robot(shown)

    # --- Observe's live view, shared by the viewers watching ----------------------------------------
    def watch(self, viewer: Viewer, on: bool) -> None:
        with self._lock:
            (self._watching.add if on else self._watching.discard)(viewer.id)
        if not on:
            viewer.hide_live()

    def watched(self) -> bool:
        with self._lock:
            return bool(self._watching)

    def unwatch_all(self) -> None:
        """The live view ends: every viewer that watched goes back to its review."""
        with self._lock:
            watching = [self._viewers[v] for v in self._watching if v in self._viewers]
            self._watching.clear()
        for viewer in watching:
            viewer.hide_live()

    def show_live(self, profile: Profile, look: LookLike, p: np.ndarray) -> None:
        """A look of the observed robot, for every viewer watching."""
        with self._lock:
            watching = [self._viewers[v] for v in self._watching if v in self._viewers]
        for viewer in watching:
            viewer.show_live(profile, look, p)
