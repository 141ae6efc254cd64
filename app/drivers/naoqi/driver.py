"""A NAO through NAOqi behind the RobotDriver interface (driver kind `naoqi`; specs naoqi.md): the driver core
(core.py) over libqi's ALMotion, ALVideoDevice and ALPreferenceManager.

Options (a connection file's fields, app/drivers/naoqi/connection.py; `calib serve --naoqi FILE` makes them): `url` (the
robot's NAOqi address, tcp://host:9559), `camera` (ALVideoDevice's index: 1, the lower camera, the paper's),
and as extensions `color_space` (what the camera is asked for: 0 grey, 9 YUV 4:2:2, 11 RGB, 13 BGR), `fps`,
`margin_deg`, `tolerance_deg` (a move has arrived when every reading is this close), `still_deg` (readings that
change less stand still), `timeout_s` (no readings for this long: disconnected), `measurement_wait_s` (how
long a look waits for an image exposed after the settled readings) and `call_timeout_s` (how long any call to
NAOqi may take before the robot is not responding: the core's deadlines, calls.py).

The robot may be away when the desk starts and may go away at any time: the link is opened on the first reading
and opened again (at most every RETRY_S) after NAOqi stopped answering; meanwhile the robot is disconnected with
the sentence why. A move sets the stiffness of every joint first and is refused, nothing moved, when a joint's
stiffness stays off. The joints' values are NAOqi's sensor readings (the paper's measured angles, the data
format's columns); the applied calibration's offsets reach the commands through the desk's model, which plans
them, and are stored on the robot by apply (deploy).
"""

from __future__ import annotations

import contextlib
import json
import math
import threading
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np

from calib_core import Calibration, InputError, Profile
from calib_core.io import NAOQI_COLOR_SPACES, estimated_offsets_deg, naoqi_image

from ...clock import Clock
from .. import RobotFault
from ..calls import calling
from ..core import DEFAULT_SETTLE_S, Command, Driver, Feed, Measurement, Motion, Poller, per_joint
from ..registry import DriverContext

OPTIONS: dict[str, Any] = {
    "url": "tcp://127.0.0.1:9559",
    "camera": 1,
    "color_space": 9,
    "fps": 15,
    "margin_deg": 1.0,
    "tolerance_deg": 0.5,
    "still_deg": 0.05,
    "timeout_s": 1.0,
    "measurement_wait_s": 5.0,
    "settle_s": DEFAULT_SETTLE_S,
    "call_timeout_s": 2.0,
}
NUMBERS = ("margin_deg", "tolerance_deg", "still_deg", "timeout_s", "measurement_wait_s", "settle_s", "call_timeout_s")
RATE_HZ = 50.0  # joint readings asked for this often
RETRY_S = 1.0  # a robot that does not answer is asked again this often
STILL_WINDOW_S = 0.15
RESOLUTION_VGA = 2  # ALVideoDevice's kVGA: 640 x 480
SUBSCRIBER = "calib_desk"
PREFERENCES = ("calib", "joint_offsets_deg")  # ALPreferenceManager's domain and setting for the offsets
STIFF = 0.5  # a joint whose stiffness reads below this after setStiffnesses(1.0) is off


def check(profile: Profile, options: Mapping[str, Any], where: str, options_at: str) -> dict[str, Any]:
    """The options checked (InputError naming `options_at`.<option>), with their defaults."""
    from . import require

    require()
    unknown = sorted(set(options) - set(OPTIONS))
    if unknown:
        raise InputError(
            f"{options_at}.{unknown[0]}: no such option of the naoqi driver (options: {', '.join(OPTIONS)})"
        )
    out = {**OPTIONS, **options}
    url = out["url"]
    if not isinstance(url, str) or not url.startswith(("tcp://", "tcps://")) or any(c.isspace() for c in url):
        raise InputError(f"{options_at}.url: expected the robot's NAOqi address, tcp://host:9559, got {url!r}")
    if out["camera"] not in (0, 1) or isinstance(out["camera"], bool):
        raise InputError(f"{options_at}.camera: expected 0 (the upper camera) or 1 (the lower one, the paper's)")
    if out["color_space"] not in NAOQI_COLOR_SPACES or isinstance(out["color_space"], bool):
        spaces = ", ".join(f"{k} ({v})" for k, v in NAOQI_COLOR_SPACES.items())
        raise InputError(f"{options_at}.color_space: expected one of {spaces}")
    if isinstance(out["fps"], bool) or not isinstance(out["fps"], int) or not 1 <= out["fps"] <= 30:
        raise InputError(f"{options_at}.fps: expected a whole number of images a second, 1..30")
    for key in NUMBERS:
        value = out[key]
        if isinstance(value, bool) or not isinstance(value, int | float) or not 0 < value < 1e6:
            raise InputError(f"{options_at}.{key}: expected a positive number, got {value!r}")
        out[key] = float(value)
    if profile.sensors[profile.data.sensor].image_size_px() is None:
        raise InputError(f"{where}: the naoqi driver reads a camera, and {profile.name}'s data sensor is none")
    return out


def create(profile: Profile, options: Mapping[str, Any], context: DriverContext) -> Driver:
    motion = Motion(
        tolerance=per_joint(profile, options["tolerance_deg"], 0.0),
        still=per_joint(profile, options["still_deg"], 0.0),
        margin_deg=options["margin_deg"],
        still_window_s=STILL_WINDOW_S,
        timeout_s=options["timeout_s"],
        settle_s=options["settle_s"],
        call_timeout_s=options["call_timeout_s"],
        measure_timeout_s=options["measurement_wait_s"] + options["call_timeout_s"],
        apply_timeout_s=options["call_timeout_s"],
    )
    return Driver(profile, NaoqiTransport(profile, options), motion, clock=context.clock)


@dataclass
class _Link:
    """An open libqi session and the robot's services on it."""

    session: Any
    motion: Any
    video: Any
    preferences: Any
    camera: str  # ALVideoDevice's handle of our subscription
    max_speed: np.ndarray  # ALMotion's maximum speed of each joint, rad/s


class NaoqiTransport:
    """Joint readings polled from ALMotion, a move an asynchronous angleInterpolationWithSpeed, STOP
    killTasksUsingResources, a look the camera's images newer than the settled readings; apply stores the
    offsets in ALPreferenceManager (Deploys)."""

    def __init__(self, profile: Profile, options: Mapping[str, Any]) -> None:
        self.profile = profile
        self.options = dict(options)
        self.url = options["url"]
        self.names = [j.name for j in profile.joints]  # the profile's joint names are NAOqi's
        self.velocity = np.array([j.velocity for j in profile.joints])
        self.readings_from = f"joint readings from ALMotion at {self.url}"
        self._lock = threading.Lock()  # the link below
        self._link: _Link | None = None
        self._tried = -math.inf  # when the link was last opened, the clock's s
        self._why = f"NAOqi at {self.url} not asked yet"
        self._offset_s = math.inf  # this clock less the robot's, as the images' stamps show it (the least seen)
        self._closing = threading.Event()

    # --- the link ---------------------------------------------------------------------------------------
    def start(self, feed: Feed, clock: Clock) -> None:
        self.clock = clock
        self.poller = Poller(self.read, feed, clock, 1.0 / RATE_HZ, f"naoqi-{self.profile.name}")

    def _connected(self) -> _Link:
        """The open link, opened now if it is time to try again; RobotFault saying why there is none."""
        with self._lock:
            if self._link is not None:
                return self._link
            if self._closing.is_set():
                raise RobotFault("the driver was closed")
            now = self.clock.now()
            if now - self._tried < RETRY_S:
                raise RobotFault(self._why)
            self._tried = now
            try:
                self._link = self._open()
            except RuntimeError as exc:
                self._why = f"NAOqi does not answer at {self.url} ({exc})"
                raise RobotFault(self._why) from None
            return self._link

    def _open(self) -> _Link:
        from . import open_session

        calling(f"the connection to {self.url}")
        session = open_session(self.url)
        try:
            motion = session.service("ALMotion")
            video = session.service("ALVideoDevice")
            preferences = session.service("ALPreferenceManager")
            calling("ALMotion.getLimits")
            max_speed = np.array([float(motion.getLimits(name)[0][2]) for name in self.names])
            o = self.options
            calling("ALVideoDevice.subscribeCamera")
            camera = video.subscribeCamera(SUBSCRIBER, o["camera"], RESOLUTION_VGA, o["color_space"], o["fps"])
        except (RuntimeError, AttributeError) as exc:  # a missing service or method: AttributeError
            session.close()
            raise RuntimeError(f"its services do not answer: {exc}") from None
        return _Link(session, motion, video, preferences, camera, max_speed)

    def _lost(self, link: _Link, exc: Exception) -> RobotFault:
        """The link is gone: forgotten (the next reading opens it again); the fault to raise."""
        with self._lock:
            if self._link is link:
                self._link = None
                self._why = f"lost NAOqi at {self.url} ({exc})"
                self._tried = -math.inf
                _close_quietly(link.session)
        return RobotFault(self._why)

    def _call(self, link: _Link, service: str, method: str, *args: Any, **kwargs: Any) -> Any:
        """`service.method(*args)` on the robot, named for the core's deadline; RobotFault naming the call when the
        robot does not offer it, or saying the link is lost."""
        calling(f"{service}.{method}")
        proxy = {"ALMotion": link.motion, "ALVideoDevice": link.video, "ALPreferenceManager": link.preferences}
        try:
            fn = getattr(proxy[service], method)
        except AttributeError:
            raise RobotFault(
                f"{service} at {self.url} offers no {method}, which the desk uses (docs/naoqi.md lists the calls): "
                "a NAOqi it cannot drive; nothing was done"
            ) from None
        try:
            return fn(*args, **kwargs)
        except RuntimeError as exc:
            raise self._lost(link, exc) from None

    def read(self) -> tuple[np.ndarray, float]:
        link = self._connected()
        q = self._call(link, "ALMotion", "getAngles", self.names, True)  # the sensors' readings, rad
        try:
            return np.array(q, float).reshape(len(self.names)), self.clock.now()
        except (TypeError, ValueError):
            raise RobotFault(f"ALMotion.getAngles answered {str(q)[:80]!r}, not one angle a joint") from None

    # --- moving -----------------------------------------------------------------------------------------
    def send(self, command: Command) -> None:
        """Stiffness on, checked, then the move at the fraction of the joints' maximum speed that takes
        command.duration_s and keeps every moving joint within its velocity limit; asynchronous, so that a stop
        can end it."""
        link = self._connected()
        self._call(link, "ALMotion", "setStiffnesses", self.names, 1.0)  # a NAO without stiffness does not move
        stiffness = np.array(self._call(link, "ALMotion", "getStiffnesses", self.names), float)
        off = [name for name, s in zip(self.names, stiffness, strict=True) if s < STIFF]
        if off:
            raise RobotFault(
                f"the stiffness of {', '.join(off)} stays off after setStiffnesses (a hot joint, or the robot "
                "resting?); nothing was moved"
            )
        fraction = self.speed_fraction(command, link.max_speed)
        goal = [float(v) for v in command.goal]
        self._call(link, "ALMotion", "angleInterpolationWithSpeed", self.names, goal, fraction, _async=True)

    def speed_fraction(self, command: Command, max_speed: np.ndarray) -> float:
        """NAOqi's fraction of the joints' maximum speed: the one that takes command.duration_s when all joints
        arrive together, never more than a moving joint's velocity limit over its maximum speed."""
        delta = np.abs(command.goal - command.start)
        moving = delta > 0
        if not moving.any():
            return 1.0
        cap = float(np.min(self.velocity[moving] / max_speed[moving]))
        if command.duration_s <= 0:
            return min(1.0, cap)
        needed = float(np.max(delta[moving] / max_speed[moving])) / command.duration_s
        return min(1.0, cap, max(needed, 0.01))

    def halt(self) -> None:
        """killTasksUsingResources: the joints hold where they are. RobotFault when NAOqi cannot be told (a robot
        that does not answer is not moving by the desk's command either, but the operator is told)."""
        with self._lock:
            link, why = self._link, self._why
        if link is None:
            raise RobotFault(why)
        self._call(link, "ALMotion", "killTasksUsingResources", self.names)

    # --- seeing -----------------------------------------------------------------------------------------
    def measure(self, since_s: float, target: int) -> Measurement:
        """The first image exposed after the settled readings (`since_s`, this clock) and newer than the one
        the camera had when the look began. The robot's stamps run on its own clock: this clock less the robot's
        is taken as the least difference seen between an image's arrival and its stamp (an image cannot arrive
        before it was exposed)."""
        try:
            link = self._connected()
        except RobotFault as exc:
            return Measurement(missing=str(exc))
        wait_s = self.options["measurement_wait_s"]
        deadline = self.clock.now() + wait_s
        first = math.nan
        while True:
            try:
                remote = self._call(link, "ALVideoDevice", "getImageRemote", link.camera)
            except RobotFault as exc:
                return Measurement(missing=str(exc))
            size = self._size(remote)
            if size:
                return Measurement(missing=size)
            try:
                image, stamp = naoqi_image(remote) if remote else (None, math.nan)
            except ValueError as exc:
                return Measurement(missing=f"camera {self.options['camera']}: {exc}")
            if image is not None:
                self._offset_s = min(self._offset_s, self.clock.now() - stamp)
                if math.isnan(first):
                    first = stamp
                elif stamp > first and stamp + self._offset_s > since_s:
                    return Measurement(images={"image": image})
            if self.clock.now() >= deadline:
                return Measurement(
                    missing=f"no image from camera {self.options['camera']} exposed after the robot settled "
                    f"(none within {wait_s:g} s)"
                )
            self.clock.wait(self._closing, 1.0 / self.options["fps"])

    def _size(self, remote: Any) -> str:
        """Why an image of the size getImageRemote says is not the profile's camera's (read before its bytes are
        decoded: a damaged header may claim any size), or ""."""
        if not remote:
            return ""
        sensor = self.profile.sensors[self.profile.data.sensor]
        width, height = sensor.image_size_px()
        if (remote[0], remote[1]) != (width, height):
            return (
                f"camera {self.options['camera']} sends {remote[0]} x {remote[1]} px images; the profile's "
                f"{sensor.name} is {width} x {height} px"
            )
        return ""

    # --- calibration ------------------------------------------------------------------------------------
    def deploy(self, cal_id: str, cal: Calibration) -> str:
        """The leg offsets (deg, to add to the readings) stored on the robot as JSON, for the software that reads
        its joints; RobotFault when NAOqi does not take them (nothing applied)."""
        offsets = estimated_offsets_deg(self.profile, cal)
        if not offsets:
            raise RobotFault(f"apply: {cal_id} estimated no joint offsets; nothing to store on the robot")
        try:
            link = self._connected()
            self._call(link, "ALPreferenceManager", "setValue", *PREFERENCES, json.dumps(offsets))
        except RobotFault as exc:
            raise RobotFault(f"apply: {exc}; nothing applied") from None
        return f"stored {len(offsets)} joint offsets in ALPreferenceManager {PREFERENCES[0]}/{PREFERENCES[1]}"

    # --- life -------------------------------------------------------------------------------------------
    def close(self) -> None:
        self._closing.set()
        self.poller.close()
        with self._lock:
            link, self._link = self._link, None
        if link is not None:
            with contextlib.suppress(RobotFault):
                self._call(link, "ALVideoDevice", "unsubscribe", link.camera)
            _close_quietly(link.session)


def _close_quietly(session: Any) -> None:
    with contextlib.suppress(RuntimeError):
        session.close()
