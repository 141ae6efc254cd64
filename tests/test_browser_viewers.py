"""Viewers in a real headless Chromium against `calib serve`: every tab has its own review and 3-D scene, the
scene comes through the API's port (viser listens on loopback only), off loopback it needs the token, a closed
tab's viewer is disconnected (tests/test_viewers.py: it goes), and after a server restart the page reloads its scene
and shows its review again."""

from __future__ import annotations

import hashlib
import socket
import time
from pathlib import Path
from typing import TYPE_CHECKING
from urllib.parse import urlsplit

import httpx
import pytest
import websockets.exceptions
import websockets.sync.client
from browser import desk_served, free_port, listening, served, wait_for_scene
from test_viewers import PROTOCOL, camera_message

if TYPE_CHECKING:
    from playwright.sync_api import ViewportSize

pytestmark = [pytest.mark.browser, pytest.mark.subprocess]

# What the page's own iframe shows, read from viser's client store: the names under the old copy's URDF (its
# robot's links), and the selected frame: its predictions and its measurements (points, and whether shown; NAO's
# three head postures of a stance share their predictions, not their measurements).
SCENE = """() => {
  const s = window.__viserSceneTree.getState();
  const names = new Set(Object.keys(s).filter(k => k.startsWith('/review/old/base/robot/'))
    .flatMap(k => k.split('/visual/').slice(1).flatMap(rest => rest.split('/'))));
  const points = k => s[k] ? [Array.from(s[k].message.props.points), s[k].visibility] : null;
  const frame = '/review/old/base/frame/';
  return { links: [...names].sort(), frame: [points(frame + 'predicted'), points(frame + 'measured')] };
}"""
CANVAS = "sel => document.querySelector(sel).toDataURL()"
SIZE: ViewportSize = {"width": 1300, "height": 900}  # a window of a test's page


def scene_frame(page):
    return next(f for f in page.frames if f != page.main_frame)


def viewer_of(page) -> str:
    """The page's viewer id: its iframe is at /scene/<viewer>/."""
    return urlsplit(page.get_attribute("#scene", "src")).path.split("/")[2]


def snapshot(page) -> dict:
    """What a page shows of its review: label, selected row, the table's first rows, both 2-D marks, the scene."""
    return {
        "label": page.text_content("#frame-label"),
        "selected": page.get_attribute("#frames tr.selected", "data-frame"),
        "rows": [r.text_content() for r in page.locator("#frames tr[data-frame]").all()[:3]],
        "marks": [hashlib.sha1(page.evaluate(CANVAS, c).encode()).hexdigest() for c in ("#split-old", "#split-new")],
        "scene": scene_frame(page).evaluate(SCENE),
    }


def open_page(context, url: str, sockets: list[str] | None = None, viewport: ViewportSize | None = None):
    """A page of the desk, ready and its scene drawn, in `context` (a context, or the test's tabs: conftest.py Tabs);
    `sockets` collects the URLs of the websockets it opens."""
    page = context.new_page(**({} if viewport is None else {"viewport": viewport}))
    if sockets is not None:
        page.on("websocket", lambda ws: sockets.append(ws.url))
    page.goto(url)
    page.wait_for_selector("body[data-ready='1']", timeout=60_000)
    wait_for_scene(page)
    return page


def open_session(page, session: str) -> None:
    page.click(f"li[data-session='{session}']")
    page.click("#tabs button[data-tab='review']")
    page.wait_for_selector("#frames tr.selected", state="attached")
    scene_frame(page).wait_for_function(
        "n => { const s = window.__viserSceneTree.getState()['/review/old/base/frame/predicted'];"
        " return s && s.message.props.points.length === 3 * n; }",
        arg=24 if session == "nao" else 1,
        polling=100,
        timeout=60_000,
    )


def wait_for_frame(page, shown: list, *, equal: bool) -> None:
    """Until the page's scene shows this frame (equal: SCENE's `frame`) or another."""
    scene_frame(page).wait_for_function(
        f"([f, eq]) => (JSON.stringify(({SCENE})().frame) === JSON.stringify(f)) === eq",
        arg=[shown, equal],
        polling=100,  # not on animation frames: a tab in the background gets none
        timeout=30_000,
    )


def step(page) -> None:
    """One frame on, and wait until the page's own scene shows it and its marks are drawn."""
    label = page.text_content("#frame-label")
    before = scene_frame(page).evaluate(SCENE)["frame"]
    page.click("#step-fwd")
    page.wait_for_function(f"document.querySelector('#frame-label').textContent !== {label!r}", polling=100)
    wait_for_frame(page, before, equal=False)
    page.wait_for_function(  # the 2-D marks are drawn after the select answers: then each canvas names its frame
        "() => { const f = document.querySelector('#frames tr.selected').dataset.frame;"
        " return ['#split-old', '#split-new'].every(s => document.querySelector(s).dataset.frame === f); }",
        polling=100,  # not on animation frames: a tab in the background gets none
    )


def test_tabs_and_contexts_review_their_own_sessions(chromium, desk_data: Path) -> None:
    """Robonaut's first day and NAO in two tabs of one browser context, Robonaut's later day in another context:
    stepping through frames in one page moves its table, label, marks and scene, and nothing in the others. The
    scene is the page's own origin (viser listens on loopback only); a closed tab's viewer is disconnected."""
    links = {"robonaut-a-day1": "shoulder_roll", "nao": "HeadYaw", "robonaut-a-day2": "shoulder_roll"}
    with desk_served(desk_data) as server:
        one, two = (chromium.new_context(viewport=SIZE) for _ in range(2))
        sockets: list[str] = []
        pages = {}
        for context, session in ((one, "robonaut-a-day1"), (one, "nao"), (two, "robonaut-a-day2")):
            pages[session] = open_page(context, server.url, sockets)
            open_session(pages[session], session)

        # The scene through the page's own origin; the viser server itself on loopback only.
        port = urlsplit(server.url).port
        for page in pages.values():
            src = page.evaluate("() => new URL(document.querySelector('#scene').src).origin === location.origin")
            assert src, page.get_attribute("#scene", "src")
        viser_port = server.get("/api/health").json()["viser_port"]
        assert viser_port != port and listening(viser_port) == {"127.0.0.1"}
        assert len(sockets) >= 3 and {urlsplit(u).netloc for u in sockets} == {f"127.0.0.1:{port}"}

        for session, page in pages.items():  # each scene shows its session's robot, and no other
            # The robot's nodes may reach the client after the frame's marks (one CI run in many read NAO still).
            scene_frame(page).wait_for_function(
                f"link => ({SCENE})().links.includes(link)", arg=links[session], polling=100, timeout=30_000
            )
            shown = scene_frame(page).evaluate(SCENE)["links"]
            assert links[session] in shown and set(links.values()) - {links[session]} - set(shown), (session, shown)
        for session, page in [*pages.items(), *pages.items()][:4]:  # each page steps, the first one twice
            before = {s: snapshot(p) for s, p in pages.items()}
            step(page)
            after = {s: snapshot(p) for s, p in pages.items()}
            moved = after[session]
            assert moved["label"] != before[session]["label"] and moved["selected"] != before[session]["selected"]
            assert moved["scene"]["frame"] != before[session]["scene"]["frame"]
            assert moved["marks"] != before[session]["marks"]
            for other in pages:
                if other != session:
                    assert after[other] == before[other], f"{session} moved {other}"
        # The server's viewers agree: each page's own, at its own frame.
        listed = {v["id"]: v for v in server.get("/api/viewers").json()}
        for session, page in pages.items():
            viewer = listed[viewer_of(page)]
            assert (viewer["session"], viewer["connected"]) == (session, True)
            assert str(viewer["index"]) == page.get_attribute("#frames tr.selected", "data-frame")

        # A closed tab's viewer is disconnected at once (it goes a few seconds later: tests/test_viewers.py);
        # the others stay connected.
        closed = viewer_of(pages["nao"])
        pages["nao"].close()
        deadline = time.monotonic() + 30
        while (listed := {v["id"]: v for v in server.get("/api/viewers").json()}).get(closed, {}).get("connected"):
            assert time.monotonic() < deadline, "the closed tab's viewer is still connected"
            time.sleep(0.1)
        assert all(listed[viewer_of(p)]["connected"] for s, p in pages.items() if s != "nao")


def _address_off_loopback() -> str | None:
    """This machine's address on its network (None: it has none)."""
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        try:
            s.connect(("192.0.2.1", 9))  # no packet is sent: this only picks the interface
            address = s.getsockname()[0]
        except OSError:
            return None
    return None if address.startswith("127.") else address


def test_off_loopback_the_scene_comes_through_the_api_port_with_the_token(chromium, desk_data: Path) -> None:
    """Served on every address and opened by this machine's network address: the page with the token shows its
    scene, which can only have come through the API's port (viser's is not reachable there); the scene's page
    and websocket without the token are refused."""
    address = _address_off_loopback()
    if address is None:
        pytest.skip("this machine has no address off loopback")
    with served(desk_data, host="0.0.0.0") as server:
        assert server.token
        port = urlsplit(server.url).port
        url = f"http://{address}:{port}"
        viser_port = server.get("/api/health").json()["viser_port"]
        assert listening(viser_port) == {"127.0.0.1"} and listening(port) == {"0.0.0.0"}
        with pytest.raises(OSError):
            socket.create_connection((address, viser_port), timeout=5).close()

        # Without the token: the scene's page 401, its websocket refused (401 instead of the upgrade).
        assert httpx.get(f"{url}/scene/stranger/", timeout=10).status_code == 401
        with pytest.raises(websockets.exceptions.InvalidStatus) as refused:
            websockets.sync.client.connect(f"ws://{address}:{port}/scene/stranger", subprotocols=[PROTOCOL])
        assert refused.value.response.status_code == 401
        # With it (as a header here; the page's iframe has the cookie): viser's scene comes through.
        with websockets.sync.client.connect(
            f"ws://{address}:{port}/scene/script",
            subprotocols=[PROTOCOL],
            additional_headers={"Authorization": f"Bearer {server.token}"},
            proxy=None,
            max_queue=None,  # every message kept: with 16 unread the connection stops reading (test_scene.py)
        ) as ws:
            assert ws.subprotocol == PROTOCOL
            ws.send(camera_message())
            assert len(ws.recv(timeout=30)) > 0

        sockets: list[str] = []
        page = open_page(
            chromium.new_context(viewport={"width": 1300, "height": 900}), f"{url}/?token={server.token}", sockets
        )
        open_session(page, "nao")
        assert "HeadYaw" in scene_frame(page).evaluate(SCENE)["links"]
        assert {urlsplit(u).netloc for u in sockets} == {f"{address}:{port}"}
        assert "token" not in page.url  # read once, then removed from the address bar

        # Opened without it (the bare address): the page asks once, however many of its first requests the server
        # refused at once, and goes on with the operator's answer; its scene comes through too.
        asked: list[str] = []
        bare = chromium.new_context(viewport={"width": 1300, "height": 900}).new_page()
        bare.on("dialog", lambda d: (asked.append(d.type), d.accept(server.token)))
        bare.goto(url)
        bare.wait_for_selector("body[data-ready='1']", timeout=60_000)
        wait_for_scene(bare)
        assert asked == ["prompt"]


def test_after_a_server_restart_the_page_shows_its_review_again(chromium, desk_data: Path) -> None:
    """The iframe's viser client does not reconnect by itself: the page sees the new server instance, reloads its
    scene and loads its review (at its frame) into its new viewer."""
    number = free_port()
    with served(desk_data, port=number) as server:
        page = open_page(chromium, server.url, viewport=SIZE)
        open_session(page, "nao")
        step(page)
        frame = page.get_attribute("#frames tr.selected", "data-frame")
        shown = scene_frame(page).evaluate(SCENE)
    with served(desk_data, port=number) as server:
        deadline = time.monotonic() + 60
        while True:
            viewers = {v["id"]: v for v in server.get("/api/viewers").json()}
            mine = viewers.get(viewer_of(page))
            if mine and mine["connected"] and mine["session"] == "nao" and str(mine["index"]) == frame:
                break
            assert time.monotonic() < deadline, f"the page did not come back: {viewers}"
            time.sleep(0.5)
        wait_for_scene(page)
        wait_for_frame(page, shown["frame"], equal=True)
        assert page.get_attribute("#frames tr.selected", "data-frame") == frame
