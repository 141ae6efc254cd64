"""The fault harness over the drivers of real robots, through the desk's API as an operator uses it: a NAO served
over libqi (the simulated NAO's CalibSim fault) and a robot node on a ROS 2 graph (the node's `fault` parameter),
both in this process, told mid-replay (after its first configuration) to hang, answer slowly, drop the connection,
stall, read NaN or beyond a limit, send a malformed or a huge image, refuse to move, or lack a call the desk uses.
Each case asserts the replay's sentence (or each frame's reason), that STOP answers at once naming the robot that
did not take it, that the frame before the fault is kept, and that the robot comes back once the fault is
cleared. The simulated robot's own matrix, on a ManualClock: test_driver_faults.py. The time STOP takes with a
robot hung in a call is benchmarks/stop.py's figure; here a STOP that waited on the robot (15 s and more before)
fails its bound."""

from __future__ import annotations

import json
import re
import time
from collections.abc import Iterator
from pathlib import Path
from types import SimpleNamespace
from typing import Any

import pytest
import yaml
from browser import free_port, served, shot
from desk_jobs import wait_job
from fastapi.testclient import TestClient

from app.drivers.faults import parse_fault
from calib_core import load_profile

qi = pytest.importorskip("qi", reason="the NAOqi faults need the naoqi extra (pip install -e '.[naoqi]')")
pytestmark = pytest.mark.slow  # robots served in this process, replays on the real clock

STOP_BOUND_S = 1.0  # far above STOP's 150 ms (benchmarks/stop.py), far below a wait on a hung robot
KEPT = "; the 1 frames before it are kept (start the replay again with resume to go on)"


@pytest.fixture(scope="module")
def nao3(client: TestClient) -> Iterator[SimpleNamespace]:
    """A simulated NAO served over libqi here (8 times as fast), on the desk as nao-3."""
    from app.drivers.naoqi.sim import SimNao, serve

    url = f"tcp://127.0.0.1:{free_port()}"
    nao = SimNao(load_profile("nao"), speed=8)
    robot = SimpleNamespace(nao=nao, url=url, sessions=[serve(nao, url)])  # each kept: libqi frees none in use
    # The calls' deadline NAOqi's default: a 30 MP image served in this process holds the interpreter for a while.
    options = {"url": url, "settle_s": 0.04, "measurement_wait_s": 2.0}
    r = client.post(
        "/api/robots",
        data={"name": "nao-3", "profile": "nao", "driver": "naoqi", "driver_options": json.dumps(options)},
    )
    assert r.status_code == 201, r.text
    _until(lambda: _robot(client, "nao-3")["connected"], "nao-3 connected")
    yield robot
    nao.faults.arm(None)
    robot.sessions[-1].close()


def _robot(client: TestClient, name: str) -> dict:
    return client.get("/api/robot", params={"robot": name}).json()


def _until(ok, what: str, timeout_s: float = 30.0) -> None:
    """Until ok(): the robot's state comes from its own stream of readings (a bound of wall time for a failure)."""
    deadline = time.monotonic() + timeout_s
    while not ok():
        assert time.monotonic() < deadline, what
        time.sleep(0.02)


def _stop(client: TestClient, robot: str) -> dict:
    """POST /api/robot/stop, checked to answer at once; the robot's entry of its answer."""
    t0 = time.monotonic()
    answer = client.post("/api/robot/stop").json()
    assert time.monotonic() - t0 < STOP_BOUND_S
    return next(s for s in answer["stops"] if s["robot"] == robot)


def _replay(client: TestClient, robot: str, name: str) -> tuple[str, dict]:
    sid = client.post("/api/sessions", json={"robot": robot, "name": name}).json()["id"]
    plan = {"count": 3, "seed": 4, "planner": "random"}
    job = client.post(f"/api/sessions/{sid}/replay", json=plan).json()["job"]
    return sid, wait_job(client, job, timeout_s=90)


def _frames(client: TestClient, sid: str) -> list[dict]:
    return client.get(f"/api/sessions/{sid}").json()["frames"]


def _replay_told(client: TestClient, robot: str, fault: str, sentence: str | None, reason: str | None) -> None:
    """A replay of 3 configurations whose second meets the fault: it ends failed with `sentence` (a pattern),
    keeping the first frame, or (None) done, each frame after the first not found with `reason` when given."""
    sid, job = _replay(client, robot, fault)
    frames = _frames(client, sid)
    if sentence is None:
        assert job["state"] == "done", job["error"]
        assert len(frames) == 3 and frames[0]["status"] == "measured"
        if reason is not None:
            assert all(f["status"] == "not found" and re.fullmatch(reason, f["reason"]) for f in frames[1:]), frames
        return
    assert job["state"] == "failed", job
    error = job["error"]
    assert error.startswith("replay stopped at configuration 2 of 3: ") and error.endswith(KEPT), error
    assert re.fullmatch(sentence, error.removeprefix("replay stopped at configuration 2 of 3: ").removesuffix(KEPT))
    assert [f["index"] for f in frames] == [1] and frames[0]["status"] == "measured", frames


NAOQI = {
    "hang": r"nao-3 (did not answer ALMotion\.\w+ within 2 s(; the robot was told to stop)?|has not answered "
    r"ALMotion\.\w+ for \d+\.\d s)",
    "slow:0.1": None,
    "drop": r"nao-3 disconnected: lost NAOqi at tcp://127\.0\.0\.1:\d+ \(.*\)",
    "stall": r"nao-3 did not arrive within \d+\.\d s \(not responding\); the robot was told to stop",
    "nan:LKneePitch": r"nao-3 reads LKneePitch nan \(not a number\): a sensor fault; nothing moves until it reads "
    r"again(; the robot was told to stop)?",
    "beyond:LKneePitch:3.0": r"nao-3 reads LKneePitch 171\.9 deg, beyond its upper limit 121\.0 deg by more than the "
    r"5 deg a reading may stray: a sensor fault; nothing moves until it reads again(; the robot was told to stop)?",
    "malformed_image": None,
    "huge_image": None,
    "refuse": r"nao-3: the stiffness of LHipYawPitch, LHipRoll, .*, HeadYaw, HeadPitch stays off after "
    r"setStiffnesses \(a hot joint, or the robot resting\?\); nothing was moved",
}
NAOQI_IMAGES = {
    "malformed_image": r"camera 1: .*",
    "huge_image": r"camera 1 sends 6000 x 5000 px images; the profile's lower_camera is 640 x 480 px",
}


@pytest.mark.parametrize("fault", list(NAOQI))
def test_a_nao_over_naoqi_that_fails_mid_replay_is_named_and_stop_answers_at_once(
    client: TestClient, nao3: SimpleNamespace, fault: str
) -> None:
    from app.drivers.naoqi.sim import serve

    driver = client.app.state.desk.robots.driver("nao-3")
    driver.move_slack_s = 0.5 if fault == "stall" else 5.0
    nao3.nao.faults.arm(parse_fault(fault), after_moves=1)
    try:
        _replay_told(client, "nao-3", fault, NAOQI[fault], NAOQI_IMAGES.get(fault))
        stop = _stop(client, "nao-3")
        if fault == "hang":
            assert not stop["confirmed"]  # sent, or queued behind the hung call of a move (it may come after it)
            assert re.fullmatch(
                r"nao-3 does not answer(: the stop was sent| \(ALMotion\.\w+ for \d+\.\d s\): the stop is queued "
                r"behind it), not confirmed\. If it moves, use its own emergency stop\.",
                stop["message"],
            ), stop
            state = _robot(client, "nao-3")
            assert not state["connected"] and state["message"].startswith("not responding: nao-3 has not answered ")
        elif fault == "drop":
            assert not stop["confirmed"] and stop["message"].startswith("nao-3: the stop failed (")
            assert stop["message"].endswith("If it moves, use its own emergency stop."), stop
        else:
            assert stop == {"robot": "nao-3", "confirmed": True, "message": "nao-3 stopped"}
    finally:
        nao3.nao.faults.arm(None)
        driver.move_slack_s = 5.0
        if fault == "drop":
            nao3.sessions.append(serve(nao3.nao, nao3.url))  # the robot back at its address
    _until(lambda: _robot(client, "nao-3")["connected"], f"nao-3 back after {fault}")
    assert _stop(client, "nao-3")["confirmed"]


def test_a_naoqi_without_a_call_the_desk_uses_says_which(client: TestClient, nao3: SimpleNamespace) -> None:
    """An ALMotion that lacks getStiffnesses: the replay ends naming the service and the call, not an internal
    error, and nothing moves."""
    from app.drivers.naoqi.sim import SimNao, serve

    url = f"tcp://127.0.0.1:{free_port()}"
    nao = SimNao(load_profile("nao"), speed=8, lacks=["ALMotion.getStiffnesses"])
    session = serve(nao, url)
    try:
        r = client.post(
            "/api/robots",
            data={"name": "nao-4", "profile": "nao", "driver": "naoqi", "driver_options": f'{{"url": "{url}"}}'},
        )
        assert r.status_code == 201, r.text
        _until(lambda: _robot(client, "nao-4")["connected"], "nao-4 connected")
        sid, job = _replay(client, "nao-4", "lacks getStiffnesses")
        assert job["state"] == "failed"
        assert job["error"] == (
            f"replay stopped at configuration 1 of 3: nao-4: ALMotion at {url} offers no getStiffnesses, which the "
            "desk uses (docs/naoqi.md lists the calls): a NAOqi it cannot drive; nothing was done; the 0 frames "
            "before it are kept (start the replay again with resume to go on)"
        )
        assert nao.commands == [] and _frames(client, sid) == []
    finally:
        client.delete("/api/robots/nao-4")
        session.close()


# --- a robot node on a ROS 2 graph ---------------------------------------------------------------------------------
@pytest.fixture(scope="module")
def nao_ros(client: TestClient, tmp_path_factory: pytest.TempPathFactory) -> Iterator[Any]:
    """The simulated NAO as a ROS 2 node here (8 times as fast, under /naof), on the desk as nao-ros, on a graph of
    this run's own."""
    pytest.importorskip("rclpy", reason="the ROS 2 faults need the ros2 extra (pip install -e '.[ros2]')")
    from ros2_graph import graph_env

    from app.drivers.ros2.sim_node import SimNode, Topics, connection_doc, load_sim_profile

    with pytest.MonkeyPatch.context() as mp:
        for key, value in graph_env().items():
            mp.setenv(key, value)
        profile, urdf = load_sim_profile("nao", None)
        node = SimNode(profile, urdf, speed=8, rate_hz=50, topics=Topics("/naof"))
        try:
            doc = connection_doc("nao", "nao-ros", profile, Topics("/naof"), 8)
            connection = tmp_path_factory.mktemp("ros2-faults") / "nao-ros.yaml"
            connection.write_text(yaml.safe_dump({**doc, "timeout_s": 0.5, "measurement_wait_s": 2.0}))
            options = json.dumps({"connection": str(connection)})
            r = client.post(
                "/api/robots", data={"name": "nao-ros", "profile": "nao", "driver": "ros2", "driver_options": options}
            )
            assert r.status_code == 201, r.text
            _until(lambda: _robot(client, "nao-ros")["connected"], "nao-ros connected")
            yield node
        finally:
            node.close()


def _set_fault(node: Any, fault: str, after_moves: int = 0) -> None:
    """Through the node's parameters, as `ros2 param set` would."""
    from rclpy.parameter import Parameter

    node.link.node.set_parameters([Parameter("fault_after_moves", value=after_moves), Parameter("fault", value=fault)])


SILENT = r"nao-ros disconnected: no joint states on /naof/joint_states for \d+\.\d s"
ROS2 = {
    "hang": SILENT,
    "slow:0.05": None,
    "drop": SILENT,
    "stall": r"nao-ros did not arrive within \d+\.\d s \(not responding\); the robot was told to stop",
    "nan:LKneePitch": r"nao-ros reads LKneePitch nan \(not a number\): a sensor fault; nothing moves until it reads "
    r"again(; the robot was told to stop)?",
    "beyond:LKneePitch:3.0": r"nao-ros reads LKneePitch 171\.9 deg, beyond its upper limit 121\.0 deg by more than "
    r"the 5 deg a reading may stray: a sensor fault; nothing moves until it reads again(; the robot was told to stop)?",
    "malformed_image": None,
    "huge_image": None,
    "refuse": r"nao-ros did not arrive within \d+\.\d s \(not responding\); the robot was told to stop",
}
ROS2_IMAGES = {
    "malformed_image": r"/naof/lower_camera/image_raw: .*",
    "huge_image": r"/naof/lower_camera/image_raw: images of 6000 x 5000 px, but the camera of robot 'nao-ros' \(its "
    r"intrinsics\) has 640 x 480 px",
}


@pytest.mark.parametrize("fault", list(ROS2))
def test_a_ros2_robot_that_fails_mid_replay_is_named_and_stop_answers_at_once(
    client: TestClient, nao_ros: Any, fault: str
) -> None:
    driver = client.app.state.desk.robots.driver("nao-ros")
    driver.move_slack_s = 0.5 if fault in ("stall", "refuse") else 5.0
    _set_fault(nao_ros, fault, after_moves=1)
    try:
        _replay_told(client, "nao-ros", fault, ROS2[fault], ROS2_IMAGES.get(fault))
        stop = _stop(client, "nao-ros")
        if fault in ("hang", "drop"):  # the empty trajectory went out; a silent robot is not taken to have it
            assert not stop["confirmed"], stop
            assert re.fullmatch(
                r"nao-ros: the stop failed \(the empty trajectory went out on /naof/joint_trajectory_controller/"
                r"joint_trajectory, but no joint states came on /naof/joint_states for \d+\.\d s: the robot may not "
                r"have it\)\. If it moves, use its own emergency stop\.",
                stop["message"],
            ), stop
        else:
            assert stop == {"robot": "nao-ros", "confirmed": True, "message": "nao-ros stopped"}
    finally:
        _set_fault(nao_ros, "")
        driver.move_slack_s = 5.0
    _until(lambda: _robot(client, "nao-ros")["connected"], f"nao-ros back after {fault}")
    assert _stop(client, "nao-ros")["confirmed"]


# --- the page ------------------------------------------------------------------------------------------------------
@pytest.mark.browser
@pytest.mark.subprocess
def test_stop_on_the_page_with_a_hung_nao_says_which_robot_did_not_take_it(chromium_2d, desk_data: Path) -> None:
    """A NAO over NAOqi whose every call hangs: the page's pill says it is not responding (its title the whole
    sentence); STOP, clicked twice and pressed as Esc, answers at once each time, and the toast names the robot that
    did not take it and what to do; nothing on the page is left waiting."""
    from app.drivers.naoqi.sim import SimNao, serve

    url = f"tcp://127.0.0.1:{free_port()}"
    nao = SimNao(load_profile("nao"), speed=8)
    session = serve(nao, url)
    conn = desk_data.parent / "nao-3.yaml"
    conn.write_text(yaml.safe_dump({"robot": "nao-3", "profile": "nao", "url": url, "camera": 1}), encoding="utf-8")
    try:
        with served(desk_data, extra=("--naoqi", str(conn))) as server:
            page = chromium_2d.new_page(viewport={"width": 1500, "height": 1000})
            page.goto(server.url)
            page.wait_for_selector("body[data-ready='1']", timeout=60_000)
            page.select_option("#robot-select", "nao-3")
            page.wait_for_function("document.querySelector('#robot-state').textContent === 'nao-3: still'")
            page.click("#stop")
            page.wait_for_function("document.querySelector('#toast').textContent === 'Stopped.'")
            nao.faults.arm(parse_fault("hang"))
            page.wait_for_function("document.querySelector('#robot-state').textContent === 'nao-3: not responding'")
            title = page.get_attribute("#robot-state", "title")
            assert title is not None and title.startswith("not responding: nao-3 ")
            said = "nao-3 does not answer: the stop was sent, not confirmed. If it moves, use its own emergency stop."
            for press in ("dblclick", "Escape"):
                page.evaluate("document.querySelector('#toast').textContent = ''")
                t0 = time.monotonic()
                page.dblclick("#stop") if press == "dblclick" else page.keyboard.press("Escape")
                page.wait_for_function("s => document.querySelector('#toast').textContent === s", arg=said)
                assert time.monotonic() - t0 < STOP_BOUND_S
                assert page.locator("#toast").get_attribute("class") == "error"
            shot(page, "stop-not-confirmed")
            nao.faults.arm(None)
            page.wait_for_function("document.querySelector('#robot-state').textContent === 'nao-3: still'")
            # The robot answers again: a stop is taken. It may first find the robot still answering the calls that
            # queued while it hung (a stop waits 0.15 s for the halt: a loaded CI machine took longer once), so
            # the operator's next STOP is taken within the next seconds.
            deadline = time.monotonic() + 30
            while True:
                page.evaluate("document.querySelector('#toast').textContent = ''")
                page.click("#stop")
                page.wait_for_function("document.querySelector('#toast').textContent !== ''")
                toast = page.text_content("#toast")
                if toast == "Stopped." or time.monotonic() > deadline:
                    break
                assert toast == said, toast
            assert toast == "Stopped.", toast
    finally:
        nao.faults.arm(None)
        session.close()
