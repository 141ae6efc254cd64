"""ROS bags into capture sessions: joint states and camera images recorded while someone drove the robot.

A ROS 1 bag (`.bag` file) or a ROS 2 bag (its folder, or its `.db3` / `.mcap` file) holds the robot's
joint states (sensor_msgs/msg/JointState, default topic /joint_states) and its camera images
(sensor_msgs/msg/Image or sensor_msgs/msg/CompressedImage): the Robonaut head's left and right camera, the
NAO's lower camera. A calibration frame needs a robot that stood still while its image was taken, so:

1. The joint states give each profile joint's reading over time (a message may carry a subset of the
   joints: the others keep their last reading). A message's joint names are the profile's joint names or
   the data format's column names (`data.joints`); a profile joint no message names is an InputError
   naming the joint and the topic, unless its limits fix it (lower = upper: it takes that value).
2. The robot's speed at each joint state is the largest joint speed, estimated from consecutive readings:
   the mean reading of the next `window_s / 2` seconds less that of the last `window_s / 2`, over the
   difference of their mean times (a slope that an encoder's one-step flicker hardly moves). A *still
   period* is a run of joint states whose speed stays at or below `still_deg_s`, without a gap of more
   than MAX_GAP_S between two of them (the robot may have moved unseen), lasting at least `still_s`.
3. Each still period gives one frame: the median of each joint's readings over the period, and of each
   image topic the image closest to the period's middle and inside the period (none: the frame is kept
   as "not found", no image).
4. The frame's images go through the data sensor's finder exactly as the simulated capture's do
   (`calib_core.vision.finders`): the Robonaut pair -> stereo depth -> BallFinder, the NAO image -> sandal
   board detector, a camera's image -> its board's detector (of several boards, those the believed
   kinematics predict in view first; boards it cannot place, the camera's or their pose not estimated yet,
   each tried and kept when exactly one is found), seeded by the believed calibration (default: the
   profile's nominal model), with the camera intrinsics and baseline from it. Frames where the finder finds
   nothing stay as "not found" records with the reason.
5. `write_session` writes the session folder whole (session.json, data.csv, images/) or not at all.

Times: the messages' header stamps when every message read has one (non-zero), else the times the bag
recorded them (the two clocks are never mixed). Reading uses `rosbags` (pure Python, no ROS installation
needed; Apache-2.0, actively maintained by Ternaris; its AnyReader reads ROS 1 and ROS 2 bags alike).
"""

from __future__ import annotations

import math
import struct
from collections.abc import Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np
from rosbags.highlevel import AnyReader, AnyReaderError
from rosbags.rosbag1 import ReaderError as Ros1ReaderError
from rosbags.rosbag2 import ReaderError as Ros2ReaderError
from rosbags.serde import SerdeError
from rosbags.typesys import Stores, get_typestore

from ..errors import InputError
from ..frame_status import FrameStatus
from ..model.profile import Profile
from ..sensors import Sensor
from ..vision.finders import finder_for, finders_served, found_targets
from ..vision.sighting import Capture, Sighting, dataset_from_captures, predicted_points
from ..vision.visibility import Visibility
from .camera_images import grey_compressed, grey_image
from .session import FrameRecord, write_session

DEFAULT_JOINT_TOPIC = "/joint_states"
DEFAULT_STILL_DEG_S = 1.0  # deg/s: a robot holding a pose; an encoder's flicker stays well below
DEFAULT_STILL_S = 0.5  # s: the shortest still period that makes a frame
VELOCITY_WINDOW_S = 0.3  # s: the speed at a joint state compares the mean readings either side of it
MAX_GAP_S = 0.5  # s: joint states farther apart end a still period

JOINT_STATE = "sensor_msgs/msg/JointState"
IMAGE = "sensor_msgs/msg/Image"
COMPRESSED_IMAGE = "sensor_msgs/msg/CompressedImage"
IMAGE_TYPES = (IMAGE, COMPRESSED_IMAGE)

# Errors rosbags raises on a file that is not a bag, is cut off or holds malformed messages.
_BAG_ERRORS = (AnyReaderError, Ros1ReaderError, Ros2ReaderError, SerdeError)
_MESSAGE_ERRORS = (*_BAG_ERRORS, struct.error, IndexError, ValueError, UnicodeDecodeError)


@dataclass(frozen=True)
class StillPeriod:
    """A stretch of time the robot stood still, with its median joint readings."""

    start_s: float  # from the bag's first joint state
    end_s: float
    joints_rad: np.ndarray  # (n_joints,) the median reading of each profile joint
    n_samples: int  # joint states in the period

    @property
    def middle_s(self) -> float:
        return 0.5 * (self.start_s + self.end_s)

    @property
    def duration_s(self) -> float:
        return self.end_s - self.start_s


@dataclass
class BagImport:
    """What an import found and wrote."""

    bag: str
    session: str
    joint_topic: str
    image_topics: dict[str, str]  # role ("left", "right", "image") -> topic
    joint_states: int
    still_periods: list[StillPeriod]
    measured: int
    not_found: int  # still periods whose detector found nothing
    without_image: int  # still periods with no image inside them (counted in not_found too)
    frames: list[FrameRecord] = field(default_factory=list)

    def summary(self) -> str:
        roles = ", ".join(f"{role} {topic}" for role, topic in self.image_topics.items())
        return (
            f"{self.joint_states} joint states on {self.joint_topic}, images from {roles}: "
            f"{len(self.still_periods)} still periods, {self.measured} frames measured, {self.not_found} not found"
            + (f" ({self.without_image} without an image)" if self.without_image else "")
        )


@dataclass
class _Stamped:
    """One message's time: its header stamp (0: none) and when the bag recorded it, both ns."""

    stamp_ns: int
    log_ns: int


@dataclass
class _ImageRef:
    time: _Stamped
    ordinal: int  # its position among its topic's messages


# --- still periods ---------------------------------------------------------------------------------------


def speeds_deg_s(times_s: np.ndarray, joints_rad: np.ndarray, window_s: float = VELOCITY_WINDOW_S) -> np.ndarray:
    """The largest joint speed (deg/s) at each joint state (N,): the mean readings of the half window after
    it less those of the half window before it (each with the state itself and at least one neighbour),
    over the difference of their mean times. Times sorted ascending; inf where the times do not differ."""
    t = np.asarray(times_s, dtype=float)
    q = np.asarray(joints_rad, dtype=float)
    n = len(t)
    if n == 0:
        return np.zeros(0)
    idx = np.arange(n)
    lo = np.minimum(np.searchsorted(t, t - window_s / 2, side="left"), np.maximum(idx - 1, 0))
    hi = np.maximum(np.searchsorted(t, t + window_s / 2, side="right"), np.minimum(idx + 2, n))
    t_rel = t - t[0]  # sums of small numbers: precise over hours of recording
    ct = np.concatenate([[0.0], np.cumsum(t_rel)])
    cq = np.vstack([np.zeros((1, q.shape[1])), np.cumsum(q, axis=0)])
    n_before, n_after = (idx + 1 - lo)[:, None], (hi - idx)[:, None]
    q_before = (cq[idx + 1] - cq[lo]) / n_before
    q_after = (cq[hi] - cq[idx]) / n_after
    dt = (ct[hi] - ct[idx]) / n_after[:, 0] - (ct[idx + 1] - ct[lo]) / n_before[:, 0]
    step = np.max(np.abs(q_after - q_before), axis=1, initial=0.0)
    with np.errstate(divide="ignore", invalid="ignore"):
        speed = np.where(dt > 1e-9, np.degrees(step) / dt, np.where(step > 0, np.inf, 0.0))
    return speed


def find_still_periods(
    times_s: np.ndarray,
    joints_rad: np.ndarray,
    *,
    still_deg_s: float = DEFAULT_STILL_DEG_S,
    still_s: float = DEFAULT_STILL_S,
    window_s: float = VELOCITY_WINDOW_S,
    max_gap_s: float = MAX_GAP_S,
) -> list[StillPeriod]:
    """The periods (in time order) in which every joint moved at most `still_deg_s` for at least `still_s`,
    from joint states at times_s (N,) with readings joints_rad (N, n_joints), times sorted ascending."""
    t = np.asarray(times_s, dtype=float)
    q = np.asarray(joints_rad, dtype=float)
    still = speeds_deg_s(t, q, window_s) <= still_deg_s
    # A run goes on from one joint state to the next while both are still and no gap hides what the robot did.
    goes_on = still[1:] & still[:-1] & (np.diff(t) <= max_gap_s)
    firsts = np.flatnonzero(still & ~np.concatenate([[False], goes_on]))
    lasts = np.flatnonzero(still & ~np.concatenate([goes_on, [False]]))
    return [
        StillPeriod(float(t[a]), float(t[b]), np.median(q[a : b + 1], axis=0), int(b - a + 1))
        for a, b in zip(firsts, lasts, strict=True)
        if t[b] - t[a] >= still_s
    ]


# --- reading the bag ---------------------------------------------------------------------------------------


def _open_reader(bag: Path) -> AnyReader:
    if not bag.exists():
        raise InputError("does not exist", file=str(bag))
    try:
        reader = AnyReader([bag], default_typestore=get_typestore(Stores.ROS2_HUMBLE))
        reader.open()
    except (*_BAG_ERRORS, OSError) as exc:
        raise InputError(f"is not a ROS 1 or ROS 2 bag rosbags can read ({_reason(exc)})", file=str(bag)) from None
    return reader


def _reason(exc: BaseException) -> str:
    text = str(exc).strip() or exc.__class__.__name__
    return text if len(text) <= 200 else text[:200] + "..."


def _topic_type(reader: AnyReader, bag: Path, topic: str, wanted: Sequence[str], what: str) -> list[Any]:
    topics = reader.topics
    if topic not in topics:
        known = ", ".join(f"{name} ({info.msgtype})" for name, info in sorted(topics.items())) or "none"
        raise InputError(f"has no {what} topic '{topic}' (topics: {known})", file=str(bag))
    msgtype = topics[topic].msgtype
    if msgtype not in wanted:
        raise InputError(
            f"topic '{topic}' carries {msgtype}, not {' or '.join(wanted)} ({what})",
            file=str(bag),
        )
    return [c for c in reader.connections if c.topic == topic]


def _default_image_topics(reader: AnyReader, bag: Path, roles: Sequence[str]) -> list[str]:
    """The image topics when none were given: the only one for a camera; those naming left and right
    for a stereo head."""
    found = sorted(name for name, info in reader.topics.items() if info.msgtype in IMAGE_TYPES)
    if len(roles) == 1 and len(found) == 1:
        return found
    if len(roles) == 2:
        pick = [[t for t in found if role in t.lower()] for role in roles]
        if all(len(p) == 1 for p in pick) and pick[0] != pick[1]:
            return [p[0] for p in pick]
    need = "one image topic" if len(roles) == 1 else "two image topics, " + " then ".join(roles)
    raise InputError(
        f"give {need} with --image-topic (image topics in the bag: {', '.join(found) or 'none'})", file=str(bag)
    )


def _stamp_ns(msg: Any) -> int:
    stamp = msg.header.stamp
    return int(stamp.sec) * 1_000_000_000 + int(stamp.nanosec)


def _joint_sources(profile: Profile) -> dict[str, int]:
    """Message joint name -> profile joint index: the joint's own name and its data column's name."""
    out: dict[str, int] = {}
    for jname, column in profile.data.joint_columns.items():
        out.setdefault(column, profile.joint(jname))
    for j, joint in enumerate(profile.joints):
        out[joint.name] = j
    return out


def _read_joint_states(
    reader: AnyReader, bag: Path, connections: list[Any], topic: str, profile: Profile
) -> tuple[list[_Stamped], np.ndarray]:
    """Every joint state once each profile joint has a reading: its time and the readings (N, n_joints) rad."""
    sources = _joint_sources(profile)
    n_joints = len(profile.joints)
    last = np.full(n_joints, np.nan)
    seen = np.zeros(n_joints, bool)
    fixed = np.array([j.lower == j.upper for j in profile.joints])
    last[fixed] = [j.lower for j in profile.joints if j.lower == j.upper]
    times: list[_Stamped] = []
    rows: list[np.ndarray] = []
    try:
        for k, (conn, log_ns, raw) in enumerate(reader.messages(connections=connections)):
            msg = reader.deserialize(raw, conn.msgtype)
            names, positions = list(msg.name), np.asarray(msg.position, dtype=float)
            if len(positions) != len(names):
                raise InputError(
                    f"topic '{topic}' message {k + 1}: {len(names)} joint names but {len(positions)} positions",
                    file=str(bag),
                )
            for name, value in zip(names, positions, strict=True):
                j = sources.get(name)
                if j is not None and math.isfinite(value):
                    last[j] = value
                    seen[j] = True
            if not np.isnan(last).any():
                times.append(_Stamped(_stamp_ns(msg), log_ns))
                rows.append(last.copy())
    except _MESSAGE_ERRORS as exc:
        if isinstance(exc, InputError):
            raise
        raise InputError(f"topic '{topic}' cannot be read ({_reason(exc)})", file=str(bag)) from None
    missing = [j.name for j, ok, fx in zip(profile.joints, seen, fixed, strict=True) if not ok and not fx]
    if missing:
        also = f" (nor {', '.join(missing[1:])})" if len(missing) > 1 else ""
        raise InputError(
            f"joint '{missing[0]}' of robot '{profile.name}' is in no message on topic '{topic}'{also}",
            file=str(bag),
        )
    return times, np.array(rows).reshape(-1, n_joints)


def _index_images(reader: AnyReader, bag: Path, connections: list[Any], topic: str) -> list[_ImageRef]:
    """Each image's time, without keeping its pixels."""
    refs = []
    try:
        for k, (conn, log_ns, raw) in enumerate(reader.messages(connections=connections)):
            refs.append(_ImageRef(_Stamped(_stamp_ns(reader.deserialize(raw, conn.msgtype)), log_ns), k))
    except _MESSAGE_ERRORS as exc:
        raise InputError(f"topic '{topic}' cannot be read ({_reason(exc)})", file=str(bag)) from None
    return refs


def _load_images(
    reader: AnyReader, bag: Path, connections: list[Any], topic: str, wanted: set[int]
) -> dict[int, tuple[Any, str]]:
    """The messages at the given positions of a topic: ordinal -> (message, its type)."""
    out: dict[int, tuple[Any, str]] = {}
    if not wanted:
        return out
    try:
        for k, (conn, _, raw) in enumerate(reader.messages(connections=connections)):
            if k in wanted:
                out[k] = (reader.deserialize(raw, conn.msgtype), conn.msgtype)
                if len(out) == len(wanted):
                    break
    except _MESSAGE_ERRORS as exc:
        raise InputError(f"topic '{topic}' cannot be read ({_reason(exc)})", file=str(bag)) from None
    return out


def decode_image(msg: Any, msgtype: str, topic: str, bag: str) -> np.ndarray | None:
    """A grey uint8 image (H, W) from an Image or CompressedImage message (calib_core.io.camera_images); None
    for a compressed image that does not decode (that frame is not found). An encoding the decoder does not know,
    or an image shorter than its size says, is an InputError naming the topic."""
    if msgtype == COMPRESSED_IMAGE:
        return grey_compressed(msg.data)
    try:
        return grey_image(msg)
    except ValueError as exc:
        raise InputError(f"topic '{topic}': {exc}", file=bag) from None


# --- detecting -----------------------------------------------------------------------------------------------


def _image_roles(profile: Profile) -> tuple[Sensor, list[str]]:
    """The data sensor and the images one of its readings takes (`Sensor.image_roles`): a sensor with a finder
    for one of its targets (calib_core.vision.finders)."""
    sensor = profile.sensors[profile.data.sensor]
    if found_targets(profile, profile.data.sensor):
        return sensor, list(sensor.image_roles)
    raise InputError(
        f"robot '{profile.name}': its sensor '{sensor.name}' has no finder for its targets, so nothing detects "
        f"them in its images (finders: {finders_served()})"
    )


def _unplaced(profile: Profile, believed: np.ndarray, frame: int) -> bool:
    """Whether the believed parameters cannot place `frame`: a registration frame on its chain still has the
    profile's nominal pose (a registration's nominal is zero: nobody has estimated where it stands yet)."""
    return any(
        profile.frames[f].registration and not believed[[op.param for op in profile.frames[f].ops]].any()
        for f in profile.chain(frame)
    )


def _ranked_targets(profile: Profile, believed: np.ndarray, q: np.ndarray) -> tuple[list[int], list[int]]:
    """The targets to look for in configuration q: those the believed kinematics place, best first, and those
    they cannot (`_unplaced`, the camera's or the board's pose unknown), in the profile's order. Of the targets
    the data sensor has a finder for, the placed ones predicted fully in view (`Visibility`, nearest the image
    centre first), then those partly in view (most points first). A sensor with one such target always looks
    for it."""
    s = profile.data.sensor
    found = found_targets(profile, s)
    if len(found) == 1:
        return found, []
    sensor = profile.sensors[s]
    camera_unplaced = _unplaced(profile, believed, sensor.frame)
    unplaced = [t for t in found if camera_unplaced or _unplaced(profile, believed, profile.targets[t].frame)]
    boards = np.array([t for t in found if t not in unplaced], int)
    if not len(boards):
        return [], unplaced
    size = sensor.image_size_px()
    assert size is not None  # a finder's sensor has its image size
    width, height = size
    qs = np.repeat(q[None], len(boards), axis=0)
    whole = Visibility(profile, believed).sees(qs, boards)
    inside = Visibility(profile, believed, margin_px=0.0).points(qs, boards).sum(axis=1)
    scored = []
    for t, full, n_inside in zip(boards.tolist(), whole, inside, strict=True):
        if not n_inside:
            continue
        uv = sensor.project(believed, predicted_points(profile, believed, q, t))
        uv = uv[np.isfinite(uv[:, 0])]
        off_centre = float(np.hypot(*(uv.mean(axis=0) - [width / 2, height / 2])))
        scored.append((not full, -int(n_inside), off_centre, t))
    return [t for *_, t in sorted(scored)], unplaced


def _sight(profile: Profile, believed: np.ndarray, q: np.ndarray, images: dict[str, np.ndarray]) -> Sighting:
    """What the finders make of one frame's images, as in the simulated capture. The placed targets are tried
    in their rank and the first found is the frame's; then every unplaced one, and the frame is its target's
    only when exactly one is found: boards the finders cannot tell apart (two checkerboards or two ChArUco
    boards alike) stay "not found" until a calibration places them."""
    ranked, unplaced = _ranked_targets(profile, believed, q)
    if not ranked and not unplaced:
        t = profile.data.target if profile.data.target is not None else 0
        grid = profile.targets[t].grid
        points = grid if grid is not None else np.full((1, 3), np.nan)
        vertices = np.arange(len(points)) if grid is not None else np.array([-1])
        return Sighting(
            profile.data.sensor, t, FrameStatus.NOT_FOUND, "no board predicted in view", None, points, vertices, {}
        )
    sightings = []
    for t in [*ranked, *unplaced]:
        finder = finder_for(profile, profile.data.sensor, t)
        assert finder is not None  # a candidate has its finder
        sightings.append(finder.find(believed, q, images))
        if sightings[-1].status == FrameStatus.MEASURED and t in ranked:
            return sightings[-1]
    measured = [s for s in sightings if s.status == FrameStatus.MEASURED]
    if len(measured) == 1:
        return measured[0]
    if not measured:
        return sightings[0]
    names = " and ".join(profile.targets[s.target].name for s in measured)
    first = measured[0]
    reason = (
        f"ambiguous: {names} are each found in this image and nobody has placed them yet; boards the finders "
        "tell apart (ChArUco boards of another size or dictionary) or a calibration that places them decide"
    )
    grid = profile.targets[first.target].grid
    assert grid is not None  # an unplaced target with a finder is a board
    detail = {**first.detail, "found": False, "reason": reason}
    return replace(
        first,
        status=FrameStatus.NOT_FOUND,
        reason=reason,
        measured=None,
        points=grid,
        vertices=np.arange(len(grid)),
        detail=detail,
    )


def _closest(times_s: np.ndarray, period: StillPeriod) -> int | None:
    """The index (into times_s) of the image closest to the period's middle and inside it."""
    inside = np.flatnonzero((times_s >= period.start_s) & (times_s <= period.end_s))
    if not len(inside):
        return None
    return int(inside[np.argmin(np.abs(times_s[inside] - period.middle_s))])


def _images_named(frames: list[FrameRecord], role_topics: dict[str, str], most: int = 8) -> str:
    """The images the detector looked at, for a message: each topic's image times (s from the first joint
    state), at most `most` of them."""
    named = []
    for role, topic in role_topics.items():
        times = [f.detail["bag"]["images_s"][role] for f in frames if role in f.detail["bag"]["images_s"]]
        if times:
            shown = ", ".join(f"{t:g} s" for t in times[:most]) + (
                f" and {len(times) - most} more" if len(times) > most else ""
            )
            named.append(f"the {len(times)} images on '{topic}' at {shown}")
    return f": no board in {' or '.join(named)}" if named else ""


# --- the import ------------------------------------------------------------------------------------------------


@dataclass
class _Recording:
    """What the import takes from a bag: the joint states, the still periods and each period's images."""

    topics: list[str]  # image topics, in the order of the sensor's roles
    joint_states: int
    periods: list[StillPeriod]
    images: list[dict[str, tuple[float, Any, str] | None]]  # per period, topic -> (time s, message, type)


def _read_recording(
    reader: AnyReader,
    bag: Path,
    profile: Profile,
    roles: list[str],
    joint_topic: str,
    image_topics: Sequence[str] | None,
    still_deg_s: float,
    still_s: float,
) -> _Recording:
    joint_conns = _topic_type(reader, bag, joint_topic, [JOINT_STATE], "joint state")
    topics = list(image_topics) if image_topics else _default_image_topics(reader, bag, roles)
    if len(topics) != len(roles):
        raise InputError(
            f"robot '{profile.name}' needs {len(roles)} image topic(s) ({', '.join(roles)}), "
            f"got {len(topics)}: {', '.join(topics)}"
        )
    if len(set(topics)) != len(topics):
        raise InputError(f"the image topics must differ, got {', '.join(topics)}")
    image_conns = {t: _topic_type(reader, bag, t, IMAGE_TYPES, "image") for t in topics}
    joint_times, joints_rad = _read_joint_states(reader, bag, joint_conns, joint_topic, profile)
    if not joint_times:
        raise InputError(f"topic '{joint_topic}' has no joint states", file=str(bag))
    refs = {t: _index_images(reader, bag, image_conns[t], t) for t in topics}

    # One clock: header stamps when every message has one, else the bag's record times.
    use_stamps = all(s.stamp_ns > 0 for s in [*joint_times, *(r.time for rs in refs.values() for r in rs)])

    def ns(s: _Stamped) -> int:
        return s.stamp_ns if use_stamps else s.log_ns

    order = np.argsort([ns(s) for s in joint_times], kind="stable")
    t0_ns = ns(joint_times[int(order[0])])
    times_s = np.array([(ns(joint_times[i]) - t0_ns) / 1e9 for i in order])
    periods = find_still_periods(times_s, joints_rad[order], still_deg_s=still_deg_s, still_s=still_s)
    if not periods:
        raise InputError(
            f"the robot never stood still (at most {still_deg_s:g} deg/s for {still_s:g} s) in the "
            f"{times_s[-1]:.1f} s of joint states on '{joint_topic}'",
            file=str(bag),
        )
    image_times = {t: np.array([(ns(r.time) - t0_ns) / 1e9 for r in refs[t]]) for t in topics}
    chosen = [{t: _closest(image_times[t], period) for t in topics} for period in periods]
    wanted = {t: {refs[t][c[t]].ordinal for c in chosen if c[t] is not None} for t in topics}
    loaded = {t: _load_images(reader, bag, image_conns[t], t, wanted[t]) for t in topics}
    images: list[dict[str, tuple[float, Any, str] | None]] = []
    for pick in chosen:
        images.append(
            {
                t: None if c is None else (float(image_times[t][c]), *loaded[t][refs[t][c].ordinal])
                for t, c in pick.items()
            }
        )
    return _Recording(topics, len(joint_times), periods, images)


def _frame_images(
    picked: dict[str, Any],
    roles: list[str],
    topics: list[str],
    period: StillPeriod,
    size_px: tuple[int, int] | None,
    profile: Profile,
    bag: Path,
) -> tuple[dict[str, np.ndarray], str, dict[str, Any]]:
    """The images of one still period by role, why they cannot be used ("" if they can), and where
    in the bag they came from. Images of another size than the camera's are bad input."""
    detail: dict[str, Any] = {"still_s": [round(period.start_s, 3), round(period.end_s, 3)], "images_s": {}}
    images: dict[str, np.ndarray] = {}
    problem = ""
    for role, topic in zip(roles, topics, strict=True):
        entry = picked[topic]
        if entry is None:
            problem = problem or f"no image on '{topic}' during the still period"
            continue
        time_s, msg, msgtype = entry
        detail["images_s"][role] = round(time_s, 3)
        image = decode_image(msg, msgtype, topic, str(bag))
        if image is None:
            problem = problem or f"the image on '{topic}' cannot be decoded"
            continue
        if size_px is None or image.shape != (size_px[1], size_px[0]):
            raise InputError(
                f"topic '{topic}': images of {image.shape[1]} x {image.shape[0]} px, but the camera of robot "
                f"'{profile.name}' (its intrinsics) has {size_px[0]} x {size_px[1]} px",  # type: ignore[index]
                file=str(bag),
            )
        images[role] = image
    return images, problem, detail


def import_bag(
    bag: str | Path,
    profile: Profile,
    out: str | Path,
    *,
    joint_topic: str = DEFAULT_JOINT_TOPIC,
    image_topics: Sequence[str] | None = None,
    still_deg_s: float = DEFAULT_STILL_DEG_S,
    still_s: float = DEFAULT_STILL_S,
    name: str | None = None,
    believed: np.ndarray | None = None,
    made_by: str = "calib import-bag",
) -> BagImport:
    """Read a bag, find the still periods, detect, and write the session folder `out` (whole or not at all).

    `image_topics`: the left and right camera's topics for a stereo head, the camera's for a camera
    (default: the bag's only image topic; for a stereo head the two naming left and right).
    `believed`: the calibration the robot ran with, internal units (seeds the detectors, gives the head's
    intrinsics); default the profile's nominal model. Bad input (file, topic, joint, option) is an
    InputError naming it, before anything is written.
    """
    bag = Path(bag)
    if not (math.isfinite(still_deg_s) and still_deg_s > 0):
        raise InputError(f"--still-deg-s {still_deg_s} must be a positive speed in deg/s")
    if not (math.isfinite(still_s) and still_s > 0):
        raise InputError(f"--still-s {still_s} must be a positive duration in s")
    sensor, roles = _image_roles(profile)
    believed = profile.nominal() if believed is None else np.asarray(believed, dtype=float)
    size_px = sensor.image_size_px()

    reader = _open_reader(bag)
    try:
        rec = _read_recording(reader, bag, profile, roles, joint_topic, image_topics, still_deg_s, still_s)
    except OSError as exc:
        raise InputError(f"cannot be read ({exc.strerror or exc})", file=str(bag)) from None
    finally:
        reader.close()

    captures: list[Capture] = []
    frames: list[FrameRecord] = []
    images: dict[int, dict[str, np.ndarray]] = {}
    for k, (period, picked) in enumerate(zip(rec.periods, rec.images, strict=True)):
        frame = k + 1
        frame_images, problem, bag_detail = _frame_images(picked, roles, rec.topics, period, size_px, profile, bag)
        q = period.joints_rad
        if problem:
            t = profile.data.target if profile.data.target is not None else 0
            sighting = Sighting(
                profile.data.sensor,
                t,
                FrameStatus.NOT_FOUND,
                problem,
                None,
                np.full((1, 3), np.nan),
                np.array([-1]),
                {},
            )
        else:
            sighting = _sight(profile, believed, q, frame_images)
        captures.append(Capture(frame, q, sighting, frame_images))
        if frame_images:
            images[frame] = frame_images
        joints_deg = {j.name: round(float(np.degrees(v)), 6) for j, v in zip(profile.joints, q, strict=True)}
        frames.append(
            FrameRecord(frame, joints_deg, sighting.status, sighting.reason, {}, {**sighting.detail, "bag": bag_detail})
        )
    without_image = sum(c.sighting.reason.startswith("no image") for c in captures)

    measured = sum(c.sighting.status == FrameStatus.MEASURED for c in captures)
    role_topics = dict(zip(roles, rec.topics, strict=True))
    if not measured:
        reasons = sorted({c.sighting.reason for c in captures})
        raise InputError(
            f"{len(rec.periods)} still periods, but the detector measured none of them ({'; '.join(reasons)})"
            + _images_named(frames, role_topics),
            file=str(bag),
        )
    data = dataset_from_captures(profile, captures, f"ROS bag {bag.name}")
    description = (
        f"Imported from the ROS bag {bag.name}: {len(rec.periods)} still periods (at most {still_deg_s:g} deg/s "
        f"for {still_s:g} s or longer on '{joint_topic}'), {measured} measured; images from "
        + ", ".join(f"{role} '{topic}'" for role, topic in role_topics.items())
        + "."
    )
    try:
        write_session(
            out,
            profile,
            name=name or Path(out).name,
            description=description,
            made_by=made_by,
            data=data,
            frames=frames,
            images=images,
        )
    except OSError as exc:
        raise InputError(f"cannot be written ({exc.strerror or exc})", file=str(out)) from None
    return BagImport(
        str(bag),
        str(out),
        joint_topic,
        role_topics,
        rec.joint_states,
        rec.periods,
        measured,
        len(rec.periods) - measured,
        without_image,
        frames,
    )
