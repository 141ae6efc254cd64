"""ROS bags into sessions (calib_core.bag_import, `calib import-bag`), on bags the tests write with rosbags.

The simulated robot drives through a few poses and holds each for a second; its joint states are
published at 50 Hz (the encoders' rounding plus a flicker of one step), its camera images a few times a
second, rendered by the simulator at wherever the robot is, moving or not. The import must find exactly
the held poses (not a short pause, not a reversal), read the joints there to the encoders' tolerance, and
measure what the simulator's truth says the camera saw.
"""

from __future__ import annotations

import json
import math
import subprocess
import sys
from dataclasses import dataclass, field
from pathlib import Path

import cv2
import numpy as np
import pytest
from rosbags.rosbag1 import Writer as Writer1
from rosbags.rosbag2 import Writer as Writer2
from rosbags.typesys import Stores, get_typestore

from app.cli import main
from calib_core import InputError, SimulatedRobot, load_profile
from calib_core.io.bag_import import (
    DEFAULT_STILL_DEG_S,
    DEFAULT_STILL_S,
    decode_image,
    find_still_periods,
    import_bag,
    speeds_deg_s,
)
from calib_core.io.session import read_session
from calib_core.vision.sandal_board import render_board_image
from calib_core.vision.stereo import StereoHead, render_pair

EPOCH_NS = 1_700_000_000 * 10**9
JOINT_RATE_HZ = 50.0


# --- a recorded drive ------------------------------------------------------------------------------------------


@dataclass
class Drive:
    """A robot driven through poses (rad, the readings the robot reports unrounded), holding each."""

    robot: SimulatedRobot
    poses_rad: np.ndarray  # (P, n_joints)
    targets: np.ndarray  # (P,)
    hold_s: float
    move_s: float
    pause_at: int | None = None  # in this move the robot stops halfway (0.45 s: too short to count)
    joint_times_s: np.ndarray = field(init=False)
    joint_readings_rad: np.ndarray = field(init=False)

    def holds(self) -> list[tuple[float, float]]:
        return [
            (k * (self.hold_s + self.move_s), k * (self.hold_s + self.move_s) + self.hold_s) for k in range(len(self))
        ]

    def __len__(self) -> int:
        return len(self.poses_rad)

    @property
    def duration_s(self) -> float:
        return len(self) * self.hold_s + (len(self) - 1) * self.move_s

    def at(self, t_s: float) -> tuple[np.ndarray, int]:
        """Where the robot is at time t, and the target of the pose it is nearest in time."""
        period = self.hold_s + self.move_s
        k = min(int(t_s // period), len(self) - 1)
        into = t_s - k * period
        if into <= self.hold_s or k == len(self) - 1:
            return self.poses_rad[k].copy(), int(self.targets[k])
        s = (into - self.hold_s) / self.move_s
        w = 0.5 - 0.5 * math.cos(math.pi * s)  # smooth start and stop
        if self.pause_at == k:  # two smooth half moves, 0.45 of the move time still between them
            u = min(s / 0.275, 1.0) if s < 0.725 else (s - 0.725) / 0.275
            w = (0.0 if s < 0.725 else 0.5) + 0.25 - 0.25 * math.cos(math.pi * u)
        q = (1 - w) * self.poses_rad[k] + w * self.poses_rad[k + 1]
        return q, int(self.targets[k if w < 0.5 else k + 1])

    def record_joints(self, rng: np.random.Generator) -> None:
        self.joint_times_s = np.arange(0.0, self.duration_s, 1 / JOINT_RATE_HZ)
        q = np.array([self.at(t)[0] for t in self.joint_times_s])
        flicker = rng.normal(0.0, math.radians(0.03), q.shape)  # near a step's edge the reading flips
        self.joint_readings_rad = self.robot.readings(q + flicker)


def _drive(profile_name: str, n_poses: int, seed: int, **kwargs) -> Drive:
    profile = load_profile(profile_name)
    robot = SimulatedRobot.from_profile(profile, seed=seed)
    q, targets = robot.configurations(n_poses)
    pick = np.linspace(0, len(q) - 1, n_poses).round().astype(int)  # NAO: both legs' boards
    drive = Drive(robot, q[pick], targets[pick], **kwargs)
    drive.record_joints(np.random.default_rng(seed))
    return drive


@dataclass
class Images:
    """Camera images of a drive: per role, times (s from the start) and pictures (grey uint8)."""

    times_s: np.ndarray
    pictures: dict[str, list[np.ndarray]]


def _nao_images(drive: Drive, rate_hz: float) -> Images:
    times = np.arange(0.11, drive.duration_s, 1 / rate_hz)
    rng = np.random.default_rng(1)
    prof, p = drive.robot.profile, drive.robot.true_params
    pictures = []
    for t in times:
        q, target = drive.at(t)
        pictures.append(render_board_image(prof, p, q, target, rng).image)
    return Images(times, {"image": pictures})


def _stereo_images(drive: Drive, rate_hz: float) -> Images:
    times = np.arange(0.07, drive.duration_s, 1 / rate_hz)
    rng = np.random.default_rng(2)
    prof, p = drive.robot.profile, drive.robot.true_params
    head = StereoHead.from_profile(prof, p, prof.sensors[prof.data.sensor].name)
    pairs = [render_pair(prof, p, drive.at(t)[0], head, rng) for t in times]
    return Images(times, {"left": [x.left for x in pairs], "right": [x.right for x in pairs]})


# --- writing bags ----------------------------------------------------------------------------------------------


@dataclass
class BagSpec:
    ros: int  # 1 or 2
    joint_topic: str = "/joint_states"
    image_topics: dict[str, str] = field(default_factory=lambda: {"image": "/camera/image"})
    compressed: bool = False
    stamps: bool = True  # header stamps; False: zero stamps, the bag's record times only
    drop_joint: str | None = None  # leave this joint out of every message
    names: dict[str, str] = field(default_factory=dict)  # profile joint -> name in the messages


def _write_bag(path: Path, drive: Drive, images: Images, spec: BagSpec) -> Path:
    """The drive as a ROS 1 or ROS 2 bag; images are received 30 ms after their stamp."""
    store = get_typestore(Stores.ROS1_NOETIC if spec.ros == 1 else Stores.ROS2_HUMBLE)
    types = store.types
    Time, Header = types["builtin_interfaces/msg/Time"], types["std_msgs/msg/Header"]
    serialize = store.serialize_ros1 if spec.ros == 1 else store.serialize_cdr

    def header(t_s: float, seq: int) -> object:
        ns = EPOCH_NS + round(t_s * 1e9) if spec.stamps else 0
        stamp = Time(sec=ns // 10**9, nanosec=ns % 10**9)
        return Header(seq=seq, stamp=stamp, frame_id="") if spec.ros == 1 else Header(stamp=stamp, frame_id="")

    messages = []  # (record time ns, topic, type, message)
    prof = drive.robot.profile
    names = [spec.names.get(j.name, j.name) for j in prof.joints]
    keep = [i for i, j in enumerate(prof.joints) if j.name != spec.drop_joint]
    JointState = types["sensor_msgs/msg/JointState"]
    for k, (t, q) in enumerate(zip(drive.joint_times_s, drive.joint_readings_rad, strict=True)):
        msg = JointState(
            header=header(t, k),
            name=[names[i] for i in keep],
            position=q[keep].astype(np.float64),
            velocity=np.zeros(0),
            effort=np.zeros(0),
        )
        messages.append((EPOCH_NS + round(t * 1e9) + 2_000_000, spec.joint_topic, JointState.__msgtype__, msg))
    for role, topic in spec.image_topics.items():
        for k, (t, picture) in enumerate(zip(images.times_s, images.pictures[role], strict=True)):
            if spec.compressed:
                ok, buf = cv2.imencode(".jpg", picture, [cv2.IMWRITE_JPEG_QUALITY, 95])
                assert ok
                typ = types["sensor_msgs/msg/CompressedImage"]
                msg = typ(header=header(t, k), format="jpeg", data=buf.ravel())
            else:
                typ = types["sensor_msgs/msg/Image"]
                h, w = picture.shape
                msg = typ(
                    header=header(t, k),
                    height=h,
                    width=w,
                    encoding="mono8",
                    is_bigendian=0,
                    step=w,
                    data=picture.ravel(),
                )
            messages.append((EPOCH_NS + round(t * 1e9) + 30_000_000, topic, typ.__msgtype__, msg))
    messages.sort(key=lambda m: m[0])
    writer = Writer1(path) if spec.ros == 1 else Writer2(path, version=9)
    with writer:
        conns = {}
        for _, topic, typ, _ in messages:
            if topic not in conns:
                conns[topic] = writer.add_connection(topic, typ, typestore=store)
        for ns, topic, typ, msg in messages:
            writer.write(conns[topic], ns, serialize(msg, typ))
    return path


# --- fixtures ---------------------------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def nao() -> tuple[Drive, Images]:
    """4 poses (two per leg), each held 1 s; 1 s moves, one of them with a 0.45 s pause halfway; 4 images/s."""
    drive = _drive("nao", 4, seed=7, hold_s=1.0, move_s=1.0, pause_at=1)
    return drive, _nao_images(drive, 4.0)


@pytest.fixture(scope="module")
def nao_bags(nao: tuple[Drive, Images], tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    d = tmp_path_factory.mktemp("bags")
    drive, images = nao
    return {
        "ros1": _write_bag(d / "nao.bag", drive, images, BagSpec(ros=1)),
        "ros2": _write_bag(d / "nao_ros2", drive, images, BagSpec(ros=2, compressed=True)),
    }


def _exact(drive: Drive) -> np.ndarray:
    """What the camera truly saw of each held pose: (P, K, dim), noise-free."""
    sim = drive.robot.measure(drive.poses_rad, drive.targets)
    return sim.exact.reshape(len(drive), -1, sim.exact.shape[1])


# --- still periods ---------------------------------------------------------------------------------------------


def test_still_periods_are_the_held_poses_only() -> None:
    """Encoder flicker does not break a hold; a reversal and a 0.3 s pause between two moves make no period;
    a gap in the joint states splits a hold; the median reading is the held pose."""
    t = np.arange(0.0, 10.5, 0.01)

    def ramp(t0: float, t1: float, rad: float) -> np.ndarray:
        return rad * np.clip((t - t0) / (t1 - t0), 0.0, 1.0)

    q = np.zeros((len(t), 2))
    q[:, 0] = ramp(2.0, 3.0, 0.5) + ramp(7.5, 7.8, 0.1) + ramp(8.1, 8.4, 0.1)  # moves; 7.8-8.1 s a pause
    q[:, 1] = np.where((t > 5) & (t < 6), 0.3 * np.sin((t - 5) * np.pi), 0.0)  # out and back by 6 s
    rng = np.random.default_rng(0)
    step = math.radians(0.1)
    q_read = np.round((q + rng.normal(0, math.radians(0.03), q.shape)) / step) * step
    keep = (t < 9.2) | (t > 9.8)  # 0.6 s without joint states inside the last hold
    periods = find_still_periods(t[keep], q_read[keep])
    holds = [(0.0, 2.0), (3.0, 5.0), (6.0, 7.5), (8.4, 9.2), (9.8, 10.5)]
    assert len(periods) == len(holds), [(p.start_s, p.end_s) for p in periods]
    for p, (a, b) in zip(periods, holds, strict=True):
        # The speed is a slope over 0.3 s: a hold's first and last 0.15 s may still count as moving.
        assert a - 0.01 <= p.start_s <= a + 0.2 and b - 0.2 <= p.end_s <= b + 0.01, (p, a, b)
        assert p.duration_s >= DEFAULT_STILL_S
        held = q[(t >= p.start_s) & (t <= p.end_s)]
        assert np.abs(p.joints_rad - held.mean(axis=0)).max() <= step  # the reading flickers between two steps
    # Slower thresholds and longer minimum durations only remove periods.
    assert len(find_still_periods(t[keep], q_read[keep], still_s=1.0)) == 3
    assert find_still_periods(t[keep], q_read[keep], still_deg_s=0.01) == []


def test_the_speed_is_the_fastest_joint_in_deg_per_s() -> None:
    t = np.arange(0.0, 2.0, 0.02)
    q = np.stack([np.radians(10.0) * t, np.radians(-40.0) * t], axis=1)
    speed = speeds_deg_s(t, q)
    assert speed == pytest.approx(np.full(len(t), 40.0), rel=1e-6)
    assert speeds_deg_s(t, np.zeros((len(t), 2))).max() == 0.0


# --- NAO: one camera, two boards ---------------------------------------------------------------------------------


@pytest.mark.parametrize("ros", ["ros1", "ros2"])
def test_nao_bag_gives_one_frame_per_held_pose(ros: str, nao, nao_bags, tmp_path: Path) -> None:
    drive, images = nao
    out = tmp_path / "session"
    result = import_bag(nao_bags[ros], drive.robot.profile, out)
    holds = drive.holds()
    # Exactly the held poses: one period inside each hold, none during the moves or the short pause.
    assert len(result.still_periods) == len(holds)
    for period, (a, b) in zip(result.still_periods, holds, strict=True):
        assert a - 0.05 <= period.start_s and period.end_s <= b + 0.05, (period, a, b)
        assert period.duration_s > 0.6
    assert result.measured == len(holds) and result.not_found == 0
    # The pause is there, and only the minimum duration keeps it out.
    assert len(find_still_periods(drive.joint_times_s, drive.joint_readings_rad, still_s=0.1)) == len(holds) + 1
    # The joints: the commanded pose, to the encoders' step.
    step = math.radians(0.1)
    for period, pose in zip(result.still_periods, drive.poses_rad, strict=True):
        assert np.abs(period.joints_rad - pose).max() <= step
    # The detections: what the true camera saw, to a fraction of a pixel (JPEG images in the ROS 2 bag).
    session = read_session(out)
    assert session.robot == "nao" and len(session.frames) == len(holds)
    data = session.data
    exact = _exact(drive)
    for c in range(data.n_configurations):
        pose = int(data.frame_ids[c]) - 1
        rows = data.cfg == c
        assert np.all(data.target[rows] == drive.targets[pose])
        err_px = np.linalg.norm(data.measured[rows] - exact[pose][data.vertex[rows]], axis=1)
        # The detector's own accuracy on these boards: RMS 0.05-0.12 px, single vertices up to 0.4 px.
        assert err_px.max() < 0.6 and np.sqrt(np.mean(err_px**2)) < 0.2, err_px
        used = np.isfinite(data.joints[c])  # NAO rows carry the joints of the head and the board's leg
        assert used.sum() == 8
        assert np.abs(np.degrees(data.joints[c, used] - drive.poses_rad[pose, used])).max() <= 0.1 + 1e-6
    # Each frame keeps the image taken nearest the middle of its still period, and the image is that one.
    for fr, period in zip(session.frames, result.still_periods, strict=True):
        assert fr.status == "measured" and set(fr.images) == {"image"}
        taken = fr.detail["bag"]["images_s"]["image"]
        inside = images.times_s[(images.times_s >= period.start_s) & (images.times_s <= period.end_s)]
        k = np.argmin(np.abs(inside - period.middle_s))
        assert taken == pytest.approx(inside[k], abs=1e-3)
        stored = cv2.imread(str(out / fr.images["image"]), cv2.IMREAD_GRAYSCALE)
        original = images.pictures["image"][int(np.flatnonzero(images.times_s == inside[k])[0])]
        assert np.abs(stored.astype(float) - original).mean() < 2.0  # the same picture, through JPEG


def test_header_stamps_missing_uses_the_record_times(nao, tmp_path: Path) -> None:
    """Zero stamps everywhere: the bag's record times (images 30 ms late) give the same periods."""
    drive, images = nao
    bag = _write_bag(tmp_path / "nostamps.bag", drive, images, BagSpec(ros=1, stamps=False))
    result = import_bag(bag, drive.robot.profile, tmp_path / "s")
    assert len(result.still_periods) == len(drive) and result.measured == len(drive)


def test_a_frame_whose_detector_finds_nothing_is_kept(nao, tmp_path: Path) -> None:
    """The last hold's images are blank: that frame stays, "not found", with its joints and image."""
    drive, images = nao
    a, b = drive.holds()[-1]
    blanked = Images(
        images.times_s,
        {
            "image": [
                np.zeros_like(p) if a <= t <= b else p
                for t, p in zip(images.times_s, images.pictures["image"], strict=True)
            ]
        },
    )
    bag = _write_bag(tmp_path / "blank.bag", drive, blanked, BagSpec(ros=1))
    result = import_bag(bag, drive.robot.profile, tmp_path / "s")
    assert (result.measured, result.not_found) == (len(drive) - 1, 1)
    session = read_session(tmp_path / "s")
    last = session.frames[-1]
    assert last.status == "not found" and last.reason
    assert last.images and session.data.n_configurations == len(drive) - 1
    assert (
        abs(last.joints_deg["HeadYaw"] - math.degrees(drive.poses_rad[-1][drive.robot.profile.joint("HeadYaw")])) < 0.11
    )


def test_a_still_period_without_an_image_is_kept_as_not_found(nao, tmp_path: Path) -> None:
    drive, images = nao
    a, b = drive.holds()[1]
    keep = (images.times_s < a) | (images.times_s > b)
    gappy = Images(
        images.times_s[keep], {"image": [p for p, k in zip(images.pictures["image"], keep, strict=True) if k]}
    )
    result = import_bag(
        _write_bag(tmp_path / "gap.bag", drive, gappy, BagSpec(ros=1)), drive.robot.profile, tmp_path / "s"
    )
    assert (result.measured, result.not_found, result.without_image) == (3, 1, 1)
    frame = read_session(tmp_path / "s").frames[1]
    assert frame.status == "not found" and frame.reason == "no image on '/camera/image' during the still period"
    assert frame.images == {}
    assert "(1 without an image)" in result.summary()


@pytest.mark.parametrize("encoding", ["mono8", "rgb8", "bgra8", "mono16", "jpeg", "png"])
def test_image_encodings_decode_to_the_same_grey(encoding: str) -> None:
    store = get_typestore(Stores.ROS2_HUMBLE)
    types = store.types
    header = types["std_msgs/msg/Header"](stamp=types["builtin_interfaces/msg/Time"](sec=1, nanosec=0), frame_id="")
    grey = (np.arange(48 * 64).reshape(48, 64) % 251).astype(np.uint8)
    if encoding in ("jpeg", "png"):
        ok, buf = cv2.imencode(f".{encoding}", grey, [cv2.IMWRITE_JPEG_QUALITY, 100] if encoding == "jpeg" else [])
        assert ok
        msg = types["sensor_msgs/msg/CompressedImage"](header=header, format=encoding, data=buf.ravel())
        msgtype = "sensor_msgs/msg/CompressedImage"
    else:
        pixels = {
            "mono8": grey,
            "rgb8": np.dstack([grey] * 3),
            "bgra8": np.dstack([grey] * 3 + [np.full_like(grey, 255)]),
            "mono16": grey.astype(">u2") * 257,  # big-endian, full 16-bit scale
        }[encoding]
        raw = np.ascontiguousarray(pixels).view(np.uint8).reshape(48, -1)
        step = raw.shape[1] + 8  # rows padded, as some drivers do
        data = np.zeros((48, step), np.uint8)
        data[:, : raw.shape[1]] = raw
        msg = types["sensor_msgs/msg/Image"](
            header=header,
            height=48,
            width=64,
            encoding=encoding,
            is_bigendian=int(encoding == "mono16"),
            step=step,
            data=data.ravel(),
        )
        msgtype = "sensor_msgs/msg/Image"
    image = decode_image(msg, msgtype, "/cam", "x.bag")
    assert image is not None and image.dtype == np.uint8 and image.shape == (48, 64)
    assert np.abs(image.astype(int) - grey).max() <= (8 if encoding == "jpeg" else 1)
    if encoding == "mono8":
        msg.encoding = "bayer_rggb8"
        with pytest.raises(InputError, match=r"x\.bag: topic '/cam': image encoding 'bayer_rggb8' is not supported"):
            decode_image(msg, msgtype, "/cam", "x.bag")


def test_joint_names_may_be_the_data_columns_and_a_fixed_joint_may_be_absent(tmp_path: Path) -> None:
    """Robonaut's neck_roll is fixed (limits 0, 0): a bag without it imports. A message may name a joint
    by the profile's data column for it; any other name leaves the joint missing."""
    drive = _drive("robonaut-a", 2, seed=3, hold_s=0.8, move_s=0.5)
    images = Images(np.array([0.4, 1.7]), {"left": [], "right": []})
    prof = drive.robot.profile
    head = StereoHead.from_profile(prof, drive.robot.true_params, "eye")
    rng = np.random.default_rng(0)
    for t in images.times_s:
        pair = render_pair(prof, drive.robot.true_params, drive.at(t)[0], head, rng)
        images.pictures["left"].append(pair.left)
        images.pictures["right"].append(pair.right)
    topics = {"left": "/head/left/image_raw", "right": "/head/right/image_raw"}
    bag = _write_bag(tmp_path / "r.bag", drive, images, BagSpec(ros=1, image_topics=topics, drop_joint="neck_roll"))
    result = import_bag(bag, prof, tmp_path / "s", believed=drive.robot.true_params)
    assert result.image_topics == topics  # found by their names, left and right
    assert len(result.still_periods) == 2 and result.measured == 2
    assert all(fr.joints_deg["neck_roll"] == 0.0 for fr in result.frames)

    renamed = BagSpec(ros=1, image_topics=topics, names={"elbow_roll": "r2/elbow_roll"})
    bag2 = _write_bag(tmp_path / "r2.bag", drive, images, renamed)
    with pytest.raises(InputError, match=r"joint 'elbow_roll'.*topic '/joint_states'"):
        import_bag(bag2, prof, tmp_path / "s2")
    assert not (tmp_path / "s2").exists()
    source = (Path(__file__).resolve().parents[1] / "calib_core" / "model" / "profiles" / "robonaut-a.yaml").read_text()
    assert source.count("    elbow_roll: elbow_roll\n") == 1  # the data section's column
    (tmp_path / "r2.yaml").write_text(source.replace("    elbow_roll: elbow_roll\n", "    elbow_roll: r2/elbow_roll\n"))
    columns = load_profile(tmp_path / "r2.yaml")
    result = import_bag(bag2, columns, tmp_path / "s2", believed=drive.robot.true_params)
    elbow = prof.joint("elbow_roll")
    for fr, pose in zip(result.frames, drive.poses_rad, strict=True):
        assert abs(fr.joints_deg["elbow_roll"] - math.degrees(pose[elbow])) <= 0.1 + 1e-6


# --- Robonaut: a stereo pair ---------------------------------------------------------------------------------------


def test_robonaut_stereo_bag(tmp_path: Path) -> None:
    """3 poses held 0.8 s, pairs at 3 Hz on ROS 2: the BallFinder's centres are the true ones to millimetres."""
    drive = _drive("robonaut-a", 3, seed=11, hold_s=0.8, move_s=0.6)
    images = _stereo_images(drive, 3.0)
    topics = {"left": "/stereo/left/image", "right": "/stereo/right/image"}
    bag = _write_bag(tmp_path / "rn", drive, images, BagSpec(ros=2, image_topics=topics))
    out = tmp_path / "session"
    # The robot ran with its true calibration: the detectors are seeded where the sphere is.
    left_right = [topics["left"], topics["right"]]
    result = import_bag(bag, drive.robot.profile, out, image_topics=left_right, believed=drive.robot.true_params)
    assert len(result.still_periods) == 3 and result.measured == 3
    data = read_session(out).data
    exact = _exact(drive)[:, 0]
    err_mm = 10 * np.linalg.norm(data.measured - exact[data.frame_ids - 1], axis=1)  # profile unit: cm
    assert err_mm.max() < 4.0 and np.median(err_mm) < 2.0, err_mm
    for fr in read_session(out).frames:
        assert set(fr.images) == {"left", "right"}


# --- the command and bad input ---------------------------------------------------------------------------------------


def test_the_command_writes_the_session(nao_bags, tmp_path: Path) -> None:
    """`calib import-bag` as a user runs it: exit 0, a summary line, a session the store can import."""
    out = tmp_path / "day1"
    calib = Path(sys.executable).with_name("calib")  # the installed command, as in test_cli
    cmd = [str(calib), "import-bag", str(nao_bags["ros1"]), "--robot", "nao"]
    proc = subprocess.run(
        [*cmd, "--out", str(out), "--name", "NAO from a bag"], capture_output=True, text=True, timeout=120, check=False
    )
    assert proc.returncode == 0, proc.stderr
    assert "4 still periods, 4 frames measured, 0 not found" in proc.stdout
    meta = json.loads((out / "session.json").read_text())
    assert meta["name"] == "NAO from a bag" and len(meta["frames"]) == 4
    assert read_session(out).data.n_configurations == 4


def _bad(argv: list[str], capsys: pytest.CaptureFixture[str]) -> str:
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert err.startswith("calib import-bag: error: ") and "Traceback" not in err
    return err


def test_bad_bags_exit_2_and_write_nothing(nao_bags, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "out"
    base = ["--robot", "nao", "--out", str(out)]
    assert "missing.bag: does not exist" in _bad(["import-bag", str(tmp_path / "missing.bag"), *base], capsys)
    text = tmp_path / "notes.bag"
    text.write_text("not a bag\n")
    assert "notes.bag: is not a ROS 1 or ROS 2 bag" in _bad(["import-bag", str(text), *base], capsys)
    folder = tmp_path / "folder"
    folder.mkdir()
    assert "is not a ROS 1 or ROS 2 bag" in _bad(["import-bag", str(folder), *base], capsys)
    bag = str(nao_bags["ros1"])
    err = _bad(["import-bag", bag, *base, "--joint-topic", "/robot/joints"], capsys)
    assert "no joint state topic '/robot/joints'" in err and "/joint_states (sensor_msgs/msg/JointState)" in err
    err = _bad(["import-bag", bag, *base, "--image-topic", "/camera/nope"], capsys)
    assert "no image topic '/camera/nope'" in err
    err = _bad(["import-bag", bag, *base, "--image-topic", "/joint_states"], capsys)
    assert "carries sensor_msgs/msg/JointState" in err
    err = _bad(["import-bag", bag, *base, "--image-topic", "/camera/image", "--image-topic", "/camera/image"], capsys)
    assert "needs 1 image topic" in err
    err = _bad(["import-bag", bag, *base, "--still-s", "30"], capsys)
    assert "never stood still" in err
    err = _bad(["import-bag", bag, *base, "--still-deg-s", "-1"], capsys)
    assert "--still-deg-s -1.0 must be a positive speed" in err
    err = _bad(["import-bag", bag, "--robot", "robonaut-a", "--out", str(out)], capsys)
    assert "give two image topics, left then right" in err
    assert not out.exists()
    assert [p.name for p in tmp_path.iterdir() if p.name.startswith(".out")] == []
    not_session = tmp_path / "docs"
    not_session.mkdir()
    err = _bad(["import-bag", bag, "--robot", "nao", "--out", str(not_session)], capsys)
    assert "exists and is not a session folder" in err


def test_a_joint_no_message_names_is_an_error(nao, tmp_path: Path) -> None:
    drive, images = nao
    bag = _write_bag(tmp_path / "nohead.bag", drive, images, BagSpec(ros=1, drop_joint="HeadPitch"))
    with pytest.raises(InputError, match=r"joint 'HeadPitch' of robot 'nao' is in no message on topic '/joint_states'"):
        import_bag(bag, drive.robot.profile, tmp_path / "s")
    assert not (tmp_path / "s").exists()


def test_images_of_another_size_are_an_error(nao, tmp_path: Path) -> None:
    drive, images = nao
    small = Images(images.times_s, {"image": [cv2.resize(p, (320, 240)) for p in images.pictures["image"]]})
    bag = _write_bag(tmp_path / "small.bag", drive, small, BagSpec(ros=1))
    with pytest.raises(InputError, match=r"images of 320 x 240 px.*640 x 480 px"):
        import_bag(bag, drive.robot.profile, tmp_path / "s")


def test_defaults_are_documented() -> None:
    doc = (Path(__file__).resolve().parents[1] / "docs" / "bag-import.md").read_text()
    assert f"{DEFAULT_STILL_DEG_S:g} deg/s" in doc and f"{DEFAULT_STILL_S:g} s" in doc
