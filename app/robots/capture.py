"""Capturing frames: one look now (Observe), automatic capture when the robot has settled (Observe with
autocapture), Replay, which drives the robot through a list of configurations after a dry run, and capture
until good enough, which plans each next configuration from the frames measured so far.

The dry run checks every configuration before anything moves (the peers' users found broken set-ups only
after the robot had moved through every pose): against the joint limits with the driver's safety margin,
and whether the believed calibration predicts the target inside the image (a configuration measured in the
session it comes from was seen: its own measurement is trusted over the prediction). A configuration beyond a joint
limit itself means the list is wrong and refuses the whole replay; one inside the safety margin (within the
limits: a pose the robot itself reached, recorded at its limit) is moved the least way out of it, with a note;
one with the target predicted out of view is skipped with its reason.
"""

from __future__ import annotations

import math
from collections import Counter
from collections.abc import Callable
from dataclasses import dataclass
from functools import partial
from typing import TYPE_CHECKING, Literal, TypedDict

import numpy as np

from calib_core import FrameStatus
from calib_core.errors import Cancelled, InputError
from calib_core.model import Profile
from calib_core.units import length_factor
from calib_core.vision import VIEW_MARGIN_PX, Visibility

from ..drivers import LimitError, Look, RobotDriver, RobotFault
from ..store import Observations, StoreWriteError

if TYPE_CHECKING:
    from calib_core.estimation import SequentialPlan

    from ..jobs.runner import JobContext
    from ..store import FrameInfo, Store

DEFAULT_MIN_GAP_DEG = 2.0
CHECK_CHUNK = 100  # configurations a dry run checks between two reports of its progress


@dataclass(frozen=True)
class Until:
    """Capture until good enough: plan each next configuration from the frames measured so far and stop when
    the predicted mean error over the workspace reaches `error` (the measurement's unit) or after `max` frames."""

    error: float
    max: int


def look_outcome(profile: Profile, look: Look) -> tuple[FrameStatus, str]:
    """A look's frame status (measured when any sensor measured) and its reason: the one sighting's, or with
    several each sensor's that found nothing, by name ("ok" when every one measured)."""
    status = FrameStatus.MEASURED if look.measured else FrameStatus.NOT_FOUND
    if len(look.sightings) == 1:
        return status, look.sightings[0].reason
    missed = [
        f"{profile.sensors[s.sensor].name} ({profile.targets[s.target].name}): {s.reason}"
        for s in look.sightings
        if s.measured is None
    ]
    return status, "; ".join(missed) or "ok"


def save_look(store: Store, profile: Profile, session_id: str, look: Look, index: int | None = None) -> FrameInfo:
    """Store what one look gave as a frame (replacing the frame `index` if it exists): every sensor's
    measurements, the images, and the detectors' figures (the first sighting's; with several, each sensor's
    status and figures under "sightings" too)."""
    status, reason = look_outcome(profile, look)
    parts = [
        Observations.of(profile, s.target, s.measured, s.points, s.vertices, s.sensor)
        for s in look.sightings
        if s.measured is not None
    ]
    detail = dict(look.sightings[0].detail)
    if len(look.sightings) > 1:
        detail["sightings"] = [
            {"sensor": profile.sensors[s.sensor].name, "target": profile.targets[s.target].name}
            | {"status": s.status, "reason": s.reason, "observations": 0 if s.measured is None else len(s.measured)}
            | {"detail": s.detail}
            for s in look.sightings
        ]
    index = store.sessions.add_frame(
        session_id,
        index=index,
        joints_rad=look.readings_rad,
        target=look.target,
        status=status,
        reason=reason,
        observations=Observations.joined(parts) if parts else None,
        images=look.images,
        detail=detail,
    )
    return store.sessions.frame(session_id, index)


def capture_frame(store: Store, driver: RobotDriver, session_id: str, index: int | None = None) -> FrameInfo:
    """Look now and store the frame (measured, or not found with the detector's reason). Refused while the
    robot moves: a frame must show the pose its joint readings say."""
    _check_robot(store, driver, session_id)
    if driver.status().moving:
        raise InputError("the robot is moving: capture a frame once it stands still")
    return save_look(store, driver.profile, session_id, driver.look(), index)


def out_of_margin(driver: RobotDriver, q_rad: np.ndarray) -> tuple[np.ndarray, str]:
    """q, or q with each joint inside the safety margin moved onto its edge, and a note saying so; LimitError
    when q is beyond a limit itself (the list is wrong: nothing is moved into range)."""
    try:
        driver.check(q_rad)
        return q_rad, ""
    except LimitError as exc:
        if exc.beyond or math.isnan(exc.value):
            raise
    profile = driver.profile
    lower, upper = profile.limits_less_margin(math.degrees(driver.margin_rad), driver.margin_m)
    moved = np.clip(q_rad, lower, upper)
    driver.check(moved)
    shift = [
        abs(profile.joint_to_display(i, moved[i]) - profile.joint_to_display(i, q_rad[i])) for i in range(len(q_rad))
    ]
    joints = ", ".join(
        f"{profile.joints[i].name} {shift[i]:.2f} {profile.joint_display_unit(i)}"
        for i in np.flatnonzero(moved != q_rad)
    )
    return moved, f"moved out of the {_margins(driver)} safety margin: {joints}"


def _margins(driver: RobotDriver) -> str:
    """The driver's safety margins, as the operator reads them: deg, and a length for a robot with a slide."""
    deg = f"{math.degrees(driver.margin_rad):.1f} deg"
    if not any(j.prismatic for j in driver.profile.joints):
        return deg
    unit = driver.profile.length_unit
    return f"{deg} / {driver.margin_m * length_factor('m', unit):.4g} {unit}"


class DryRunRow(TypedDict):
    """One configuration as the dry run checked it (see `dry_run`)."""

    index: int  # the frame index, or the 1-based position of a new configuration
    target: int
    ok: bool
    problem: str  # "": none
    action: Literal["capture", "skip", "refuse"]
    note: str  # how it is moved out of the safety margin ("": it is not)


def dry_run(
    driver: RobotDriver,
    configurations_rad: np.ndarray,
    targets: np.ndarray,
    believed: np.ndarray,
    *,
    indices: list[int] | None = None,
    seen: np.ndarray | None = None,
    margin_px: float = VIEW_MARGIN_PX,
    progress: Callable[[int, int], None] | None = None,
) -> list[DryRunRow]:
    """Check every configuration, moving nothing. Per configuration: {"index", "target", "ok", "problem",
    "action", "note"}, action "capture", "skip" (not predicted in view) or "refuse" (beyond a joint limit);
    `note`: how it is moved out of the safety margin (out_of_margin). `index` is the frame index, or the
    1-based position without `indices`. `seen` (bool per configuration): measured in the session it comes from,
    so in view whatever the believed calibration predicts (a model off by a few degrees predicts a target near
    the image border outside it). `progress(checked, total)`: called after each CHECK_CHUNK configurations (it
    may raise Cancelled to stop the check)."""
    q = np.asarray(configurations_rad, dtype=float)
    t = np.asarray(targets, dtype=int)
    seen_ = np.zeros(len(q), bool) if seen is None else np.asarray(seen, dtype=bool)
    if q.ndim != 2 or len(q) != len(t) or (indices is not None and len(indices) != len(q)) or len(seen_) != len(q):
        raise ValueError("configurations, targets and indices must have one entry per configuration")
    profile = driver.profile
    n_targets = len(profile.targets)
    if np.any((t < 0) | (t >= n_targets)):
        raise InputError(f"targets must be in 0..{n_targets - 1} for {profile.name}")
    view = Visibility(profile, np.asarray(believed, dtype=float), margin_px=margin_px)
    moved, notes, refusals = q.copy(), [""] * len(q), [""] * len(q)
    in_view = seen_.copy()
    for at in range(0, len(q), CHECK_CHUNK):
        part = np.arange(at, min(at + CHECK_CHUNK, len(q)))
        for c in part:
            try:
                moved[c], notes[c] = out_of_margin(driver, q[c])
            except LimitError as exc:
                refusals[c] = str(exc)
        unseen = part[~seen_[part]]
        if len(unseen):
            in_view[unseen] = view.sees(moved[unseen], t[unseen])
        if progress is not None:
            progress(int(part[-1]) + 1, len(q))
    rows: list[DryRunRow] = []
    for k in range(len(q)):
        problem = refusals[k]
        action: Literal["capture", "skip", "refuse"] = "refuse" if problem else "capture"
        if not problem and not in_view[k]:
            problem, action = f"{profile.targets[t[k]].name} not predicted in view", "skip"
        index = indices[k] if indices is not None else k + 1
        rows.append(
            {
                "index": index,
                "target": int(t[k]),
                "ok": not problem,
                "problem": problem,
                "action": action,
                "note": notes[k],
            }
        )
    return rows


def replay(
    ctx: JobContext,
    store: Store,
    driver: RobotDriver,
    session_id: str,
    configurations_rad: np.ndarray,
    targets: np.ndarray,
    indices: list[int] | None = None,
    *,
    seen: np.ndarray | None = None,
    believed: np.ndarray | None = None,
    settle_timeout_s: float = 30.0,
) -> str | None:
    """Drive through the configurations and capture a frame at each (a thread job; returns the session id).

    `indices`: the frame index each configuration is stored under (re-measure: a session's own indices, so
    its frames are replaced); None appends. The dry run comes first, with the robot's believed calibration
    unless `believed` is given; `seen`: which configurations were measured where they come from (dry_run). A
    skipped configuration is recorded as a "skipped" frame unless the session already holds a frame with its
    index (re-measure keeps the old one). On cancel, a stop or any failure the
    robot is stopped; frames captured so far stay. A robot fault (disconnected, not responding) or a data
    directory that cannot be written fails the job naming the configuration it stopped at.
    """
    _check_robot(store, driver, session_id)
    q = np.asarray(configurations_rad, dtype=float)
    t = np.asarray(targets, dtype=int)
    p = driver.believed_params() if believed is None else np.asarray(believed, dtype=float)
    plan = dry_run(driver, q, t, p, indices=indices, seen=seen)
    refused = [r for r in plan if r["action"] == "refuse"]
    if refused:
        more = f" (and {len(refused) - 1} more)" if len(refused) > 1 else ""
        raise InputError(
            f"replay refused before moving: configuration {refused[0]['index']}: {refused[0]['problem']}{more}"
        )
    existing = {f.index for f in store.sessions.frames(session_id)} if indices is not None else set()
    counts: Counter[FrameStatus] = Counter()
    k = 0
    ctx.on_cancel(partial(driver.stop, wait_s=0.0))  # a wait on the robot ends with the cancel
    try:
        for k, row in enumerate(plan):
            ctx.checkpoint()
            index = indices[k] if indices is not None else None
            if row["action"] == "skip":
                status, reason = FrameStatus.SKIPPED, row["problem"]
                if index is None or index not in existing:
                    index = store.sessions.add_frame(
                        session_id, index=index, joints_rad=q[k], target=int(t[k]), status=status, reason=reason
                    )
            else:
                frame = _capture_at(ctx, store, driver, session_id, q[k], int(t[k]), index, settle_timeout_s)
                index, status, reason = frame.index, frame.status, frame.reason
            counts[status] += 1
            ctx.progress(
                (k + 1) / len(plan),
                frame=index,
                status=status,
                reason=reason,
                done=k + 1,
                total=len(plan),
                **_tally(counts),
            )
    except (RobotFault, StoreWriteError) as exc:
        driver.stop()
        if ctx.cancelled:  # the robot call the cancel let go of
            raise Cancelled("cancelled") from None
        done = sum(counts.values())
        hint = " (start the replay again with resume to go on)" if indices is None else ""
        raise InputError(
            f"replay stopped at configuration {k + 1} of {len(plan)}: {exc}; the {done} frames before it are kept"
            + hint
        ) from exc
    except BaseException:
        driver.stop()
        raise
    return session_id


def capture_until(
    ctx: JobContext,
    store: Store,
    driver: RobotDriver,
    session_id: str,
    sequence: SequentialPlan,
    until: Until,
    believed: np.ndarray,
    *,
    settle_timeout_s: float = 30.0,
) -> str | None:
    """Capture until good enough (a thread job; returns the session id): drive to the configuration the
    sequential plan proposes, capture, and stop once the predicted mean error over the workspace reaches
    `until.error` or after `until.max` configurations. Each one is dry-run first; one not predicted in view or
    not found is never proposed again. The progress reports the predicted error after each frame (`predicted`,
    and `curve`: every value so far)."""
    _check_robot(store, driver, session_id)
    unit = sequence.design.unit
    curve: list[float | None] = []

    def report(k: int, **detail: object) -> float:
        error = sequence.mean_error()
        curve.append(error if math.isfinite(error) else None)
        ctx.progress(
            min(k / until.max, 1.0),
            phase="driving",
            predicted=curve[-1],
            target_error=until.error,
            unit=unit,
            curve=list(curve),
            done=k,
            total=until.max,
            **detail,
        )
        return error

    counts: Counter[FrameStatus] = Counter()
    error = report(0, **_tally(counts))
    k = 0
    ctx.on_cancel(partial(driver.stop, wait_s=0.0))  # a wait on the robot ends with the cancel
    try:
        while k < until.max and not error <= until.error:
            ctx.checkpoint()
            proposal = sequence.proposal()
            if proposal is None:
                ctx.progress(min(k / until.max, 1.0), stopped="no candidate configuration left")
                break
            q, target = proposal
            row = dry_run(driver, q[None], np.array([target]), believed)[0]
            if row["action"] != "capture":
                sequence.measured(False)
                continue
            frame = _capture_at(ctx, store, driver, session_id, q, target, None, settle_timeout_s)
            sequence.measured(frame.status == FrameStatus.MEASURED)
            counts[frame.status] += 1
            k += 1
            error = report(
                k,
                frame=frame.index,
                status=frame.status,
                reason=frame.reason,
                **_tally(counts),
            )
    except (RobotFault, StoreWriteError) as exc:
        driver.stop()
        if ctx.cancelled:  # the robot call the cancel let go of
            raise Cancelled("cancelled") from None
        raise InputError(f"capture stopped after {k} configurations: {exc}; the frames before it are kept") from exc
    except BaseException:
        driver.stop()
        raise
    return session_id


class AutoCapture:
    """Observe with autocapture: poll() stores a frame when the robot has settled (its own settle window), its
    configuration differs from the last captured by at least min_gap_rad (largest joint difference), and the
    detector measured the target. A configuration whose look failed is not looked at again."""

    def __init__(
        self,
        store: Store,
        driver: RobotDriver,
        session_id: str,
        *,
        min_gap_rad: float = math.radians(DEFAULT_MIN_GAP_DEG),
    ) -> None:
        _check_robot(store, driver, session_id)
        self.store = store
        self.driver = driver
        self.session_id = session_id
        self.min_gap_rad = min_gap_rad
        frames = store.sessions.frames(session_id)
        self._last: np.ndarray | None = max(frames, key=lambda f: f.index).joints_rad if frames else None
        self._looked: np.ndarray | None = None
        self.last_look: Look | None = None  # the latest look poll() made (for a live view)

    def poll(self) -> FrameInfo | None:
        if not self.driver.settled():
            return None
        q = self.driver.read_joints()
        if self._last is not None and np.max(np.abs(q - self._last)) < self.min_gap_rad:
            return None
        if self._looked is not None and np.array_equal(q, self._looked):
            return None
        look = self.driver.look()
        self.last_look = look
        if not np.array_equal(look.readings_rad, q) or self.driver.status().moving:
            return None  # it moved while we looked
        self._looked = q
        if not look.measured:
            return None
        frame = save_look(self.store, self.driver.profile, self.session_id, look)
        self._last = q
        return frame


def _check_robot(store: Store, driver: RobotDriver, session_id: str) -> None:
    robot = store.sessions.get(session_id).robot
    if robot != driver.profile.name:
        raise InputError(f"session '{session_id}' is of robot {robot}, not {driver.profile.name}")


def _tally(counts: Counter[FrameStatus]) -> dict[str, int]:
    """A replay's frames so far by status, as its job's progress names them (measured, not_found, skipped)."""
    return {s.name.lower(): counts[s] for s in (FrameStatus.MEASURED, FrameStatus.NOT_FOUND, FrameStatus.SKIPPED)}


def _capture_at(
    ctx: JobContext,
    store: Store,
    driver: RobotDriver,
    session_id: str,
    q_rad: np.ndarray,
    target: int,
    index: int | None,
    settle_timeout_s: float,
) -> FrameInfo:
    """Drive to q (out of the safety margin), let the robot settle and keep a frame there. A pause holds at once:
    the move under way stops where the robot is, a look under way is not kept, and on resume the move is made
    again; no frame is kept once a pause has been answered. Cancelled on cancel or when the robot is stopped."""
    goal = out_of_margin(driver, q_rad)[0]
    while True:
        ctx.checkpoint()  # held here while paused
        held = False

        def stop_asked() -> bool:
            nonlocal held
            held = held or ctx.paused
            return ctx.cancelled or held

        driver.set_target(target)
        if not driver.move_to(goal, should_stop=stop_asked):
            if ctx.cancelled or not held:
                raise Cancelled("cancelled" if ctx.cancelled else "the robot was stopped")
            continue
        if not driver.wait_settled(None, settle_timeout_s, should_stop=stop_asked):
            if ctx.cancelled:
                raise Cancelled("cancelled")
            continue
        frame = ctx.unless_paused(partial(save_look, store, driver.profile, session_id, driver.look(), index))
        if frame is not None:
            return frame
