"""Safety of the desk: every commanded configuration goes through the limit check, a stop halts motion at
once (mid-move and mid-replay) and leaves the session consistent, and an apply that is worse than the
active calibration or moves a parameter beyond its sane bound needs the operator's confirmation. The desk's
drivers run on a ManualClock that the tests advance: no test waits for motion to take its time."""

from __future__ import annotations

import io
import math
import time
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from desk_jobs import wait_job
from fastapi.testclient import TestClient

from app.clock import ManualClock
from app.drivers import LimitError
from app.drivers.core import Command
from app.drivers.simulated import SimulatedDriver
from app.services import safety
from calib_core import load_profile

SAMPLES = Path(__file__).resolve().parent.parent / "sample_sessions"


ROBOTS = 3  # the desk's built-in robots, each driver's poller waiting on the clock
CLOCK = ManualClock()


@pytest.fixture(scope="module")
def desk_options() -> dict:
    """Robots at twice their velocity limits, on a clock the tests advance."""
    return {"time_scale": 2.0, "clock": CLOCK}


class Recording:
    """A driver as a real robot would be plugged in: every call recorded, motion by the simulator."""

    def __init__(self, inner: SimulatedDriver) -> None:
        self.inner = inner
        self.profile = inner.profile
        self.calls: list[tuple[str, np.ndarray]] = []

    def check(self, q_rad: np.ndarray) -> None:
        self.calls.append(("check", np.array(q_rad, float)))
        self.inner.check(q_rad)

    def move_to(self, q_rad: np.ndarray, **kw: Any) -> bool:
        self.calls.append(("move_to", np.array(q_rad, float)))
        return self.inner.move_to(q_rad, **kw)

    def __getattr__(self, name: str) -> Any:
        return getattr(self.inner, name)


@pytest.mark.slow
def test_every_path_that_moves_checks_the_configuration_first(client: TestClient) -> None:
    """API move, goto and replay call the driver's check with the very configuration before move_to."""
    desk = client.app.state.desk
    nao = desk.robots.get("nao")
    sim = nao.driver
    rec = Recording(sim)
    nao.driver = rec
    try:
        joint = rec.profile.joints[0]
        mid_deg = math.degrees((joint.lower + joint.upper) / 2)
        assert client.post("/api/robot/move", json={"robot": "nao", "joints": {joint.name: mid_deg}}).status_code == 202
        assert client.post("/api/sessions/nao/frames/1/goto").status_code == 202
        sid = client.post("/api/sessions", json={"robot": "nao", "name": "checked"}).json()["id"]
        job = client.post(f"/api/sessions/{sid}/replay", json={"from_session": "nao", "count": None}).json()["job"]
        CLOCK.run(lambda: sum(c == "move_to" for c, _ in rec.calls) >= 3, threads=ROBOTS + 1)  # and the replay
        client.post("/api/robot/stop")
        wait_job(client, job)
    finally:
        nao.driver = sim
    moves = [k for k, (call, _) in enumerate(rec.calls) if call == "move_to"]
    assert len(moves) >= 3
    for k in moves:
        checked = [q for call, q in rec.calls[:k] if call == "check"]
        assert checked and any(np.array_equal(q, rec.calls[k][1]) for q in checked), k


def test_the_simulated_robot_checks_every_motion_it_starts() -> None:
    """Operator moves, replays and the wander all start in one place, which checks the limits again."""
    profile = load_profile("robonaut-a")
    clock = ManualClock()
    with SimulatedDriver(profile, seed=1, time_scale=50.0, clock=clock) as driver:
        robot = driver.transport
        here = driver.read_joints()
        beyond = here.copy()
        beyond[profile.joint_names.index("elbow_pitch")] = profile.joints[3].upper + math.radians(0.5)
        with pytest.raises(LimitError, match="elbow_pitch"):
            robot.send(Command(here, beyond, 1.0))  # a command that never went through the driver's check
        # A wander whose pool held a configuration beyond a limit ends rather than go there.
        robot.visible_configurations = lambda n: (beyond[None, :], np.zeros(1, int))  # type: ignore[method-assign]
        start = driver.true_joints_rad()
        driver.wander(True)
        robot._wander_thread.join()  # it ended by itself
        clock.advance(1.0)
        assert np.array_equal(driver.true_joints_rad(), start)
        st = driver.status()
        assert not st.moving and not st.wandering


@pytest.mark.parametrize(("offset_deg", "words"), [(5.0, "beyond its upper limit"), (-0.5, "safety margin")])
def test_a_refused_move_names_the_joint_and_the_limit(client: TestClient, offset_deg: float, words: str) -> None:
    profile = load_profile("robonaut-a")
    joint = profile.joints[profile.joint_names.index("elbow_pitch")]
    upper = math.degrees(joint.upper)
    before = client.get("/api/robot", params={"robot": "robonaut-a"}).json()
    r = client.post("/api/robot/move", json={"robot": "robonaut-a", "joints": {"elbow_pitch": upper + offset_deg}})
    assert r.status_code == 422
    detail = r.json()["detail"]
    assert "elbow_pitch" in detail and words in detail and f"{upper:.1f} deg" in detail, detail
    after = client.get("/api/robot", params={"robot": "robonaut-a"}).json()
    assert not after["moving"] and after["joints"] == before["joints"]


def test_goto_a_frame_beyond_a_limit_is_refused(client: TestClient) -> None:
    profile = load_profile("robonaut-a")
    lines = (SAMPLES / "robonaut-a-day1" / "data.csv").read_text().splitlines()
    header, cells = lines[0].split(","), lines[1].split(",")
    upper = math.degrees(profile.joints[profile.joint_names.index("wrist_yaw")].upper)
    cells[header.index("wrist_yaw")] = f"{upper + 3:.1f}"
    r = client.post(
        "/api/sessions/import",
        data={"robot": "robonaut-a", "name": "beyond"},
        files={"data": ("beyond.csv", io.BytesIO("\n".join([lines[0], ",".join(cells)]).encode()))},
    )
    sid = r.json()["id"]
    index = client.get(f"/api/sessions/{sid}").json()["frames"][0]["index"]
    r = client.post(f"/api/sessions/{sid}/frames/{index}/goto")
    assert r.status_code == 422 and "wrist_yaw" in r.json()["detail"] and "upper limit" in r.json()["detail"]
    assert not client.get("/api/robot", params={"robot": "robonaut-a"}).json()["moving"]


def test_stop_halts_a_move_at_once(client: TestClient) -> None:
    client.post("/api/robot/stop")
    client.post("/api/robot/connect", json={"robot": "robonaut-a"})
    start = client.get("/api/robot").json()["joints"]["elbow_pitch"]
    goal = start - 60.0 if start > 0 else start + 60.0
    assert client.post("/api/robot/move", json={"joints": {"elbow_pitch": goal}}).status_code == 202
    until = CLOCK.now() + 0.2
    CLOCK.run(lambda: CLOCK.now() >= until, threads=ROBOTS)
    assert client.get("/api/robot").json()["moving"]
    t0 = time.monotonic()
    stopped = client.post("/api/robot/stop").json()
    assert time.monotonic() - t0 < 0.5
    assert not stopped["moving"] and stopped["message"] == "stopped"
    here = stopped["joints"]["elbow_pitch"]
    assert min(start, goal) + 1.0 < here < max(start, goal) - 1.0  # halted on the way, not at the goal
    CLOCK.advance(1.0)  # the readings of a second later
    CLOCK.until_waiting(ROBOTS)
    assert client.get("/api/robot").json()["joints"] == stopped["joints"]


@pytest.mark.slow
def test_stop_mid_replay_cancels_it_and_keeps_the_frames(client: TestClient) -> None:
    client.post("/api/robot/stop")
    sid = client.post("/api/sessions", json={"robot": "robonaut-a", "name": "stopped replay"}).json()["id"]
    job = client.post(f"/api/sessions/{sid}/replay", json={"count": 6, "seed": 5}).json()["job"]
    # Once a frame is in and the robot is on its way to the next configuration: STOP.
    robot = client.app.state.desk.robots.driver("robonaut-a")
    CLOCK.run(
        lambda: client.get(f"/api/jobs/{job}").json()["detail"].get("done", 0) >= 1 and robot.status().moving,
        threads=ROBOTS + 1,  # and the replay
    )
    stopped = client.post("/api/robot/stop").json()
    assert not client.get("/api/robot", params={"robot": "robonaut-a"}).json()["moving"]
    j = wait_job(client, job)
    assert j["state"] == "cancelled", j
    frames = client.get(f"/api/sessions/{sid}").json()["frames"]
    assert 1 <= len(frames) < 6
    assert [f["index"] for f in frames] == list(range(1, len(frames) + 1))
    assert all(f["status"] in ("measured", "not found", "skipped") for f in frames)
    listed = next(s for s in client.get("/api/sessions").json() if s["id"] == sid)
    assert listed["frames"] == len(frames)
    assert listed["measured"] == sum(f["status"] == "measured" for f in frames)
    CLOCK.advance(1.0)  # nothing moves or is captured after the stop
    CLOCK.until_waiting(ROBOTS)
    assert len(client.get(f"/api/sessions/{sid}").json()["frames"]) == len(frames)
    assert client.get("/api/robot", params={"robot": "robonaut-a"}).json()["joints"] == stopped["joints"]
    assert client.get(f"/api/jobs/{job}").json()["state"] == "cancelled"


def test_sane_bounds_per_parameter_kind() -> None:
    robonaut, nao = load_profile("robonaut-a"), load_profile("nao")
    assert safety.bound(robonaut, "length").display == pytest.approx(5.0)  # cm
    assert safety.bound(nao, "length").display == pytest.approx(50.0)  # mm
    assert safety.bound(nao, "angle").internal == pytest.approx(math.radians(10))
    assert safety.bound(nao, "angle", safety.FROM_NOMINAL).display == pytest.approx(20.0)
    p = robonaut.nominal()
    q = p.copy()
    q[robonaut.param("elbow_pitch.theta")] += math.radians(9.9)
    q[robonaut.param("wrist_yaw.a")] += 5.1
    q[robonaut.param("neck_yaw.theta")] -= math.radians(10.5)
    jumps = safety.parameter_jumps(robonaut, q, p, "the active calibration c-1")
    assert len(jumps) == 2
    assert jumps[0].startswith("neck_yaw.theta moves by -10.50 deg") and "bound 10 deg" in jumps[0]
    assert jumps[1].startswith("wrist_yaw.a moves by +5.10 cm") and "bound 5 cm" in jumps[1]
    assert safety.parameter_jumps(robonaut, q, p, "the nominal model", from_nominal=True) == []


@pytest.mark.slow
def test_apply_asks_for_confirmation_when_worse_or_beyond(client: TestClient) -> None:
    def calibrate(session: str, body: dict) -> str:
        r = client.post(f"/api/sessions/{session}/calibrations", json=body)
        j = wait_job(client, r.json()["job"])
        assert j["state"] == "done", j
        return j["result"]

    # A normal calibration applies with a plain POST (the pinned contract).
    full = calibrate("robonaut-a-day1", {"mode": "full", "holdout": 0.3})
    r = client.post(f"/api/calibrations/{full}/apply")
    assert r.status_code == 200, r.text
    assert r.json()["active"] == full
    # A daily calibration from the nominal model keeps the drawing's link lengths: on the day-2 frames it
    # predicts far worse than the full calibration, and it moves wrist_yaw.a back by 7.6 cm.
    daily = calibrate("robonaut-a-day2", {"mode": "daily", "base": None, "holdout": 0.3})
    history = client.get("/api/robot/history", params={"robot": "robonaut-a"}).json()
    r = client.post(f"/api/calibrations/{daily}/apply")
    assert r.status_code == 409, r.text
    body = r.json()
    assert daily in body["detail"] and "confirm" in body["detail"]
    assert "held-out frames of session robonaut-a-day2" in body["reasons"][0] and full in body["reasons"][0]
    assert any(x.startswith("wrist_yaw.a moves by") and "bound 5 cm" in x for x in body["reasons"])
    assert "its solver did not converge (maximum iterations reached after 100 iterations)" in body["reasons"]
    assert client.get("/api/robot/calibration", params={"robot": "robonaut-a"}).json()["id"] == full
    assert client.get("/api/robot/history", params={"robot": "robonaut-a"}).json() == history
    assert client.get("/api/robot", params={"robot": "robonaut-a"}).json()["calibration"] == full
    # Confirmed, it applies.
    r = client.post(f"/api/calibrations/{daily}/apply", json={"confirm": True, "note": "operator confirmed"})
    assert r.status_code == 200 and r.json() == {
        "active": daily,
        "previous": full,
        "robot": "robonaut-a",
        "recorded": True,
    }
    assert client.get("/api/robot", params={"robot": "robonaut-a"}).json()["calibration"] == daily
    # Rolling back is not worse, but the parameters jump as far back: that is asked too.
    r = client.post(f"/api/calibrations/{full}/apply")
    assert r.status_code == 409, r.text
    assert not any("mean error" in x for x in r.json()["reasons"])
    assert any(x.startswith("wrist_yaw.a moves by +7.5") for x in r.json()["reasons"])
    assert client.post(f"/api/calibrations/{full}/apply", json={"confirm": True}).json()["active"] == full
