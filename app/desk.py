"""The calibration desk: the store, the jobs, the robots and the 3-D scene, composed.

The HTTP API (app/api.py) is a thin layer over this class; a script or a test can drive the desk
directly. One desk per process: it owns the viser server and the robot drivers.
"""

from __future__ import annotations

import site
import sys
import tempfile
import threading
import time
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np
import viser

from calib_core import Dataset, InputError, Profile, SimulatedRobot, load_profile
from calib_core.estimation.registration import register, registration_params
from calib_core.model.loader import BUILTIN_PROFILES

from . import safety, security
from .capture import AutoCapture, capture_frame, dry_run, replay
from .drivers import LimitError, Look, RobotDriver, SimulatedDriver, reads_points
from .jobs import JobContext, JobManager
from .review import Review
from .scene import ReviewScene
from .store import FrameInfo, Store

PACKAGE_DIR = Path(__file__).resolve().parent.parent
SAMPLE_DIR = PACKAGE_DIR / "sample_sessions"
PROFILE_DIR = PACKAGE_DIR / "calib_core" / "model" / "profiles"
OBSERVE_PERIOD_S = 0.5
MIN_REGISTRATION_FRAMES = 3  # measured frames an external tracker's pose is fitted on (3 points not on one line)
# A resumed replay leaves out a configuration the session holds a frame at within this on every joint: a
# frame's joints are the encoder readings at the commanded configuration (0.1 deg resolution, servo error).
RESUME_TOLERANCE_DEG = 0.5
MAX_PLANNED = 2000  # new configurations one replay may plan
# The simulated robots' "today": Robonaut is the later-day robot of its day-2 sample session (its
# offsets drifted since day 1), so a calibration made on day 1 and applied shows the drift live.
SIMULATED_DAY = {"robonaut-a": 2}


class Desk:
    def __init__(
        self,
        data_dir: Path,
        *,
        sample_dir: Path | None = SAMPLE_DIR,
        viser_host: str = "127.0.0.1",
        viser_port: int = 0,
        time_scale: float = 1.0,
        workers: int = 1,
    ) -> None:
        self.data_dir = Path(data_dir)
        self.sample_dir = sample_dir
        self.viser_host = viser_host
        self.viser_port = viser_port
        self.time_scale = time_scale
        self.workers = workers
        self.scrub = security.Scrubber(server_paths(self.data_dir))  # every error text the desk shows
        self.profiles: dict[str, Profile] = {}
        self.drivers: dict[str, RobotDriver] = {}
        self.connected = BUILTIN_PROFILES[0]
        self._review: Review | None = None
        self._review_key: dict[str, Any] = {}
        self._review_lock = threading.Lock()
        self._observe: _Observer | None = None

    # --- life ---------------------------------------------------------------------------------
    def start(self) -> None:
        self.store = Store(self.data_dir)
        self.store.fail_interrupted_jobs()
        if self.sample_dir is not None and self.sample_dir.is_dir():
            self.store.ensure_samples(self.sample_dir)
        self.jobs = JobManager(self.store, workers=self.workers, scrub=self.scrub)
        for name in BUILTIN_PROFILES:
            profile = self.profile(name)
            if not simulated(profile):
                continue  # real data only: its sessions are imported, there is no robot to drive
            day = SIMULATED_DAY.get(name, 1)
            driver = SimulatedDriver(profile, seed=1, day=day, time_scale=self.time_scale)
            self.drivers[name] = driver
            self._push_active(name)
        if self.connected not in self.drivers and self.drivers:
            self.connected = next(iter(self.drivers))
        self.viser = viser.ViserServer(host=self.viser_host, port=self.viser_port, verbose=False)
        security.close_viser_share(self.viser)
        urdf = PROFILE_DIR / f"{self.connected}.urdf"
        self.scene = ReviewScene(self.viser, urdf if urdf.is_file() else None)

    def stop(self) -> None:
        self.observe(None)
        for driver in self.drivers.values():
            driver.stop()
            close = getattr(driver, "close", None)
            if close is not None:
                close()
        self.jobs.shutdown()
        self.viser.stop()

    @property
    def viser_port_number(self) -> int:
        return int(self.viser.get_port())

    # --- robots -------------------------------------------------------------------------------
    def profile(self, robot: str) -> Profile:
        if robot not in self.profiles:
            if robot not in BUILTIN_PROFILES:
                raise InputError(f"unknown robot '{robot}' (known: {', '.join(BUILTIN_PROFILES)})")
            self.profiles[robot] = load_profile(robot)
        return self.profiles[robot]

    @property
    def robots(self) -> tuple[str, ...]:
        """Every robot the desk knows: those it can drive and those with real data only."""
        return BUILTIN_PROFILES

    def driver(self, robot: str | None = None) -> RobotDriver:
        robot = robot or self.connected
        if robot not in self.drivers:
            raise InputError(self._no_driver(robot))
        return self.drivers[robot]

    def connect(self, robot: str) -> None:
        if robot not in self.drivers:  # named exactly: driver() would take "" for the connected one
            raise InputError(self._no_driver(robot))
        if robot != self.connected:
            self.observe(None)
            self.connected = robot
        self._show(robot)

    def _show(self, robot: str) -> None:
        """The scene shows this robot (its built-in URDF at zero joint angles) unless it shows it already;
        the review of another robot it showed is closed."""
        with self._review_lock:
            if self.scene.robot == robot:
                return
            urdf = PROFILE_DIR / f"{robot}.urdf"
            if urdf.is_file():
                self.scene.set_robot(urdf, robot)
            else:
                self.scene.show_robot(self.profile(robot))
            self._review = None
            self._review_key = {}

    def _no_driver(self, robot: str) -> str:
        drivable = ", ".join(self.drivers) or "none"
        if robot in BUILTIN_PROFILES:
            return (
                f"{robot} has no robot to drive here (real data only, no simulation): import its sessions "
                f"from CSV to calibrate and review them (robots to drive: {drivable})"
            )
        return f"no robot '{robot}' to drive (robots to drive: {drivable})"

    def active_params(self, robot: str) -> tuple[str | None, np.ndarray]:
        """The robot's active calibration id and its parameters (the nominal model when none)."""
        profile = self.profile(robot)
        cal_id = self.store.active(robot)
        if cal_id is None:
            return None, profile.nominal()
        return cal_id, self.store.calibration(cal_id).params(profile)

    def _push_active(self, robot: str) -> None:
        cal_id, p = self.active_params(robot)
        self.drivers[robot].apply_calibration(cal_id, None if cal_id is None else p)

    def apply(self, cal_id: str, note: str = "", *, confirm: bool = False) -> dict[str, Any]:
        """Make a calibration its robot's active one: recorded first, then pushed to the driver. One that
        is worse than the active one or moves a parameter beyond its sane bound (app/safety.py) raises
        ConfirmationRequired unless `confirm`."""
        info = self.store.calibration_info(cal_id)
        if not confirm:
            reasons = self.apply_concerns(cal_id)
            if reasons:
                raise safety.ConfirmationRequired(
                    f"applying {cal_id} to {info.robot} needs confirmation: {reasons[0]}"
                    + (f" (and {len(reasons) - 1} more)" if len(reasons) > 1 else ""),
                    reasons,
                )
        active, previous = self.store.apply(info.robot, cal_id, note)
        if info.robot in self.drivers:
            self._push_active(info.robot)
        return {"active": active, "previous": previous, "robot": info.robot}

    def apply_concerns(self, cal_id: str) -> list[str]:
        """Why applying this calibration needs a confirmation (empty: it does not)."""
        info = self.store.calibration_info(cal_id)
        profile = self.profile(info.robot)
        active_id, active_p = self.active_params(info.robot)
        if active_id == cal_id:
            return []
        active = "the nominal model" if active_id is None else f"the active calibration {active_id}"
        cal = self.store.calibration(cal_id)
        new_p = cal.params(profile)
        reasons = []
        if info.session_id is not None and info.session_id in {s.id for s in self.store.sessions()}:
            data = self.store.dataset(info.session_id, profile)
            heldout = np.isin(data.frame_ids, cal.frames.get("holdout", []))
            where = f"the held-out frames of session {info.session_id}"
            train = ~heldout
            if not heldout.any():
                heldout[:] = True
                where = f"the frames of session {info.session_id}"
            # An external tracker (if any) stood where this session's data say: the active parameters see it
            # through a registration fitted on the frames the candidate was fitted on.
            active_here = register(profile, data.select(train if train.any() else heldout), active_p)
            worse = safety.worse_than_active(profile, data.select(heldout), new_p, active_here, active, where)
            if worse is not None:
                reasons.append(worse)
        reasons += safety.parameter_jumps(profile, new_p, active_p, active, from_nominal=active_id is None)
        return safety.concerns(reasons)

    # --- capture ------------------------------------------------------------------------------
    def capture(self, session_id: str) -> FrameInfo:
        session = self.store.session(session_id)
        return capture_frame(self.store, self.driver(session.robot), session_id)

    def replay_plan(
        self,
        session_id: str,
        *,
        from_session: str | None,
        count: int | None,
        remeasure: bool,
        seed: int = 0,
        resume: bool = False,
    ) -> tuple[np.ndarray, np.ndarray, list[int] | None]:
        """The configurations (rad), targets and frame indices (None: append) a replay drives through.

        `resume` goes on with a replay a fault or an abort stopped: the same plan (source session, or count
        and seed with the same active calibration) less the configurations the session holds a frame at.
        """
        self._check_plan(session_id, from_session=from_session, count=count, remeasure=remeasure, resume=resume)
        q, targets, indices = self._plan(
            session_id, from_session=from_session, count=count, remeasure=remeasure, seed=seed
        )
        if not resume:
            return q, targets, indices
        have = np.array([f.joints_rad for f in self.store.frames(session_id)]).reshape(-1, q.shape[1])
        near = np.abs(q[:, None, :] - have[None, :, :]) <= np.radians(RESUME_TOLERANCE_DEG)
        todo = ~np.all(near, axis=2).any(axis=1)
        if not todo.any():
            raise InputError(
                f"nothing to resume: session '{session_id}' has a frame at each of the {len(q)} configurations"
            )
        return q[todo], targets[todo], None

    def _check_plan(
        self, session_id: str, *, from_session: str | None, count: int | None, remeasure: bool, resume: bool
    ) -> None:
        """What can be wrong with a replay request before any planning: the session, its robot, the options."""
        robot = self.store.session(session_id).robot
        self.driver(robot)  # a robot with real data only has nothing to replay on
        if resume and remeasure:
            raise InputError("resume goes on with a replay that adds frames; start a re-measure again instead")
        if not (remeasure or from_session) and (not count or count < 1 or count > MAX_PLANNED):
            raise InputError(f"give from_session, remeasure, or a count of configurations between 1 and {MAX_PLANNED}")

    def _plan(
        self, session_id: str, *, from_session: str | None, count: int | None, remeasure: bool, seed: int
    ) -> tuple[np.ndarray, np.ndarray, list[int] | None]:
        session = self.store.session(session_id)
        profile = self.profile(session.robot)
        if remeasure or from_session:
            source = self.store.session(session_id if remeasure else str(from_session))
            if source.robot != session.robot:
                raise InputError(f"session '{source.id}' is of robot {source.robot}, not {session.robot}")
            frames = self.store.frames(source.id)
            if not frames:
                raise InputError(f"session '{source.id}' has no frames to replay")
            q = np.array([f.joints_rad for f in frames])
            targets = np.array([f.target for f in frames])
            return q, targets, [f.index for f in frames] if remeasure else None
        assert count is not None  # _check_plan
        # Configurations the robot believes it sees the fixture in: planned with its active model. Twice
        # as many as asked, since those inside a joint's safety margin are left out.
        _, believed = self.active_params(session.robot)
        planner = SimulatedRobot.from_profile(profile, seed=seed, truth=believed)
        q, targets = planner.configurations(2 * count + 10)
        driver = self.driver(session.robot)
        keep = [k for k in range(len(q)) if _within_limits(driver, q[k])][:count]
        return q[keep], targets[keep], None

    def dry_run(self, session_id: str, **plan: Any) -> dict[str, Any]:
        robot = self.store.session(session_id).robot
        q, targets, _ = self.replay_plan(session_id, **plan)
        _, believed = self.active_params(robot)
        rows = dry_run(self.driver(robot), q, targets, believed)
        return {"ok": all(r["ok"] for r in rows), "configurations": rows}

    def start_replay(self, session_id: str, **plan: Any) -> str:
        """Queue a replay job. A plan from frames (another session's, or a re-measure) is made here, so its
        mistakes answer at once; N new configurations are planned in the job (NAO: tens of ms each), so the
        request returns at once and the job shows "planning" meanwhile."""
        robot = self.store.session(session_id).robot
        driver = self.driver(robot)
        if plan.get("remeasure") or plan.get("from_session"):
            ready = self.replay_plan(session_id, **plan)
        else:
            self._check_plan(
                session_id,
                from_session=None,
                count=plan.get("count"),
                remeasure=False,
                resume=bool(plan.get("resume")),
            )
            ready = None

        def run(ctx: JobContext) -> str | None:
            if ready is None:
                ctx.progress(0.0, phase="planning")
                q, targets, indices = self.replay_plan(session_id, **plan)
                ctx.checkpoint()
                ctx.progress(0.0, phase="driving")
            else:
                q, targets, indices = ready
            return replay(ctx, self.store, driver, session_id, q, targets, indices)

        return self.jobs.submit_thread("replay", run, session_id=session_id)

    def observe(self, session_id: str | None, *, autocapture: bool = False) -> None:
        """Observe (the paper's GenVisCalData): look at the robot while someone else drives it, show
        the live detection against the prediction, and optionally capture settled good frames."""
        if self._observe is not None:
            self._observe.stop()
            self._observe = None
        if session_id is None:
            return
        robot = self.store.session(session_id).robot
        self.connect(robot)
        self._observe = _Observer(self, session_id, autocapture)
        self._observe.start()

    def observing(self) -> dict[str, Any] | None:
        return None if self._observe is None else self._observe.snapshot()

    # --- review -------------------------------------------------------------------------------
    def _params(self, robot: str, ref: str | None) -> tuple[str | None, np.ndarray]:
        profile = self.profile(robot)
        if ref == "active":
            return self.active_params(robot)
        if ref is None:
            return None, profile.nominal()
        cal = self.store.calibration(ref)
        if cal.robot != robot:
            raise InputError(f"calibration '{ref}' is for robot {cal.robot}, not {robot}")
        return ref, cal.params(profile)

    def review(self, session_id: str, old: str | None, new: str | None) -> dict[str, Any]:
        """Load a session into the review scene with an old and a new calibration."""
        session = self.store.session(session_id)
        profile = self.profile(session.robot)
        old_id, old_p = self._params(session.robot, old)
        new_id, new_p = (None, None) if new is None else self._params(session.robot, new)
        heldout: set[int] = set()
        if new_id is not None:
            heldout = set(self.store.calibration(new_id).frames.get("holdout", []))
        frames = self.store.frames(session_id)
        data = self.store.dataset(session_id, profile) if session.measured else None
        if data is not None and registration_params(profile):
            old_p = self._registered(profile, data, old_p, old_id, session_id, heldout)
            new_p = None if new_p is None else self._registered(profile, data, new_p, new_id, session_id, heldout)
        review = Review.build(profile, frames, data, old_p, new_p, heldout_frames=heldout)
        watched = self._observe.driver.profile.name if self._observe is not None else None
        if watched is not None and watched != session.robot:
            self.observe(None)  # the scene shows one robot: the review replaces the live view of another
        with self._review_lock:
            self.scene.load(review)  # another robot's: replaces everything the scene showed
            self._review = review
            self._review_key = {"session": session_id, "old": old_id, "new": new_id}
        return {**self._review_key, "robot": session.robot, "table": review.table(), "summary": review.summary()}

    def _registered(
        self, profile: Profile, data: Dataset, p: np.ndarray, cal_id: str | None, session_id: str, heldout: set[int]
    ) -> np.ndarray:
        """An external tracker's pose belongs to its set-up, that is to a session: parameters from elsewhere
        (the nominal model, another session's calibration) see this session's tracker through a registration
        fitted on its frames (those the new calibration was fitted on, when it held some out)."""
        if cal_id is not None and self.store.calibration_info(cal_id).session_id == session_id:
            return p
        train = ~np.isin(data.frame_ids, sorted(heldout))
        return register(profile, data.select(train) if train.any() else data, p)

    def _current_review(self) -> Review:
        if self._review is None:
            raise InputError("no session is loaded for review (POST /api/review first)")
        return self._review

    def select(self, index: int, *, show_all: bool = False, overlay: bool = False) -> dict[str, Any]:
        t0 = time.perf_counter()
        with self._review_lock:
            self._current_review()
            self.scene.set_overlay(overlay)
            self.scene.show_all(show_all)
            self.scene.select(index)
        return {"index": index, "all": show_all, "overlay": overlay, "server_ms": (time.perf_counter() - t0) * 1e3}

    def marks(self, index: int) -> dict[str, Any]:
        review = self._current_review()
        marks = review.marks(index)
        frame = self.store.frame(self._review_key["session"], index)
        path = frame.images.get(marks["role"]) if marks.get("role") else None
        return {**marks, "image": None if path is None else f"/api/files/{path}"}


def simulated(profile: Profile) -> bool:
    """Whether the simulator can stand in for the robot: the profile has a simulation section and its data
    sensor is one the simulator renders (a stereo head or a camera; calib_core.simulator's capture) or reads
    directly (a point sensor without images, like the Motoman's laser tracker; drivers.reads_points)."""
    sensor = profile.sensors[profile.data.sensor]
    return bool(profile.simulation) and (sensor.reading in ("stereo", "image") or reads_points(sensor))


def server_paths(data_dir: Path) -> list[Path]:
    """The folders no answer may name a path in: the data directory, the code, the home folder, the
    Python installation (virtualenv, site-packages) and the temporary folder."""
    python = {Path(sys.prefix), Path(sys.base_prefix), Path(sys.exec_prefix), *map(Path, site.getsitepackages())}
    return [Path(data_dir), PACKAGE_DIR, Path.home(), *sorted(python), Path(tempfile.gettempdir())]


def _within_limits(driver: RobotDriver, q_rad: np.ndarray) -> bool:
    try:
        driver.check(q_rad)
    except LimitError:
        return False
    return True


class _Observer:
    """The live loop of Observe: at a few Hz, look through the cameras when the robot stands still
    and show the detection beside the prediction; with autocapture, keep the good settled frames."""

    def __init__(self, desk: Desk, session_id: str, autocapture: bool) -> None:
        self.desk = desk
        self.session_id = session_id
        robot = desk.store.session(session_id).robot
        self.driver = desk.driver(robot)
        self.auto = AutoCapture(desk.store, self.driver, session_id) if autocapture else None
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="observe", daemon=True)
        self._last: dict[str, Any] = {"session": session_id, "autocapture": autocapture, "captured": 0}
        self._registration: tuple[tuple, np.ndarray | None] | None = None  # (frames and calibration, fitted p)

    def start(self) -> None:
        self._thread.start()

    def stop(self) -> None:
        self._stop.set()
        self._thread.join(timeout=5)
        self.desk.scene.hide_live()

    def snapshot(self) -> dict[str, Any]:
        return dict(self._last)

    def _run(self) -> None:
        while not self._stop.wait(OBSERVE_PERIOD_S):
            try:
                self._tick()
            except Exception as exc:  # a failed look must not end observing; it is shown instead
                self._last["message"] = self.desk.scrub(f"{type(exc).__name__}: {exc}")

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
        if look is None:
            if not self.driver.settled(0.2):
                self._last["detection"] = "moving"
                return
            look = self.driver.look()
        self._last["detection"] = look.sighting.status
        self._last["reason"] = look.sighting.reason
        p, registered = self._live_params()
        if not registered:  # where the tracker stands is unknown: its reading has no place in the scene yet
            look = Look(look.readings_rad, look.target, replace(look.sighting, measured=None), look.images)
            self._last["reason"] = f"shown once {MIN_REGISTRATION_FRAMES} frames are measured (the tracker's pose)"
        self.desk.scene.show_live(self.driver.profile, look, p)

    def _live_params(self) -> tuple[np.ndarray, bool]:
        """The active calibration, seeing an external tracker (if any) through a registration fitted on this
        session's measured frames; False when the session has too few of them to place the tracker."""
        profile = self.driver.profile
        cal_id, p = self.desk.active_params(profile.name)
        if not registration_params(profile):
            return p, True
        frames = self.desk.store.frames(self.session_id)
        key = (cal_id, tuple(f.index for f in frames if f.status == "measured"))
        if self._registration is None or self._registration[0] != key:
            data = self.desk.store.dataset(self.session_id, profile)
            fitted = register(profile, data, p) if data.n_configurations >= MIN_REGISTRATION_FRAMES else None
            self._registration = (key, fitted)
        fitted = self._registration[1]
        return (p, False) if fitted is None else (fitted, True)
