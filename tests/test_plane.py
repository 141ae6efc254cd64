"""The plane constraint (calib_core/sensors/plane.py): a touch probe on a table and two walls.

Ground truth is the simulator's hidden robot (tests/profiles/probe-arm.yaml): joint offsets, the
probe's position on the flange and the planes' true poses. The configurations are found on the true
robot so that the probe touches a plane (calib_core/sim/contact.py), the readings rounded to the
encoders' step, the distances read with 0.02 mm of noise.
"""

from __future__ import annotations

import math
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
from jacobian_check import check_jacobian, perturbed

from app.cli import main
from calib_core import InputError, Problem, SimulatedRobot, calibrate, load_profile, parse_dataset, to_csv

PROFILE = Path(__file__).resolve().parent / "profiles" / "probe-arm.yaml"


@pytest.fixture(scope="module")
def arm():
    return load_profile(PROFILE)


@pytest.fixture(scope="module")
def robot(arm):
    return SimulatedRobot.from_profile(arm, seed=3)


@pytest.fixture(scope="module")
def touches(robot):
    return robot.simulate(40)  # 40 touches of each plane


def test_every_simulated_touch_is_on_its_plane(arm, robot, touches) -> None:
    """The simulator's configurations touch their plane on the true robot, and only that one."""
    data = touches.data
    assert data.sensors == [0, 1, 2] and data.n_observations == 120
    exact = Problem(arm, data, [], robot.true_params, noise_model=False)
    unquantised = replace(data, joints=touches.true_joints)
    on_plane = Problem(arm, unquantised, [], robot.true_params, noise_model=False).predict(robot.true_params)
    assert np.abs(on_plane).max() < 1e-6  # mm
    # The encoders' rounding (0.001 deg) moves the probe by micrometres, the noise by 0.02 mm.
    assert np.abs(exact.predict(robot.true_params) - data.measured).max() < 0.12
    lo, hi = arm.joint_limits()
    assert np.all((touches.true_joints > lo) & (touches.true_joints < hi))


def test_the_plane_jacobian_is_exact(arm, touches) -> None:
    rng = np.random.default_rng(5)
    data = replace(touches.data, measured=rng.normal(0, 2.0, touches.data.measured.shape))
    mode = arm.mode("planes")
    problem = Problem(arm, data, list(mode.free), perturbed(arm, rng))
    assert check_jacobian(problem, [arm.parameters[i].name for i in mode.free]) == len(mode.free)


def test_known_planes_recover_the_joint_offsets(arm, robot) -> None:
    """Planes where the profile says they are, a hidden truth in the joint offsets only."""
    truth = arm.nominal().copy()
    offsets = list(arm.mode("offsets").free)
    truth[offsets] = robot.true_params[offsets]
    data = SimulatedRobot.from_profile(arm, seed=4, truth=truth).simulate(30).data
    cal = calibrate(arm, data, "offsets", holdout=0.3)
    assert cal.converged and cal.identifiability.held_fixed == []
    for e in cal.parameters:
        if e.estimated:
            i = arm.param(e.name)
            err = abs(e.value - arm.to_display(i, truth[i]))
            assert err < 0.01 and err < 4 * e.std, (e.name, err, e.std)  # deg
    assert cal.figures["before"].rms > 20 * cal.figures["after"].rms
    assert cal.figures["holdout_after"].rms < 0.05  # mm: the 0.02 mm noise, per touch


def test_unknown_planes_are_estimated_with_the_robot(arm, robot, touches) -> None:
    """The planes' poses free as well: what the data cannot tell apart is held and named, and every
    estimate is the truth (moved along the stated dependencies) within its standard deviations."""
    cal = calibrate(arm, touches.data, "planes", holdout=0.3)
    held = {h.parameter for h in cal.identifiability.held_fixed}
    # The probe's y and j6's offset both swing the probe about the flange axis; turning the whole
    # arm (j1) is turning both walls about the vertical.
    assert held == {"probe.y", "side.rz"}
    truth = robot.true_params.copy()
    shift = truth[arm.param("side.rz")] - arm.nominal()[arm.param("side.rz")]
    truth[[arm.param("side.rz"), arm.param("j1.offset"), arm.param("wall.rz")]] -= shift
    for e in cal.parameters:
        if e.estimated:
            i = arm.param(e.name)
            z = (e.value - arm.to_display(i, truth[i])) / e.std
            assert abs(z) < 4.0, (e.name, e.value, arm.to_display(i, truth[i]), e.std)
    assert cal.figures["holdout_after"].rms < 0.04  # mm
    assert set(cal.sensor_figures) == {"table", "wall", "side"}


def test_one_plane_cannot_see_a_turn_about_its_normal(arm, touches) -> None:
    """The table alone: turning the arm about the vertical moves no probe height, and the report says
    so instead of returning a number for j1's offset."""
    table_only = touches.data.of_sensor(arm.sensors.index(next(s for s in arm.sensors if s.name == "table")))
    cal = calibrate(arm, table_only, "offsets")
    held = {h.parameter: h.message for h in cal.identifiability.held_fixed}
    assert "j1.offset" in held and "no effect on any prediction" in held["j1.offset"]


def test_csv_with_a_plane_column_round_trips(arm, touches) -> None:
    text = to_csv(arm, touches.data)
    assert text.splitlines()[0].startswith("frame,plane,distance_mm,j1")
    back = parse_dataset(arm, text, "touches.csv")
    np.testing.assert_array_equal(back.sensor, touches.data.sensor)
    np.testing.assert_allclose(back.measured, touches.data.measured, atol=1e-6)


def test_cli_solves_plane_touches_and_names_a_bad_plane(arm, touches, tmp_path: Path, capsys) -> None:
    data = tmp_path / "touches.csv"
    data.write_text(to_csv(arm, touches.data))
    out = tmp_path / "cal.json"
    args = ["solve", "--robot", str(PROFILE), "--mode", "planes", "--data", str(data), "--out", str(out)]
    assert main(args) == 0
    assert "probe-arm planes calibration" in capsys.readouterr().out
    lines = data.read_text().splitlines()
    lines[5] = lines[5].replace(",wall,", ",ceiling,").replace(",table,", ",ceiling,").replace(",side,", ",ceiling,")
    data.write_text("\n".join(lines) + "\n")
    out.unlink()
    assert main(args) == 2
    err = capsys.readouterr().err
    assert "line 6" in err and "plane" in err and "ceiling" in err
    assert not out.exists()


@pytest.mark.parametrize(
    ("edit", "words"),
    [
        (("model: plane, noise", "model: plane, normal: [0, 0, 0], noise"), "sensors[0].normal: must not be zero"),
        (
            ("columns: [distance_mm]", "columns: [distance_mm, other_mm]"),
            "a plane sensor ('table') measures 1 number, not 2",
        ),
        (("noise: {sigma: 0.02}}\n  - {name: wall", "noise: {sigma: -1}}\n  - {name: wall"), "sensors[0].noise.sigma"),
        (("wall: wall, side: side}", "wall: wall, side: floor}"), "data.sensors.side: unknown sensor 'floor'"),
    ],
)
def test_a_broken_plane_profile_names_the_field(tmp_path: Path, edit: tuple[str, str], words: str) -> None:
    text = PROFILE.read_text()
    assert edit[0] in text
    path = tmp_path / "arm.yaml"
    path.write_text(text.replace(edit[0], edit[1], 1))
    with pytest.raises(InputError) as err:
        load_profile(path)
    assert words in str(err.value) and str(path) in str(err.value)


def test_a_plane_is_a_sensor_of_one_number_in_the_length_unit(arm) -> None:
    table = arm.sensors[0]
    assert (table.kind, table.dim, table.unit, table.reading) == ("plane", 1, "mm", "direct")
    x = np.array([[1.0, 2.0, 3.0], [0.0, 0.0, -4.5]])
    h, dh_dx, _ = table.predict(arm.nominal(), x, derivatives=True)
    np.testing.assert_allclose(h.ravel(), [3.0, -4.5])
    np.testing.assert_allclose(dh_dx[:, 0], [[0, 0, 1], [0, 0, 1]])
    assert math.isclose(float(np.linalg.norm(arm.sensors[1].normal)), 1.0)
