"""The 3-D scene through the API's port: viser's client page and a websocket proxy to the loopback viser server.

The viser server is bound to 127.0.0.1 only; browsers reach it through FastAPI, same origin and same token as
the API (app/web/security.py guards `/scene` like `/api`, the websocket included):

- `GET /scene/<viewer>/` answers viser's prebuilt client page (the `index.html` of the installed package's
  `client/build/`) with static/viser_marks.js inlined (the review's marks drawn over the bodies) and
  static/viser_notice.js (viser's notice of software WebGL hidden; the desk's page says it under the view). viser's
  client makes its websocket URL from the page's address without the query, so the iframe's websocket comes to
  `/scene/<viewer>`: the path names the viewer (app/scene/viewers.py).
- `/scene/<viewer>` (websocket) opens a websocket to the viser server offering the browser's `viser-v<version>`
  subprotocol (viser closes with 1002 without it), accepts the browser's with the one viser chose, then copies
  frames (binary and text) both ways until one side closes, and closes the other with its code.

Which viser client a proxied websocket became: viser numbers clients in the order it accepts them, and its
connect callback does not say which request made them, so counting would go wrong as soon as two tabs connect
at once (or anything else connects to the loopback port). `ViserClients` hooks viser's websocket server
(app/scene/viser_private.py), whose connect callback runs at the handshake, and records each new connection's peer
address with its client id; the proxy looks up its own upstream socket's local address, which is that peer
address.
"""

from __future__ import annotations

import asyncio
import contextlib
import importlib.resources
import logging
import threading
from functools import cache
from typing import Annotated

import viser
import websockets
from fastapi import APIRouter, Path, Response, WebSocket, WebSocketDisconnect
from starlette.concurrency import run_in_threadpool
from websockets.asyncio.client import ClientConnection, connect

from ..scene.viewers import VIEWER_PATTERN, TooManyViewers
from ..scene.viser_private import Address, on_connections
from .static_dir import STATIC_DIR

CLAIM_TIMEOUT_S = 5.0  # viser reports a connection at its handshake: milliseconds
OPEN_TIMEOUT_S = 10.0
SENDABLE_CLOSE_CODES = frozenset({1000, 1001, 1002, 1003, 1007, 1008, 1009, 1010, 1011, 1012, 1013, 1014})
ViewerId = Annotated[str, Path(pattern=VIEWER_PATTERN, description="the viewer: an id the page makes")]
router = APIRouter(include_in_schema=False)
log = logging.getLogger("calib.scene")


@cache
def client_page() -> bytes:
    """viser's prebuilt client (one HTML file with everything inlined, shipped in the viser package), the script
    that draws the review's marks over the robot's bodies (static/viser_marks.js) and the one that hides viser's
    notice of software WebGL (static/viser_notice.js)."""
    page = importlib.resources.files("viser").joinpath("client", "build", "index.html").read_bytes()
    scripts = b"".join(
        b"<script>\n" + (STATIC_DIR / name).read_bytes() + b"</script>\n"
        for name in ("viser_marks.js", "viser_notice.js")
    )
    head, body_end, tail = page.rpartition(b"</body>")
    if not body_end:
        raise RuntimeError("viser's client page has no </body>: the desk's scripts have no place")
    return head + scripts + body_end + tail


class ViserClients:
    """The viser client id of each websocket connection to a viser server, by the connection's peer address."""

    def __init__(self, server: viser.ViserServer) -> None:
        self._lock = threading.Lock()
        self._ids: dict[Address, int] = {}  # reported, not yet claimed
        self._address: dict[int, Address] = {}
        self._waiting: dict[Address, tuple[asyncio.AbstractEventLoop, asyncio.Future[int]]] = {}
        on_connections(server, self._opened, self._closed)

    async def claim(self, connection: ClientConnection) -> int | None:
        """The viser client id of our connection to the viser server; None if viser closed it first (it refuses
        a client of another version before reporting it); TimeoutError if viser neither reports nor closes it."""
        address = _address(connection.local_address)
        loop = asyncio.get_running_loop()
        with self._lock:
            client_id = self._ids.pop(address, None)
            if client_id is not None:
                return client_id
            future: asyncio.Future[int] = loop.create_future()
            self._waiting[address] = (loop, future)
        closed = asyncio.ensure_future(connection.wait_closed())
        try:
            await asyncio.wait({future, closed}, timeout=CLAIM_TIMEOUT_S, return_when=asyncio.FIRST_COMPLETED)
        finally:
            closed.cancel()
            with self._lock:
                self._waiting.pop(address, None)
        if future.done():
            return future.result()
        if closed.done():
            return None
        raise TimeoutError(f"viser did not report the connection from {address}")

    # --- viser's callbacks, on its event loop ---------------------------------------------------------
    def _opened(self, client_id: int, address: Address) -> None:
        with self._lock:
            self._address[client_id] = address
            waiting = self._waiting.pop(address, None)
            if waiting is None:
                self._ids[address] = client_id
        if waiting is not None:
            loop, future = waiting
            loop.call_soon_threadsafe(_resolve, future, client_id)

    def _closed(self, client_id: int) -> None:
        with self._lock:
            address = self._address.pop(client_id, None)
            if address is not None:
                self._ids.pop(address, None)


def _resolve(future: asyncio.Future[int], client_id: int) -> None:
    if not future.done():
        future.set_result(client_id)


def _address(address: object) -> Address:
    host, port = tuple(address)[:2]  # type: ignore[call-overload]
    return str(host), int(port)


@router.get("/scene/{viewer}/")
def scene_page(viewer: ViewerId) -> Response:
    return Response(client_page(), media_type="text/html; charset=utf-8", headers={"Cache-Control": "no-cache"})


@router.websocket("/scene/{viewer}")
async def scene_socket(websocket: WebSocket, viewer: ViewerId) -> None:
    desk = websocket.app.state.desk
    try:
        await run_in_threadpool(desk.viewers.get, viewer)
    except TooManyViewers as exc:
        await websocket.close(1013, str(exc)[:120])
        return
    offered = [p for p in websocket.scope.get("subprotocols", []) if p.startswith("viser-v")]
    try:
        upstream = await connect(
            f"ws://127.0.0.1:{desk.viser_port_number}",
            subprotocols=offered or None,  # type: ignore[arg-type]
            compression=None,
            proxy=None,
            max_size=None,
            open_timeout=OPEN_TIMEOUT_S,
        )
    except (OSError, TimeoutError, websockets.InvalidHandshake):
        await websocket.close(1011, "the 3-D scene's server is not answering")
        return
    try:
        client_id = await desk.viser_clients.claim(upstream)
    except TimeoutError:
        await upstream.close()
        await websocket.close(1011, "the 3-D scene's server did not take the connection")
        return
    if client_id is None:  # refused by viser (another client version: 1002): the browser's client says why
        await websocket.accept(subprotocol=upstream.subprotocol)
        await _close(websocket, upstream)
        return
    try:
        await run_in_threadpool(desk.viewers.connected, viewer, client_id)
        await websocket.accept(subprotocol=upstream.subprotocol)
        await _relay(websocket, upstream)
    finally:
        desk.viewers.disconnected(client_id)
        await asyncio.shield(upstream.close())  # also when this task is cancelled (the server stopping)


async def _relay(browser: WebSocket, upstream: ClientConnection) -> None:
    """Copy messages both ways until one side closes; then close the other with its code."""

    async def from_browser() -> int:
        while True:
            message = await browser.receive()
            if message["type"] == "websocket.disconnect":
                return int(message.get("code") or 1000)
            data = message.get("bytes")
            await upstream.send(data if data is not None else message.get("text", ""))

    async def to_browser() -> None:
        async for data in upstream:
            if isinstance(data, bytes):
                await browser.send_bytes(data)
            else:
                await browser.send_text(data)

    browser_side = asyncio.create_task(from_browser())
    viser_side = asyncio.create_task(to_browser())
    await asyncio.wait({browser_side, viser_side}, return_when=asyncio.FIRST_COMPLETED)
    for task in (browser_side, viser_side):
        task.cancel()
    await asyncio.gather(browser_side, viser_side, return_exceptions=True)
    for task in (browser_side, viser_side):
        error = None if task.cancelled() else task.exception()
        if error is not None and not isinstance(error, websockets.ConnectionClosed | WebSocketDisconnect):
            log.warning("scene websocket: %s: %s", type(error).__name__, error)
    if not browser_side.cancelled() and browser_side.exception() is None:  # the browser left
        code = browser_side.result()
        await upstream.close(code if code in SENDABLE_CLOSE_CODES else 1000)
        return
    await _close(browser, upstream)


async def _close(browser: WebSocket, upstream: ClientConnection) -> None:
    """Close the browser's websocket as viser closed ours."""
    code = upstream.close_code if upstream.close_code in SENDABLE_CLOSE_CODES else 1011
    with contextlib.suppress(RuntimeError, WebSocketDisconnect, OSError):  # the browser may be gone as well
        await browser.close(code, upstream.close_reason or "")
