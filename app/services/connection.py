"""The robot in view: the robot the desk is connected to (a request that names no robot means it) and Observe,
the live view of one of its sessions, shown to the viewers watching it.

Connecting another robot ends Observe. A viewer that loads a review of another robot stops watching, and the
live view ends when nobody watches it any more. A new viewer shows the connected robot, or the desk's first.
Requests come on several threads at once (two tabs): what changes the connected robot or Observe is done under
one lock, so an Observe started meanwhile is either running or not yet made, never half made.
"""

from __future__ import annotations

import threading
from collections.abc import Callable

from ..drivers import RobotDriver
from ..errors import NotFound
from ..robots.roster import Robot, Robots
from ..scene.live_look import LookView
from ..scene.viewers import Shown, Viewer, Viewers
from ..store import Store
from .observe import Observed, Observer


class Connection:
    def __init__(
        self, store: Store, robots: Robots, viewers: Viewers, scrub: Callable[[str], str], connected: str | None
    ) -> None:
        """`connected`: the robot connected at the start (None: none can be driven); `scrub`: what Observe's
        failures are shown through (no path of the server)."""
        self.store = store
        self.robots = robots
        self.viewers = viewers
        self.scrub = scrub
        self.connected = connected
        self._observer: Observer | None = None
        self._changing = threading.RLock()  # connect, Observe on and off: one at a time (observe connects)

    def stop(self) -> None:
        self.observe(None)

    # --- the robot a request means ----------------------------------------------------------------
    def robot_name(self, robot: str | None) -> str:
        """`robot`, or the connected one when None (bad input when no robot can be driven)."""
        if robot:
            return robot
        if self.connected is None:
            raise self.robots.no_driver_error(None)
        return self.connected

    def driver(self, robot: str | None) -> RobotDriver:
        """The driver of `robot` (None: the connected one); bad input for a robot that has none."""
        return self.robots.driver(self.robot_name(robot))

    def connect(self, robot: str, viewer: Viewer | None = None) -> None:
        """Connect the desk to a drivable robot; the viewer (None: the default one) shows it, closing its review
        of another robot."""
        self.robots.driver(robot)  # named exactly: robot_name would take "" for the connected one
        with self._changing:
            if robot != self.connected:
                self.observe(None)
                self.connected = robot
            (viewer or self.viewers.default).show_robot(self.shown(robot))

    def shown(self, robot: str) -> Shown:
        r = self.robots.get(robot)
        return Shown(r.profile, None if r.urdf is None else r.urdf.read_text(encoding="utf-8"))

    def shown_first(self) -> Shown | None:
        """What a new viewer shows: the connected robot, or the first one on the desk."""
        robot = self.connected or next(iter(self.robots.names()), None)
        return None if robot is None else self.shown(robot)

    # --- robots coming and going -------------------------------------------------------------------
    def added(self, robot: Robot) -> None:
        """A robot added to the running desk: the first drivable one is connected."""
        with self._changing:
            if self.connected is None and robot.drivable:
                self.connected = robot.name

    def release(self, robot: str) -> None:
        """Observe of `robot` ends (its driver is about to close)."""
        with self._changing:
            observer = self._observer
            if observer is not None and observer.robot == robot:
                self.observe(None)

    def removed(self, name: str) -> None:
        """A robot taken off the desk: the desk connects to the next drivable one, and the viewers showing it show
        what a new viewer would."""
        with self._changing:
            if self.connected == name:
                self.connected = next((r.name for r in self.robots.all() if r.drivable), None)
            self.viewers.replace_robot(name, self.shown_first())

    # --- Observe ------------------------------------------------------------------------------------
    def observe(self, session_id: str | None, *, autocapture: bool = False, viewer: Viewer | None = None) -> None:
        """Observe a session's robot, its live view shown to the viewer (None: the default one) and to those
        already watching that robot; None: stop observing (every viewer watching goes back to its review)."""
        with self._changing:
            if self._observer is not None:
                self._observer.stop()
                self._observer = None
            if session_id is None:
                self.viewers.unwatch_all()
                return
            viewer = viewer or self.viewers.default
            self.connect(self.store.sessions.get(session_id).robot, viewer)  # another robot: the watchers stop
            self.viewers.watch(viewer, True)
            observer = Observer(self.store, self.robots, self.viewers, session_id, autocapture, self.scrub)
            observer.start()
            self._observer = observer

    def observing(self, robot: str | None = None) -> Observed | None:
        """What Observe sees now (None: not observing, or observing another robot than `robot` when given)."""
        observer = self._observer
        if observer is None or (robot is not None and observer.robot != robot):
            return None
        return observer.snapshot()

    def look(self, robot: str | None = None) -> LookView:
        """Observe's latest look through the camera (app/scene/live_look.py); NotFound when not observing `robot`."""
        observer = self._observer
        if observer is None or (robot is not None and observer.robot != robot):
            raise NotFound(f"Observe is not watching {robot or 'a robot'}: turn on Watch live")
        return observer.look()

    def reviewing(self, viewer: Viewer, robot: str) -> None:
        """The viewer loads a review of `robot`: watching another robot live, it stops; the live view ends when
        nobody watches it any more."""
        with self._changing:
            observer = self._observer
            if observer is not None and observer.robot != robot:
                self.viewers.watch(viewer, False)
                if not self.viewers.watched():
                    self.observe(None)
