"""The review scene's state in a real (in-process) viser server: nodes, colours, positions, URDF joints."""

from __future__ import annotations

import io
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import msgspec
import numpy as np
import pytest
import viser
import websockets.sync.client
import yourdfpy
import zstandard
from sim_frames import measured_frames, unmeasured_frames
from test_flange_pose import _looking_at_the_board, _pose, _rot, _synthetic_doc, _truth
from test_viewers import PROTOCOL, camera_message, wait_until

from app.errors import NotFound
from app.scene.framing import DEFAULT_FOV_RAD, camera_reported
from app.scene.review import Review
from app.scene.review_scene.layout import display_rotation
from app.scene.review_scene.scene import ReviewScene
from calib_core import SimulatedRobot, load_profile
from calib_core.estimation import register
from calib_core.model.flange_pose import readings, reference_rotation
from calib_core.model.kinematics import forward
from calib_core.model.loader import compile_profile
from calib_core.vision.sighting import Sighting

URDF_DIR = Path(__file__).resolve().parents[1] / "calib_core" / "model" / "profiles"
RED, BLUE, GREEN = [255, 0, 0], [0, 0, 255], [0, 200, 0]


@dataclass
class Look:
    readings_rad: np.ndarray
    sightings: list[Sighting]


def build(name: str, n: int, *, new: bool = True) -> Review:
    """n simulated measured frames and one more whose detector found nothing."""
    profile = load_profile(name)
    robot = SimulatedRobot.from_profile(profile, seed=2)
    sim = robot.simulate(n)
    frames = measured_frames(sim.data)
    frames += unmeasured_frames(robot, len(frames) + 1, 1)
    return Review.build(profile, frames, sim.data, profile.nominal(), sim.true_params if new else None)


@pytest.fixture(scope="module")
def robonaut_review() -> Review:
    return build("robonaut-a", 12)


def _points(state: dict, name: str) -> np.ndarray:
    node = state["nodes"][name]
    return np.array(node["points"] if "points" in node else node["segments"])


def test_select_shows_the_frame_on_both_copies(viser_server: viser.ViserServer, robonaut_review: Review) -> None:
    scene = ReviewScene(viser_server, URDF_DIR / "robonaut-a.urdf")
    assert scene.robot == "robonaut-a"
    scene.load(robonaut_review)
    assert scene.state()["index"] == 1
    scene.select(5)
    state = scene.state()
    g = robonaut_review.frame_geometry(5)
    assert state["index"] == 5 and not state["overlay"] and not state["all"]
    for side, color in (("old", BLUE), ("new", GREEN)):
        base = f"/review/{side}/base/frame"
        assert state["nodes"][f"{base}/measured"]["color"] == RED
        assert state["nodes"][f"{base}/predicted"]["color"] == color
        assert state["nodes"][f"{base}/lines"]["color"] == color
        for part in ("measured", "predicted", "lines"):
            assert state["nodes"][f"{base}/{part}"]["shown"]
            assert not state["nodes"][f"/review/{side}/base/all/{part}"]["shown"]
        np.testing.assert_allclose(_points(state, f"{base}/measured"), g.measured_m[side], atol=1e-6)
        np.testing.assert_allclose(_points(state, f"{base}/predicted"), g.predicted_m[side], atol=1e-6)
        segments = _points(state, f"{base}/lines")
        np.testing.assert_allclose(segments[:, 0], g.predicted_m[side], atol=1e-6)
        np.testing.assert_allclose(segments[:, 1], g.measured_m[side], atol=1e-6)
        joints = state["urdf"][side]["joints"]
        assert state["urdf"][side]["shown"]
        np.testing.assert_allclose([joints[n] for n in robonaut_review.profile.joint_names], g.joints_rad, atol=1e-12)
        assert state["nodes"][f"/review/{side}/label"]["text"] == f"{side} calibration"
    # Side by side along the world y: old on the left (-y), new on the right, apart by more than the robot.
    y_old = state["nodes"]["/review/old"]["position"][1]
    y_new = state["nodes"]["/review/new"]["position"][1]
    span_m = robonaut_review.bounds_m[1] - robonaut_review.bounds_m[0]
    assert y_new - y_old > span_m.max() * 0.5 and y_old < y_new
    assert "ghost" not in state["urdf"] and not state["live"]  # built when the overlay is first asked for


def test_overlay_and_show_all_change_the_scene(viser_server: viser.ViserServer, robonaut_review: Review) -> None:
    scene = ReviewScene(viser_server)
    scene.load(robonaut_review)
    scene.select(3)
    scene.set_overlay(True)
    state = scene.state()
    assert state["overlay"]
    assert state["nodes"]["/review/old"]["position"] == state["nodes"]["/review/new"]["position"]
    assert state["urdf"]["ghost"]["shown"] and not state["urdf"]["old"]["shown"] and state["urdf"]["new"]["shown"]
    # One label names both copies (two in one place would stack).
    assert not state["nodes"]["/review/old/label"]["shown"] and state["nodes"]["/review/new/label"]["shown"]
    assert state["nodes"]["/review/new/label"]["text"] == "old calibration (translucent) and new calibration"
    ghost = state["urdf"]["ghost"]["joints"]
    np.testing.assert_allclose(
        [ghost[n] for n in robonaut_review.profile.joint_names],
        robonaut_review.frame_geometry(3).joints_rad,
        atol=1e-12,
    )
    scene.set_overlay(False)
    state = scene.state()
    assert state["nodes"]["/review/old"]["position"] != state["nodes"]["/review/new"]["position"]
    assert state["urdf"]["old"]["shown"] and not state["urdf"]["ghost"]["shown"]
    assert (
        state["nodes"]["/review/old/label"]["shown"]
        and state["nodes"]["/review/new/label"]["text"] == "new calibration"
    )

    scene.show_all(True)
    state = scene.state()
    for side in ("old", "new"):
        measured, predicted = robonaut_review.all_points(side)
        assert len(measured) == 12  # the frame without a measurement has nothing to show here
        np.testing.assert_allclose(_points(state, f"/review/{side}/base/all/measured"), measured, atol=1e-6)
        np.testing.assert_allclose(_points(state, f"/review/{side}/base/all/predicted"), predicted, atol=1e-6)
        for part in ("measured", "predicted", "lines"):
            assert state["nodes"][f"/review/{side}/base/all/{part}"]["shown"]
            assert not state["nodes"][f"/review/{side}/base/frame/{part}"]["shown"]
    scene.show_all(False)
    assert scene.state()["nodes"]["/review/new/base/frame/predicted"]["shown"]


def test_a_frame_without_a_measurement_shows_only_its_prediction(
    viser_server: viser.ViserServer, robonaut_review: Review
) -> None:
    scene = ReviewScene(viser_server)
    scene.load(robonaut_review)
    scene.select(13)
    state = scene.state()
    for side in ("old", "new"):
        base = f"/review/{side}/base/frame"
        assert state["nodes"][f"{base}/predicted"]["shown"]
        assert not state["nodes"][f"{base}/measured"]["shown"] and not state["nodes"][f"{base}/lines"]["shown"]


def test_selecting_a_frame_that_is_not_there_is_a_clear_error(
    viser_server: viser.ViserServer, robonaut_review: Review
) -> None:
    scene = ReviewScene(viser_server)
    with pytest.raises(ValueError, match="no review is loaded"):
        scene.select(1)
    scene.load(robonaut_review)
    scene.select(2)
    with pytest.raises(NotFound, match=r"frame 0 is not in this review \(frames 1\.\.13\)"):
        scene.select(0)
    assert scene.state()["index"] == 2


def test_without_a_new_calibration_only_the_old_copy(viser_server: viser.ViserServer) -> None:
    scene = ReviewScene(viser_server)
    scene.load(build("robonaut-a", 4, new=False))
    state = scene.state()
    assert not state["nodes"]["/review/new"]["shown"] and state["nodes"]["/review/old"]["shown"]
    assert state["nodes"]["/review/old/base/frame/predicted"]["color"] == BLUE


def flange_review(*, new: bool) -> Review:
    """A robot known by its flange pose (calib_core/model/flange_pose.py), eye-in-hand: 8 frames of its camera
    looking at the board, simulated; the old side through the camera's and board's poses registered on them (as
    the desk reviews it), the new one (`new`) at the truth."""
    rng = np.random.default_rng(7)
    X = _pose(_rot(rng, 5), np.array([0.03, -0.05, 0.04]))
    Z = _pose(np.eye(3), np.array([0.6, 0.1, -0.2]))
    T = _looking_at_the_board(8, rng, X, Z)
    reference = reference_rotation(T[:, :3, :3])
    profile = compile_profile(_synthetic_doc(reference), "<test>")
    q = readings(T, reference)
    q[:, 3:] = np.radians(q[:, 3:])
    truth = _truth(profile, X, Z)
    data = SimulatedRobot(profile, truth, pixel_noise=0.3, seed=1).measure(q, np.zeros(len(q), int)).data
    old = register(profile, data, profile.nominal())
    return Review.build(profile, measured_frames(data), data, old, truth if new else None)


def test_a_robot_known_by_its_flange_pose_is_framed_on_what_its_review_shows(viser_server: viser.ViserServer) -> None:
    """Such a robot stands at its base at zero readings (its reading places the flange; the camera and the board
    hang from registration frames): the camera is framed on the selected frame as both copies show it, the flange
    where the reading puts it and the board's marks, from the review before its first calibration too (one copy;
    the calibration puts the new one beside it and leaves the camera where it is)."""
    scene = ReviewScene(viser_server)
    scene.load(flange_review(new=False))
    review = flange_review(new=True)
    scene.load(review)
    state = scene.state()
    assert state["nodes"]["/review/new"]["shown"] and state["index"] == review.indices[0]
    box = np.array(state["camera"]["framing"]["box_m"])
    profile = review.profile
    R = display_rotation(profile)
    flange = profile.frame("flange")
    geometry = review.frame_geometry(state["index"])
    for side in ("old", "new"):
        root = np.asarray(state["nodes"][f"/review/{side}"]["position"])
        poses = forward(profile, review.sides[side].p, geometry.joints_rad[None], frames=[flange])
        for what, points_m in (("flange", poses.t[flange] / 1000), ("board", geometry.measured_m[side])):
            world = points_m @ R.T + root
            # Within a mm: the copies of the review with both sides stand a hair apart from where the first review
            # put them (its bounds hold the new side's points too).
            outside = ~np.all((world >= box[0] - 1e-3) & (world <= box[1] + 1e-3), axis=1)
            assert not outside.any(), (side, what, world[outside], box)


def test_nao_board_and_switching_robots(viser_server: viser.ViserServer, robonaut_review: Review) -> None:
    scene = ReviewScene(viser_server)
    scene.load(robonaut_review)
    review = build("nao", 6)
    scene.load(review)
    scene.select(4)
    state = scene.state()
    g = review.frame_geometry(4)
    assert state["robot"] == "nao" and set(state["urdf"]["new"]["joints"]) == set(review.profile.joint_names)
    for side in ("old", "new"):
        assert len(_points(state, f"/review/{side}/base/frame/measured")) == 24
        np.testing.assert_allclose(_points(state, f"/review/{side}/base/frame/measured"), g.measured_m[side], atol=1e-6)
        joints = state["urdf"][side]["joints"]
        np.testing.assert_allclose([joints[n] for n in review.profile.joint_names], g.joints_rad, atol=1e-12)
    # NAO's torso has z up already; Robonaut's chest has y down and is turned upright.
    assert state["nodes"]["/review/old/base"]["wxyz"] == pytest.approx([1.0, 0.0, 0.0, 0.0])


def test_live_view_replaces_the_review_until_the_next_select(
    viser_server: viser.ViserServer, robonaut_review: Review
) -> None:
    scene = ReviewScene(viser_server)
    scene.load(robonaut_review)
    profile = robonaut_review.profile
    p = profile.true_params()
    q = robonaut_review.frame_geometry(2).joints_rad
    point_cm = np.array([[3.0, 60.0, -1.0]])  # a detection in the eye frame
    sighting = Sighting(0, 0, "measured", "ok", point_cm, np.full((1, 3), np.nan), np.array([-1]))
    scene.show_live(profile, Look(q, [sighting]), p)
    state = scene.state()
    assert state["live"] and state["nodes"]["/live"]["shown"]
    assert not state["nodes"]["/review/old"]["shown"] and not state["nodes"]["/review/new"]["shown"]
    joints = state["urdf"]["live"]["joints"]
    np.testing.assert_allclose([joints[n] for n in profile.joint_names], q, atol=1e-12)
    eye = profile.sensors[profile.data.sensor].frame
    poses = forward(profile, p, q[None], frames=[eye])
    expected_m = (poses.R[eye][0] @ point_cm[0] + poses.t[eye][0]) / 100
    np.testing.assert_allclose(_points(state, "/live/base/frame/measured")[0], expected_m, atol=1e-6)
    assert state["nodes"]["/live/base/frame/measured"]["color"] == RED
    assert state["nodes"]["/live/base/frame/predicted"]["color"] == BLUE
    scene.select(2)
    state = scene.state()
    assert not state["live"] and not state["nodes"]["/live"]["shown"] and state["nodes"]["/review/old"]["shown"]


def _link_nodes(urdf_text: str, node: str) -> set[str]:
    """The viser names the scene gives a URDF's links under `node`: visual/<links from the root's child down>."""
    urdf = yourdfpy.URDF.load(io.StringIO(urdf_text), build_scene_graph=False)
    parent = {j.child: j.parent for j in urdf.joint_map.values()}
    names = set()
    for link in urdf.link_map:
        chain = [link]
        while chain[-1] in parent:
            chain.append(parent[chain[-1]])
        if len(chain) > 1:  # the root link is the `visual` frame itself
            names.add(f"{node}/visual/" + "/".join(reversed(chain[:-1])))
    return names


def test_switching_robots_removes_everything_the_previous_one_showed(
    viser_server: viser.ViserServer, robonaut_review: Review
) -> None:
    """A Robonaut review (and its live view), then a NAO review: no node of a Robonaut copy is left in viser
    (what a browser gets), and the scene shows NAO's copies only."""
    scene = ReviewScene(viser_server, URDF_DIR / "robonaut-a.urdf")
    scene.load(robonaut_review)
    profile = robonaut_review.profile
    sighting = Sighting(0, 0, "measured", "ok", np.array([[3.0, 60.0, -1.0]]), np.full((1, 3), np.nan), np.array([-1]))
    scene.set_overlay(True)
    scene.show_live(profile, Look(robonaut_review.frame_geometry(2).joints_rad, [sighting]), profile.true_params())
    state = scene.state()
    assert set(state["urdf"]) == {"old", "ghost", "new", "live"}
    texts = {slot: scene.copies[slot].text for slot in state["urdf"]}
    before = {name for slot, c in state["urdf"].items() for name in _link_nodes(texts[slot], c["node"])}
    assert any(name.endswith("/wrist_yaw/fixture") for name in before)  # the arm and its sphere
    assert all(viser_server.scene.get_handle_by_name(name) is not None for name in before)

    nao = build("nao", 3, new=False)
    scene.load(nao)
    state = scene.state()
    assert state["robot"] == "nao" and not state["live"] and not state["nodes"]["/live"]["shown"]
    assert set(state["urdf"]) == {"old", "ghost"}  # no new calibration: no Robonaut copy stays on that side
    scene.set_overlay(False)
    left = sorted(name for name in before if viser_server.scene.get_handle_by_name(name) is not None)
    assert left == [], f"{len(left)} Robonaut nodes left, e.g. {left[:3]}"
    for c in state["urdf"].values():
        assert set(c["joints"]) == set(nao.profile.joint_names)
        nodes = _link_nodes(nao.urdf["old"], c["node"])
        assert all(viser_server.scene.get_handle_by_name(n) is not None for n in nodes)
    # Robonaut's detection and points went with it: the only points shown are NAO's frame on the old side.
    shown = {n for n, v in state["nodes"].items() if v["kind"] in ("points", "lines", "rings") and v["shown"]}
    assert shown == {f"/review/old/base/frame/{part}" for part in ("measured", "predicted", "lines")}
    assert len(_points(state, "/review/old/base/frame/measured")) == 24


def test_residuals_are_drawn_magnified_and_the_labels_say_so(
    viser_server: viser.ViserServer, robonaut_review: Review
) -> None:
    """x10: each measurement's ring at prediction + 10 (measurement - prediction), its residual line ten times as
    long, the predictions where they were; every frame's marks too; x1 draws the measurements where they are."""
    scene = ReviewScene(viser_server)
    scene.load(robonaut_review)
    scene.select(5)
    scene.set_magnify(10)
    g = robonaut_review.frame_geometry(5)
    state = scene.state()
    assert state["magnify"] == 10
    for side in ("old", "new"):
        base = f"/review/{side}/base/frame"
        got = np.isfinite(g.measured_m[side]).all(axis=1)
        pred, meas = g.predicted_m[side][got], g.measured_m[side][got]
        residual_m = np.linalg.norm(meas - pred, axis=1)
        assert residual_m.max() > 0
        rings = _points(state, f"{base}/measured")
        np.testing.assert_allclose(rings, pred + 10 * (meas - pred), atol=1e-6)
        lines = _points(state, f"{base}/lines")
        np.testing.assert_allclose(np.linalg.norm(lines[:, 1] - lines[:, 0], axis=1), 10 * residual_m, atol=1e-6)
        np.testing.assert_allclose(_points(state, f"{base}/predicted"), g.predicted_m[side], atol=1e-6)
        assert "residuals x10" in state["nodes"][f"/review/{side}/label"]["text"]
        every_measured, every_predicted = robonaut_review.all_points(side)
        np.testing.assert_allclose(
            _points(state, f"/review/{side}/base/all/measured"),
            every_predicted + 10 * (every_measured - every_predicted),
            atol=1e-6,
        )
    scene.select(6)  # the next frame keeps the factor
    g6 = robonaut_review.frame_geometry(6)
    got = np.isfinite(g6.measured_m["new"]).all(axis=1)
    pred, meas = g6.predicted_m["new"][got], g6.measured_m["new"][got]
    np.testing.assert_allclose(
        _points(scene.state(), "/review/new/base/frame/measured"), pred + 10 * (meas - pred), atol=1e-6
    )
    scene.set_magnify(1)
    state = scene.state()
    np.testing.assert_allclose(_points(state, "/review/new/base/frame/measured"), meas, atol=1e-6)
    assert state["nodes"]["/review/new/label"]["text"] == "new calibration"
    with pytest.raises(ValueError, match=r"magnify: 0\.5 is not a factor from 1 to 1000"):
        scene.set_magnify(0.5)


@contextmanager
def reported_camera(server: viser.ViserServer) -> Iterator[tuple[viser.ClientHandle, Any]]:
    """A client of the server that has reported its camera (a browser's first message, tests/test_viewers.py's),
    so framings move it, and its websocket (to report where the operator put the camera)."""
    # Every message kept (max_queue=None): with the default 16 unread the connection stops reading, viser's reply
    # to the close cannot come through, and the close waited its whole 10-s timeout.
    with websockets.sync.client.connect(
        f"ws://127.0.0.1:{server.get_port()}", subprotocols=[PROTOCOL], proxy=None, max_queue=None
    ) as ws:
        ws.send(camera_message())
        wait_until(lambda: any(camera_reported(c.camera) for c in server.get_clients().values()), what="a camera")
        yield next(iter(server.get_clients().values())), ws


def _in_view(camera: viser.CameraHandle, points: np.ndarray) -> bool:
    """Every point inside the camera's field of view (both directions)."""
    axis = (camera.look_at - camera.position) / np.linalg.norm(camera.look_at - camera.position)
    rays = (points - camera.position) / np.linalg.norm(points - camera.position, axis=1)[:, None]
    half = min(camera.fov, 2 * np.arctan(np.tan(camera.fov / 2) * camera.image_width / camera.image_height)) / 2
    return bool(np.all(np.arccos(np.clip(rays @ axis, -1, 1)) < half))


def _marks_world(scene: ReviewScene, side: str) -> np.ndarray:
    """The selected frame's marks on one copy, in the world."""
    state = scene.state()
    R = display_rotation(load_profile(state["robot"]))
    group = f"/review/{side}/base/frame"
    lift = np.asarray(state["nodes"][group]["position"])
    local = np.concatenate([_points(state, f"{group}/{part}") for part in ("measured", "predicted")])
    return (local + lift) @ R.T + np.asarray(state["nodes"][f"/review/{side}"]["position"])


def test_the_camera_stays_where_the_operator_put_it_until_frame_it(
    viser_server: viser.ViserServer, robonaut_review: Review
) -> None:
    """Stepping frames, the overlay and every frame leave the camera where the operator put it (as in RViz);
    "frame it" brings it onto both copies' marks, from far enough (a narrow field of view) that the two copies are
    seen from directions within 5 degrees of each other, the marks filling a good part of the view."""
    with reported_camera(viser_server) as (client, ws):
        scene = ReviewScene(viser_server)
        scene.load(robonaut_review)
        wait_until(lambda: scene.camera.state()["clients"][client.client_id]["framed"], what="the robot's framing")
        put = np.array([1.7, -0.9, 1.3])
        report = msgspec.msgpack.decode(camera_message())
        ws.send(msgspec.msgpack.encode(report | {"position": put.tolist(), "look_at": [0.1, 0.2, 0.4]}))
        wait_until(lambda: np.allclose(client.camera.position, put), what="the operator's camera")
        for index in (3, 5, 7):
            scene.select(index)
        scene.set_overlay(True)
        scene.select(8)
        scene.show_all(True)
        scene.show_all(False)
        scene.set_overlay(False)
        scene.select(9)
        np.testing.assert_allclose(client.camera.position, put)  # a moved camera is set here at once
        np.testing.assert_allclose(client.camera.look_at, [0.1, 0.2, 0.4])

        scene.frame_marks()
        camera = client.camera
        old, new = _marks_world(scene, "old"), _marks_world(scene, "new")
        assert _in_view(camera, np.concatenate([old, new]))
        to_old, to_new = camera.position - old.mean(axis=0), camera.position - new.mean(axis=0)
        apart_deg = np.degrees(np.arccos(to_old @ to_new / np.linalg.norm(to_old) / np.linalg.norm(to_new)))
        assert apart_deg <= 5.0 + 1e-6, apart_deg
        # Not a speck: the marks of both copies span more than half the narrower field of view.
        span = np.linalg.norm(new.mean(axis=0) - old.mean(axis=0)) / np.linalg.norm(camera.position - camera.look_at)
        assert span > 0.5 * min(camera.fov, 2 * np.arctan(np.tan(camera.fov / 2) * 640 / 480)), span


def _messages(ws: Any, until: Callable[[dict], bool]) -> list[dict]:
    """The messages viser sends this websocket (its wire format: two sizes, zstd-compressed msgpack, buffers),
    up to the first for which `until` holds."""
    out: list[dict] = []
    while not out or not until(out[-1]):
        data = ws.recv(timeout=15)
        size = int.from_bytes(data[8:16], "little")
        inner = zstandard.ZstdDecompressor().decompress(data[16 : 16 + size])
        for message in msgspec.msgpack.decode(inner)["messages"]:
            out.append(message)
            if until(message):
                break
    return out


def _own(message: dict, kind: str) -> bool:
    """A message of that kind to this browser's camera (not viser's initial camera, for browsers to come)."""
    return message["type"] == kind and not message.get("initial", False)


def test_a_robot_change_sets_the_field_of_view_the_browser_reported_late(
    viser_server: viser.ViserServer, robonaut_review: Review
) -> None:
    """ "Frame it" narrows the browser's field of view; a camera report the browser sent before it took the narrow
    one (still the default) arrives after. The next robot's framing, at the default field of view, must still send
    it: the browser keeps the narrow one otherwise, at the default's distance (a CI run saw it)."""
    with reported_camera(viser_server) as (client, ws):
        scene = ReviewScene(viser_server)
        scene.load(robonaut_review)
        wait_until(lambda: scene.camera.state()["clients"][client.client_id]["framed"], what="the robot's framing")
        scene.select(3)
        scene.frame_marks()
        assert client.camera.fov < DEFAULT_FOV_RAD / 2
        _messages(ws, lambda m: _own(m, "SetCameraFovMessage") and m["fov"] < DEFAULT_FOV_RAD / 2)
        stale = msgspec.msgpack.decode(camera_message()) | {"fov": DEFAULT_FOV_RAD}
        ws.send(msgspec.msgpack.encode(stale))
        wait_until(lambda: np.isclose(client.camera.fov, DEFAULT_FOV_RAD), what="the late report")

        scene.load(build("nao", 3, new=False))
        look_at = scene.camera.current.look_at
        sent = _messages(
            ws, lambda m: _own(m, "SetCameraLookAtMessage") and np.allclose(m["look_at"], look_at, atol=1e-6)
        )
        fovs = [m["fov"] for m in sent if _own(m, "SetCameraFovMessage")]
        assert fovs and np.isclose(fovs[-1], DEFAULT_FOV_RAD), fovs
