"""Capture, dry run, replay and autocapture against the simulated robots, a real Store and real thread jobs:
frames land with their statuses, a dry run catches limits and views before anything moves, a replay refuses
a configuration beyond a limit, skips what it cannot see, keeps its frames on cancel and stops the robot,
pauses and resumes, and re-measures a session in place. Where a test follows motion or settling, the driver
runs on a ManualClock that the test advances (with the replay's job waiting on it: `threads`)."""

from __future__ import annotations

import csv
import math
import threading
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest
from manual_jobs import manual_runner, wait

from app.clock import ManualClock
from app.drivers import LimitError
from app.drivers.simulated import SimulatedDriver
from app.jobs.runner import JobRunner
from app.jobs.snapshot import JobState
from app.robots.capture import AutoCapture, capture_frame, dry_run, out_of_margin, replay
from app.store import Store
from calib_core import InputError, Problem, SimulatedRobot, Visibility, load_profile
from calib_core.io.session import read_session

DEG = math.pi / 180
SAMPLES = Path(__file__).resolve().parent.parent / "sample_sessions"


@pytest.fixture(scope="module")
def jobs(store: Store) -> Iterator[JobRunner]:
    with manual_runner(store) as runner:
        yield runner


@pytest.fixture(scope="module")
def nao_plan(nao):
    """NAO stances the nominal model predicts in view and within the limits less the margin."""
    q, targets = SimulatedRobot.from_profile(nao, seed=7).configurations(12)
    with SimulatedDriver(nao, seed=3) as d:
        rows = dry_run(d, q, targets, nao.nominal())
    ok = [r["action"] == "capture" and not r["note"] for r in rows]  # none moved out of the margin
    assert sum(ok) >= 5
    return q[ok], targets[ok]


@pytest.fixture
def nao_driver(nao) -> Iterator[SimulatedDriver]:
    d = SimulatedDriver(nao, seed=3, time_scale=20.0)
    yield d
    d.close()


def test_capture_frame_stores_what_the_robot_sees(store, nao, nao_driver) -> None:
    sid = store.sessions.create("nao", "observe", source="capture")
    frame = capture_frame(store, nao_driver, sid)
    assert frame.index == 1 and frame.status == "measured"
    assert np.array_equal(frame.joints_rad, nao_driver.read_joints())
    assert frame.target == nao_driver.status().target
    assert set(frame.images) == {"image"} and (store.data_dir / frame.images["image"]).is_file()
    assert store.sessions.dataset(sid, nao).measured.shape == (24, 2)
    assert capture_frame(store, nao_driver, sid).index == 2


def test_a_frame_keeps_every_sensor_s_sighting_of_one_look(store) -> None:
    """The Motoman's tracker and two cameras look at once, at two of the data set's poses with both arms in the
    cameras' view (leica_rep_self1): each frame holds the tracker's reflector of the arm it is pointed at and
    each camera's faces of both arms, with the readings of that one moment, each row where the hidden truth puts
    it (the cameras' pixels noise-free, the profile gives them no noise; the tracker within 5 sigma)."""
    mm = load_profile("motoman")
    names = [s.name for s in mm.sensors]
    with (SAMPLES / "motoman-ctu" / "camera_poses.csv").open() as f:
        poses = [r for r in csv.DictReader(f) if r["source_file"] == "leica_rep_self1_dataset.mat"][:2]
    q = [np.radians([float(r[f"{j.name}_deg"]) for j in mm.joints]) for r in poses]
    sid = store.sessions.create("motoman", "three sensors", source="capture")
    with SimulatedDriver(mm, seed=3, time_scale=50.0, start_rad=q[0]) as d:
        for arm, qk in zip(("LR1", "LR2"), q, strict=True):
            assert d.move_to(qk)
            d.set_target(mm.target(arm))
            look = d.look()
            assert (look.sightings[0].sensor, look.sightings[0].target) == (names.index("tracker"), mm.target(arm))
            cameras = {(names[s.sensor], mm.targets[s.target].name) for s in look.sightings[1:]}
            assert cameras == {(f"camera{c}", f"markers{a}") for c in (1, 2) for a in (1, 2)}
            frame = capture_frame(store, d, sid)
            assert frame.status == "measured" and frame.reason == "ok" and frame.target == mm.target(arm)
            assert [x["sensor"] for x in frame.detail["sightings"]] == [names[s.sensor] for s in look.sightings]
        truth = d.true_params()
    counts = store.sessions.sensor_counts(sid)
    camera_rows = {names.index(f"camera{c}"): 40 for c in (1, 2)}
    assert all(c == {names.index("tracker"): 1} | camera_rows for c in counts.values()), counts
    data = store.sessions.dataset(sid, mm)
    assert data.n_configurations == 2
    for s in data.sensors:
        own = data.of_sensor(s)
        dim = mm.sensors[s].dim
        error = np.linalg.norm(Problem(mm, own, [], truth).predict(truth)[:, :dim] - own.measured[:, :dim], axis=1)
        limit = 5 * mm.simulation["noise"]["point"] if names[s] == "tracker" else 1e-6
        assert error.max() < limit, (names[s], error.max())


def test_capture_frame_refuses_a_moving_robot_and_another_robots_session(store, nao, rn, nao_driver) -> None:
    sid = store.sessions.create("nao", "moving", source="capture")
    slow = SimulatedDriver(nao, seed=3, time_scale=0.05)
    try:
        q = slow.true_joints_rad()
        q[nao.joint("HeadYaw")] += 20 * DEG
        slow.move_to(q, wait=False)
        with pytest.raises(InputError, match="moving"):
            capture_frame(store, slow, sid)
    finally:
        slow.close()
    other = store.sessions.create("robonaut-a", "arm", source="capture")
    with pytest.raises(InputError, match="robonaut-a, not nao"):
        capture_frame(store, nao_driver, other)
    assert store.sessions.frames(sid) == [] and store.sessions.frames(other) == []


def test_dry_run_flags_limits_and_views_before_anything_moves(rn) -> None:
    planner = SimulatedRobot.from_profile(rn, seed=11)
    q_ok, _ = planner.configurations(1)
    lo, hi = rn.joint_limits()
    rng = np.random.default_rng(0)
    margin = np.minimum(DEG, (hi - lo) / 2)
    random_q = rng.uniform(lo + margin, hi - margin, (200, len(lo)))
    hidden = random_q[~Visibility(rn, rn.nominal()).sees(random_q, np.zeros(200, int))][0]
    beyond, in_margin = q_ok[0].copy(), q_ok[0].copy()
    beyond[rn.joint("shoulder_pitch")] = 95 * DEG
    in_margin[rn.joint("wrist_roll")] = hi[rn.joint("wrist_roll")] - 0.5 * DEG  # the fixture stays in view
    q = np.array([q_ok[0], beyond, in_margin, hidden])
    with SimulatedDriver(rn, seed=3) as d:
        before = d.true_joints_rad()
        rows = dry_run(d, q, np.zeros(4, int), rn.nominal(), indices=[5, 6, 7, 8])
        assert np.array_equal(d.true_joints_rad(), before) and not d.status().moving
    assert [r["index"] for r in rows] == [5, 6, 7, 8]
    assert [r["action"] for r in rows] == ["capture", "refuse", "capture", "skip"]
    assert [r["ok"] for r in rows] == [True, False, True, False]
    assert rows[1]["problem"] == "shoulder_pitch 95.0 deg is beyond its upper limit 90.0 deg (margin 1.0 deg)"
    # Inside the margin but within the limits (the robot reached it): moved onto the margin's edge, said so.
    assert rows[2]["note"] == "moved out of the 1.0 deg safety margin: wrist_roll 0.50 deg" and not rows[2]["problem"]
    assert rows[3]["problem"] == "fixture not predicted in view"
    assert [r["note"] for r in rows if r is not rows[2]] == ["", "", ""]
    with SimulatedDriver(rn, seed=3) as d:
        moved, note = out_of_margin(d, in_margin)
        d.check(moved)
        assert note == rows[2]["note"]
        wrist = rn.joint("wrist_roll")
        assert moved[wrist] == pytest.approx(hi[wrist] - DEG)
        assert np.array_equal(np.delete(moved, wrist), np.delete(in_margin, wrist))
        with pytest.raises(LimitError, match="beyond its upper limit"):
            out_of_margin(d, beyond)


def test_dry_run_trusts_a_frames_own_measurement_over_the_prediction(rn) -> None:
    """The day-1 sample re-measured on the robot as it is: a configuration measured in its session was seen,
    whatever the nominal model predicts (it put 29 of its 67 frames out of view); one without a measurement
    keeps the prediction."""
    folder = SAMPLES / "robonaut-a-day1"
    frames = read_session(folder, rn).frames
    q = np.radians([[f.joints_deg[n] for n in rn.joint_names] for f in frames])
    seen = np.array([f.status == "measured" for f in frames])
    targets = np.zeros(len(q), int)
    with SimulatedDriver(rn, seed=3) as d:
        predicted = dry_run(d, q, targets, rn.nominal())
        trusted = dry_run(d, q, targets, rn.nominal(), seen=seen)
    assert sum(r["action"] == "skip" for r, s in zip(predicted, seen, strict=True) if s) > 20
    assert all(r["action"] == "capture" and r["ok"] for r, s in zip(trusted, seen, strict=True) if s)
    unseen = [k for k in range(len(q)) if not seen[k]]
    assert unseen and [trusted[k] for k in unseen] == [predicted[k] for k in unseen]


def test_dry_run_predicts_the_board_with_the_believed_calibration(nao, nao_plan, nao_driver) -> None:
    """The same stance is in view for the board of the lifted foot, not for the other foot's board; and a
    believed camera pitched 40 deg away predicts the board out of the image."""
    q, targets = nao_plan
    assert all(r["ok"] for r in dry_run(nao_driver, q[:2], targets[:2], nao.nominal()))
    other = dry_run(nao_driver, q[:2], 1 - targets[:2], nao.nominal())
    assert [r["problem"] for r in other] == [f"{nao.targets[1 - t].name} not predicted in view" for t in targets[:2]]
    tilted = nao.nominal()
    tilted[nao.param("CamPitch")] += 40 * DEG
    assert not any(r["ok"] for r in dry_run(nao_driver, q[:2], targets[:2], tilted))


def test_replay_captures_frames_with_their_statuses(store, jobs, nao, nao_plan, nao_driver) -> None:
    q, targets = nao_plan
    hidden = q[0].copy()
    plan_q = np.array([q[0], q[1], hidden, q[2]])
    plan_t = np.array([targets[0], targets[1], 1 - targets[0], targets[2]])
    sid = store.sessions.create("nao", "replay", source="capture")
    job = jobs.submit_thread("replay", lambda ctx: replay(ctx, store, nao_driver, sid, plan_q, plan_t), session_id=sid)
    snap = wait(jobs, job)
    assert snap.state == JobState.DONE, snap.error
    assert snap.result == sid and snap.progress == 1.0
    frames = store.sessions.frames(sid)
    assert [f.index for f in frames] == [1, 2, 3, 4]
    assert frames[2].status == "skipped" and frames[2].reason.endswith("not predicted in view")
    assert frames[2].images == {}
    captured = [frames[0], frames[1], frames[3]]
    assert all(f.status in ("measured", "not found") for f in captured)
    assert sum(f.status == "measured" for f in captured) >= 2
    for f, k in zip(captured, [0, 1, 3], strict=True):
        assert f.target == plan_t[k] and set(f.images) == {"image"}
        assert np.all(np.abs(f.joints_rad - plan_q[k]) <= 0.05 * DEG + 1e-12)  # the readings of the pose
    detail = snap.detail
    assert (detail["done"], detail["total"], detail["skipped"]) == (4, 4, 1)
    assert detail["measured"] == sum(f.status == "measured" for f in frames)
    assert detail["frame"] == 4 and detail["status"] == frames[3].status


def test_replay_drives_a_configuration_inside_the_margin_to_its_edge(store, jobs, rn) -> None:
    """A recorded pose 0.5 deg inside a joint's 1 deg margin is driven to the margin's edge and captured (it
    used to be skipped: a third of some sample sessions), never past it."""
    q_ok, targets = SimulatedRobot.from_profile(rn, seed=11).configurations(1)
    _, hi = rn.joint_limits()
    wrist = rn.joint("wrist_roll")
    q = q_ok[0].copy()
    q[wrist] = hi[wrist] - 0.5 * DEG
    sid = store.sessions.create("robonaut-a", "margin", source="capture")
    with SimulatedDriver(rn, seed=3, time_scale=50.0) as d:
        job = jobs.submit_thread("replay", lambda ctx: replay(ctx, store, d, sid, q[None], targets), session_id=sid)
        snap = wait(jobs, job)
        assert snap.state == JobState.DONE, snap.error
        assert d.true_joints_rad()[wrist] <= hi[wrist] - DEG + 1e-9
    (frame,) = store.sessions.frames(sid)
    assert frame.status in ("measured", "not found")
    assert abs(frame.joints_rad[wrist] - (hi[wrist] - DEG)) <= 0.05 * DEG + 1e-12


def test_replay_refuses_a_configuration_beyond_a_limit_before_moving(store, jobs, nao, nao_plan, nao_driver) -> None:
    q, targets = nao_plan
    bad = q[1].copy()
    bad[nao.joint("LKneePitch")] = 125 * DEG
    sid = store.sessions.create("nao", "refused", source="capture")
    before = nao_driver.true_joints_rad()
    job = jobs.submit_thread(
        "replay",
        lambda ctx: replay(ctx, store, nao_driver, sid, np.array([q[0], bad]), targets[:2]),
        session_id=sid,
    )
    snap = wait(jobs, job)
    assert snap.state == JobState.FAILED
    assert snap.error == (
        "replay refused before moving: configuration 2: LKneePitch 125.0 deg is beyond its upper limit "
        "121.0 deg (margin 1.0 deg)"
    )
    assert store.sessions.frames(sid) == []
    assert np.array_equal(nao_driver.true_joints_rad(), before)


def _done(jobs: JobRunner, job: str) -> int:
    return jobs.get(job).detail.get("done", 0)


def test_cancel_mid_replay_keeps_the_frames_and_stops_the_robot(store, jobs, nao, nao_plan) -> None:
    q, targets = nao_plan
    sid = store.sessions.create("nao", "cancelled", source="capture")
    clock = ManualClock()
    with SimulatedDriver(nao, seed=3, time_scale=1.0, clock=clock) as d:  # moves of a few tenths of a second
        job = jobs.submit_thread("replay", lambda ctx: replay(ctx, store, d, sid, q, targets), session_id=sid)
        # Cancelled in the middle of the move to the second configuration (the poller and the job on the clock).
        clock.run(lambda: _done(jobs, job) >= 1 and d.status().moving, threads=2)
        moving = d.status()
        jobs.cancel(job)
        clock.run(lambda: jobs.get(job).state.finished, threads=2)
        snap = wait(jobs, job)
        assert snap.state == JobState.CANCELLED
        st = d.status()
        assert moving.moving and not st.moving and st.message == "stopped"
        halted = d.true_joints_rad()
        clock.advance(1.0)
        assert np.array_equal(d.true_joints_rad(), halted)
    frames = store.sessions.frames(sid)
    assert 1 <= len(frames) == snap.detail["done"] < len(q)
    assert all(f.status in ("measured", "not found") for f in frames)


def test_pause_holds_the_replay_at_once_and_resume_finishes_it(store, jobs, nao, nao_plan) -> None:
    """A pause in the middle of a move stops the robot where it is and keeps no frame after it is answered; resumed,
    the replay makes that move again and captures every configuration, each at its own pose."""
    q, targets = nao_plan[0][:4], nao_plan[1][:4]
    sid = store.sessions.create("nao", "paused", source="capture")
    clock = ManualClock()
    with SimulatedDriver(nao, seed=3, time_scale=1.0, clock=clock) as d:  # moves of a few tenths of a second
        job = jobs.submit_thread("replay", lambda ctx: replay(ctx, store, d, sid, q, targets), session_id=sid)
        # Paused once the move to the second configuration is under way (the poller and the job on the clock).
        clock.run(lambda: _done(jobs, job) >= 1 and d.status().moving, threads=2)
        jobs.pause(job)
        held = len(store.sessions.frames(sid))
        # The robot stops at once, short of the second configuration ...
        clock.run(lambda: not d.status().moving, threads=2, limit_s=0.2)
        pose = d.true_joints_rad()
        assert np.abs(pose - out_of_margin(d, q[1])[0]).max() > math.radians(1.0)
        # ... then nothing moves and nothing is captured while paused, however long.
        until = clock.now() + 5.0
        clock.run(lambda: clock.now() >= until, threads=1, step_s=0.5)
        assert len(store.sessions.frames(sid)) == held == 1 == _done(jobs, job)
        assert np.array_equal(d.true_joints_rad(), pose)
        assert jobs.get(job).state == JobState.RUNNING and jobs.get(job).paused
        jobs.resume(job)
        clock.run(lambda: jobs.get(job).state.finished, threads=2)
        snap = wait(jobs, job)
    assert snap.state == JobState.DONE
    frames = store.sessions.frames(sid)
    assert [f.index for f in frames] == [1, 2, 3, 4]
    for f, qk in zip(frames, q, strict=True):  # each frame at its own configuration (the readings' 0.1 deg)
        assert np.abs(f.joints_rad - out_of_margin(d, qk)[0]).max() < math.radians(0.2)


def test_remeasure_replaces_frames_in_place_and_keeps_skipped_ones(store, jobs, nao, nao_plan, nao_driver) -> None:
    q, targets = nao_plan
    sid = store.sessions.create("nao", "remeasure", source="capture")
    for k in range(3):
        nao_driver.set_target(int(targets[k]))
        assert nao_driver.move_to(q[k])
        capture_frame(store, nao_driver, sid, index=10 + k)
    old = {f.index: f for f in store.sessions.frames(sid)}
    frames = list(old.values())
    plan_t = np.array([f.target for f in frames])
    plan_t[1] = 1 - plan_t[1]  # frame 11 now predicted out of view: skipped, the old record stays
    job = jobs.submit_thread(
        "remeasure",
        lambda ctx: replay(
            ctx, store, nao_driver, sid, np.array([f.joints_rad for f in frames]), plan_t, [f.index for f in frames]
        ),
        session_id=sid,
    )
    snap = wait(jobs, job)
    assert snap.state == JobState.DONE, snap.error
    new = {f.index: f for f in store.sessions.frames(sid)}
    assert sorted(new) == [10, 11, 12]
    assert (new[11].captured, new[11].status, new[11].images) == (old[11].captured, old[11].status, old[11].images)
    for i in (10, 12):
        assert new[i].captured > old[i].captured
        assert np.array_equal(new[i].joints_rad, old[i].joints_rad)


def test_autocapture_takes_settled_distinct_well_detected_frames(store, nao) -> None:
    sid = store.sessions.create("nao", "auto", source="capture")
    clock = ManualClock()
    d = SimulatedDriver(nao, seed=3, time_scale=20.0, clock=clock)  # settling 0.3 s takes 15 ms of the clock
    auto = AutoCapture(store, d, sid, min_gap_rad=3 * DEG)
    target = d.status().target
    other_knee = nao.joint("RKneePitch" if target == 0 else "LKneePitch")  # the leg the camera does not watch

    def settle() -> None:
        clock.run(lambda: d.settled(0.3), threads=1)  # the poller

    def move(q: np.ndarray) -> bool:
        result: list[bool] = []
        mover = threading.Thread(target=lambda: result.append(d.move_to(q)))
        mover.start()
        clock.run(lambda: not mover.is_alive(), threads=2)
        mover.join()
        return result == [True]

    q = d.true_joints_rad()
    q[other_knee] += 10 * DEG
    d.move_to(q, wait=False)
    assert auto.poll() is None  # moving
    clock.run(lambda: not d.status().moving, threads=1)
    assert auto.poll() is None  # not yet settled for 0.3 s
    settle()
    first = auto.poll()
    assert first is not None and first.status == "measured"
    settle()
    assert auto.poll() is None  # the same configuration again
    q[other_knee] += 2 * DEG  # less than min_gap
    assert move(q)
    settle()
    assert auto.poll() is None
    q[other_knee] += 2 * DEG  # 4 deg from the first frame
    assert move(q)
    settle()
    second = auto.poll()
    assert second is not None and second.index == first.index + 1
    # A look that finds nothing (the other foot's board is not in view) stores nothing, and the same
    # configuration is not looked at again.
    d.set_target(1 - target)
    q[other_knee] += 5 * DEG
    assert move(q)
    settle()
    assert auto.poll() is None
    assert auto.last_look is not None and auto.last_look.sightings[0].status == "not found"
    seen = auto.last_look
    assert auto.poll() is None and auto.last_look is seen
    assert [f.index for f in store.sessions.frames(sid)] == [first.index, second.index]
    # A new AutoCapture continues from the session's last frame.
    assert AutoCapture(store, d, sid, min_gap_rad=3 * DEG).poll() is None
    d.close()
