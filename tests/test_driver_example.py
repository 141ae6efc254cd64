"""The example driver of docs/drivers.md, run as written: a NAOqi driver that is one module and one registry line
over the driver core. A stand-in for NAOqi (the simulated NAO behind ALMotion and ALVideoDevice, on the test's
ManualClock) answers its calls: its options are checked, a refused move sends nothing, a move arrives at the
fraction of the joints' speed the velocity limits allow, a stop halts it, a look finds the sandal board in the
camera's YUV 4:2:2 image, and closing unsubscribes the camera. This is what the spec (specs naoqi.md) asks of
the core: joint readings polled, an asynchronous move call, a stop, a camera image."""

from __future__ import annotations

import math
import re
import sys
import threading
from collections.abc import Callable
from pathlib import Path
from types import SimpleNamespace
from typing import Any

import numpy as np
import pytest

from app.clock import ManualClock
from app.drivers import LimitError, registry
from app.drivers.registry import DriverContext, DriverSpec
from calib_core import InputError, SimulatedRobot, load_profile
from calib_core.estimation.planning import within_margin

ROOT = Path(__file__).resolve().parent.parent
DEG = math.pi / 180


def example() -> str:
    blocks = re.findall(
        r"^```python\n(.*?)^```", (ROOT / "docs" / "drivers.md").read_text(encoding="utf-8"), re.S | re.M
    )
    (source,) = [b for b in blocks if "class NaoqiTransport" in b]
    return source


class FakeNao:
    """ALMotion and ALVideoDevice as NAOqi answers them, over the simulated NAO: each joint moves towards its
    goal at `fraction` of its velocity limit (NAOqi's angleInterpolationWithSpeed), the camera exposes FPS images
    a second of the clock, rendered at the true pose."""

    FPS = 5

    def __init__(self, profile: Any, clock: ManualClock, q0: np.ndarray) -> None:
        self.sim = SimulatedRobot.from_profile(profile, seed=3)
        self.clock = clock
        self.names = [j.name for j in profile.joints]
        self.velocity = np.array([j.velocity for j in profile.joints])
        self.lock = threading.Lock()
        self.q, self.move = q0.copy(), None
        self.calls: list[tuple] = []
        self.subscribed: set[str] = set()

    def position(self, now: float) -> np.ndarray:
        with self.lock:
            if self.move is not None:
                start, goal, t0, speed = self.move
                step = np.minimum(np.abs(goal - start), speed * (now - t0))
                self.q = start + np.sign(goal - start) * step
            return self.q.copy()

    # ALMotion
    def getAngles(self, names: list[str], use_sensors: bool) -> list[float]:  # NAOqi's names
        assert names == self.names and use_sensors
        return self.sim.readings(self.position(self.clock.now())).tolist()

    def setStiffnesses(self, names: list[str], stiffness: float) -> None:
        self.calls.append(("setStiffnesses", stiffness))

    def angleInterpolationWithSpeed(self, names: list[str], angles: list[float], fraction: float, _async: bool) -> None:
        assert names == self.names and _async and 0 < fraction <= 1
        self.calls.append(("angleInterpolationWithSpeed", fraction))
        now = self.clock.now()
        start = self.position(now)
        with self.lock:
            self.move = (start, np.array(angles), now, fraction * self.velocity)

    def killTasksUsingResources(self, names: list[str]) -> None:
        self.calls.append(("killTasksUsingResources",))
        self.position(self.clock.now())
        with self.lock:
            self.move = None

    # ALVideoDevice
    def subscribeCamera(self, name: str, camera: int, resolution: int, space: int, fps: int) -> str:
        assert (camera, resolution, space, fps) == (1, 2, 9, self.FPS)
        self.subscribed.add(name)
        return name

    def getImageRemote(self, handle: str) -> list:
        assert handle in self.subscribed
        exposure = math.floor(self.clock.now() * self.FPS) / self.FPS
        images, _ = self.sim.render(self.position(exposure), 0)  # the left foot's board
        grey = images["image"]
        yuyv = np.dstack([grey, np.full_like(grey, 128)])  # kYUV422: Y U Y V, the luma every other byte
        return [grey.shape[1], grey.shape[0], 2, 9, int(exposure), round(exposure % 1 * 1e6), yuyv.tobytes()]

    def unsubscribe(self, handle: str) -> None:
        self.subscribed.discard(handle)


@pytest.fixture
def naoqi(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> FakeNao:
    """The example written to a module and registered as kind `naoqi` (its one registry line), `qi` a stand-in
    whose session's services are the fake NAO (returned)."""
    (tmp_path / "naoqi_example.py").write_text(example(), encoding="utf-8")
    monkeypatch.syspath_prepend(str(tmp_path))
    monkeypatch.setitem(registry.KINDS, "naoqi", "naoqi_example")
    nao = load_profile("nao")
    fake = FakeNao(nao, ManualClock(), SimulatedRobot.from_profile(nao, seed=5).configurations(1)[0][0])

    def connect(url: str) -> None:
        assert url == "tcp://127.0.0.1:9559"

    session = SimpleNamespace(connect=connect, service=lambda name: fake)
    monkeypatch.setitem(sys.modules, "qi", SimpleNamespace(Session=lambda: session))
    return fake


def _in_thread(clock: ManualClock, threads: int, call: Callable[[], Any]) -> Any:
    """call() in a thread of its own, the clock run (with the driver's poller) until it returns."""
    out: list[Any] = []
    worker = threading.Thread(target=lambda: out.append(call()))
    worker.start()
    clock.run(lambda: not worker.is_alive(), threads=threads, limit_s=60)
    worker.join()
    return out[0]


def test_the_example_driver_is_one_module_of_about_150_lines() -> None:
    assert len(example().splitlines()) <= 150


@pytest.mark.slow
def test_the_example_naoqi_driver_moves_stops_and_looks_through_the_core(naoqi) -> None:
    nao = load_profile("nao")
    with pytest.raises(InputError, match=r"^driver\.camera: expected 0 \(the upper camera\) or 1"):
        registry.check(DriverSpec("naoqi", {"camera": 3}), nao)
    with pytest.raises(InputError, match=r"^driver_options\.port: no such option of the naoqi driver"):
        registry.check(DriverSpec("naoqi", {"port": 9559}), nao, options_at="driver_options")
    fake = naoqi
    clock = fake.clock
    driver = registry.create(registry.check(DriverSpec("naoqi"), nao), nao, DriverContext(clock=clock))
    try:
        assert driver.status().connected and fake.subscribed == {"calib_desk"}
        np.testing.assert_array_equal(driver.read_joints(), fake.sim.readings(fake.q))

        # Beyond a limit: refused by the core, nothing reaches NAOqi.
        beyond = driver.read_joints()
        beyond[nao.joint("LKneePitch")] = 125 * DEG
        with pytest.raises(LimitError, match=r"LKneePitch 125\.0 deg is beyond its upper limit"):
            driver.move_to(beyond)
        assert fake.calls == []

        # A move to a stance with the left foot's board in view arrives; stiffness first, then the move at
        # full speed (the core's duration is what the velocity limits allow).
        planner = SimulatedRobot.from_profile(nao, seed=7)
        qs, targets = planner.configurations(12)
        ok = list(np.flatnonzero((targets == 0) & within_margin(nao, qs)))  # the driver's 1 deg margin
        goal = qs[ok[0]]
        driver.set_target(0)
        assert _in_thread(clock, 2, lambda: driver.move_to(goal))
        assert fake.calls == [("setStiffnesses", 1.0), ("angleInterpolationWithSpeed", 1.0)]
        assert np.abs(driver.read_joints() - goal).max() <= 0.5 * DEG
        clock.run(lambda: driver.settled(0.3), threads=1)

        # A look: an image exposed after it began, decoded from YUV 4:2:2, the board found by the core.
        look = _in_thread(clock, 2, driver.look)
        assert look.sightings[0].status == "measured", look.sightings[0].reason
        assert look.sightings[0].measured.shape == (24, 2) and look.images["image"].shape == (480, 640)

        # A stop under way: NAOqi's tasks killed, the robot holds where it was.
        here = driver.read_joints()
        far = max(ok[1:], key=lambda k: driver.duration_s(here, qs[k]))
        driver.move_to(qs[far], wait=False)
        until = clock.now() + driver.duration_s(here, qs[far]) / 2
        clock.run(lambda: clock.now() >= until, threads=1)
        driver.stop()
        held = fake.position(clock.now())
        clock.run(lambda: clock.now() >= until + 1.0, threads=1)
        assert fake.calls[-1] == ("killTasksUsingResources",)
        np.testing.assert_array_equal(fake.position(clock.now()), held)
        assert np.abs(held - qs[far]).max() > 1 * DEG and driver.status().message == "stopped"
    finally:
        driver.close()
    assert fake.subscribed == set() and not driver.status().connected
