"""calib_core.evaluate: a calibration's figures on data it was not fitted on, per sensor when the
data hold several, judged on a simulated robot whose truth is known."""

from __future__ import annotations

import numpy as np
import pytest

from calib_core import SimulatedRobot, calibrate, evaluate
from calib_core.estimation.problem import Problem


def test_several_sensors_each_in_its_unit_and_another_setup_needs_the_registration(motoman) -> None:
    robot = SimulatedRobot.from_profile(motoman, seed=4)
    n = 120
    q, targets = robot.configurations(n)
    train = robot.measure(q, targets)  # the tracker on the right arm's reflector
    cal = calibrate(motoman, train.data, "full")
    q2, t2 = robot.configurations(n)
    fresh = robot.measure(q2, t2)
    result = evaluate(motoman, cal, fresh.data)
    # Against the truth: the calibration predicts fresh poses nearly as well as the truth does.
    truth = fresh.true_params
    floor = np.linalg.norm(Problem(motoman, fresh.data, [], truth).predict(truth) - fresh.data.measured, axis=1)
    assert result.figures.unit == "m" and result.figures.n == n
    assert result.figures.rms < 2 * np.sqrt(np.mean(floor**2))
    assert result.to_dict().keys() == {"mean", "rms", "max", "n", "unit"}
    # The same poses seen from a tracker moved by 1 m: wrong unless its pose is fitted again.
    moved = robot.true_params.copy()
    moved[motoman.parameter_names.index("tracker.x")] += 1.0
    elsewhere = SimulatedRobot.from_profile(motoman, seed=4, truth=moved).measure(q2, t2)
    assert evaluate(motoman, cal, elsewhere.data).figures.mean > 0.5
    again = evaluate(motoman, cal, elsewhere.data, reregister=True)
    assert again.registered and again.figures.rms == pytest.approx(result.figures.rms, rel=0.05)
    # Several sensors: the tracker and both cameras, each reported in its own unit.
    sensors = np.repeat([0, 1, 2], n // 3)
    mixed = robot.measure(
        q2, np.where(sensors == 0, t2, [[t.name for t in motoman.targets].index("markers1")] * n), sensors=sensors
    )
    each = evaluate(motoman, cal, mixed.data)
    assert set(each.sensors) == {"tracker", "camera1", "camera2"}
    assert each.sensors["camera1"].unit == "px" and each.sensors["tracker"].unit == "m"
    assert set(each.to_dict()["sensors"]) == {"tracker", "camera1", "camera2"}
