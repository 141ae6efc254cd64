"""Every use of viser's private names, in one place: the desk needs two things viser has no public API for.

- Which client a websocket became: viser's connect callback does not say which request made the client, so
  the scene proxy (app/web/scene_proxy.py) hooks viser's websocket server, whose callbacks run at the handshake,
  and reads the connection's peer address there.
- The share tunnel closed: the share button is hidden (`configure_theme`), but any websocket client can still
  send the message that asks viser to tunnel the scene through an external service; its handlers are dropped.
- A browser's field of view set for sure: viser's setter sends nothing when the value equals the one the browser
  last reported, and that report may predate the browser taking the previous setting (a narrow "frame it"
  view, then a robot change asking for the default: the browser kept the narrow one at the default's distance).

In viser's client (the browser), one more: static/viser_marks.js reads the three.js objects of the marks' nodes
(`window.__viserMutable.nodeRefFromName`, viser's hook for its own browser tests) to draw them over the bodies,
before each frame the client draws (`window.__viserMutable.scene`, three.js's `onBeforeRender` of the scene).

pyproject.toml pins viser to the minor version these were written and tested against (tests/test_security.py,
tests/test_viewers.py, tests/test_browser_scene.py); a new minor version is taken only once they pass on it.
"""

from __future__ import annotations

import time
from collections.abc import Callable

import viser

Address = tuple[str, int]


def on_connections(
    server: viser.ViserServer, opened: Callable[[int, Address], None], closed: Callable[[int], None]
) -> None:
    """Call `opened(client_id, peer_address)` as viser accepts a websocket, `closed(client_id)` as one closes
    (on viser's event loop)."""
    websock = server._websock_server

    def _opened(conn: object) -> None:
        client_id = int(conn.client_id)  # type: ignore[attr-defined]
        host, port = websock._live_connections[client_id].remote_address[:2]
        opened(client_id, (str(host), int(port)))

    def _closed(conn: object) -> None:
        closed(int(conn.client_id))  # type: ignore[attr-defined]

    websock.on_client_connect(_opened)
    websock.on_client_disconnect(_closed)


def close_share_tunnel(server: viser.ViserServer) -> None:
    """Drop viser's handlers of the share request, so no websocket client can tunnel the scene out."""
    from viser import _messages

    websock = server._websock_server
    for message in (_messages.ShareUrlRequest, _messages.ShareUrlDisconnect):
        if message in websock._incoming_handlers:
            websock.unregister_handler(message)


def send_fov(camera: viser.CameraHandle, fov_rad: float) -> None:
    """Set the browser's vertical field of view to `fov_rad`, sent even if viser believes it has it already."""
    from viser import _messages

    state = camera._state
    state.fov = float(fov_rad)
    state.update_timestamp = time.time()
    state.client._websock_connection.queue_message(_messages.SetCameraFovMessage(float(fov_rad)))
