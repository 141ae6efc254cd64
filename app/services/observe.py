"""Observe (the paper's GenVisCalData): watch the robot while someone else drives it.

At a few Hz, look through the cameras when the robot stands still and show the detection beside the
prediction of the active calibration; while it moves (a replay, the sliders, someone else), show the robot at
its readings ten times a second, without a look; with autocapture, keep the good settled frames (app/robots/capture.py's
AutoCapture). One robot is observed at a time; its live view goes to the viewers watching (app/scene/viewers.py).
"""

from __future__ import annotations

import threading
from collections.abc import Callable
from contextlib import suppress
from dataclasses import replace
from typing import NotRequired, Protocol, TypedDict

import numpy as np

from calib_core import FrameStatus, InputError, Profile
from calib_core.estimation import register, registration_params

from ..drivers import Look, RobotDriver
from ..errors import NotFound
from ..robots.capture import AutoCapture, look_outcome
from ..robots.roster import Robots
from ..scene.live_look import LookView, look_view
from ..scene.review_scene.scene import LookLike
from ..store import Store

OBSERVE_PERIOD_S = 0.5
MOVING_PERIOD_S = 0.1  # the live robot follows a moving robot at this period (a pose costs a few ms, a look more)
MIN_REGISTRATION_FRAMES = 3  # measured frames an external tracker's pose is fitted on (3 points not on one line)


class Observed(TypedDict):
    """What Observe sees now (the API's ObserveState): a key without a value yet is left out."""

    session: str
    autocapture: bool
    captured: int  # frames autocapture kept
    last_frame: NotRequired[int]  # the latest of them
    detection: NotRequired[str]  # the latest look's status, or "moving"
    reason: NotRequired[str]  # why it found nothing ("ok": it measured)
    message: NotRequired[str]  # the latest look's failure
    look: NotRequired[int]  # the latest look with an image


class LiveView(Protocol):
    """Where the looks go (app.scene.viewers.Viewers: every viewer watching)."""

    def show_live(self, profile: Profile, look: LookLike, p: np.ndarray) -> None: ...


class Observer:
    """The live loop of one observed session."""

    def __init__(
        self,
        store: Store,
        robots: Robots,
        live: LiveView,
        session_id: str,
        autocapture: bool,
        scrub: Callable[[str], str],
    ) -> None:
        self.store = store
        self.robots = robots
        self.live = live
        self.session_id = session_id
        self.robot = store.sessions.get(session_id).robot
        self.driver: RobotDriver = robots.driver(self.robot)
        self.auto = AutoCapture(store, self.driver, session_id) if autocapture else None
        self._scrub = scrub
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="observe", daemon=True)
        self._last = Observed(session=session_id, autocapture=autocapture, captured=0)
        self._registration: tuple[tuple, np.ndarray | None] | None = None  # (frames and calibration, fitted p)
        self._period = OBSERVE_PERIOD_S
        self._seen: Look | None = None  # the latest look: its target's points stand in while the robot moves
        self._shown: tuple[int, Profile, Look, np.ndarray | None] | None = None  # the latest look with an image

    def start(self) -> None:
        self._thread.start()

    def stop(self) -> None:
        self._stop.set()
        self._thread.join(timeout=5)

    def snapshot(self) -> Observed:
        return self._last.copy()

    def look(self) -> LookView:
        """The latest settled look with an image, for Observe's 2-D view (app/scene/live_look.py)."""
        shown = self._shown
        if shown is None:
            raise NotFound(f"Observe has not looked through {self.robot}'s camera yet")
        number, profile, look, p = shown
        return look_view(profile, look, p, number)

    def _run(self) -> None:
        while not self._stop.wait(self._period):
            try:
                self._tick()
            except Exception as exc:  # a failed look must not end observing; it is shown instead
                self._last["message"] = self._scrub(f"{type(exc).__name__}: {exc}")

    def _tick(self) -> None:
        look = None
        if self.auto is not None:
            before = self.auto.last_look
            frame = self.auto.poll()
            if frame is not None:
                self._last["captured"] += 1
                self._last["last_frame"] = frame.index
            if self.auto.last_look is not before:
                look = self.auto.last_look  # one render per tick: reuse the look autocapture made
        if look is None and not self.driver.settled(0.2):
            self._last["detection"] = "moving"
            self._period = MOVING_PERIOD_S
            self._show_moving()
            return
        self._period = OBSERVE_PERIOD_S
        if look is None:
            look = self.driver.look()
        self._seen = look
        profile = self.driver.profile
        detection, reason = look_outcome(profile, look)
        p, registered = self._live_params()
        if look.images:  # the 2-D view: the pixels found need no pose; a prediction needs the sensor's
            number = self._shown[0] + 1 if self._shown is not None else 1
            self._shown = (number, profile, look, p if registered else None)
        if not registered:  # where the tracker stands is unknown: its reading has no place in the scene yet
            unplaced = [
                replace(s, measured=None) if registration_params(profile, [s.sensor]) else s for s in look.sightings
            ]
            look = Look(look.readings_rad, look.target, unplaced, look.images)
            unknown = sorted(
                {profile.sensors[s.sensor].name for s in look.sightings if registration_params(profile, [s.sensor])}
            )
            reason = (
                f"placed in 3-D once {MIN_REGISTRATION_FRAMES} frames are measured ({', '.join(unknown)}: pose unknown)"
            )
        self.live.show_live(profile, look, p)
        if self._shown is not None:
            self._last["look"] = self._shown[0]
        # Said once the scene shows it: whoever reads the detection finds the look in the scene.
        self._last["detection"], self._last["reason"] = detection, reason

    def _show_moving(self) -> None:
        """The robot at its readings now, with the prediction of the target last looked at and nothing
        measured (a look mid-motion would show a blurred pose)."""
        st = self.driver.status()
        seen = self._seen
        if seen is None or seen.target != st.target:
            seen = self._seen = self.driver.look()
        sightings = [replace(s, status=FrameStatus.NOT_FOUND, reason="moving", measured=None) for s in seen.sightings]
        p, _ = self._live_params()
        self.live.show_live(self.driver.profile, Look(st.joints_rad, st.target, sightings, {}), p)

    def _live_params(self) -> tuple[np.ndarray, bool]:
        """The active calibration, seeing an external tracker (if any) through a registration fitted on this
        session's measured frames; False when the session has too few of them to place the tracker."""
        profile = self.driver.profile
        cal_id, p = self.robots.active_params(self.robot)
        if not registration_params(profile):
            return p, True
        frames = self.store.sessions.frames(self.session_id)
        key = (cal_id, tuple(f.index for f in frames if f.status == FrameStatus.MEASURED))
        if self._registration is None or self._registration[0] != key:
            data = self.store.sessions.dataset(self.session_id, profile)
            fitted = None
            if data.n_configurations >= MIN_REGISTRATION_FRAMES:
                with suppress(InputError):  # a camera's frames may not fix its pose yet (no board pose, one axis)
                    fitted = register(profile, data, p)
            self._registration = (key, fitted)
        fitted = self._registration[1]
        return (p, False) if fitted is None else (fitted, True)
