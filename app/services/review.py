"""Review: a session's frames as an old and a new calibration see them, in a viewer's scene and as figures.

Each viewer (a browser tab, app/scene/viewers.py) has its own review: the one it loaded last is the one its frame
slider and 2-D marks address; loading a session of another robot replaces what that viewer's scene showed.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from typing import TypedDict

import numpy as np

from calib_core import Dataset, InputError, Profile
from calib_core.estimation import Covariance, register, registration_params

from ..robots.roster import Robots
from ..scene.review import Marks, Review, ReviewRow, ReviewSummary
from ..scene.robot_look import robot_look
from ..scene.viewers import ReviewKey, Viewer
from ..store import Store
from .connection import Connection


class Reviewed(ReviewKey):
    """A review as the API answers it (its ReviewOut): what it is of, its table and summary (app/scene/review.py)
    and what the scene could not show as asked."""

    table: list[ReviewRow]
    summary: ReviewSummary
    warnings: list[str]


class Selection(TypedDict):
    """A frame selected in a viewer's scene (the API's Selected): all frames or one, the overlay, the server's
    time for it."""

    index: int
    all: bool
    overlay: bool
    server_ms: float


class MarksShown(Marks):
    """A frame's 2-D marks as the API answers them (its Marks): with the URL of the image they belong to (None: no
    image)."""

    image: str | None


class ReviewService:
    def __init__(self, store: Store, robots: Robots, connection: Connection, scrub: Callable[[str], str]) -> None:
        """`connection`: the robot in view (a viewer watching another robot live stops to review); `scrub`: what
        the answer's warnings are shown through (no path of the server)."""
        self.store = store
        self.robots = robots
        self.connection = connection
        self.scrub = scrub

    def load(
        self, viewer: Viewer, session_id: str, old: str | None, new: str | None, sensor: str | None = None
    ) -> Reviewed:
        """Load a review (as one sensor sees it; None: the data format's) into a viewer: `build`, then `show`. A
        viewer watching another robot live stops watching (the live view ends when nobody watches it any more)."""
        review, key = self.build(session_id, old, new, sensor)
        self.connection.reviewing(viewer, key["robot"])
        answer = self.show(viewer, review, key)
        answer["warnings"] = [self.scrub(w) for w in answer["warnings"]]  # a mesh's absolute path
        return answer

    def build(
        self, session_id: str, old: str | None, new: str | None, sensor: str | None = None
    ) -> tuple[Review, ReviewKey]:
        """A session's review with an old and a new calibration ("active": the robot's active one; None: the
        nominal model) as one sensor sees it (its name; None: the data format's), and its key (session, old,
        new, sensor, the sensors the session has observations of and those of them that take an image: the 2-D
        view's); `show` puts it in the scene."""
        session = self.store.sessions.get(session_id)
        profile = self.robots.get(session.robot).profile
        sensor_index = self._sensor(profile, session.robot, sensor)
        old_id, old_p, old_cov = self._params(session.robot, profile, old)
        new_id, new_p, new_cov = (None, None, None) if new is None else self._params(session.robot, profile, new)
        heldout: set[int] = set()
        if new_id is not None:
            heldout = set(self.store.calibrations.load(new_id).frames.get("holdout", []))
        frames = self.store.sessions.frames(session_id)
        data = self.store.sessions.dataset(session_id, profile) if session.measured else None
        if data is not None and registration_params(profile):
            old_p = self._registered(profile, data, old_p, old_id, session_id, heldout)
            new_p = None if new_p is None else self._registered(profile, data, new_p, new_id, session_id, heldout)
        review = Review.build(
            profile,
            frames,
            data,
            old_p,
            new_p,
            heldout_frames=heldout,
            sensor=sensor_index,
            covariances={"old": old_cov, "new": new_cov},
        )
        observed = sorted(data.sensors) if data is not None else [profile.data.sensor]
        return review, ReviewKey(
            session=session_id,
            old=old_id,
            new=new_id,
            robot=session.robot,
            sensor=profile.sensors[sensor_index].name,
            sensors=[profile.sensors[i].name for i in observed],
            images=[profile.sensors[i].name for i in observed if profile.sensors[i].image_size_px() is not None],
        )

    def show(self, viewer: Viewer, review: Review, key: ReviewKey) -> Reviewed:
        """Show a review in a viewer's scene (another robot's replaces everything it showed): its table, summary
        and what the scene could not show as asked (a URDF mesh that cannot be read)."""
        viewer.load(review, key)
        look = robot_look(review.profile)  # read by the scene's load: the URDF visuals it could not draw
        warnings = [] if look is None or look.warning is None else [look.warning]
        return Reviewed(**key, table=review.table(), summary=review.summary(), warnings=warnings)

    def select(self, viewer: Viewer, index: int, *, show_all: bool = False, overlay: bool = False) -> Selection:
        t0 = time.perf_counter()
        viewer.select(index, show_all=show_all, overlay=overlay)
        return Selection(index=index, all=show_all, overlay=overlay, server_ms=(time.perf_counter() - t0) * 1e3)

    @staticmethod
    def magnify(viewer: Viewer, factor: float) -> float:
        """The viewer's 3-D residuals drawn `factor` times their length: the factor."""
        viewer.set_magnify(factor)
        return factor

    @staticmethod
    def frame_marks(viewer: Viewer) -> int | None:
        """The viewer's camera onto the selected frame's marks: that frame (None: none selected)."""
        viewer.frame_marks()
        return viewer.index

    def marks(self, viewer: Viewer, index: int) -> MarksShown:
        with viewer.lock:
            review, key = viewer.current(), viewer.key
        assert key is not None  # loaded with its review
        session = key["session"]
        marks = review.marks(index)
        frame = self.store.sessions.frame(session, index)
        path = frame.images.get(marks["role"]) if marks["role"] else None
        return MarksShown(**marks, image=None if path is None else f"/api/files/{path}")

    @staticmethod
    def _sensor(profile: Profile, robot: str, name: str | None) -> int:
        if name is None:
            return profile.data.sensor
        names = [s.name for s in profile.sensors]
        if name not in names:
            raise InputError(f"sensor: '{name}' is not a sensor of robot {robot} (its sensors: {', '.join(names)})")
        return names.index(name)

    def _params(
        self, robot: str, profile: Profile, ref: str | None
    ) -> tuple[str | None, np.ndarray, Covariance | None]:
        """(id, parameters, covariance) of a calibration, "active" or None (the nominal model: no covariance)."""
        if ref == "active":
            ref = self.store.calibrations.active(robot)
        if ref is None:
            return None, profile.nominal(), None
        info = self.store.calibrations.info(ref)
        if info.robot != robot:
            raise InputError(f"calibration '{ref}' is for robot {info.robot}, not {robot}")
        cal = self.store.calibrations.load(ref)
        return ref, cal.params(profile), cal.covariance

    def _registered(
        self, profile: Profile, data: Dataset, p: np.ndarray, cal_id: str | None, session_id: str, heldout: set[int]
    ) -> np.ndarray:
        """An external tracker's pose belongs to its set-up, that is to a session: parameters from elsewhere
        (the nominal model, another session's calibration) see this session's tracker through a registration
        fitted on its frames (those the new calibration was fitted on, when it held some out)."""
        if cal_id is not None and self.store.calibrations.info(cal_id).session_id == session_id:
            return p
        train = ~np.isin(data.frame_ids, sorted(heldout))
        return register(profile, data.select(train) if train.any() else data, p)
