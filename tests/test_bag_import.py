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
from pathlib import Path

import cv2
import numpy as np
import pytest
from rosbags.typesys import Stores, get_typestore

from app.cli import main
from calib_core import InputError, load_profile
from calib_core.io.bag_import import (
    DEFAULT_STILL_DEG_S,
    DEFAULT_STILL_S,
    decode_image,
    find_still_periods,
    import_bag,
    speeds_deg_s,
)
from calib_core.io.session import read_session
from calib_core.sim.recorded_drive import BagSpec, Drive, Images, camera_images
from calib_core.sim.recorded_drive import make_drive as _drive
from calib_core.sim.recorded_drive import write_bag as _write_bag
from calib_core.vision.stereo import StereoHead, render_pair

# --- fixtures ---------------------------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def nao_drive() -> tuple[Drive, Images]:
    """4 poses (two per leg), each held 1 s; 1 s moves, one of them with a 0.45 s pause halfway; 4 images/s."""
    drive = _drive("nao", 4, seed=7, hold_s=1.0, move_s=1.0, pause_at=1)
    return drive, camera_images(drive, 4.0)


@pytest.fixture(scope="module")
def nao_bags(nao_drive: tuple[Drive, Images], tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    d = tmp_path_factory.mktemp("bags")
    drive, images = nao_drive
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


@pytest.mark.slow
@pytest.mark.parametrize("ros", ["ros1", "ros2"])
def test_nao_bag_gives_one_frame_per_held_pose(ros: str, nao_drive, nao_bags, tmp_path: Path) -> None:
    drive, images = nao_drive
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


@pytest.mark.slow
def test_header_stamps_missing_uses_the_record_times(nao_drive, tmp_path: Path) -> None:
    """Zero stamps everywhere: the bag's record times (images 30 ms late) give the same periods."""
    drive, images = nao_drive
    bag = _write_bag(tmp_path / "nostamps.bag", drive, images, BagSpec(ros=1, stamps=False))
    result = import_bag(bag, drive.robot.profile, tmp_path / "s")
    assert len(result.still_periods) == len(drive) and result.measured == len(drive)


@pytest.mark.slow
def test_a_frame_whose_detector_finds_nothing_is_kept(nao_drive, tmp_path: Path) -> None:
    """The last hold's images are blank: that frame stays, "not found", with its joints and image."""
    drive, images = nao_drive
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


@pytest.mark.slow
def test_a_still_period_without_an_image_is_kept_as_not_found(nao_drive, tmp_path: Path) -> None:
    drive, images = nao_drive
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


@pytest.mark.slow
def test_robonaut_stereo_bag(tmp_path: Path) -> None:
    """3 poses held 0.8 s, pairs at 3 Hz on ROS 2: the BallFinder's centres are the true ones to millimetres."""
    drive = _drive("robonaut-a", 3, seed=11, hold_s=0.8, move_s=0.6)
    images = camera_images(drive, 3.0, start_s=0.07, seed=2)
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


@pytest.mark.subprocess
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


@pytest.mark.slow
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


@pytest.mark.slow
def test_a_joint_no_message_names_is_an_error(nao_drive, tmp_path: Path) -> None:
    drive, images = nao_drive
    bag = _write_bag(tmp_path / "nohead.bag", drive, images, BagSpec(ros=1, drop_joint="HeadPitch"))
    with pytest.raises(InputError, match=r"joint 'HeadPitch' of robot 'nao' is in no message on topic '/joint_states'"):
        import_bag(bag, drive.robot.profile, tmp_path / "s")
    assert not (tmp_path / "s").exists()


@pytest.mark.slow
def test_images_of_another_size_are_an_error(nao_drive, tmp_path: Path) -> None:
    drive, images = nao_drive
    small = Images(images.times_s, {"image": [cv2.resize(p, (320, 240)) for p in images.pictures["image"]]})
    bag = _write_bag(tmp_path / "small.bag", drive, small, BagSpec(ros=1))
    with pytest.raises(InputError, match=r"images of 320 x 240 px.*640 x 480 px"):
        import_bag(bag, drive.robot.profile, tmp_path / "s")


def test_defaults_are_documented() -> None:
    doc = (Path(__file__).resolve().parents[1] / "docs" / "bag-import.md").read_text()
    assert f"{DEFAULT_STILL_DEG_S:g} deg/s" in doc and f"{DEFAULT_STILL_S:g} s" in doc
