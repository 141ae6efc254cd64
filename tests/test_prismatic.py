"""Prismatic joints anywhere in a chain: a mobile manipulator's torso lift below its arm and a
telescoping upper arm, imported from a URDF the test writes.

A prismatic joint is Trans_axis(offset + reading) with the offset and the reading in the profile's
length unit. Its forward kinematics is checked against yourdfpy (an independent URDF reader), its
Jacobian column against central differences, and a simulated laser tracker's data must give back the
hidden offsets (mm for the prismatic joints, deg for the revolute ones).
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
import viser
import yourdfpy
from jacobian_check import check_jacobian, perturbed
from scene_nodes import node_pose
from sim_frames import measured_frames

from app.drivers import LimitError
from app.drivers.simulated import SimulatedDriver
from app.robots.capture import out_of_margin
from app.scene.review import Review
from app.scene.review_scene.scene import ReviewScene
from calib_core import InputError, Problem, SimulatedRobot, calibrate, load_profile, parse_dataset, to_csv
from calib_core.estimation.planning import within_margin
from calib_core.io.csv_format import readings_beyond_limits
from calib_core.model.kinematics import forward

# name, type, parent, child, xyz (m), rpy (rad), axis, limits (m or rad)
ROBOT = [
    ("torso_lift", "prismatic", "base_link", "torso", (0.1, 0, 0.4), (0, 0, 0), (0, 0, 1), (0.0, 0.35)),
    ("shoulder_pan", "revolute", "torso", "shoulder", (0.05, 0, 0.3), (0, 0, 0), (0, 0, 1), (-2.5, 2.5)),
    ("shoulder_lift", "revolute", "shoulder", "upper_arm", (0.1, 0, 0.05), (0, 0, 0), (0, 1, 0), (-1.2, 1.2)),
    ("telescope", "prismatic", "upper_arm", "upper_arm_ext", (0.3, 0, 0), (0, 0, 0), (1, 0, 0), (0.0, 0.2)),
    ("elbow", "revolute", "upper_arm_ext", "forearm", (0.05, 0, 0), (0, 0.3, 0), (0, 1, 0), (-2.0, 2.0)),
    ("wrist_roll", "revolute", "forearm", "wrist", (0.3, 0, 0), (0, 0, 0), (1, 0, 0), (-3.0, 3.0)),
    ("flange", "fixed", "wrist", "tool0", (0.08, 0, 0), (0, 0, 0), None, None),
]
JOINTS = [j[0] for j in ROBOT if j[1] != "fixed"]
PRISMATIC = {"torso_lift", "telescope"}
LINKS = [j[3] for j in ROBOT]

PROFILE = """\
profile: 1
name: lift-arm
units: {length: mm, angle: deg}
urdf: robot.urdf
frames:
  - {name: tracker, parent: base_link, registration: true}
targets:
  - {name: smr, frame: tool0, point: {x: 20, y: 40, z: 30}}
sensors:
  - {name: tracker, frame: tracker, model: point3d, noise: {model: isotropic, sigma: 0.01}}
data:
  sensor: tracker
  target: smr
  measurement: {columns: [x, y, z], unit: mm}
  prediction_columns: [pred_x, pred_y, pred_z]
simulation:
  noise: {point: 0.01}
"""


def robot_urdf() -> str:
    out = ['<?xml version="1.0"?>', '<robot name="lift_arm">', '  <link name="base_link"/>']
    out += [f'  <link name="{link}"/>' for link in LINKS]
    for name, kind, parent, child, xyz, rpy, axis, limits in ROBOT:
        out += [
            f'  <joint name="{name}" type="{kind}">',
            f'    <parent link="{parent}"/><child link="{child}"/>',
            f'    <origin xyz="{" ".join(map(str, xyz))}" rpy="{" ".join(map(str, rpy))}"/>',
        ]
        if axis is not None:
            out.append(f'    <axis xyz="{" ".join(map(str, axis))}"/>')
            out.append(f'    <limit lower="{limits[0]}" upper="{limits[1]}" effort="100" velocity="0.5"/>')
        out.append("  </joint>")
    return "\n".join([*out, "</robot>"]) + "\n"


@pytest.fixture
def profile_path(tmp_path: Path) -> Path:
    (tmp_path / "robot.urdf").write_text(robot_urdf(), encoding="utf-8")
    path = tmp_path / "lift-arm.yaml"
    path.write_text(PROFILE, encoding="utf-8")
    return path


def _readings(profile, rng: np.random.Generator, n: int) -> np.ndarray:
    lo, hi = profile.joint_limits()
    return rng.uniform(lo, hi, (n, len(lo)))


def test_prismatic_joints_import_in_length_units(profile_path: Path) -> None:
    profile = load_profile(profile_path)
    assert profile.joint_names == JOINTS
    kinds = {j.name: j.prismatic for j in profile.joints}
    assert {j for j, prismatic in kinds.items() if prismatic} == PRISMATIC
    lift = profile.joints[profile.joint("torso_lift")]
    assert (lift.lower, lift.upper, lift.velocity) == pytest.approx((0.0, 350.0, 500.0))  # mm, mm/s
    pan = profile.joints[profile.joint("shoulder_pan")]
    assert (pan.lower, pan.upper) == pytest.approx((-2.5, 2.5))  # rad
    assert profile.unit(profile.param("telescope")) == "mm" and profile.unit(profile.param("elbow")) == "deg"
    assert profile.notes == ()


def test_forward_kinematics_match_yourdfpy(profile_path: Path) -> None:
    """Every link where yourdfpy puts it: the prismatic readings in mm here, in m there."""
    profile = load_profile(profile_path)
    urdf = yourdfpy.URDF.load(str(profile_path.parent / "robot.urdf"), build_scene_graph=True, load_meshes=False)
    q = _readings(profile, np.random.default_rng(1), 20)
    poses = forward(profile, profile.nominal(), q)
    metres = np.array([1e-3 if j in PRISMATIC else 1.0 for j in JOINTS])
    for n in range(len(q)):
        urdf.update_cfg(dict(zip(JOINTS, q[n] * metres, strict=True)))
        for link in LINKS:
            T = urdf.get_transform(frame_to=link, frame_from="base_link")
            f = profile.frame(link)
            np.testing.assert_allclose(poses.R[f][n], T[:3, :3], rtol=0, atol=1e-12)
            np.testing.assert_allclose(poses.t[f][n] / 1000.0, T[:3, 3], rtol=0, atol=1e-12)


def test_jacobian_of_every_parameter_against_finite_differences(profile_path: Path) -> None:
    """Every parameter free, the prismatic offsets among them: each exact column against central
    differences, with every parameter moved from nominal (zero-value paths exercised)."""
    profile = load_profile(profile_path)
    rng = np.random.default_rng(2)
    sim = SimulatedRobot.from_profile(profile, seed=3, truth=perturbed(profile, rng))
    data = sim.simulate(15).data
    free = list(range(len(profile.parameters)))
    problem = Problem(profile, data, free, perturbed(profile, rng), noise_model=False)
    nonzero = check_jacobian(problem, profile.parameter_names)
    assert nonzero == len(free)  # every parameter moves the tracker's reading of the SMR
    lift = profile.param("torso_lift")
    column = problem.residuals_jacobian(problem.x0)[1][:, free.index(lift)]
    assert np.linalg.norm(column) > 0


def test_a_simulated_tracker_recovers_the_offsets(profile_path: Path) -> None:
    """Hidden offsets (1 mm, 1 deg): the offsets mode finds each one the tracker can see, to well
    under its uncertainty; those it cannot (the lift and the pan move the whole arm as the
    tracker's pose does, the last roll turns the SMR about its axis) are held and named."""
    profile = load_profile(profile_path)
    truth = profile.nominal()
    hidden = {"shoulder_lift": 1.1, "telescope": -0.8, "elbow": -0.9, "wrist_roll": 0.0}  # deg or mm
    for name, value in hidden.items():
        truth[profile.param(name)] = profile.from_display(profile.param(name), value)
    tracker = {"tracker.x": 2000.0, "tracker.y": -300.0, "tracker.z": 100.0, "tracker.yaw": 150.0}
    for name, value in tracker.items():
        truth[profile.param(name)] = profile.from_display(profile.param(name), value)
    truth[list(profile.targets[0].point_params)] = [20.5, 39.6, 30.4]
    sim = SimulatedRobot.from_profile(profile, seed=5, truth=truth).simulate(80)
    # Through the CSV format: the prismatic readings are written and read in mm.
    data = parse_dataset(profile, to_csv(profile, sim.data))
    np.testing.assert_allclose(data.joints, sim.data.joints, rtol=0, atol=1e-6)  # written to 6 decimals

    cal = calibrate(profile, data, "offsets")
    est = {p.name: p for p in cal.parameters}
    held = {p.name for p in cal.parameters if p.note and "held" in p.note}
    assert held == {"torso_lift", "shoulder_pan", "wrist_roll"}
    for name in held:
        assert est[name].value == 0.0
    for name, value in hidden.items():
        if name in held:
            continue
        p = est[name]
        assert p.unit == ("mm" if name in PRISMATIC else "deg")
        assert p.estimated and p.std is not None
        assert abs(p.value - value) < 4 * p.std, (name, p.value, value, p.std)
        assert abs(p.value - value) < 0.01, (name, p.value, value)  # deg or mm
    assert cal.figures["after"].rms < 1.15 * 0.01 * math.sqrt(3)


OPS_PROFILE = """\
profile: 1
name: slide
units: {length: mm, angle: deg}
joints:
  slide: {type: prismatic, lower: 0, upper: 500, velocity: 100, resolution: 0.01}
  turn: {lower: -90, upper: 90}
frames:
  - {name: carriage, parent: base, joint: slide, ops: [{tx: 0, joint: true, param: slide_offset}]}
  - {name: arm, parent: carriage, joint: turn, urdf: {xyz: [0, 0, 100], axis: [0, 0, 1]}}
  - {name: station, parent: base, urdf: {xyz: [0, 0, 0]}}
targets:
  - {name: tip, frame: arm, points: [[200, 0, 0]]}
sensors:
  - {name: s, frame: station, model: point3d}
data:
  sensor: s
  target: tip
  joints: {slide: slide_m, turn: turn}
  joint_length_unit: m
  measurement: {columns: [x, y, z], unit: mm}
  prediction_columns: [px, py, pz]
modes:
  all: {free: [slide_offset, arm.offset]}
"""


def _yaml_profile(tmp_path: Path, text: str = OPS_PROFILE) -> Path:
    path = tmp_path / "slide.yaml"
    path.write_text(text, encoding="utf-8")
    return path


def test_a_prismatic_joint_in_a_yaml_profile(tmp_path: Path) -> None:
    """`type: prismatic`: limits in mm, a translation op, CSV readings in data.joint_length_unit."""
    profile = load_profile(_yaml_profile(tmp_path))
    slide = profile.joints[profile.joint("slide")]
    assert slide.prismatic and (slide.lower, slide.upper, slide.resolution) == (0.0, 500.0, 0.01)
    assert profile.joints[profile.joint("turn")].upper == pytest.approx(math.pi / 2)
    data = parse_dataset(profile, "frame,x,y,z,slide_m,turn\n1,0,0,0,0.25,90\n")
    np.testing.assert_allclose(data.joints[0], [250.0, math.pi / 2])  # mm, rad
    tip = forward(profile, profile.nominal(), data.joints).t[profile.frame("arm")][0]
    np.testing.assert_allclose(tip, [250.0, 0.0, 100.0], atol=1e-12)
    assert "slide_m" in to_csv(profile, data) and ",0.25," in to_csv(profile, data)


@pytest.mark.parametrize(("length_unit", "reading"), [("m", "0.350184"), ("mm", "350.184")])
def test_a_slide_reading_a_hair_past_its_limit_is_a_note_never_an_angle(
    tmp_path: Path, length_unit: str, reading: str
) -> None:
    """TIAGo's torso read 0.350184 m against its 0.35 m limit, and the whole file was refused as "joint readings
    look like degrees" (the length read as an angle). A length is never an angle; past its limit it is a note."""
    text = OPS_PROFILE.replace("upper: 500,", "upper: 350,").replace(
        "joint_length_unit: m", f"joint_length_unit: {length_unit}\n  joint_unit: rad"
    )
    profile = load_profile(_yaml_profile(tmp_path, text))
    rows = [f"{k},0,0,0,{float(reading) * k / 4:.6f},{0.3 * k - 0.5:.3f}" for k in range(1, 4)]
    csv = "frame,x,y,z,slide_m,turn\n" + "\n".join([*rows, f"4,0,0,0,{reading},1.2"]) + "\n"
    data = parse_dataset(profile, csv, "tiago.csv")
    assert data.joints[-1, profile.joint("slide")] == pytest.approx(350.184)
    (note,) = readings_beyond_limits(profile, data)
    assert note == "tiago.csv, line 5, column 'slide_m': slide reads 350.18 mm, beyond its upper limit 350.00 mm"


BAD_PRISMATIC = {
    "a rotation driven by a prismatic joint": (
        "ops: [{tx: 0, joint: true, param: slide_offset}]",
        "ops: [{rx: 0, joint: true, param: slide_offset}]",
        "frames[0]: joint 'slide' is prismatic: the op it drives must be a translation (tx, ty, tz)",
    ),
    "a translation driven by a revolute joint": (
        "{type: prismatic, lower: 0, upper: 500,",
        "{lower: 0, upper: 500,",
        "frames[0]: joint 'slide' is revolute: the op it drives must be a rotation (rx, ry, rz)",
    ),
    "a DH row": (
        "ops: [{tx: 0, joint: true, param: slide_offset}]",
        "mdh: {a: 0, alpha: 0, d: 0, theta: 0}",
        "frames[0]: prismatic joint 'slide' needs a urdf or ops frame, not mdh",
    ),
    "an unknown type": ("{type: prismatic,", "{type: spherical,", "joints.slide.type: unknown joint type 'spherical'"),
    "an unknown length unit": ("joint_length_unit: m", "joint_length_unit: inch", "data.joint_length_unit: unknown"),
}


@pytest.mark.parametrize("case", list(BAD_PRISMATIC))
def test_bad_prismatic_profiles_name_the_field(tmp_path: Path, case: str) -> None:
    old, new, words = BAD_PRISMATIC[case]
    assert old in OPS_PROFILE
    text = OPS_PROFILE.replace(old, new, 1).replace(
        "modes:\n  all: {free: [slide_offset, arm.offset]}\n", "modes: {}\n"
    )
    with pytest.raises(InputError) as err:
        load_profile(_yaml_profile(tmp_path, text))
    assert err.value.file == str(tmp_path / "slide.yaml")
    assert words in str(err.value), str(err.value)


def test_the_review_scene_draws_a_prismatic_joint_in_metres(profile_path: Path) -> None:
    """The display model (to_urdf) has the prismatic joints, and the scene drives them with the readings in m:
    every link of the copy where the profile's kinematics put it."""
    profile = load_profile(profile_path)
    sim = SimulatedRobot.from_profile(profile, seed=4).simulate(3)
    review = Review.build(profile, measured_frames(sim.data), sim.data, profile.nominal(), sim.true_params)
    server = viser.ViserServer(host="127.0.0.1", port=0, verbose=False)
    try:
        scene = ReviewScene(server)
        scene.load(review)
        index = int(review.indices[1])
        scene.select(index)
        copy = scene.copies["new"]
        q = review.frame_geometry(index).joints_rad
        assert copy.urdf.joint_map["telescope"].type == "prismatic"
        poses = forward(profile, review.sides["new"].p, q[None])
        for link in LINKS:  # as the browser gets them: the link frames' poses under the copy's base
            T = node_pose(server, copy.robot.links[link], "/review/new/base")
            f = profile.frame(link)
            np.testing.assert_allclose(T[:3, :3], poses.R[f][0], atol=1e-6)
            np.testing.assert_allclose(T[:3, 3], poses.t[f][0] / 1000.0, atol=1e-6)
    finally:
        server.stop()


def test_a_prismatic_joint_keeps_its_own_safety_margin_in_length(profile_path: Path) -> None:
    """The driver keeps a slide 1 mm (margin_m) clear of its limits, says so in the profile's length unit, and a
    replay's configuration inside that margin is moved onto its edge; the planner keeps the same margin. (One
    margin in degrees was applied to every joint: 0.017 mm for this mm profile's slides.)"""
    profile = load_profile(profile_path)
    driver = SimulatedDriver(profile, time_scale=50.0)
    try:
        telescope = profile.joint("telescope")
        q = np.zeros(len(profile.joints))
        q[profile.joint("torso_lift")] = 100.0  # mm, inside its range
        q[telescope] = 199.5  # 0.5 mm below its upper limit of 200 mm
        with pytest.raises(
            LimitError, match=r"^telescope 199\.5 mm is within the 1 mm safety margin of its upper limit 200 mm$"
        ):
            driver.check(q)
        q[telescope] = 200.5
        with pytest.raises(LimitError, match=r"^telescope 200\.5 mm is beyond its upper limit 200 mm \(margin 1 mm\)$"):
            driver.check(q)
        q[telescope] = 199.5
        moved, note = out_of_margin(driver, q)
        assert moved[telescope] == pytest.approx(199.0) and np.delete(moved, telescope) == pytest.approx(
            np.delete(q, telescope)
        )
        assert note == "moved out of the 1.0 deg / 1 mm safety margin: telescope 0.50 mm"
        q[telescope] = 199.0
        driver.check(q)  # on the margin's edge: allowed
    finally:
        driver.close()
    lower, upper = profile.limits_less_margin(1.0, 0.001)
    assert lower[telescope] == pytest.approx(1.0) and upper[telescope] == pytest.approx(199.0)
    assert upper[profile.joint("elbow")] == pytest.approx(2.0 - np.radians(1.0))
    q[telescope] = 199.5
    assert not within_margin(profile, q[None])[0]
    q[telescope] = 198.5
    assert within_margin(profile, q[None])[0]
