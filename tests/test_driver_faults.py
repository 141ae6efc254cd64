"""The fault harness (app/drivers/faults.py) over every driver kind: the simulated robot (here, on a ManualClock: the
waits are the desk's own), a NAO served over libqi and a ROS 2 robot node (test_driver_faults_remote.py). Each
robot is told, mid-replay (after its first configuration), to hang, answer slowly, drop the connection, stall,
read NaN or beyond a limit, send a malformed or a huge image, or refuse to move; each case asserts what the
operator is told (the replay's sentence, or each frame's reason), what STOP answers, and that the frames captured
before the fault are kept."""

from __future__ import annotations

import math
import re
import threading
from collections.abc import Iterator

import numpy as np
import pytest
from manual_jobs import manual_runner, wait

from app.clock import ManualClock
from app.drivers import RobotFault
from app.drivers.simulated import SimulatedDriver
from app.jobs.runner import JobRunner
from app.jobs.snapshot import JobState
from app.robots.capture import dry_run, replay
from calib_core import SimulatedRobot

KEPT = "; the 1 frames before it are kept (start the replay again with resume to go on)"
# What the operator reads when the fault strikes on the way to configuration 2 of 4 (None: the replay ends done).
SENTENCES = {
    "slow:0.05": None,
    "drop": r"nao disconnected: the link to the robot was lost",
    "stall": r"nao did not arrive within \d+\.\d s \(not responding\); the robot was told to stop",
    "nan:LKneePitch": r"nao reads LKneePitch nan \(not a number\): a sensor fault; nothing moves until it reads "
    r"again(; the robot was told to stop)?",
    "beyond:LKneePitch:3.0": r"nao reads LKneePitch 171\.9 deg, beyond its upper limit 121\.0 deg by more than the 5 "
    r"deg a reading may stray: a sensor fault; nothing moves until it reads again(; the robot was told to stop)?",
    "malformed_image": None,
    "huge_image": None,
    "refuse": r"nao: the robot refused the move \(its motors are off\); nothing was moved",
}
# The reason of each frame the detector could not look at (the replay goes on).
IMAGE_REASONS = {
    "malformed_image": "the image is a float64 array of shape (153600,), not a grey image of 8-bit pixels",
    "huge_image": "the image is 6000 x 5000 px, more than the 25 MP a camera sends",
}


@pytest.fixture(scope="module")
def jobs(store) -> Iterator[JobRunner]:
    with manual_runner(store) as runner:
        yield runner


@pytest.fixture(scope="module")
def plan(nao) -> tuple[np.ndarray, np.ndarray]:
    """Four NAO stances in view and within the limits less the margin."""
    q, targets = SimulatedRobot.from_profile(nao, seed=7).configurations(12)
    with SimulatedDriver(nao, seed=3) as d:
        rows = dry_run(d, q, targets, nao.nominal())
    ok = [r["action"] == "capture" and not r["note"] for r in rows]
    return q[ok][:4], targets[ok][:4]


def _start(store, jobs: JobRunner, d: SimulatedDriver, plan, fault: str) -> tuple[str, str]:
    """A replay of the plan with `fault` striking on the way to its second configuration, run until the first
    frame is in (the poller and the job waiting on the clock); the session and the job."""
    q, targets = plan
    sid = store.sessions.create("nao", fault, source="capture")
    d.inject_fault(fault, after_moves=1)
    job = jobs.submit_thread("replay", lambda ctx: replay(ctx, store, d, sid, q, targets), session_id=sid)
    d.clock.run(lambda: jobs.get(job).detail.get("done", 0) >= 1, threads=2)
    return sid, job


def test_a_robot_that_hangs_mid_replay_ends_it_naming_the_call_and_stop_answers_at_once(store, jobs, nao, plan) -> None:
    """Every call hangs (a NAOqi that is stuck): the replay ends when its poll's deadline has passed on the desk's
    clock, naming the call; STOP answers after its own 0.15 s, not confirmed, saying what to do; the frame before is
    kept; once the robot answers again the stop queued behind its hung call reaches it."""
    clock = ManualClock()
    d = SimulatedDriver(nao, seed=3, time_scale=1.0, clock=clock, move_slack_s=10.0)
    try:
        sid, job = _start(store, jobs, d, plan, "hang")
        clock.run(lambda: d.calls.busy("readings") is not None, threads=2)  # a read that does not come back
        clock.advance(4.9)
        assert d.status().connected and not jobs.get(job).state.finished
        clock.advance(0.2)  # the poll's deadline, 5 s of the clock
        # The replay then tells the robot to stop, and waits for that 0.15 s (its halt hangs too).
        clock.run(lambda: jobs.get(job).state.finished, threads=1, limit_s=5)  # the poller's steps
        snap = wait(jobs, job)
        assert (
            snap.error == "replay stopped at configuration 2 of 4: nao did not answer joint readings within 5 s" + KEPT
        )
        assert [(f.index, f.status) for f in store.sessions.frames(sid)] == [(1, "measured")]
        status = d.status()
        assert not status.connected and re.fullmatch(
            r"not responding: nao (did not answer joint readings within 5 s|has not answered joint readings for "
            r"\d+\.\d s)",
            status.message,
        ), status
        answered = []
        stopper = threading.Thread(target=lambda: answered.append(d.stop()), name="stop")
        stopper.start()
        clock.until_thread_waits("stop")
        assert not answered  # it waits the desk's own 0.15 s, and no longer
        clock.advance(0.15)
        stopper.join(5)
        (halt,) = answered
        assert not halt.confirmed
        assert halt.sentence() == (
            "nao does not answer: the stop was sent, not confirmed. If it moves, use its own emergency stop."
        )
        d.inject_fault(None)  # it answers again: the halt it was sent is taken
        clock.run(lambda: halt.confirmed and d.status().connected and not d.status().moving, threads=1)
        assert d.status().message == "stopped"
    finally:
        d.inject_fault(None)
        clock.advance(1.0)
        d.close()


@pytest.mark.parametrize("fault", list(SENTENCES))
def test_a_simulated_robot_that_fails_mid_replay_says_how_and_keeps_the_frames_before(
    store, jobs, nao, plan, fault: str
) -> None:
    clock = ManualClock()
    d = SimulatedDriver(nao, seed=3, time_scale=1.0, clock=clock, move_slack_s=1.0)
    try:
        sid, job = _start(store, jobs, d, plan, fault)
        clock.run(lambda: jobs.get(job).state.finished, threads=2, limit_s=120)
        snap = wait(jobs, job)
        frames = store.sessions.frames(sid)
        if SENTENCES[fault] is None:
            assert snap.state == JobState.DONE, snap.error
            assert len(frames) == 4 and frames[0].status == "measured"
            if fault in IMAGE_REASONS:
                assert [(f.status, f.reason) for f in frames[1:]] == [("not found", IMAGE_REASONS[fault])] * 3
            else:
                assert all(f.status == "measured" for f in frames)
        else:
            assert snap.state == JobState.FAILED
            assert snap.error is not None and snap.error.startswith("replay stopped at configuration 2 of 4: ")
            message = snap.error.removeprefix("replay stopped at configuration 2 of 4: ").removesuffix(KEPT)
            assert snap.error.endswith(KEPT) and re.fullmatch(SENTENCES[fault], message), snap.error
            assert [(f.index, f.status) for f in frames] == [(1, "measured")]
        d.inject_fault(None)
        halt = d.stop(wait_s=0.0)
        clock.run(lambda: halt.confirmed, threads=1)
        if fault == "drop":
            d.reconnect()
        clock.run(lambda: d.status().connected and not d.status().moving, threads=1)
        here = d.true_joints_rad()
        clock.advance(1.0)  # nothing moves after the stop
        assert np.array_equal(d.true_joints_rad(), here)
        assert math.isfinite(d.read_joints().sum())
    finally:
        d.inject_fault(None)
        clock.advance(1.0)  # a call that answers slowly ends
        d.close()


def test_a_fault_is_written_as_text_and_a_wrong_one_is_named() -> None:
    from app.drivers.faults import Fault, FaultSwitch, parse_fault
    from calib_core import InputError

    assert parse_fault("slow:0.5") == Fault("slow", delay_s=0.5)
    assert parse_fault("beyond:LKneePitch:2.5") == Fault("beyond", "LKneePitch", 2.5)
    assert parse_fault("nan") == Fault("nan")
    for text, said in (
        ("bogus", r"^--fault: unknown fault 'bogus' \(known: hang, slow, drop"),
        ("slow", r"^--fault: expected slow:SECONDS$"),
        ("nan:LKneePitch:x", r"^--fault: expected nan\[:JOINT\]\[:VALUE\]$"),
        ("hang:3", r"^--fault: the fault 'hang' takes no value$"),
    ):
        with pytest.raises(InputError, match=said):
            parse_fault(text, "--fault")
    switch = FaultSwitch(["a", "b"])
    with pytest.raises(InputError, match="no joint c"):
        switch.arm(Fault("nan", "c"))
    switch.arm(Fault("stall"), after_moves=2)  # two moves pass, the third stalls, the fourth does not
    assert [switch.moved() for _ in range(4)] == [None, None, Fault("stall"), None]
    switch.arm(Fault("nan", "b"), after_moves=1)
    assert np.isfinite(switch.reading(np.zeros(2))).all() and switch.moved() is None
    switch.moved()  # it strikes from the second move on, until cleared
    assert np.isnan(switch.reading(np.zeros(2))[1]) and np.isnan(switch.reading(np.zeros(2))[1])
    switch.arm(None)
    assert np.isfinite(switch.reading(np.zeros(2))).all()


def test_a_reading_a_hair_past_its_limit_is_taken_and_one_far_past_it_is_a_fault(nao) -> None:
    """Encoders of a real robot read a little past a limit: within the 5 deg a reading may stray it is the robot's
    pose; past that, nothing moves and the status names the joint, the value and the limit."""
    clock = ManualClock()
    with SimulatedDriver(nao, seed=3, clock=clock) as d:
        k = nao.joint_names.index("LKneePitch")
        upper = nao.joints[k].upper
        d.inject_fault(f"beyond:LKneePitch:{upper + math.radians(4.5)}")
        clock.run(lambda: d.read_joints()[k] > upper, threads=1)
        assert d.status().connected
        d.inject_fault(f"beyond:LKneePitch:{upper + math.radians(5.5)}")
        clock.run(lambda: not d.status().connected, threads=1)
        assert d.status().message == (
            "faulty readings: nao reads LKneePitch 126.5 deg, beyond its upper limit 121.0 deg by more than the 5 deg "
            "a reading may stray: a sensor fault; nothing moves until it reads again"
        )
        with pytest.raises(RobotFault, match=r"^nao reads LKneePitch 126\.5 deg"):
            d.move_to(d.true_joints_rad())
        d.inject_fault(None)
        clock.run(lambda: d.status().connected, threads=1)
