"""Security of the desk (app/web/security.py): the access token off loopback, the cross-origin guard, the Host
names answered, request size limits, paths that cannot leave the data directory, error texts without
paths or tracebacks, and the viser share tunnel closed."""

from __future__ import annotations

import asyncio
import io
import stat
import time
from collections.abc import Iterator
from functools import partial
from pathlib import Path

import msgspec
import pytest
import viser
import websockets
from browser import listening
from fastapi.testclient import TestClient
from starlette.testclient import WebSocketDenialResponse
from test_viewers import PROTOCOL, camera_message

from app.scene.viser_private import close_share_tunnel
from app.web.limits import DEFAULT_MAX_UPLOAD_BYTES as MAX_UPLOAD_BYTES
from app.web.security import (
    LOOPBACK_NAMES,
    TOKEN_FILE,
    Scrubber,
    TokenFile,
    is_loopback,
)
from app.web.server import create_app

LOCAL = "http://127.0.0.1:8000"


@pytest.fixture(scope="module")
def local(tmp_path_factory: pytest.TempPathFactory) -> Iterator[TestClient]:
    """Bound to loopback as `calib serve` binds it: no token, only loopback host names answered."""
    app = create_app(tmp_path_factory.mktemp("local"), time_scale=50.0, trusted_hosts=LOOPBACK_NAMES)
    with TestClient(app, base_url=LOCAL) as c:
        yield c


@pytest.fixture(scope="module")
def remote(tmp_path_factory: pytest.TempPathFactory) -> Iterator[TestClient]:
    """Bound to every address (the API and the scene's page and websocket; viser itself stays on loopback)."""
    app = create_app(tmp_path_factory.mktemp("remote"), sample_dir=None, host="0.0.0.0", time_scale=50.0)
    with TestClient(app, base_url="http://192.0.2.10:8000") as c:
        yield c


def bearer(token: str) -> dict[str, str]:
    return {"Authorization": f"Bearer {token}"}


def test_loopback_addresses() -> None:
    assert all(is_loopback(h) for h in ("127.0.0.1", "127.0.1.1", "::1", "[::1]", "localhost"))
    assert not any(is_loopback(h) for h in ("0.0.0.0", "::", "192.168.1.5", "example.org", ""))


def test_off_loopback_every_api_request_but_health_needs_the_token(remote: TestClient) -> None:
    token = remote.app.state.new_token
    assert token and len(token) >= 40
    remote.cookies.clear()
    assert remote.get("/api/health").status_code == 200
    assert remote.get("/").status_code == 200  # the page itself holds no data: it asks for the token
    for method, path, body in [
        ("get", "/api/sessions", None),
        ("get", "/api/robot", None),
        ("post", "/api/sessions", {"robot": "nao", "name": "stranger's"}),
        ("post", "/api/robot/move", {"joints": {"HeadYaw": 5.0}}),
        ("post", "/api/robot/stop", None),
    ]:
        for headers in ({}, bearer("not-the-token"), {"Authorization": token}):
            r = remote.request(method, path, json=body, headers=headers)
            assert r.status_code == 401, (method, path, headers, r.text)
            assert r.headers["www-authenticate"] == "Bearer"
            assert "token" in r.json()["detail"]
    assert remote.get("/api/sessions", headers=bearer(token)).json() == []  # nothing was created
    r = remote.post("/api/sessions", json={"robot": "nao", "name": "operator's"}, headers=bearer(token))
    assert r.status_code == 201, r.text
    assert [s["name"] for s in remote.get("/api/sessions", headers=bearer(token)).json()] == ["operator's"]


def test_the_read_cookie_reads_but_never_changes(remote: TestClient) -> None:
    """The page's images and server-sent events cannot send a header: an answer to a request with the
    token sets a cookie that allows reads (GET) only."""
    token = remote.app.state.new_token
    remote.cookies.clear()
    r = remote.get("/api/robot", headers=bearer(token))
    cookie = r.headers["set-cookie"]
    assert "HttpOnly" in cookie and "SameSite=Strict" in cookie and token not in cookie
    assert remote.get("/api/robot").status_code == 200  # the cookie jar sends it back
    assert remote.post("/api/robot/stop").status_code == 401
    assert remote.post("/api/sessions", json={"robot": "nao", "name": "via cookie"}).status_code == 401
    remote.cookies.clear()
    remote.cookies.set("calib_read", "guessed")
    assert remote.get("/api/robot").status_code == 401
    remote.cookies.clear()


def test_the_token_is_stored_hashed_and_made_once(remote: TestClient, tmp_path: Path) -> None:
    token = remote.app.state.new_token
    path = remote.app.state.desk.data_dir / TOKEN_FILE
    assert stat.S_IMODE(path.stat().st_mode) == 0o600
    text = path.read_text()
    assert token not in text and "sha256" in text
    again = TokenFile(path.parent)
    assert again.ensure() is None  # a later start shows nothing: the token was shown once
    assert again.verify(token) and not again.verify(token + "x") and not again.verify("")
    # A new token (calib serve --new-token) replaces the old one.
    other = TokenFile(tmp_path)
    first = other.ensure()
    second = other.renew()
    assert first and second and first != second
    assert TokenFile(tmp_path).verify(second) and not TokenFile(tmp_path).verify(first)


def test_loopback_needs_no_token(local: TestClient) -> None:
    assert local.get("/api/sessions").status_code == 200
    assert local.post("/api/robot/stop").status_code == 200
    assert local.app.state.new_token is None
    assert not (local.app.state.desk.data_dir / TOKEN_FILE).exists()


def test_another_sites_page_cannot_change_anything(local: TestClient) -> None:
    before = len(local.get("/api/sessions").json())
    for origin in ("http://evil.example", "null", "http://127.0.0.1:9999", "https://127.0.0.1:8000"):
        r = local.post("/api/sessions", json={"robot": "nao", "name": "csrf"}, headers={"Origin": origin})
        assert r.status_code == 403, (origin, r.text)
        assert "another site" in r.json()["detail"]
        r = local.post("/api/robot/move", json={"joints": {"elbow_pitch": 10.0}}, headers={"Origin": origin})
        assert r.status_code == 403
    assert len(local.get("/api/sessions").json()) == before
    assert not local.get("/api/robot").json()["moving"]
    # The desk's own page, and clients that send no Origin (curl, scripts), may.
    assert local.post("/api/robot/stop", headers={"Origin": LOCAL}).status_code == 200
    assert local.post("/api/robot/stop").status_code == 200
    # CORS stays closed: no answer allows another origin to read.
    r = local.get("/api/sessions", headers={"Origin": "http://evil.example"})
    assert "access-control-allow-origin" not in r.headers
    r = local.options(
        "/api/sessions",
        headers={"Origin": "http://evil.example", "Access-Control-Request-Method": "POST"},
    )
    assert "access-control-allow-origin" not in r.headers


def test_a_rebound_host_name_is_refused_on_loopback(local: TestClient) -> None:
    """DNS rebinding: a page on evil.example whose name now points at 127.0.0.1 sends Host evil.example."""
    r = local.post("/api/robot/stop", headers={"Host": "evil.example:8000", "Origin": "http://evil.example:8000"})
    assert r.status_code == 403
    assert local.get("/api/sessions", headers={"Host": "evil.example:8000"}).status_code == 403
    assert local.get("/api/sessions", headers={"Host": "localhost:8000"}).status_code == 200


def test_an_upload_too_large_is_refused_before_it_is_read(local: TestClient) -> None:
    before = len(local.get("/api/sessions").json())
    big = b"frame,x\n" + b"1,2\n" * ((MAX_UPLOAD_BYTES + 200_000) // 4)
    r = local.post(
        "/api/sessions/import",
        data={"robot": "robonaut-a", "name": "huge"},
        files={"data": ("huge.csv", io.BytesIO(big), "text/csv")},
    )
    assert r.status_code == 413, r.text[:200]
    assert "MB" in r.json()["detail"]

    # Without a Content-Length (chunked), the stream is cut off when it passes the cap.
    def chunks() -> Iterator[bytes]:
        yield b'--b\r\nContent-Disposition: form-data; name="robot"\r\n\r\nnao\r\n'
        yield b'--b\r\nContent-Disposition: form-data; name="name"\r\n\r\nstreamed\r\n'
        yield b'--b\r\nContent-Disposition: form-data; name="data"; filename="s.csv"\r\n\r\n'
        for _ in range(MAX_UPLOAD_BYTES // (1 << 20) + 2):
            yield b"1,2\n" * (1 << 18)
        yield b"\r\n--b--\r\n"

    r = local.post(
        "/api/sessions/import", content=chunks(), headers={"Content-Type": "multipart/form-data; boundary=b"}
    )
    assert r.status_code == 413, r.text[:200]
    assert "request body larger than" in r.json()["detail"]
    # A JSON body on any other endpoint is capped at 1 MB.
    r = local.post("/api/sessions", json={"robot": "nao", "name": "x" * 2_000_000})
    assert r.status_code == 413
    assert len(local.get("/api/sessions").json()) == before


@pytest.mark.parametrize(
    "path",
    [
        "/api/files/sessions/nao/images/..%2F..%2F..%2Fstore.sqlite",
        "/api/files/sessions/..%2F..%2Fcalibrations/images/0001_image.jpg",
        "/api/files/sessions/%2e%2e/images/0001_image.jpg",
        "/api/files/sessions/nao/images/%2e%2e",
        "/api/files/sessions/%2Fetc/images/passwd",
        "/api/files/sessions/nao/images/%2Fetc%2Fpasswd",
        "/api/files/sessions/nao/images/0001_image.jpg%00.txt",
        "/api/files/sessions/nao/../../store.sqlite",
        "/api/sessions/..%2F..%2Fstore.sqlite",
        "/api/sessions/%2e%2e",
        "/api/calibrations/..%2F..%2Fstore.sqlite",
        "/api/jobs/..%2F..%2Fstore.sqlite",
    ],
)
def test_names_cannot_leave_the_data_directory(local: TestClient, path: str) -> None:
    r = local.get(path)
    assert r.status_code == 404, (path, r.status_code, r.text[:200])
    assert b"SQLite format" not in r.content and b"root:" not in r.content
    frames = local.get("/api/sessions/nao").json()["frames"]
    assert local.get(frames[0]["images"]["image"]).status_code == 200  # the real image is served


def test_deleting_a_session_by_a_path_deletes_nothing(local: TestClient) -> None:
    data_dir = local.app.state.desk.data_dir
    for sid in ("..%2F..%2Fsessions", "%2e%2e", "..%2Fnao"):
        assert local.delete(f"/api/sessions/{sid}").status_code in (404, 405)  # 405: "/" splits the route
    assert (data_dir / "sessions" / "nao").is_dir() and (data_dir / "store.sqlite").is_file()
    assert local.get("/api/sessions/nao").status_code == 200


def test_no_error_names_a_path_or_shows_a_traceback(local: TestClient) -> None:
    desk = local.app.state.desk
    r = local.post("/api/sessions/robonaut-a-day1/calibrations", json={"mode": "daily"})
    job = r.json()["job"]
    deadline = time.monotonic() + 120
    while (j := local.get(f"/api/jobs/{job}").json())["state"] not in ("done", "failed", "cancelled"):
        assert time.monotonic() < deadline
        time.sleep(0.1)
    assert j["state"] == "done", j
    cal_id = j["result"]
    (desk.data_dir / desk.store.calibrations.info(cal_id).path).write_text('{"format": "calib-calibration/1", "rob')
    bad = [
        local.get(f"/api/calibrations/{cal_id}"),
        local.get(f"/api/calibrations/{cal_id}/export", params={"format": "urdf"}),
        local.post(f"/api/calibrations/{cal_id}/apply"),
        local.post("/api/review", json={"session": "robonaut-a-day1", "new": cal_id}),
        local.get("/api/sessions/no-such"),
        local.get("/api/files/sessions/nao/images/9999_image.jpg"),
        local.post("/api/sessions/import", data={"robot": "nao", "name": "b"}, files={"data": ("b.csv", b"\xff\xfe")}),
        local.post("/api/sessions/import", data={"robot": "nao", "name": "b"}, files={"data": ("b.csv", b"a,b\n1")}),
        local.post("/api/sessions/import", data={"robot": "r2d2", "name": "b"}, files={"data": ("b.csv", b"a\n")}),
        local.post("/api/robot/move", json={"joints": {"elbow_pitch": 1e9}}),
        local.post("/api/robot/move", content=b"{not json", headers={"Content-Type": "application/json"}),
        local.post("/api/sessions/nao/replay", json={"from_session": "../../etc"}),
        local.post("/api/jobs/j-00000000/pause"),
        local.get("/api/review/marks/3"),
    ]
    roots = {str(desk.data_dir), str(desk.data_dir.resolve()), str(Path(__file__).resolve().parent.parent)}
    for r in bad:
        assert r.status_code >= 400, r.text
        detail = r.json()["detail"]
        assert isinstance(detail, str) and detail, r.text
        assert "Traceback" not in detail and 'File "' not in detail and ".py" not in detail, detail
        assert not any(root in detail for root in roots), detail
    # The corrupt file is named by its name only.
    assert f"{cal_id}.json" in bad[0].json()["detail"]


def test_the_scrubber_keeps_names_and_drops_directories(tmp_path: Path) -> None:
    scrub = Scrubber([tmp_path])
    assert scrub(f"{tmp_path}/calibrations/c-1.json: line 2: bad") == "c-1.json: line 2: bad"
    assert scrub(f"cannot write '{tmp_path}/sessions/s-1/images/0001_a.jpg'") == "cannot write '0001_a.jpg'"
    assert scrub("no session is loaded (POST /api/review first)") == "no session is loaded (POST /api/review first)"
    assert scrub(f"{tmp_path}x/other") == f"{tmp_path}x/other"  # another directory that shares a prefix


def _share_requests(server: viser.ViserServer) -> list[int]:
    """Send the share-URL request any websocket client can send, and count the tunnels asked for."""
    asked: list[int] = []
    server.request_share_url = lambda *a, **k: asked.append(1)  # type: ignore[method-assign]

    async def send() -> None:
        url = f"ws://127.0.0.1:{server.get_port()}"
        async with websockets.connect(url, subprotocols=[f"viser-v{viser.__version__}"]) as ws:
            await ws.send(msgspec.msgpack.encode({"type": "ShareUrlRequest"}))
            await asyncio.sleep(0.5)

    asyncio.run(send())
    return asked


@pytest.mark.slow
def test_no_websocket_client_can_open_the_viser_share_tunnel() -> None:
    plain = viser.ViserServer(host="127.0.0.1", port=0, verbose=False)
    closed = viser.ViserServer(host="127.0.0.1", port=0, verbose=False)
    try:
        close_share_tunnel(closed)
        assert _share_requests(plain) == [1]  # the message works: viser would tunnel the scene out
        assert _share_requests(closed) == []
    finally:
        plain.stop()
        closed.stop()


def test_the_desks_scene_has_its_share_closed(remote: TestClient, local: TestClient) -> None:
    from viser import _messages

    for client in (remote, local):
        desk = client.app.state.desk
        assert _messages.ShareUrlRequest not in desk.viser._websock_server._incoming_handlers
        # Off loopback too, viser listens on loopback only: browsers reach the scene through the API's port.
        assert listening(desk.viser_port_number) == {"127.0.0.1"}


# --- the 3-D scene through the API's port (app/web/scene_proxy.py) ----------------------------------------------
def _scene_socket(client: TestClient, **headers: str):
    """The scene's websocket as a browser on the desk's page opens it (TestClient would say Host: testserver)."""
    return client.websocket_connect(
        "/scene/tab", subprotocols=[PROTOCOL], headers={"Host": client.base_url.netloc.decode(), **headers}
    )


def _refused(client: TestClient, **headers: str) -> WebSocketDenialResponse:
    with pytest.raises(WebSocketDenialResponse) as refused, _scene_socket(client, **headers):
        pass
    return refused.value


def test_off_loopback_the_scene_needs_the_token(remote: TestClient) -> None:
    """The scene's page and its websocket, like the API: refused without the token, answered with it (header,
    ?token= on the page, or the read cookie an answer to a request with the token set)."""
    token = remote.app.state.new_token
    remote.cookies.clear()
    for r in (
        remote.get("/scene/tab/"),
        remote.get("/scene/tab/?token=wrong"),
        remote.get("/scene/tab/", headers=bearer("x")),
    ):
        assert r.status_code == 401 and "token" in r.json()["detail"], r.text
    for headers in ({}, {"Authorization": "Bearer wrong"}):
        refusal = _refused(remote, **headers)
        assert refusal.status_code == 401 and "token" in refusal.json()["detail"]
    remote.cookies.set("calib_read", "guessed")
    assert _refused(remote).status_code == 401
    remote.cookies.clear()

    page = remote.get("/scene/tab/", headers=bearer(token))
    assert page.status_code == 200 and b"<html" in page.content[:200].lower()
    with _scene_socket(remote, Authorization=f"Bearer {token}") as ws:
        assert ws.accepted_subprotocol == PROTOCOL
    remote.cookies.clear()
    page = remote.get(f"/scene/tab/?token={token}")  # the iframe's address may carry it
    assert page.status_code == 200 and "Path=/;" in page.headers["set-cookie"]
    cookie = f"calib_read={page.cookies['calib_read']}"
    remote.cookies.clear()
    with _scene_socket(remote, Cookie=cookie) as ws:  # the browser's websocket carries the cookie only
        assert ws.accepted_subprotocol == PROTOCOL
        ws.send_bytes(camera_message())
        assert len(ws.receive_bytes()) > 0  # viser's scene comes through
    remote.cookies.clear()


def test_another_sites_page_cannot_open_the_scene(local: TestClient) -> None:
    """On loopback no token is needed, so a page of another site (whose websocket the browser would open with the
    desk's cookies) and a rebound host name are refused."""
    for origin in ("http://evil.example", "null", "http://127.0.0.1:9999"):
        refusal = _refused(local, Origin=origin)
        assert refusal.status_code == 403 and "another site" in refusal.json()["detail"]
    assert _refused(local, Host="evil.example:8000").status_code == 403
    with _scene_socket(local, Origin=LOCAL) as ws:
        assert ws.accepted_subprotocol == PROTOCOL
    assert local.get("/scene/tab/", headers={"Host": "evil.example:8000"}).status_code == 403


def test_off_loopback_the_api_document_and_its_page_need_the_token(remote: TestClient) -> None:
    """/openapi.json and /docs describe every endpoint: off loopback they answer only with the token (the page,
    opened by address, may carry it as ?token=, which sets the read cookie its fetch of the document uses)."""
    token = remote.app.state.new_token
    remote.cookies.clear()
    for path in ("/openapi.json", "/docs"):
        assert remote.get(path).status_code == 401, path
    assert remote.get("/openapi.json", headers=bearer(token)).json()["info"]["title"]
    remote.cookies.clear()
    page = remote.get(f"/docs?token={token}")
    assert page.status_code == 200 and "swagger" in page.text.lower()
    assert remote.get("/openapi.json").status_code == 200  # with the read cookie the page's answer set
    remote.cookies.clear()


def test_no_page_of_another_site_can_frame_the_desk(local: TestClient) -> None:
    """Headers: the page and the API forbid every framing; the scene allows only the desk's own page."""
    for path in ("/", "/index.html", "/api/health", "/api/sessions", "/docs"):
        r = local.get(path)
        assert r.headers["x-frame-options"] == "DENY", path
        assert r.headers["content-security-policy"] == "frame-ancestors 'none'", path
    scene = local.get("/scene/tab/")
    assert scene.status_code == 200
    assert scene.headers["x-frame-options"] == "SAMEORIGIN"
    assert scene.headers["content-security-policy"] == "frame-ancestors 'self'"


@pytest.mark.browser
@pytest.mark.subprocess
def test_a_framing_page_of_another_site_gets_nothing_in_the_browser(chromium, tmp_path: Path, desk_data: Path) -> None:
    """Clickjacking: a page on another origin frames the desk to have a click start the scripted wander. In a
    real browser the frame stays empty, while the same page frames one of its own pages; the desk's own page
    still shows its scene in its iframe."""
    from http.server import SimpleHTTPRequestHandler, ThreadingHTTPServer
    from threading import Thread

    from browser import desk_served, free_port, ready_page, wait_for_scene

    with desk_served(desk_data) as server:
        site = tmp_path / "site"
        site.mkdir()
        (site / "own.html").write_text("<p id=own>the attacker's own page</p>")
        (site / "attack.html").write_text(
            f'<iframe id=desk src="{server.url}/" width=800 height=600></iframe><iframe id=own src="own.html"></iframe>'
        )
        handler = partial(SimpleHTTPRequestHandler, directory=str(site))
        other = ThreadingHTTPServer(("127.0.0.1", free_port()), handler)
        Thread(target=other.serve_forever, daemon=True).start()
        try:
            page = chromium.new_page()
            page.goto(f"http://127.0.0.1:{other.server_address[1]}/attack.html")
            own = page.frame_locator("#own").locator("#own")
            own.wait_for(timeout=30_000)  # a frame the browser lets in shows its page
            page.wait_for_load_state("load")  # every frame has loaded, or failed to
            desk = page.query_selector("#desk").content_frame()
            assert desk is not None and desk.url.startswith("chrome-error"), desk and desk.url  # refused
            assert desk.query_selector("#robot-select") is None
            # The desk's own page still frames its scene.
            wait_for_scene(ready_page(chromium, server.url))
        finally:
            other.shutdown()
