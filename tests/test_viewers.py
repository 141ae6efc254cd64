"""Viewers in-process: each browser tab's review and scene are its own (app/scene/viewers.py), and the scene's websocket
through the API's port reaches the loopback viser server as its own viser client (app/web/scene_proxy.py).

A "browser" here is a websocket through the app (FastAPI's TestClient) that sends what viser's client sends
first, its camera; viser then reports the client and the viewer draws on it.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import replace

import msgspec
import numpy as np
import pytest
import viser
import websockets.sync.client
from fastapi.testclient import TestClient
from starlette.testclient import WebSocketTestSession
from starlette.websockets import WebSocketDisconnect

from app.scene.viewers import Viewer
from app.web.desk import Desk
from app.web.static_dir import STATIC_DIR

PROTOCOL = f"viser-v{viser.__version__}"


def camera_message(width: int = 640) -> bytes:
    """viser's client's camera report (its first message): the width tells one browser from another."""
    return msgspec.msgpack.encode(
        {
            "type": "ViewerCameraMessage",
            "wxyz": [1.0, 0.0, 0.0, 0.0],
            "position": [3.0, 0.0, 1.0],
            "fov": 1.3,
            "near": 0.01,
            "far": 100.0,
            "image_height": 480,
            "image_width": width,
            "look_at": [0.0, 0.0, 0.0],
            "up_direction": [0.0, 0.0, 1.0],
        }
    )


def wait_until(condition, timeout_s: float = 15.0, what: str = "the condition") -> None:
    deadline = time.monotonic() + timeout_s
    while not condition():
        if time.monotonic() > deadline:
            raise AssertionError(f"timed out waiting for {what}")
        time.sleep(0.02)


@contextmanager
def browser(client: TestClient, viewer: str, width: int = 640) -> Iterator[WebSocketTestSession]:
    """A browser's scene websocket for `viewer`, open (and its scene drawn on) until the block ends."""
    with client.websocket_connect(f"/scene/{viewer}", subprotocols=[PROTOCOL]) as ws:
        assert ws.accepted_subprotocol == PROTOCOL
        ws.send_bytes(camera_message(width))
        v = client.app.state.desk.viewers.get(viewer)
        wait_until(lambda: v.scene is not None and v.client_id in v.connections, what=f"viewer {viewer}'s scene")
        yield ws


def tab(viewer: str) -> dict[str, str]:
    return {"X-Viewer": viewer}


@pytest.mark.slow
def test_two_viewers_review_different_robots_without_moving_each_other(client: TestClient) -> None:
    desk: Desk = client.app.state.desk
    with browser(client, "tab-a", 601), browser(client, "tab-b", 602):
        a = client.post("/api/review", json={"session": "robonaut-a-day1"}, headers=tab("tab-a")).json()
        b = client.post("/api/review", json={"session": "nao"}, headers=tab("tab-b")).json()
        assert (a["robot"], b["robot"]) == ("robonaut-a", "nao")
        va, vb = desk.viewers.get("tab-a"), desk.viewers.get("tab-b")
        for step in range(3):
            ia, ib = 10 + step, 100 + step
            assert client.post("/api/review/frame", json={"index": ia}, headers=tab("tab-a")).status_code == 200
            assert (
                client.post("/api/review/frame", json={"index": ib, "all": True}, headers=tab("tab-b")).status_code
                == 200
            )
            sa, sb = va.scene.state(), vb.scene.state()
            assert (sa["robot"], sa["index"], sa["all"]) == ("robonaut-a", ia, False)
            assert (sb["robot"], sb["index"], sb["all"]) == ("nao", ib, True)
            # Each viewer's marks are of its own review and frame.
            ma = client.get(f"/api/review/marks/{ia}", headers=tab("tab-a")).json()
            mb = client.get(f"/api/review/marks/{ib}", headers=tab("tab-b")).json()
            assert (ma["index"], ma["role"], len(ma["measured"])) == (ia, "left", 1)
            assert (mb["index"], mb["role"], len(mb["measured"])) == (ib, "image", 24)
        # Each scene is its own viser client's, with that robot's joints.
        assert va.client_id != vb.client_id
        assert set(sa["urdf"]["old"]["joints"]) != set(sb["urdf"]["old"]["joints"])
        # A frame of the other viewer's session is not in this one's review.
        r = client.post("/api/review/frame", json={"index": 140}, headers=tab("tab-a"))
        assert r.status_code == 404 and "frame 140 is not in this review" in r.json()["detail"]
        listed = {v["id"]: v for v in client.get("/api/viewers").json()}
        assert (listed["tab-a"]["session"], listed["tab-a"]["index"], listed["tab-a"]["connected"]) == (
            "robonaut-a-day1",
            12,
            True,
        )
        assert (listed["tab-b"]["session"], listed["tab-b"]["index"]) == ("nao", 102)


def test_requests_without_a_viewer_address_the_default_one(client: TestClient) -> None:
    """The old request shapes (scripts, benchmarks, single-viewer clients) keep working, on a viewer of their own."""
    client.post("/api/review", json={"session": "robonaut-a-day2"}, headers=tab("tab-c"))
    client.post("/api/review/frame", json={"index": 7}, headers=tab("tab-c"))
    r = client.post("/api/review", json={"session": "nao", "old": None})
    assert r.status_code == 200 and r.json()["robot"] == "nao"
    assert client.post("/api/review/frame", json={"index": 3, "overlay": True}).json()["index"] == 3
    assert client.get("/api/review/marks/3").json()["index"] == 3
    default = client.app.state.desk.viewers.default.state()
    assert (default["session"], default["index"], default["overlay"]) == ("nao", 3, True)
    other = client.app.state.desk.viewers.get("tab-c").state()
    assert (other["session"], other["index"], other["overlay"]) == ("robonaut-a-day2", 7, False)


def test_a_review_loaded_before_the_scene_connects_is_drawn_when_it_does(client: TestClient) -> None:
    client.post("/api/review", json={"session": "nao"}, headers=tab("tab-late"))
    client.post("/api/review/frame", json={"index": 9, "overlay": True}, headers=tab("tab-late"))
    with browser(client, "tab-late"):
        state = client.app.state.desk.viewers.get("tab-late").scene.state()
        assert (state["robot"], state["index"], state["overlay"]) == ("nao", 9, True)
        assert state["urdf"]["ghost"]["shown"]


def test_bad_viewer_ids_and_too_many_viewers_are_4xx(client: TestClient) -> None:
    for bad in ("a b", "x" * 65, "../default", b"\xc3\xa9"):
        r = client.post("/api/review/frame", json={"index": 1}, headers={"X-Viewer": bad})
        assert r.status_code == 422 and "X-Viewer" in r.json()["detail"], (bad, r.text)
    assert client.get("/scene/a%20b/").status_code == 422
    viewers = client.app.state.desk.viewers
    limit = viewers.limit
    viewers.limit = 0  # no new viewer (those there stay)
    try:
        r = client.post("/api/review", json={"session": "nao"}, headers=tab("one-too-many"))
        assert r.status_code == 429 and "close a tab" in r.json()["detail"]
        with (
            pytest.raises(WebSocketDisconnect) as refused,
            client.websocket_connect("/scene/one-too-many", subprotocols=[PROTOCOL]),
        ):
            pass
        assert refused.value.code == 1013  # try again later
    finally:
        viewers.limit = limit


def test_concurrent_scene_connections_each_become_their_own_viser_client(client: TestClient) -> None:
    """Browsers connecting at once, with direct connections to the loopback viser port in between: every proxied
    websocket's viewer draws on the viser client that websocket became (the camera width each browser reports
    names it), never on another one's."""
    desk: Desk = client.app.state.desk
    n = 6
    ready = threading.Barrier(n + 2)
    opened: dict[str, Viewer] = {}
    done = threading.Event()
    errors: list[BaseException] = []

    def open_tab(k: int) -> None:
        try:
            ready.wait()
            with browser(client, f"many-{k}", 700 + k):
                opened[f"many-{k}"] = desk.viewers.get(f"many-{k}")
                done.wait(30)
        except BaseException as exc:
            errors.append(exc)

    def direct() -> None:
        ready.wait()
        with websockets.sync.client.connect(
            f"ws://127.0.0.1:{desk.viser_port_number}", subprotocols=[PROTOCOL], proxy=None, max_queue=None
        ) as ws:  # every message kept: with 16 unread the connection stops reading (tests/test_scene.py)
            ws.send(camera_message(999))
            done.wait(30)

    threads = [threading.Thread(target=open_tab, args=(k,)) for k in range(n)]
    threads += [threading.Thread(target=direct) for _ in range(2)]
    for t in threads:
        t.start()
    try:
        wait_until(lambda: len(opened) == n or errors, timeout_s=60, what="every tab's scene")
        assert not errors, errors
        clients = desk.viser.get_clients()
        for k in range(n):
            viewer = opened[f"many-{k}"]
            assert clients[viewer.client_id].camera.image_width == 700 + k
        assert len({v.client_id for v in opened.values()}) == n
    finally:
        done.set()
        for t in threads:
            t.join(timeout=30)


@pytest.mark.slow
def test_a_closed_tabs_viewer_goes_and_the_default_stays(client: TestClient) -> None:
    viewers = client.app.state.desk.viewers
    linger = viewers.linger_s
    viewers.linger_s = 0.3
    try:
        with browser(client, "tab-closing"):
            client.post("/api/review", json={"session": "robonaut-a-day1"}, headers=tab("tab-closing"))
            time.sleep(0.6)
            assert "tab-closing" in {v.id for v in viewers.all()}  # connected: kept however long
        wait_until(lambda: "tab-closing" not in {v.id for v in viewers.all()}, what="the closed tab's viewer to go")
        client.post("/api/review", json={"session": "nao"}, headers=tab("never-connected"))
        wait_until(lambda: "never-connected" not in {v.id for v in viewers.all()}, what="an unconnected viewer to go")
        assert viewers.default in viewers.all()
    finally:
        viewers.linger_s = linger


def test_the_proxy_forwards_viser_closing_without_its_subprotocol(client: TestClient) -> None:
    """Without the viser-v<version> subprotocol viser refuses the client (1002, "Version mismatch"): the proxy
    passes the close on, and the browser's viser client says so."""
    with client.websocket_connect("/scene/no-protocol") as ws:
        message = ws.receive()
        assert message["type"] == "websocket.close" and message["code"] == 1002, message
        assert "Version mismatch" in message["reason"]


@pytest.mark.slow
def test_the_live_view_goes_to_the_viewers_watching_only(client: TestClient) -> None:
    """Observe's live view is shown to the viewer that asked (and others that joined); a viewer reviewing a
    session meanwhile keeps its review in its scene."""
    desk: Desk = client.app.state.desk
    with browser(client, "watcher"), browser(client, "reviewer"):
        client.post("/api/review", json={"session": "robonaut-a-day1"}, headers=tab("reviewer"))
        client.post("/api/review/frame", json={"index": 4}, headers=tab("reviewer"))
        sid = "nao"
        r = client.post(f"/api/sessions/{sid}/observe", json={"on": True}, headers=tab("watcher"))
        assert r.status_code == 200, r.text
        watcher, reviewer = desk.viewers.get("watcher"), desk.viewers.get("reviewer")
        wait_until(lambda: watcher.scene.state()["live"], what="the live view")
        time.sleep(1.2)  # a few looks of the live loop
        state = reviewer.scene.state()
        assert (state["robot"], state["index"], state["live"]) == ("robonaut-a", 4, False)
        assert state["nodes"]["/review/old"]["shown"] and "/live" not in state["nodes"]
        assert watcher.scene.state()["robot"] == "nao" and watcher.scene.state()["nodes"]["/live"]["shown"]
        client.post(f"/api/sessions/{sid}/observe", json={"on": False}, headers=tab("watcher"))
        assert not watcher.state()["live"] and not watcher.scene.state()["live"]


def test_a_reloaded_iframe_is_drawn_as_before(client: TestClient) -> None:
    """A new browser of one viewer (its iframe reloaded) shows the frame the viewer had selected."""
    client.post("/api/review", json={"session": "robonaut-a-day1"}, headers=tab("reloaded"))
    client.post("/api/review/frame", json={"index": 20}, headers=tab("reloaded"))
    viewer = client.app.state.desk.viewers.get("reloaded")
    expected = viewer.review.frame_geometry(20).joints_rad
    for _ in range(2):
        with browser(client, "reloaded"):
            state = viewer.scene.state()
            assert state["index"] == 20
            joints = state["urdf"]["old"]["joints"]
            np.testing.assert_allclose([joints[n] for n in viewer.review.profile.joint_names], expected, atol=1e-12)


def test_a_viewer_with_two_clients_draws_on_both_and_goes_on_with_the_one_left(client: TestClient) -> None:
    """After a server restart the old iframe's client may reconnect beside the new iframe's, in either order, and
    then close: whichever the page shows, it shows the review (a CI run once showed a stale frame)."""
    client.post("/api/review", json={"session": "robonaut-a-day1"}, headers=tab("restarted"))
    viewer = client.app.state.desk.viewers.get("restarted")
    with browser(client, "restarted"):
        new_iframe = viewer.client_id
        with browser(client, "restarted", width=800):
            wait_until(lambda: viewer.client_id != new_iframe, what="the old iframe's client attached")
            client.post("/api/review/frame", json={"index": 20}, headers=tab("restarted"))
            assert len(viewer.scenes) == 2 and all(s.state()["index"] == 20 for s in viewer.scenes.values())
        wait_until(lambda: viewer.client_id == new_iframe, what="the new iframe's client alone")
        client.post("/api/review/frame", json={"index": 30}, headers=tab("restarted"))
        assert viewer.scene.state()["index"] == 30


def test_viewers_are_listed_and_the_scene_is_no_api(client: TestClient) -> None:
    listed = client.get("/api/viewers").json()
    assert listed[0]["id"] == "default" and all(set(v) >= {"id", "connected", "session", "index"} for v in listed)
    paths = client.app.openapi()["paths"]
    assert "/api/viewers" in paths and not any(p.startswith("/scene") for p in paths)


@pytest.mark.slow
def test_the_live_robot_follows_the_robot_while_it_moves(client: TestClient, monkeypatch: pytest.MonkeyPatch) -> None:
    """Observe shows the robot at its readings mid-motion (a replay, the sliders), not only once it stands still:
    the live copy passes through poses between the start and the goal."""
    desk: Desk = client.app.state.desk
    with browser(client, "follower"):
        assert client.post("/api/robot/connect", json={"robot": "nao"}, headers=tab("follower")).status_code == 200
        driver = desk.robots.driver("nao")
        monkeypatch.setattr(driver, "motion", replace(driver.motion, time_scale=0.25))  # a move of a second or two
        client.post("/api/sessions/nao/observe", json={"on": True}, headers=tab("follower"))
        viewer = desk.viewers.get("follower")
        wait_until(lambda: viewer.scene.state()["live"], what="the live view")
        profile = driver.profile
        k = profile.joint("HeadYaw")
        start = driver.read_joints()
        goal = start.copy()
        lo, hi = profile.joint_limits()
        goal[k] = hi[k] - 0.1 if start[k] < 0 else lo[k] + 0.1
        driver.move_to(goal, wait=False)
        shown = set()
        while driver.status().moving:
            shown.add(round(viewer.scene.state()["urdf"]["live"]["joints"][profile.joints[k].name], 3))
            time.sleep(0.03)
        client.post("/api/sessions/nao/observe", json={"on": False}, headers=tab("follower"))
    between = {x for x in shown if min(abs(x - start[k]), abs(x - goal[k])) > 0.05}
    assert len(between) >= 3, (start[k], goal[k], sorted(shown))


def test_a_viewer_magnifies_its_residuals_and_frames_its_marks(client: TestClient) -> None:
    """POST /api/review/magnify draws the viewer's 3-D residuals k times their length (1 to 1000, else a 422
    naming the field), kept when its page reloads; POST /api/review/frame-marks frames its selected frame."""
    desk: Desk = client.app.state.desk
    with browser(client, "tab-mag"):
        assert client.post("/api/review", json={"session": "nao"}, headers=tab("tab-mag")).status_code == 200
        assert client.post("/api/review/frame", json={"index": 101}, headers=tab("tab-mag")).status_code == 200
        robot = desk.viewers.get("tab-mag").scene.camera.state()["framing"]  # framed on NAO as it was loaded
        r = client.post("/api/review/frame-marks", headers=tab("tab-mag"))
        assert r.status_code == 200 and r.json() == {"index": 101}
        marks = desk.viewers.get("tab-mag").scene.camera.state()["framing"]
        assert marks["radius_m"] < 0.8 * robot["radius_m"] and marks["look_at"] != robot["look_at"]
        for bad in (0.5, 1e6, "x10"):
            r = client.post("/api/review/magnify", json={"factor": bad}, headers=tab("tab-mag"))
            assert r.status_code == 422 and "factor" in r.text, r.text
        r = client.post("/api/review/magnify", json={"factor": 100}, headers=tab("tab-mag"))
        assert r.status_code == 200 and r.json() == {"factor": 100}
        state = desk.viewers.get("tab-mag").scene.state()
        assert state["magnify"] == 100 and "residuals x100" in state["nodes"]["/review/old/label"]["text"]
        listed = {v["id"]: v for v in client.get("/api/viewers").json()}
        assert listed["tab-mag"]["magnify"] == 100 and listed["default"]["magnify"] == 1
        # The scene's page draws the marks over the bodies (static/viser_marks.js, inlined).
        page = client.get("/scene/tab-mag/")
        assert page.status_code == 200 and (STATIC_DIR / "viser_marks.js").read_text() in page.text
    with browser(client, "tab-mag"):  # its page reloaded: a new scene, at the same factor
        assert desk.viewers.get("tab-mag").scene.state()["magnify"] == 100
