"""The simulated robot driver: limits with a margin, velocity-limited motion whose joints arrive together, an
immediate stop, quantised readings, a camera that sees the fixture where the truth puts it, seeded by the
calibration the robot was given, and a wander that stays within limits. Motion and settling are followed on a
ManualClock that the tests advance: nothing here waits for time to pass."""

from __future__ import annotations

import math
import threading
from collections.abc import Iterator

import numpy as np
import pytest

from app.clock import ManualClock
from app.drivers import LimitError, check_limits
from app.drivers.simulated import REST_AFTER_S, SimulatedDriver
from calib_core import InputError, SimulatedRobot, load_profile
from calib_core.vision.sighting import predicted_points

DEG = math.pi / 180


@pytest.fixture
def clock() -> ManualClock:
    return ManualClock()


@pytest.fixture
def driver(rn, clock):
    d = SimulatedDriver(rn, seed=3, time_scale=10.0, clock=clock)
    yield d
    d.close()


def move(d: SimulatedDriver, clock: ManualClock, q: np.ndarray) -> bool:
    """d.move_to(q) in a thread of its own, the clock run (its poller and that thread) until it returns."""
    result: list[bool | BaseException] = []

    def run() -> None:
        try:
            result.append(d.move_to(q))
        except BaseException as exc:
            result.append(exc)

    mover = threading.Thread(target=run)
    mover.start()
    clock.run(lambda: not mover.is_alive(), threads=2, limit_s=60)
    mover.join()
    if isinstance(result[0], BaseException):
        raise result[0]
    return result[0]


def _q(rn, **deg: float) -> np.ndarray:
    """A configuration well inside the limits, with some joints set (deg)."""
    q = np.zeros(len(rn.joints))
    for name, value in deg.items():
        q[rn.joint(name)] = value * DEG
    return q


def test_check_refuses_beyond_limits_naming_joint_value_and_limit(rn, driver) -> None:
    with pytest.raises(LimitError, match=r"shoulder_pitch 95\.0 deg is beyond its upper limit 90\.0 deg") as info:
        driver.check(_q(rn, shoulder_pitch=95))
    assert info.value.joint == "shoulder_pitch" and info.value.beyond
    with pytest.raises(LimitError, match=r"wrist_pitch -61\.5 deg is beyond its lower limit -60\.0 deg"):
        driver.check(_q(rn, wrist_pitch=-61.5))
    # Inside the 1 deg margin: refused too, but not "beyond" the limit itself.
    with pytest.raises(LimitError, match=r"elbow_pitch 119\.5 deg is within the 1\.0 deg safety margin") as info:
        driver.check(_q(rn, elbow_pitch=119.5))
    assert not info.value.beyond
    driver.check(_q(rn, elbow_pitch=118.9, shoulder_pitch=-88.9))
    # neck_roll is fixed at 0 (range 0..0): exactly 0 passes, anything else is refused.
    with pytest.raises(LimitError, match="neck_roll"):
        driver.check(_q(rn, neck_roll=0.2))
    with pytest.raises(LimitError, match="not a number"):
        driver.check(_q(rn, wrist_yaw=math.nan))
    with pytest.raises(ValueError, match="expected 10 joint values"):
        check_limits(rn, np.zeros(3), DEG)


def test_move_beyond_limits_is_refused_and_nothing_moves(rn, driver, clock) -> None:
    before = driver.true_joints_rad()
    with pytest.raises(LimitError, match="elbow_roll"):
        driver.move_to(_q(rn, elbow_roll=-90.5))
    clock.advance(1.0)  # the robot's truth follows the clock: a move started would have taken it somewhere
    assert not driver.status().moving
    assert np.array_equal(driver.true_joints_rad(), before)


def test_motion_keeps_velocity_limits_and_all_joints_arrive_together(rn, clock) -> None:
    time_scale, tick_s = 10.0, 0.02  # the poller's period at its 50 Hz
    with SimulatedDriver(rn, seed=3, time_scale=time_scale, start_rad=_q(rn), clock=clock) as d:
        goal = _q(rn, shoulder_roll=60, wrist_roll=-80, neck_yaw=20, elbow_pitch=10)
        samples: list[tuple[float, np.ndarray]] = []
        result: list[bool] = []
        mover = threading.Thread(target=lambda: result.append(d.move_to(goal)))
        mover.start()
        while mover.is_alive():  # a sample of each tick of the poller, until move_to returns
            clock.until_waiting(2, unless=lambda: not mover.is_alive())
            st = d.status()
            samples.append((st.stamp, st.joints_rad))
            clock.advance(tick_s)
        mover.join()
        assert result == [True]
        assert np.allclose(d.read_joints(), goal, atol=0.051 * DEG)

    velocity = np.array([j.velocity for j in rn.joints]) * time_scale
    step = np.array([j.resolution for j in rn.joints])
    stamps = np.array([s for s, _ in samples])
    qs = np.array([q for _, q in samples])
    keep = np.r_[True, np.diff(stamps) > 0]  # one sample per tick of the poller
    stamps, qs = stamps[keep], qs[keep]
    assert len(stamps) >= 5
    elapsed = stamps[np.flatnonzero(np.all(qs == qs[-1], axis=1))[0]]  # the tick the goal was first read
    dq = np.abs(np.diff(qs, axis=0))
    dt = np.diff(stamps)[:, None]
    # Readings are rounded to the encoder step: allow one step per difference.
    assert np.all(dq <= velocity * dt * (1 + 1e-9) + step + 1e-12)
    # The slowest joint's ratio sets the duration (wrist_roll: 80 deg at 45 deg/s, shoulder_roll: 60 at 30); the
    # arrival is seen at the first tick after it.
    expected_s = max(80 / 45, 60 / 30) / time_scale
    assert expected_s - 1e-9 <= elapsed <= expected_s + tick_s + 1e-9
    # Linear interpolation: every sample is start + s (goal - start) with one s for all joints.
    moving = np.abs(goal - _q(rn)) > 0
    s = (qs[:, moving] - _q(rn)[moving]) / (goal - _q(rn))[moving]
    assert np.all(np.ptp(s, axis=1) <= 2 * 0.05 / 10)  # half a 0.1 deg step over the smallest move (10 deg)


def test_stop_halts_where_it_is_and_move_to_returns_false(rn, clock) -> None:
    with SimulatedDriver(rn, seed=3, time_scale=1.0, start_rad=_q(rn), clock=clock) as d:
        result: list[bool] = []
        mover = threading.Thread(target=lambda: result.append(d.move_to(_q(rn, shoulder_roll=60))))
        mover.start()
        clock.run(lambda: clock.now() >= 0.3, threads=2)
        clock.advance(0.01)  # between two ticks of the poller: stop() halts at this moment, not at the tick
        d.stop()
        after = d.true_joints_rad()
        mover.join()
        st = d.status()
        clock.advance(1.0)
        later = d.true_joints_rad()
    assert result == [False]  # move_to returned (the motion's safety is below)
    assert not st.moving and st.message == "stopped"
    assert np.array_equal(st.joints_rad, d.transport.sim.readings(after))  # the readings where it halted
    # 30 deg/s for 0.31 s: it halts there, and nothing moves after.
    assert after[0] == pytest.approx(30 * DEG * 0.31)
    assert np.array_equal(later, after)


def test_a_robot_at_rest_is_read_five_times_a_second_and_a_move_at_once(rn, clock) -> None:
    """At rest (no move for REST_AFTER_S) the simulated robot's readings do not change and are read every 0.2 s of
    the clock, not 50 times a second (an idle desk of four such robots spent 5.7% of a core: idle_desk.py); a move wakes
    the poller: its first reading comes with the clock standing still, the next ones every 0.02 s."""
    with SimulatedDriver(rn, seed=3, time_scale=10.0, start_rad=_q(rn), clock=clock) as d:

        def readings(steps: int) -> int:
            """How many readings come in that many steps of 0.02 s."""
            start, seen = clock.now(), set()
            for _ in range(steps):
                clock.advance(0.02)
                clock.until_waiting(1)  # the poller, once it has read what was due
                seen.add(d.status().stamp)
            return len({s for s in seen if s > start})

        clock.run(lambda: clock.now() >= REST_AFTER_S + 0.05, threads=1)
        assert readings(50) == 5
        assert d.move_to(_q(rn, wrist_yaw=30.0), wait=False)
        clock.until_waiting(1)
        assert d.status().stamp == clock.now() and d.status().moving
        assert readings(10) == 10


def test_readings_are_quantised_to_the_encoder_step(rn) -> None:
    with SimulatedDriver(rn, seed=3, time_scale=20.0, start_rad=_q(rn)) as d:
        assert d.move_to(_q(rn, shoulder_roll=12.3456, elbow_pitch=-33.3333))
        readings, true = d.read_joints(), d.true_joints_rad()
        status = d.status().joints_rad
    steps = readings / (0.1 * DEG)
    assert np.allclose(steps, np.round(steps), atol=1e-9)
    assert np.array_equal(status, readings)
    assert not np.allclose(true, readings)  # the truth is not on the grid
    assert np.all(np.abs(readings - true) <= 0.05 * DEG + 1e-12)
    assert readings[rn.joint("shoulder_roll")] == pytest.approx(12.3 * DEG)


def test_settled_needs_the_robot_still_for_the_time_asked(rn, clock) -> None:
    """Settled: no move under way and the readings unchanged for the time asked, robot time (the clock's times
    time_scale), as the readings show it (a robot polled seldom is not settled between its readings)."""
    with SimulatedDriver(rn, seed=3, time_scale=2.0, start_rad=_q(rn), clock=clock) as d:
        assert move(d, clock, _q(rn, wrist_yaw=1.0))
        arrived = clock.now()
        assert not d.settled(0.3)
        clock.run(lambda: clock.now() >= arrived + 0.14, threads=1)  # 0.28 s of robot time
        assert not d.settled(0.3)
        clock.advance(0.019)  # time passes, but no reading comes
        assert not d.settled(0.3)
        clock.run(lambda: clock.now() >= arrived + 0.16, threads=1)  # the next reading: 0.32 s
        assert d.settled(0.3)


def test_a_stop_ends_a_settle_wait_without_the_clock_moving(rn, clock) -> None:
    """A replay waiting for the robot to settle when STOP comes (its job cancelled, then the robot stopped) asks
    again at once, not at its next poll: on a clock that stands still it would wait for ever."""
    with SimulatedDriver(rn, seed=3, time_scale=2.0, start_rad=_q(rn), clock=clock) as d:
        assert move(d, clock, _q(rn, wrist_yaw=1.0))
        cancelled = threading.Event()
        result: list[bool] = []
        waiter = threading.Thread(target=lambda: result.append(d.wait_settled(10.0, 60.0, cancelled.is_set)))
        waiter.start()
        clock.until_waiting(2)  # the poller and the settle wait
        cancelled.set()
        d.stop()
        waiter.join(timeout=30)
        assert not waiter.is_alive() and result == [False]


def test_a_move_that_does_not_arrive_times_out_on_the_clock(rn, clock) -> None:
    """A stalled move (an injected fault) is given up when its duration and the slack have passed on the driver's
    clock: the robot is stopped and the move reported, as a RobotFault."""
    from app.drivers import RobotFault

    with SimulatedDriver(rn, seed=3, time_scale=1.0, start_rad=_q(rn), clock=clock, move_slack_s=2.0) as d:
        d.inject_fault("stall")
        with pytest.raises(RobotFault, match=r"robonaut-a did not arrive within 3\.0 s \(not responding\)"):
            move(d, clock, _q(rn, shoulder_roll=30))  # 30 deg at 30 deg/s: 1 s, and 2 s of slack
        assert 3.0 < clock.now() <= 3.05
        st = d.status()
        assert (st.connected, st.moving, st.message) == (True, False, "stopped")
        assert move(d, clock, _q(rn, shoulder_roll=30))  # the next one arrives


def _visit(d: SimulatedDriver, configurations: np.ndarray) -> Iterator[np.ndarray]:
    """Drive to each configuration within the limits (others are skipped), one at a time."""
    for q in configurations:
        try:
            d.check(q)
        except LimitError:
            continue
        assert d.move_to(q)
        yield q


@pytest.mark.slow
def test_look_finds_the_sphere_within_1_cm_of_the_truth(rn) -> None:
    """In typical visible configurations (a few, since the forearm can hide the sphere), the BallFinder
    seeded by the nominal model measures the fixture centre where the hidden truth puts it."""
    planner = SimulatedRobot.from_profile(rn, seed=5)
    configurations, _ = planner.configurations(16)
    with SimulatedDriver(rn, seed=3, time_scale=50.0) as d:
        errors = []
        for _ in _visit(d, configurations):
            look = d.look()
            assert look.target == 0 and set(look.images) == {"left", "right"}
            assert look.images["left"].shape == (480, 640)
            assert np.array_equal(look.readings_rad, d.read_joints())
            if look.sightings[0].status == "measured":
                truth = predicted_points(rn, d.true_params(), d.true_joints_rad(), 0)[0]
                errors.append(float(np.linalg.norm(look.sightings[0].measured[0] - truth)))
            if len(errors) == 2:
                break
    assert len(errors) == 2
    assert max(errors) < 1.0  # cm


def test_applied_calibration_seeds_the_detector(rn) -> None:
    """A calibration that puts the fixture 60 cm away from where it is makes the BallFinder search in the
    wrong place (outside its gate): the robot reports what its calibration lets it see."""
    wrong = rn.nominal()
    wrong[rn.param("fixture.x")] += 60.0
    planner = SimulatedRobot.from_profile(rn, seed=5)
    configurations, _ = planner.configurations(16)
    with SimulatedDriver(rn, seed=3, time_scale=50.0) as d:
        for _ in _visit(d, configurations):
            if d.look().sightings[0].status == "measured":
                break
        else:
            pytest.fail("no configuration measured with the nominal calibration")
        d.apply_calibration("c-wrong", wrong)
        assert d.status().calibration_id == "c-wrong"
        assert np.array_equal(d.believed_params(), wrong)
        assert d.look().sightings[0].status == "not found"
        assert d.look(believed=rn.nominal()).sightings[0].status == "measured"  # an explicit belief wins
        d.apply_calibration(None, None)
        assert d.status().calibration_id is None
        assert np.array_equal(d.believed_params(), rn.nominal())
        assert d.look().sightings[0].status == "measured"


def test_day_drifts_the_hidden_joint_offsets(rn) -> None:
    with SimulatedDriver(rn, seed=1) as first, SimulatedDriver(rn, seed=1, day=2) as later:
        changed = np.flatnonzero(first.true_params() != later.true_params())
    assert len(changed) > 0
    assert all(rn.parameter_names[i].endswith(".theta") for i in changed)


def test_wander_moves_through_configurations_within_limits(rn, clock) -> None:
    lo, hi = rn.joint_limits()
    margin = np.minimum(DEG, (hi - lo) / 2)
    with SimulatedDriver(rn, seed=3, time_scale=50.0, clock=clock) as d:
        start = d.true_joints_rad()
        d.wander(True)
        assert d.status().wandering
        true, stopped = [], 0
        for _ in range(300):  # 1.5 s of the clock, 75 s of the robot's
            clock.until_waiting(2)  # the poller and the wander
            true.append(d.true_joints_rad())
            stopped += not d.status().moving
            clock.advance(0.005)
        d.wander(False)
        st = d.status()
        assert not st.wandering and not st.moving
    true_a = np.array(true)
    distinct = np.unique(np.round(true_a, 9), axis=0)
    assert len(distinct) > 20
    assert np.max(np.abs(true_a - start)) > 10 * DEG  # it really went somewhere
    assert stopped > 0  # with pauses between moves
    assert np.all(true_a >= lo + margin - 1e-9) and np.all(true_a <= hi - margin + 1e-9)


def test_an_operator_move_or_stop_ends_the_wander(rn, clock) -> None:
    with SimulatedDriver(rn, seed=3, time_scale=50.0, clock=clock) as d:
        d.wander(True)
        clock.run(lambda: clock.now() >= 0.1, threads=2)
        assert move(d, clock, _q(rn, shoulder_roll=10))
        assert not d.status().wandering
        clock.advance(1.0)
        assert np.allclose(d.true_joints_rad(), _q(rn, shoulder_roll=10))
        d.wander(True)
        clock.run(lambda: clock.now() >= 1.2 and d.status().moving, threads=2)
        d.stop()
        halted = d.true_joints_rad()
        clock.advance(1.0)
        assert not d.status().wandering
        assert np.array_equal(d.true_joints_rad(), halted)


def test_nao_looks_at_the_board_of_the_selected_foot(nao) -> None:
    with SimulatedDriver(nao, seed=3, time_scale=50.0) as d:
        st = d.status()
        look = d.look()
        assert look.target == st.target
        assert set(look.images) == {"image"}
        assert look.sightings[0].status == "measured"
        assert look.sightings[0].measured.shape == (24, 2)
        with pytest.raises(ValueError, match=r"targets 0\.\.1"):
            d.set_target(2)
        d.set_target(1 - st.target)
        assert d.status().target == 1 - st.target
        assert d.look().target == 1 - st.target


def test_a_closed_driver_reports_disconnected_and_refuses_moves(rn) -> None:
    d = SimulatedDriver(rn, seed=3)
    d.close()
    assert not d.status().connected
    with pytest.raises(RuntimeError, match="closed"):
        d.move_to(_q(rn))


def test_the_simulated_motoman_reads_its_tracker_on_the_arm_it_is_pointed_at() -> None:
    """A laser tracker has no image: a look is its reading of the reflector on the chosen arm, where the hidden
    truth (the tracker's true pose too) puts it, with the profile's tracker noise."""
    motoman = load_profile("motoman")
    sigma = motoman.simulation["noise"]["point"]
    with SimulatedDriver(motoman, seed=3, time_scale=50.0) as d:
        assert d.status().target == motoman.target("LR1")  # the right arm's reflector unless told
        errors = {}
        for name in ("LR1", "LR2"):
            d.set_target(motoman.target(name))
            looks = [d.look() for _ in range(30)]
            assert all(look.images == {} and look.sightings[0].status == "measured" for look in looks)
            assert all(look.target == motoman.target(name) for look in looks)
            truth = predicted_points(motoman, d.true_params(), d.true_joints_rad(), motoman.target(name))[0]
            errors[name] = np.array([look.sightings[0].measured[0] - truth for look in looks])
        for name, e in errors.items():
            assert np.all(np.abs(e.mean(axis=0)) < 4 * sigma / math.sqrt(len(e))), name
            assert 0.6 * sigma < e.std() < 1.5 * sigma, (name, e.std())
        with pytest.raises(InputError, match="the tracker reads LR1, LR2, not markers1"):
            d.set_target(motoman.target("markers1"))
