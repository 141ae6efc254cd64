"""Where a ROS 2 robot's calibrated camera goes: the connection file's `apply.frames` (specs ros2.md) names the
calibrated URDF's links as the robot's TF does. The hand-eye arm (`calib sim-ros2 --robot arm-handeye`, a process
of its own) and `calib serve --ros2` with the camera's, the flange's and the board's links named: a calibration of
an imported session applied, robot_state_publisher receives the URDF with those links, each at the calibration's
pose in its named parent (computed here from the profile's kinematics), and the launch file written beside it holds
the same poses. A connection file whose names do not fit is refused before the desk starts."""

from __future__ import annotations

import ast
import importlib.util
import xml.etree.ElementTree as ET
from dataclasses import replace
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest
import yaml
from scipy.spatial.transform import Rotation

from app.cli import main
from calib_core import load_profile
from calib_core.estimation.calibration import Calibration
from calib_core.model.kinematics import forward

HAVE_RCLPY = importlib.util.find_spec("rclpy") is not None
pytestmark = pytest.mark.skipif(
    not HAVE_RCLPY, reason="rclpy is not installed: the ROS 2 tests need the ros2 extra (pip install -e '.[test,ros2]')"
)

PROFILE = "arm-handeye"
ROBOT = "arm-ros"
# The profile's frame -> the link name the robot's TF uses; the frame's parent in the profile.
FRAMES = {"camera_mount": "camera_color_optical_frame", "tool0": "flange", "board_frame": "charuco_board"}
PARENTS = {"camera_mount": "tool0", "tool0": "wrist_3_link", "board_frame": "base_link"}
METRES, RADIANS = 1e-6, 1e-6


def connection(path: Path, frames: object, node: bool = True) -> Path:
    """The arm's connection file as `calib sim-ros2 --connection-out` writes it, with `apply.frames` (and without
    the node to set unless `node`)."""
    from app.drivers.ros2.sim_node import Topics, connection_doc

    doc = connection_doc(PROFILE, ROBOT, load_profile(PROFILE), Topics(), speed=8)
    doc["apply"] = {**(doc["apply"] if node else {}), "frames": frames}
    path.write_text(yaml.safe_dump({**doc, "wait_s": 120}, sort_keys=False), encoding="utf-8")
    return path


@pytest.fixture(scope="module")
def applied(tmp_path_factory: pytest.TempPathFactory) -> SimpleNamespace:
    """A handeye calibration of 10 simulated views of the board, applied on the graph: the desk's answer, the
    description the robot re-published, the files the driver wrote and the calibration's parameters."""
    from ros2_graph import Sim, Watcher, graph_env, served_ros2, wait_done, wait_until

    folder = tmp_path_factory.mktemp("tf_static")
    env = graph_env()
    csv = folder / "views.csv"
    assert main(["simulate", "--robot", PROFILE, "--configurations", "10", "--seed", "3", "--out", str(csv)]) == 0
    conn = connection(folder / "arm.yaml", FRAMES)
    sim = Sim(["--robot", PROFILE, "--speed", "8", "--rate", "50"], env)
    with pytest.MonkeyPatch.context() as mp:
        for key, value in env.items():
            mp.setenv(key, value)  # the watcher in this process joins the same graph
        watcher = Watcher().start()
        try:
            sim.launch()  # the desk starts meanwhile and waits for the robot (wait_s)
            with served_ros2(conn, folder / "data", env) as server:
                sim.ready()
                form = {"robot": ROBOT, "name": "wrist camera"}
                imported = server.post(
                    "/api/sessions/import", data=form, files={"data": ("views.csv", csv.read_bytes())}
                )
                assert imported.status_code == 201, imported.text
                job = server.post(f"/api/sessions/{imported.json()['id']}/calibrations", json={"mode": "handeye"})
                cal_id = wait_done(server, job.json()["job"])["result"]
                exported = server.get(f"/api/calibrations/{cal_id}/export").json()
                before = len(watcher.descriptions)
                answer = server.post(f"/api/calibrations/{cal_id}/apply", json={"confirm": True})
                assert answer.status_code == 200, answer.text
                wait_until(lambda: len(watcher.descriptions) > before, "the robot re-publishes its description")
        finally:
            sim.stop()
            watcher.close()
    profile = replace(load_profile(PROFILE), name=ROBOT)  # the robot's name on the desk
    return SimpleNamespace(
        deployed=answer.json()["deployed"],
        description=watcher.descriptions[-1],
        files=folder / "data" / "ros2" / ROBOT,
        cal_id=cal_id,
        profile=profile,
        p=Calibration.from_dict(exported).params(profile),
    )


def expected_pose(run: SimpleNamespace, frame: str) -> np.ndarray:
    """The profile frame's pose in its parent frame (4 x 4, m) by the profile's kinematics at the calibration."""
    profile = run.profile
    scale = 1e-3 if profile.length_unit == "mm" else 1.0
    q = np.zeros((1, len(profile.joints)))
    pose = {}
    for name in (frame, PARENTS[frame]):
        T = np.eye(4)
        if name != profile.base:
            f = profile.frame(name)
            poses = forward(profile, run.p, q, frames=[f])
            T[:3, :3], T[:3, 3] = poses.R[f][0], poses.t[f][0] * scale
        pose[name] = T
    return np.linalg.inv(pose[PARENTS[frame]]) @ pose[frame]


def assert_same_pose(T: np.ndarray, expected: np.ndarray, what: str) -> None:
    off_m = np.linalg.norm(T[:3, 3] - expected[:3, 3])
    off_rad = Rotation.from_matrix(T[:3, :3].T @ expected[:3, :3]).magnitude()
    assert off_m < METRES and off_rad < RADIANS, (what, off_m, off_rad)


@pytest.mark.subprocess
def test_robot_state_publisher_receives_the_named_links_at_the_calibrated_poses(applied) -> None:
    run = applied
    assert (run.files / f"{run.cal_id}.urdf").read_text(encoding="utf-8") == run.description
    root = ET.fromstring(run.description)
    links = {el.get("name") for el in root.findall("link")}
    assert set(FRAMES.values()) <= links and not set(FRAMES) & links
    joints = {el.find("child").get("link"): el for el in root.findall("joint")}
    for frame, link in FRAMES.items():
        joint = joints[link]
        parent = PARENTS[frame]
        assert joint.get("type") == "fixed", link
        assert joint.find("parent").get("link") == FRAMES.get(parent, parent), link
        origin = joint.find("origin")
        T = np.eye(4)
        T[:3, :3] = Rotation.from_euler("xyz", [float(v) for v in origin.get("rpy").split()]).as_matrix()
        T[:3, 3] = [float(v) for v in origin.get("xyz").split()]
        assert_same_pose(T, expected_pose(run, frame), link)
    assert np.linalg.norm(expected_pose(run, "camera_mount")[:3, 3]) > 0.05  # found 60 mm off the flange's axis
    assert run.deployed == (
        "set robot_description of /robot_state_publisher to the calibrated URDF; /robot_state_publisher publishes "
        "camera_color_optical_frame under flange, flange under wrist_3_link and charuco_board under base_link on "
        f"/tf_static; wrote {run.cal_id}.urdf, {run.cal_id}.offsets.yaml and {run.cal_id}.tf_static.launch.py"
    )


@pytest.mark.subprocess
def test_the_launch_file_publishes_the_same_poses(applied) -> None:
    run = applied
    text = (run.files / f"{run.cal_id}.tf_static.launch.py").read_text(encoding="utf-8")
    nodes = [n for n in ast.walk(ast.parse(text)) if isinstance(n, ast.Call) and getattr(n.func, "id", "") == "Node"]
    published = {}
    for node in nodes:
        kw = {k.arg: ast.literal_eval(k.value) for k in node.keywords}
        assert (kw["package"], kw["executable"]) == ("tf2_ros", "static_transform_publisher")
        args = dict(zip(kw["arguments"][::2], kw["arguments"][1::2], strict=True))
        T = np.eye(4)
        T[:3, :3] = Rotation.from_quat([float(args[f"--{k}"]) for k in ("qx", "qy", "qz", "qw")]).as_matrix()
        T[:3, 3] = [float(args[f"--{k}"]) for k in "xyz"]
        published[args["--child-frame-id"]] = (args["--frame-id"], T)
    assert sorted(published) == sorted(FRAMES.values())
    for frame, link in FRAMES.items():
        parent, T = published[link]
        assert parent == FRAMES.get(PARENTS[frame], PARENTS[frame])
        assert_same_pose(T, expected_pose(run, frame), link)


@pytest.mark.parametrize(
    ("frames", "expected"),
    [
        ({"camera": "camera_optical_frame"}, "apply.frames.camera: no such frame in the profile (frames: base_link, "),
        ({"camera_mount": "wrist_3_link"}, "apply.frames.camera_mount: 'wrist_3_link' is the name of another link"),
        (
            {"camera_mount": "cam", "board_frame": "cam"},
            "apply.frames.camera_mount: 'cam' is the name apply.frames.board_frame gives too",
        ),
        ({"camera_mount": ""}, "apply.frames.camera_mount: expected a link name (a letter or _, then letters,"),
        ({"camera_mount": "camera frame"}, "apply.frames.camera_mount: expected a link name"),
        ([], "apply.frames: expected {profile frame: link name}"),
    ],
)
def test_serve_refuses_apply_frames_that_do_not_fit(frames, expected, tmp_path, capsys) -> None:
    bad = connection(tmp_path / "bad.yaml", frames)
    code = main(["serve", "--ros2", str(bad), "--data-dir", str(tmp_path / "data")])
    err = capsys.readouterr().err
    assert code == 2 and f"{bad}: {expected}" in err and "Traceback" not in err, err
    assert not (tmp_path / "data").exists()


def test_without_robot_state_publisher_apply_writes_the_launch_file_of_the_fixed_links(tmp_path) -> None:
    """`apply: {frames}` alone (no node to set): apply writes the renamed URDF and the launch file, which publishes
    the named links on fixed joints only (a link a joint moves is robot_state_publisher's, on /tf); the renamed base
    is the tree's root (no pose)."""
    from test_export import _calibration

    from app.drivers.ros2.connection import load_connection
    from app.drivers.ros2.driver import ros2_driver
    from app.drivers.ros2.link import Link

    frames = {"camera_mount": "camera_optical_frame", "wrist_3_link": "link6", "base_link": "world"}
    conn = load_connection(connection(tmp_path / "arm.yaml", frames, node=False))
    profile = conn.load_profile(None)
    p = profile.nominal()
    p[[profile.param(f"camera_mount.{k}") for k in ("y", "yaw")]] = 60.0, np.radians(2.0)  # mm, rad
    driver = ros2_driver(profile, conn, Link("tf_static_test"), files=tmp_path / "files")  # no graph traffic
    try:
        done = driver.deploy("c1", _calibration(profile, p, "handeye"))
    finally:
        driver.close()
    assert done == (
        "wrote c1.urdf, c1.offsets.yaml and c1.tf_static.launch.py; c1.tf_static.launch.py publishes "
        "camera_optical_frame under tool0 on /tf_static"
    )
    root = ET.fromstring((tmp_path / "files" / "c1.urdf").read_text(encoding="utf-8"))
    parents = {el.find("child").get("link"): el.find("parent").get("link") for el in root.findall("joint")}
    assert parents["shoulder_link"] == "world" and parents["camera_optical_frame"] == "tool0"
    assert parents["link6"] == "wrist_2_link" and parents["tool0"] == "link6"
    text = (tmp_path / "files" / "c1.tf_static.launch.py").read_text(encoding="utf-8")
    assert text.count("static_transform_publisher") == 1
    assert '"--y", "0.06"' in text and '"--frame-id", "tool0", "--child-frame-id", "camera_optical_frame"' in text


def test_a_profile_of_the_graphs_urdf_has_its_names_checked_against_the_urdf_received(tmp_path) -> None:
    """`urdf: ros2` (the demo arm): the links are known once the robot's URDF is received, and `calib serve` checks
    apply.frames against that URDF's links then (connect(), before the desk starts)."""
    from app.drivers.ros2.connection import check_against, load_connection
    from calib_core import InputError

    arm = Path(__file__).resolve().parent.parent / "docs" / "ros2"
    doc = yaml.safe_load((arm / "arm-connection.yaml").read_text(encoding="utf-8"))
    doc["profile"] = str(arm / doc["profile"])
    for tool, expected in (("flange", None), ("wrist_2_link", "'wrist_2_link' is the name of another link")):
        doc["apply"]["frames"] = {"mocap": "mocap_optical_frame", "tool0": tool}
        path = tmp_path / "arm.yaml"
        path.write_text(yaml.safe_dump(doc), encoding="utf-8")
        conn = load_connection(path)  # no URDF yet: the profile's links are not known
        received = arm / "arm.urdf"
        profile = conn.load_profile(received)
        if expected is None:
            check_against(conn, profile, received)
            continue
        with pytest.raises(InputError) as refused:
            check_against(conn, profile, received)
        assert str(refused.value).startswith(f"{path}: apply.frames.tool0: {expected}")
