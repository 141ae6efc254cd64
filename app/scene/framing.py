"""Where the 3-D view's camera stands: a framing of a box, kept on every browser that shows the scene.

A framing looks at the box's centre from the front (+x, the way the scene turns every robot) and a little
above, far enough that the box's bounding sphere fits the narrower of the camera's two fields of view. When
the robot shown changes, `ClientFraming.frame` moves the camera of every browser the scene draws on (its
own framing would show a 2 m robot through a camera set for a 0.5 m one, or the other way round): one
viewer's browser, or every connected one, when viser's initial camera is set too for browsers that connect
later. A browser that has not reported its camera yet is framed when it first does.

A framing may stand at a given distance (`distance_m`): each browser then narrows its field of view until the
box fits (a telephoto view, the Review's "frame it": both side-by-side copies seen from nearly the same
direction); one without it sets the default field of view back (`fov_rad`), or keeps the browser's.
"""

from __future__ import annotations

import math
import threading
from dataclasses import dataclass
from typing import TypedDict

import numpy as np
import viser

from .viser_private import send_fov

ELEVATION_DEG = 20.0  # the camera's height above the box centre, as an angle
MARGIN = 1.1  # room around the bounding sphere
DEFAULT_FOV_RAD = math.radians(75.0)  # viser's vertical field of view (three.js' default)
MIN_RADIUS_M = 0.05  # a box of a single point still gets a view
FRONT = np.array(  # from the look-at point to the camera: ahead (+x) and a little above
    [math.cos(math.radians(ELEVATION_DEG)), 0.0, math.sin(math.radians(ELEVATION_DEG))]
)


@dataclass(frozen=True)
class Framing:
    """A view of a (2, 3) world box: look at its centre from `direction` (unit, centre to camera)."""

    box_m: np.ndarray
    look_at: np.ndarray
    direction: np.ndarray
    radius_m: float  # of the box's bounding sphere
    up: tuple[float, float, float] = (0.0, 0.0, 1.0)
    distance_m: float | None = None  # stand this far from the look-at point, the field of view narrowed to fit
    fov_rad: float | None = None  # the vertical field of view to set (None: the browser's own)

    def view(self, fov_rad: float = DEFAULT_FOV_RAD, aspect: float = 1.0) -> tuple[float, float]:
        """(distance, vertical field of view) for a browser whose camera has `fov_rad` and `aspect`."""
        aspect = aspect if math.isfinite(aspect) and aspect > 0 else 1.0
        if self.distance_m is None:
            fov = fov_rad if self.fov_rad is None else self.fov_rad
            return self.distance(fov, aspect), fov
        # The narrower of the two fields of view just holds the bounding sphere (with the margin).
        narrow = 2 * math.asin(min(1.0, MARGIN * self.radius_m / self.distance_m))
        fov = narrow if aspect >= 1 else 2 * math.atan(math.tan(narrow / 2) / aspect)
        fov = min(fov, DEFAULT_FOV_RAD)
        return max(self.distance_m, self.distance(fov, aspect)), fov

    def distance(self, fov_rad: float = DEFAULT_FOV_RAD, aspect: float = 1.0) -> float:
        """From the look-at point to the camera: the bounding sphere inside the vertical field of view
        `fov_rad` and the horizontal one it gives at `aspect` (width / height)."""
        if not (math.isfinite(fov_rad) and 0 < fov_rad < math.pi):
            fov_rad = DEFAULT_FOV_RAD
        aspect = aspect if math.isfinite(aspect) and aspect > 0 else 1.0
        horizontal = 2 * math.atan(math.tan(fov_rad / 2) * aspect)
        return MARGIN * self.radius_m / math.sin(min(fov_rad, horizontal) / 2)


def framing(
    box_m: np.ndarray,
    *,
    min_radius_m: float = MIN_RADIUS_M,
    distance_m: float | None = None,
    fov_rad: float | None = None,
) -> Framing:
    """The framing of a (2, 3) min/max box in the world (z up), its bounding sphere at least `min_radius_m`;
    `distance_m`, `fov_rad`: see Framing."""
    box = np.asarray(box_m, dtype=float).reshape(2, 3)
    radius = max(float(np.linalg.norm(box[1] - box[0])) / 2, min_radius_m, MIN_RADIUS_M)
    return Framing(box, box.mean(axis=0), FRONT, radius, distance_m=distance_m, fov_rad=fov_rad)


def leave_box(start: np.ndarray, direction: np.ndarray, box_m: np.ndarray) -> float:
    """How far from `start` along unit `direction` a ray leaves the (2, 3) box (0: it starts outside)."""
    start = np.asarray(start, float)
    if not np.all((box_m[0] <= start) & (start <= box_m[1])):
        return 0.0
    with np.errstate(divide="ignore"):
        far = np.where(direction > 0, box_m[1] - start, box_m[0] - start) / direction
    return float(np.min(far[np.isfinite(far) & (direction != 0)]))


def camera_reported(camera: viser.CameraHandle) -> bool:
    """Whether the browser has sent its camera yet (before that viser knows nothing of it)."""
    try:
        return camera.update_timestamp > 0
    except AssertionError:
        return False


Target = viser.ViserServer | viser.ClientHandle  # every browser's scene, or one browser's


class FramingState(TypedDict):
    """The current framing (`ClientFraming.state`)."""

    look_at: list[float]
    radius_m: float
    box_m: list[list[float]]


class ClientCamera(TypedDict):
    """A browser's camera: whether it has the current framing, where it is (None: it has not reported yet)."""

    framed: bool
    look_at: list[float] | None
    position: list[float] | None


class CameraState(TypedDict):
    """`ClientFraming.state`: the framing (None: none yet) and each browser's camera by client id."""

    framing: FramingState | None
    clients: dict[int, ClientCamera]


class ClientFraming:
    """Keeps the browsers' cameras on the latest framing: moved once per framing, free in between. The browsers
    of a target: one (a viser client) or every one connected (the server; those that connect later start at
    the framing too)."""

    def __init__(self, target: Target) -> None:
        self.target = target
        self.current: Framing | None = None
        self._version = 0
        self._framed: dict[int, int] = {}  # client id -> the framing version its camera was given
        self._lock = threading.Lock()
        if isinstance(target, viser.ClientHandle):
            self._connected(target)
        else:
            target.on_client_connect(self._connected)
            target.on_client_disconnect(self._disconnected)

    def frame(self, f: Framing) -> None:
        """Frame `f` on every browser of the target now (and, for the server, on those that connect later)."""
        with self._lock:
            self.current = f
            self._version += 1
            if isinstance(self.target, viser.ViserServer):
                self.target.initial_camera.up = f.up
                self.target.initial_camera.look_at = tuple(float(v) for v in f.look_at)
                distance, fov = f.view()
                self.target.initial_camera.fov = fov
                self.target.initial_camera.position = tuple(float(v) for v in f.look_at + distance * f.direction)
        for client in list(self._clients().values()):
            self._apply(client)

    def _clients(self) -> dict[int, viser.ClientHandle]:
        target = self.target
        return {target.client_id: target} if isinstance(target, viser.ClientHandle) else target.get_clients()

    def state(self) -> CameraState:
        """{framing: {look_at, radius_m, box_m} or None, clients: {id: {framed, look_at, position}}}."""
        with self._lock:
            f, version, framed = self.current, self._version, dict(self._framed)
        clients: dict[int, ClientCamera] = {}
        for cid, client in self._clients().items():
            cam = client.camera
            seen = camera_reported(cam)
            clients[cid] = {
                "framed": framed.get(cid) == version,
                "look_at": [float(v) for v in cam.look_at] if seen else None,
                "position": [float(v) for v in cam.position] if seen else None,
            }
        out: FramingState | None = None
        if f is not None:
            out = {"look_at": f.look_at.tolist(), "radius_m": f.radius_m, "box_m": f.box_m.tolist()}
        return {"framing": out, "clients": clients}

    # --- viser callbacks ----------------------------------------------------------------------------
    def _connected(self, client: viser.ClientHandle) -> None:
        client.camera.on_update(lambda _camera: self._apply(client))

    def _disconnected(self, client: viser.ClientHandle) -> None:
        with self._lock:
            self._framed.pop(client.client_id, None)

    def _apply(self, client: viser.ClientHandle) -> None:
        """Move this browser's camera to the current framing unless it has it already."""
        cam = client.camera
        with self._lock:
            f, version = self.current, self._version
            if f is None or self._framed.get(client.client_id) == version or not camera_reported(cam):
                return
            self._framed[client.client_id] = version
            aspect = cam.image_width / cam.image_height if cam.image_height else 1.0
            distance, fov = f.view(cam.fov, aspect)
            position = f.look_at + distance * f.direction
            send_fov(cam, fov)
            cam.up_direction = f.up
            cam.position = position  # moves the look-at point along with it
            cam.look_at = f.look_at
