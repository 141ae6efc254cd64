"""A robot from its URDF, calibrated without writing code: a profile YAML that names the URDF, the
`calib` command, and the exports a driver takes.

The truth is a URDF too: the test arm with hidden origin errors, read by yourdfpy (an independent
URDF reader) at the physical joint angles (reading + hidden offset), seen by a laser tracker at a
hidden pose with 0.02 mm noise. Nothing of calib_core's kinematics makes the data.
"""

from __future__ import annotations

import csv
import math
from pathlib import Path

import numpy as np
import pytest
import yaml
import yourdfpy
from lxml import etree

from app.cli import main
from calib_core import Calibration, InputError, load_profile
from calib_core.estimation.calibration import parameter_estimate
from calib_core.io.export import calibrated_urdf, offsets_yaml
from calib_core.model.kinematics import forward
from calib_core.model.urdf_import import profile_frames, read_urdf
from calib_core.units import length_factor

HALF_PI = math.pi / 2
# name, type, parent, child, xyz (m), rpy (rad), axis: a UR5-like arm, fixed flange and TCP, a prismatic
# finger, and a planar tray (which cannot be calibrated: left out)
ARM = [
    ("shoulder_pan", "revolute", "base_link", "shoulder_link", (0, 0, 0.089), (0, 0, 0), (0, 0, 1)),
    ("shoulder_lift", "revolute", "shoulder_link", "upper_arm_link", (0, 0.136, 0), (0, HALF_PI, 0), (0, 1, 0)),
    ("elbow", "revolute", "upper_arm_link", "forearm_link", (0, -0.12, 0.425), (0, 0, 0), (0, 1, 0)),
    ("wrist_1", "revolute", "forearm_link", "wrist_1_link", (0, 0, 0.392), (0, HALF_PI, 0), (0, 1, 0)),
    ("wrist_2", "revolute", "wrist_1_link", "wrist_2_link", (0, 0.093, 0), (0, 0, 0), (0, 0, 1)),
    ("wrist_3", "continuous", "wrist_2_link", "wrist_3_link", (0, 0, 0.095), (0, 0, 0), (0, 1, 0)),
    ("flange", "fixed", "wrist_3_link", "tool0", (0, 0.082, 0), (-HALF_PI, 0, 0), None),
    ("tcp_joint", "fixed", "tool0", "tcp", (0, 0, 0), (0, 0, 0), None),  # written without <origin>
    ("finger_joint", "prismatic", "tool0", "finger", (0, 0, 0.02), (0, 0, 0), (1, 0, 0)),
    ("tray_joint", "planar", "base_link", "tray", (0.3, 0, 0), (0, 0, 0), (0, 0, 1)),
]
JOINTS = [j[0] for j in ARM if j[1] in ("revolute", "continuous")]  # the chain to the tracker's SMR
FINGER_M = (0.0, 0.04)  # the finger's limits
LINKS = ["base_link"] + [j[3] for j in ARM]
SIGMA_MM = 0.02  # the tracker's noise per axis
FLOOR_MM = SIGMA_MM * math.sqrt(3)  # the RMS distance that noise alone gives
TRACKER = {"x": 2500.0, "y": 300.0, "z": -200.0, "yaw": 170.0, "pitch": 2.0, "roll": -1.0}  # mm, deg: hidden
SMR = np.array([30.3, 9.6, 40.4])  # mm in tool0, hidden (nominal 30, 10, 40)

PROFILE = """\
profile: 1
name: test-arm
units: {length: mm, angle: deg}
urdf: arm.urdf
frames:
  - {name: tracker, parent: base_link, registration: true}
targets:
  - {name: smr, frame: tool0, point: {x: 30, y: 10, z: 40}}
sensors:
  - {name: tracker, frame: tracker, model: point3d, noise: {model: isotropic, sigma: 0.02}}
data:
  sensor: tracker
  target: smr
  measurement: {columns: [x, y, z], unit: mm}
  prediction_columns: [pred_x, pred_y, pred_z]
"""


def arm_urdf(errors: dict[str, tuple[np.ndarray, np.ndarray]] | None = None) -> str:
    """The test arm's URDF, with what a real one has besides kinematics (missing meshes, inertials,
    materials, a transmission naming a joint, a gazebo tag, comments); `errors`: joint -> (dxyz m,
    drpy rad) added to its origin."""
    errors = errors or {}
    out = [
        '<?xml version="1.0"?>',
        "<!-- the test arm -->",
        '<robot name="arm">',
        '  <material name="blue"><color rgba="0 0 1 1"/></material>',
    ]
    for link in LINKS:
        out += [
            f'  <link name="{link}">',
            '    <inertial><origin xyz="0 0 0.05"/><mass value="2"/>'
            '<inertia ixx="0.01" ixy="0" ixz="0" iyy="0.01" iyz="0" izz="0.01"/></inertial>',
            f'    <visual><geometry><mesh filename="package://arm_description/meshes/{link}.dae"/></geometry>'
            '<material name="blue"/></visual>',
            '    <collision><geometry><cylinder radius="0.05" length="0.1"/></geometry></collision>',
            "  </link>",
        ]
    for name, kind, parent, child, xyz, rpy, axis in ARM:
        dxyz, drpy = errors.get(name, (np.zeros(3), np.zeros(3)))
        xyz_s = " ".join(repr(float(v)) for v in np.add(xyz, dxyz))
        rpy_s = " ".join(repr(float(v)) for v in np.add(rpy, drpy))
        out += [
            f'  <joint name="{name}" type="{kind}">',
            f'    <parent link="{parent}"/>',
            f'    <child link="{child}"/>',
        ]
        if np.any(np.add(xyz, dxyz)) or np.any(np.add(rpy, drpy)):
            out.append(f'    <origin xyz="{xyz_s}" rpy="{rpy_s}"/>')
        if axis is not None:
            out.append(f'    <axis xyz="{" ".join(str(a) for a in axis)}"/>')
        if kind == "revolute":
            out.append('    <limit lower="-3.1" upper="3.1" effort="150" velocity="3.15"/>')
        if kind == "prismatic":
            out.append('    <limit lower="0" upper="0.04" effort="10" velocity="0.1"/>')
        out.append("  </joint>")
    out += [
        '  <transmission name="elbow_trans"><type>transmission_interface/SimpleTransmission</type>',
        '    <joint name="elbow"><hardwareInterface>PositionJointInterface</hardwareInterface></joint>',
        '    <actuator name="elbow_motor"><mechanicalReduction>1</mechanicalReduction></actuator></transmission>',
        '  <gazebo reference="tool0"><material>Gazebo/Orange</material></gazebo>',
        "</robot>",
    ]
    return "\n".join(out) + "\n"


def _setup(tmp_path: Path, profile_text: str = PROFILE, urdf_text: str | None = None) -> Path:
    (tmp_path / "arm.urdf").write_text(arm_urdf() if urdf_text is None else urdf_text, encoding="utf-8")
    path = tmp_path / "arm.yaml"
    path.write_text(profile_text, encoding="utf-8")
    return path


def _rot(yaw: float, pitch: float, roll: float) -> np.ndarray:
    cz, sz, cy, sy, cx, sx = (f(a) for a in (yaw, pitch, roll) for f in (math.cos, math.sin))
    Rz = np.array([[cz, -sz, 0], [sz, cz, 0], [0, 0, 1]])
    Ry = np.array([[cy, 0, sy], [0, 1, 0], [-sy, 0, cy]])
    Rx = np.array([[1, 0, 0], [0, cx, -sx], [0, sx, cx]])
    return Rz @ Ry @ Rx


def _tracker_pose(tracker: dict[str, float]) -> tuple[np.ndarray, np.ndarray]:
    """R, t (mm) of the tracker in the base frame."""
    R = _rot(*(math.radians(tracker[k]) for k in ("yaw", "pitch", "roll")))
    return R, np.array([tracker[k] for k in "xyz"])


def _tool_points(urdf: yourdfpy.URDF, angles: np.ndarray, smr_mm: np.ndarray) -> np.ndarray:
    """The SMR in the base frame (mm) at physical joint angles (N, 6) rad, by yourdfpy."""
    out = []
    for a in angles:
        urdf.update_cfg(dict(zip(JOINTS, a, strict=True)))
        T = urdf.get_transform(frame_to="tool0", frame_from="base_link")
        out.append(T[:3, :3] @ (smr_mm / 1000.0) + T[:3, 3])
    return np.array(out) * 1000.0


def _load(path: Path) -> yourdfpy.URDF:
    return yourdfpy.URDF.load(str(path), build_scene_graph=True, load_meshes=False)


class Truth:
    """The hidden robot: origin errors, joint offsets, the tracker's pose and the SMR."""

    def __init__(self, tmp_path: Path, seed: int, origin_errors: bool) -> None:
        rng = np.random.default_rng(seed)
        self.offsets = np.radians(rng.normal(0.0, 0.5, len(JOINTS)))
        errors = {}
        if origin_errors:
            errors = {j: (rng.normal(0, 0.5e-3, 3), np.radians(rng.normal(0, 0.1, 3))) for j in JOINTS}
        path = tmp_path / f"truth-{seed}.urdf"
        path.write_text(arm_urdf(errors), encoding="utf-8")
        self.urdf = _load(path)
        self.R, self.t = _tracker_pose(TRACKER)

    def measure(self, readings: np.ndarray) -> np.ndarray:
        """Noise-free tracker measurements (mm) of the SMR at the given readings (rad)."""
        base = _tool_points(self.urdf, readings + self.offsets, SMR)
        return (base - self.t) @ self.R


def _readings(rng: np.random.Generator, n: int) -> np.ndarray:
    return rng.uniform(-2.5, 2.5, (n, len(JOINTS)))


def _write_csv(path: Path, readings: np.ndarray, measured: np.ndarray) -> None:
    with path.open("w", newline="", encoding="utf-8") as f:
        w = csv.writer(f)
        w.writerow(["frame", "x", "y", "z", *JOINTS])
        for n, (q, m) in enumerate(zip(readings, measured, strict=True)):
            w.writerow([n + 1, *(repr(float(v)) for v in m), *(repr(math.degrees(v)) for v in q)])


def _dataset(tmp_path: Path, truth: Truth, n: int, seed: int) -> Path:
    rng = np.random.default_rng(seed)
    q = _readings(rng, n)
    path = tmp_path / f"data-{seed}.csv"
    _write_csv(path, q, truth.measure(q) + rng.normal(0.0, SIGMA_MM, (n, 3)))
    return path


def _solve(profile: Path, data: Path, mode: str, out: Path, capsys: pytest.CaptureFixture) -> Calibration:
    code = main(["solve", "--robot", str(profile), "--mode", mode, "--data", str(data), "--out", str(out)])
    captured = capsys.readouterr()
    assert code == 0, captured.err
    assert "Traceback" not in captured.err
    return Calibration.load(out)


# --- the profile from the URDF ------------------------------------------------------------------


@pytest.mark.parametrize("units", [("mm", "deg"), ("m", "rad"), ("cm", "deg")])
def test_profile_kinematics_match_yourdfpy(tmp_path: Path, units: tuple[str, str]) -> None:
    """Every link of the URDF where yourdfpy puts it, at random readings, in the profile's units."""
    text = PROFILE.replace("units: {length: mm, angle: deg}", f"units: {{length: {units[0]}, angle: {units[1]}}}")
    text = text.replace("{x: 30, y: 10, z: 40}", "{x: 0, y: 0, z: 0}")
    profile = load_profile(_setup(tmp_path, text))
    assert profile.base == "base_link"
    assert profile.joint_names == [*JOINTS, "finger_joint"]  # the planar tray is left out
    assert "tray" not in [f.name for f in profile.frames]
    urdf = _load(tmp_path / "arm.urdf")
    rng = np.random.default_rng(3)
    scale = length_factor(profile.length_unit, "m")
    finger_m = rng.uniform(*FINGER_M, (20, 1))
    q = np.hstack([rng.uniform(-3.1, 3.1, (20, len(JOINTS))), finger_m / scale])  # the finger in the length unit
    poses = forward(profile, profile.nominal(), q)
    for n in range(len(q)):
        urdf.update_cfg(dict(zip([*JOINTS, "finger_joint"], [*q[n, :-1], finger_m[n, 0]], strict=True)))
        for link in LINKS[1:-1]:
            T = urdf.get_transform(frame_to=link, frame_from="base_link")
            f = profile.frame(link)
            np.testing.assert_allclose(poses.R[f][n], T[:3, :3], rtol=0, atol=1e-9)
            np.testing.assert_allclose(poses.t[f][n] * scale, T[:3, 3], rtol=0, atol=1e-9)


def test_parameters_limits_and_default_modes(tmp_path: Path) -> None:
    profile = load_profile(_setup(tmp_path))
    names = profile.parameter_names
    for j in JOINTS:
        assert {j, f"{j}.x", f"{j}.y", f"{j}.z", f"{j}.roll", f"{j}.pitch", f"{j}.yaw"} <= set(names)
    assert "flange.x" in names and "flange" not in names  # a fixed joint: origin, no offset
    assert profile.label(profile.param("elbow.z")) == "z(elbow)"
    assert profile.nominal()[profile.param("elbow.z")] == pytest.approx(425.0)  # m -> mm
    assert math.degrees(profile.nominal()[profile.param("wrist_1.pitch")]) == pytest.approx(90.0)
    limits = {j.name: j for j in profile.joints}
    assert limits["elbow"].lower == pytest.approx(-3.1) and limits["elbow"].velocity == pytest.approx(3.15)
    assert limits["wrist_3"].upper == pytest.approx(2 * math.pi)  # continuous: a turn either way
    assert profile.data.joint_columns == {j: j for j in JOINTS}  # the joints on the chain, by name

    offsets, origins = profile.modes["offsets"], profile.modes["origins"]
    setup = [f"tracker.{k}" for k in ("x", "y", "z", "yaw", "pitch", "roll")] + ["smr.x", "smr.y", "smr.z"]
    assert [names[i] for i in offsets.free] == setup + JOINTS
    corrections = [f"{j}.{k}" for j in JOINTS for k in ("x", "y", "z", "yaw", "pitch", "roll")]
    assert [names[i] for i in origins.free] == setup + JOINTS + corrections
    assert not offsets.priors
    assert {names[i] for i in origins.priors} == set(corrections)
    assert origins.priors[profile.param("elbow.x")] == pytest.approx(5.0)  # mm
    assert origins.priors[profile.param("elbow.yaw")] == pytest.approx(math.radians(1.0))


def test_own_modes_joints_and_units_are_kept(tmp_path: Path) -> None:
    text = PROFILE.replace("units: {length: mm, angle: deg}", "units: {length: m, angle: rad}")
    text += "joints:\n  elbow: {lower: -1.0, resolution: 0.001}\nmodes:\n  mine: {free: [elbow, 'wrist_?']}\n"
    profile = load_profile(_setup(tmp_path, text))
    assert list(profile.modes) == ["mine"]
    elbow = profile.joints[profile.joint("elbow")]
    assert (elbow.lower, elbow.upper, elbow.resolution) == pytest.approx((-1.0, 3.1, 0.001))
    assert profile.nominal()[profile.param("elbow.z")] == pytest.approx(0.425)


def test_profile_frames_give_the_yaml_schema(tmp_path: Path) -> None:
    _setup(tmp_path)
    robot = read_urdf(tmp_path / "arm.urdf")
    assert robot.root == "base_link" and set(robot.left_out) == {"tray"}
    frames, joints = profile_frames(robot, "mm", "deg")
    assert frames[1] == {
        "name": "upper_arm_link",
        "parent": "shoulder_link",
        "joint": "shoulder_lift",
        "urdf": {"xyz": [0.0, 136.0, 0.0], "rpy": [0.0, 90.0, 0.0], "axis": [0.0, 1.0, 0.0]},
        "names": {
            "x": "shoulder_lift.x",
            "y": "shoulder_lift.y",
            "z": "shoulder_lift.z",
            "roll": "shoulder_lift.roll",
            "pitch": "shoulder_lift.pitch",
            "yaw": "shoulder_lift.yaw",
            "offset": "shoulder_lift",
        },
    }
    assert joints["shoulder_lift"] == pytest.approx({"lower": -177.6169, "upper": 177.6169, "velocity": 180.4817}, 1e-5)
    finger = next(f for f in frames if f["name"] == "finger")
    assert finger["urdf"]["axis"] == [1.0, 0.0, 0.0] and finger["names"]["offset"] == "finger_joint"
    assert joints["finger_joint"] == {"type": "prismatic", "lower": 0.0, "upper": 40.0, "velocity": 100.0}  # mm
    yaml.safe_dump({"frames": frames, "joints": joints})  # plain data, writable as a profile


# --- calibrating from the command line ----------------------------------------------------------


def test_offsets_mode_recovers_the_hidden_offsets(tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    """No origin errors: the offsets mode must find the hidden offsets, tracker pose and SMR.

    What no tracker can see is held and named: the first axis turns with the tracker's pose (yaw),
    the last one with the SMR's position about it; the truth they must match is then the
    equivalent robot with those two offsets zero (the tracker turned by -offset about the first
    axis, the SMR by +offset about the last)."""
    profile_path = _setup(tmp_path)
    truth = Truth(tmp_path, seed=1, origin_errors=False)
    data = _dataset(tmp_path, truth, 80, seed=11)
    cal = _solve(profile_path, data, "offsets", tmp_path / "offsets.json", capsys)
    est = {p.name: p for p in cal.parameters}
    held = {p.name for p in cal.parameters if p.note and "held" in p.note}
    assert held == {"shoulder_pan", "wrist_3"}

    pan, last = truth.offsets[0], truth.offsets[-1]
    t = _tracker_pose(TRACKER)[1]
    expected = {name: math.degrees(v) for name, v in zip(JOINTS, truth.offsets, strict=True)}
    expected |= {"shoulder_pan": 0.0, "wrist_3": 0.0}
    Rz = _rot(-pan, 0.0, 0.0)
    expected |= dict(zip(("tracker.x", "tracker.y", "tracker.z"), Rz @ t, strict=True))
    expected |= {"tracker.yaw": TRACKER["yaw"] - math.degrees(pan), "tracker.pitch": 2.0, "tracker.roll": -1.0}
    expected |= dict(zip(("smr.x", "smr.y", "smr.z"), _rot(last, 0.0, 0.0) @ SMR, strict=True))
    for name, value in expected.items():
        p = est[name]
        if name in held:
            assert p.value == 0.0
            continue
        assert p.estimated and p.std is not None
        assert abs(p.value - value) < 4 * p.std + 1e-9, (name, p.value, value, p.std)
        assert p.std < (0.003 if p.unit == "deg" else 0.05), (name, p.std)
    assert cal.figures["after"].rms < 1.15 * FLOOR_MM
    assert cal.figures["before"].rms > 20 * FLOOR_MM


def test_origins_mode_reaches_the_noise_and_the_urdf_export_the_truth(
    tmp_path: Path, capsys: pytest.CaptureFixture
) -> None:
    """Hidden origin errors (0.5 mm, 0.1 deg per joint): offsets alone cannot reach the noise, the
    origins mode does on held-out data, and the exported URDF predicts the true robot."""
    profile_path = _setup(tmp_path)
    truth = Truth(tmp_path, seed=2, origin_errors=True)
    train = _dataset(tmp_path, truth, 120, seed=21)
    test = _dataset(tmp_path, truth, 60, seed=22)
    profile = load_profile(profile_path)

    def heldout_rms(cal: Calibration) -> float:
        code = main(
            [
                "predict",
                "--robot",
                str(profile_path),
                "--calibration",
                str(cal_path),
                "--data",
                str(test),
                "--out",
                str(pred),
            ]
        )
        assert code == 0
        with pred.open(encoding="utf-8") as f:
            rows = list(csv.DictReader(f))
        e = [[float(r[a]) - float(r[f"pred_{a}"]) for a in "xyz"] for r in rows]
        return float(np.sqrt(np.mean(np.sum(np.square(e), axis=1))))

    pred = tmp_path / "pred.csv"
    cal_path = tmp_path / "offsets.json"
    offsets_only = heldout_rms(_solve(profile_path, train, "offsets", cal_path, capsys))
    cal_path = tmp_path / "origins.json"
    cal = _solve(profile_path, train, "origins", cal_path, capsys)
    origins = heldout_rms(cal)
    assert offsets_only > 5 * FLOOR_MM, offsets_only
    assert origins < 1.2 * FLOOR_MM, origins

    # The driver's file: the calibrated URDF at the raw readings, the SMR and the tracker as calibrated.
    urdf_path = tmp_path / "calibrated.urdf"
    cmd = ["export", "--robot", str(profile_path), "--calibration", str(cal_path), "--format", "urdf"]
    assert main([*cmd, "--out", str(urdf_path)]) == 0
    capsys.readouterr()
    p = cal.params(profile)
    at_rest = forward(profile, p, np.zeros((1, len(profile.joints))))
    R, t = at_rest.R[profile.frame("tracker")][0], at_rest.t[profile.frame("tracker")][0]
    smr = p[[profile.param(f"smr.{k}") for k in "xyz"]]
    q = _readings(np.random.default_rng(23), 30)
    predicted = (_tool_points(_load(urdf_path), q, smr) - t) @ R
    error = np.linalg.norm(predicted - truth.measure(q), axis=1)
    assert error.max() < 3 * FLOOR_MM, error.max()


def test_the_urdf_export_is_the_users_file_with_corrected_origins(tmp_path: Path, capsys) -> None:
    profile_path = _setup(tmp_path)
    profile = load_profile(profile_path)
    rng = np.random.default_rng(5)
    p = profile.nominal() + rng.normal(0.0, 0.01, len(profile.parameters))  # mm, rad: every parameter moved
    cal = _calibration(profile, p)
    text = calibrated_urdf(profile, cal)
    (tmp_path / "out.urdf").write_text(text, encoding="utf-8")

    # Forward kinematics of the calibrated model at the raw readings, to 1e-9 m, by yourdfpy; the
    # finger's offset (mm) is folded into its origin along its axis.
    urdf = _load(tmp_path / "out.urdf")
    q = _arm_readings(rng, 15)
    poses = forward(profile, p, q)
    for n in range(len(q)):
        urdf.update_cfg(_cfg(q[n]))
        for link in LINKS[1:-1]:
            T = urdf.get_transform(frame_to=link, frame_from="base_link")
            np.testing.assert_allclose(poses.R[profile.frame(link)][n], T[:3, :3], rtol=0, atol=1e-9)
            np.testing.assert_allclose(poses.t[profile.frame(link)][n] / 1000, T[:3, 3], rtol=0, atol=1e-9)
            np.testing.assert_allclose(poses.t[profile.frame(link)][n] / 1000, T[:3, 3], rtol=0, atol=1e-9)

    # The tracker's registration frame (not in the user's file) is added as a link on a fixed joint at its pose.
    tracker = profile.frame("tracker")
    T = urdf.get_transform(frame_to="tracker", frame_from="base_link")
    np.testing.assert_allclose(poses.R[tracker][0], T[:3, :3], rtol=0, atol=1e-9)
    np.testing.assert_allclose(poses.t[tracker][0] / 1000, T[:3, 3], rtol=0, atol=1e-9)

    # Everything else but the imported joints' origins is the user's file (comments apart).
    parser = etree.XMLParser(remove_comments=True, remove_blank_text=True)
    ours = etree.fromstring(text.encode(), parser)
    theirs = etree.fromstring(arm_urdf().encode(), parser)
    added = [ours.find("link[@name='tracker']"), ours.find("joint[@name='tracker_calibrated']")]
    for element in added:
        ours.remove(element)
    changed = []
    for a, b in zip(ours.findall("joint"), theirs.findall("joint"), strict=True):
        origins = [j.find("origin") for j in (a, b)]
        attrs = [None if o is None else dict(o.attrib) for o in origins]
        if attrs[0] != attrs[1]:
            changed.append(a.get("name"))
        for j, o in zip((a, b), origins, strict=True):
            if o is not None:
                j.remove(o)
    assert changed == [*JOINTS, "flange", "tcp_joint", "finger_joint"]  # the planar tray is untouched
    assert etree.tostring(ours) == etree.tostring(theirs)
    assert 'mesh filename="package://arm_description/meshes/tool0.dae"' in text
    assert "<!-- the test arm -->" in text
    first = etree.fromstring(text.encode())[0]
    assert isinstance(first, etree._Comment) and "raw encoder readings" in first.text
    assert "Added links" in first.text and ": tracker." in first.text  # the registration, as a link
    assert "tracker.x" not in first.text and "smr.x" in first.text  # the target's point: not in the file
    assert 'calibrated: origin was xyz="0.0 -0.12 0.425" rpy="0.0 0.0 0.0"; changes: elbow.x ' in text


def test_a_changed_urdf_is_not_exported_as_the_profiles(tmp_path: Path) -> None:
    profile = load_profile(_setup(tmp_path))
    cal = _calibration(profile, profile.nominal())
    (tmp_path / "arm.urdf").write_text(arm_urdf({"elbow": (np.array([0.0, 0.0, 0.001]), np.zeros(3))}))
    with pytest.raises(InputError, match="joint 'elbow' is not what the profile 'test-arm' was loaded with"):
        calibrated_urdf(profile, cal)


def test_offsets_yaml_with_the_original_urdf_is_the_calibrated_model(tmp_path: Path) -> None:
    """An offsets-only calibration: the user's unchanged URDF at reading + offset (yourdfpy) puts
    every link where the calibrated model puts it at the reading; the set-up is listed apart."""
    profile_path = _setup(tmp_path)
    profile = load_profile(profile_path)
    rng = np.random.default_rng(6)
    p = profile.nominal()
    for i in profile.modes["offsets"].free:
        p[i] += rng.normal(0.0, 0.02)
    doc = yaml.safe_load(offsets_yaml(profile, _calibration(profile, p)))
    assert set(doc["joints"]) == {*JOINTS, "finger_joint"}
    assert (doc["joints"]["finger_joint"]["offset"], doc["joints"]["finger_joint"]["unit"]) == (0.0, "mm")
    assert doc["geometry"] == {}
    assert set(doc["setup"]) == {f"tracker.{k}" for k in ("x", "y", "z", "yaw", "pitch", "roll")} | {
        "smr.x",
        "smr.y",
        "smr.z",
    }
    assert doc["urdf"].endswith("arm.urdf")
    offsets = np.radians([doc["joints"][j]["offset"] for j in JOINTS])
    urdf = _load(tmp_path / "arm.urdf")
    q = _arm_readings(rng, 10)
    poses = forward(profile, p, q)
    for n in range(len(q)):
        urdf.update_cfg(_cfg(q[n] + [*offsets, 0.0]))
        T = urdf.get_transform(frame_to="tool0", frame_from="base_link")
        np.testing.assert_allclose(poses.t[profile.frame("tool0")][n] / 1000, T[:3, 3], rtol=0, atol=1e-9)


def _arm_readings(rng: np.random.Generator, n: int) -> np.ndarray:
    """Readings (n, 7) of the mm profile's joints: the arm's in rad, then the finger's in mm."""
    return np.hstack([rng.uniform(-3.1, 3.1, (n, len(JOINTS))), rng.uniform(0.0, 40.0, (n, 1))])


def _cfg(q: np.ndarray) -> dict[str, float]:
    """yourdfpy's configuration (rad, m) for readings of the mm profile."""
    return {**dict(zip(JOINTS, q[:-1], strict=True)), "finger_joint": q[-1] / 1000.0}


def _calibration(profile, p: np.ndarray) -> Calibration:
    nominal = profile.nominal()
    params = [
        parameter_estimate(profile, i, p, nominal, estimated=bool(p[i] != nominal[i]), std=0.01)
        for i in range(len(profile.parameters))
    ]
    return Calibration(profile.name, "test", "lm", "2026-01-01T00:00:00Z", "test", params, {}, {}, {})


# --- bad URDFs ----------------------------------------------------------------------------------


def _replace(old: str, new: str) -> str:
    text = arm_urdf()
    assert old in text
    return text.replace(old, new, 1)


BAD = {
    "not XML": ("<robot name='arm'><link name='a'>", ["not valid XML", "line 1"]),
    "not a robot": ("<?xml version='1.0'?>\n<sdf/>", ["not a URDF", "<sdf>"]),
    "unknown parent": (
        _replace('<parent link="forearm_link"/>', '<parent link="forarm_link"/>'),
        ["joint 'wrist_1'", "parent link 'forarm_link' is not a <link>"],
    ),
    "a loop": (
        _replace(
            "</robot>",
            '  <joint name="back" type="fixed"><parent link="upper_arm_link"/>'
            '<child link="shoulder_link"/></joint>\n</robot>',
        ),
        ["link 'shoulder_link' is the child of two joints, 'shoulder_pan' and 'back'"],
    ),
    "a loop without a root": (
        _replace('<parent link="base_link"/>', '<parent link="tool0"/>'),
        ["form a loop", "'shoulder_pan'", "'flange'"],
    ),
    "limits the wrong way round": (
        _replace('<limit lower="-3.1" upper="3.1"', '<limit lower="3.1" upper="-3.1"'),
        ["joint 'shoulder_pan'", "<limit> lower 3.1 is above upper -3.1"],
    ),
    "bad origin": (_replace('xyz="0.0 0.0 0.089"', 'xyz="0 0.089"'), ["joint 'shoulder_pan'", "three finite numbers"]),
}


@pytest.mark.parametrize("case", list(BAD))
def test_bad_urdfs_name_the_file_and_the_joint(tmp_path: Path, case: str) -> None:
    text, words = BAD[case]
    profile_path = _setup(tmp_path, urdf_text=text)
    with pytest.raises(InputError) as err:
        load_profile(profile_path)
    message = str(err.value)
    assert err.value.file == str(tmp_path / "arm.urdf")
    for word in words:
        assert word in message, message


def test_bad_profiles_of_a_urdf(tmp_path: Path) -> None:
    cases = {
        "urdf: arm.urdf": ("urdf: nowhere.urdf", "URDF file does not exist"),
        "  - {name: smr, frame: tool0,": (
            "  - {name: smr, frame: tray,",
            "targets[0].frame: link 'tray' hangs below joint 'tray_joint' (planar)",
        ),
        "profile: 1\n": ("profile: 1\nbase: world\n", "base: 'world' is not the root link 'base_link' of arm.urdf"),
        "  - {name: tracker, parent: base_link,": (
            "  - {name: tool0, parent: base_link,",
            "frames[0].name: 'tool0' is already a link of arm.urdf",
        ),
    }
    for old, (new, words) in cases.items():
        assert old in PROFILE
        with pytest.raises(InputError) as err:
            load_profile(_setup(tmp_path, PROFILE.replace(old, new, 1)))
        assert words in str(err.value)


def test_the_command_line_says_what_is_wrong_with_a_urdf(tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    profile_path = _setup(tmp_path, urdf_text=BAD["unknown parent"][0])
    data = tmp_path / "data.csv"
    data.write_text("frame,x,y,z\n", encoding="utf-8")
    code = main(["solve", "--robot", str(profile_path), "--mode", "offsets", "--data", str(data), "--out", "x.json"])
    err = capsys.readouterr().err
    assert code == 2
    assert "arm.urdf" in err and "joint 'wrist_1'" in err and "Traceback" not in err


# --- what URDFs in the wild get wrong, tolerated with a note --------------------------------------


LENIENT = {
    "version 0.0": (
        lambda t: t.replace('<?xml version="1.0"?>', '<?xml version="0.0" ?>', 1),
        'arm.urdf, line 1: the XML declaration says version="0.0", read as XML 1.0',
    ),
    "declaration after comments": (
        lambda t: "<!-- written by hand -->\n\n" + t,
        "arm.urdf, line 3: the XML declaration is not at the start of the file (after comments), moved there",
    ),
    "declaration after blank lines": (
        lambda t: "\n\n\n" + t,
        "arm.urdf, line 4: the XML declaration is not at the start of the file (after blank lines), moved there",
    ),
    "NUL bytes after the root": (lambda t: t + "\0", "arm.urdf: NUL bytes after the root element, ignored"),
}


@pytest.mark.parametrize("case", list(LENIENT))
def test_xml_quirks_load_with_a_note(tmp_path: Path, case: str, capsys: pytest.CaptureFixture) -> None:
    """The same robot as the well-formed file, and a note saying what was put right; the CLI prints it."""
    fix, note = LENIENT[case]
    (tmp_path / "clean").mkdir()
    clean = load_profile(_setup(tmp_path / "clean"))
    path = _setup(tmp_path, urdf_text=fix(arm_urdf()))
    profile = load_profile(path)
    assert len(profile.notes) == 1 and profile.notes[0].endswith(note), profile.notes
    np.testing.assert_array_equal(profile.nominal(), clean.nominal())
    assert profile.parameter_names == clean.parameter_names
    # The export rewrites the file as read, put right: valid XML that yourdfpy reads.
    text = calibrated_urdf(profile, _calibration(profile, profile.nominal() + 0.001))
    (tmp_path / "out.urdf").write_text(text, encoding="utf-8")
    # The user's joints, and the tracker's registration frame added on a fixed joint of its own.
    exported = _load(tmp_path / "out.urdf").joint_names
    assert exported == [*_load(tmp_path / "clean" / "arm.urdf").joint_names, "tracker_calibrated"]
    data = tmp_path / "data.csv"
    data.write_text("frame,x,y,z\n", encoding="utf-8")
    main(["solve", "--robot", str(path), "--mode", "offsets", "--data", str(data), "--out", str(tmp_path / "c.json")])
    assert f"calib solve: note: {profile.notes[0]}" in capsys.readouterr().err


def test_other_xml_errors_stay_errors_on_the_files_line(tmp_path: Path) -> None:
    """Put-right declarations keep every line where it was: a later error names its own line."""
    text = "<!-- c -->\n" + arm_urdf().replace('xyz="0.0 0.0 0.089"', 'xyz="0 0.089"', 1)
    line = text[: text.index('xyz="0 0.089"')].count("\n") + 1
    with pytest.raises(InputError) as err:
        load_profile(_setup(tmp_path, urdf_text=text))
    assert err.value.line == line  # the <origin>'s line in the file as written
    assert "joint 'shoulder_pan'" in str(err.value)
    with pytest.raises(InputError, match="not valid XML"):  # broken XML with a quirk: still broken
        load_profile(_setup(tmp_path, urdf_text='<?xml version="0.0"?>\n<robot name="a"><link name="a">'))


NO_LIMITS = '<limit lower="-3.1" upper="3.1" effort="150" velocity="3.15"/>'


def test_a_revolute_joint_without_limits_gets_zero_and_notes(tmp_path: Path) -> None:
    """The URDF spec's default: lower = upper = 0. The joint cannot move, yet the default modes
    estimate its offset: both said, naming the joint."""
    text = arm_urdf().replace(NO_LIMITS, '<limit effort="150" velocity="3.15"/>', 1)  # shoulder_pan
    profile = load_profile(_setup(tmp_path, urdf_text=text))
    pan = profile.joints[profile.joint("shoulder_pan")]
    assert (pan.lower, pan.upper) == (0.0, 0.0)
    assert len(profile.notes) == 2, profile.notes
    assert (
        "joint 'shoulder_pan' (revolute) has no <limit lower=... upper=...>: both 0, the URDF default"
        in (profile.notes[0])
    )
    assert profile.notes[0].startswith(f"{tmp_path / 'arm.urdf'}, line ")
    assert profile.notes[1].startswith("joint 'shoulder_pan' cannot move (lower = upper = 0 deg)")
    assert "mode(s) offsets, origins estimate its offset" in profile.notes[1]


def test_the_profiles_joints_give_limits_before_they_are_checked(tmp_path: Path) -> None:
    """A joint without limits, and one with limits the wrong way round, made usable by the profile."""
    text = arm_urdf().replace(NO_LIMITS, '<limit effort="150" velocity="3.15"/>', 1)  # shoulder_pan
    text = text.replace(NO_LIMITS, '<limit lower="1" upper="-1" effort="150" velocity="3.15"/>', 1)  # lift
    profile_text = (
        PROFILE + "joints:\n  shoulder_pan: {lower: -90, upper: 90}\n  shoulder_lift: {lower: -45, upper: 45}\n"
    )
    profile = load_profile(_setup(tmp_path, profile_text, urdf_text=text))
    assert profile.notes == ()
    limits = {j.name: (j.lower, j.upper) for j in profile.joints}
    assert limits["shoulder_pan"] == pytest.approx((-HALF_PI, HALF_PI))
    assert limits["shoulder_lift"] == pytest.approx((-HALF_PI / 2, HALF_PI / 2))
    # Only one limit given: the other is still the URDF's default, and the note stays.
    profile_text = PROFILE + "joints:\n  shoulder_pan: {upper: 90}\n  shoulder_lift: {lower: -45, upper: 45}\n"
    profile = load_profile(_setup(tmp_path, profile_text, urdf_text=text))
    assert len(profile.notes) == 1 and "joint 'shoulder_pan' (revolute) has no <limit" in profile.notes[0]
    # An override that puts them the wrong way round is the profile's mistake, named there.
    profile_text = PROFILE + "joints:\n  shoulder_lift: {lower: 45, upper: -45}\n"
    with pytest.raises(InputError) as err:
        load_profile(_setup(tmp_path, profile_text, urdf_text=text))
    assert err.value.file == str(tmp_path / "arm.yaml") and "joints.shoulder_lift" in str(err.value)


def test_the_api_robot_answer_carries_the_notes_and_prismatic_units(tmp_path: Path) -> None:
    from app.robots.roster import Robot  # noqa: F401  (the router's answer is built from a loaded profile)
    from app.web.routers.robots import _joint_out

    text = arm_urdf().replace('<?xml version="1.0"?>', '<?xml version="0.0"?>', 1)
    profile = load_profile(_setup(tmp_path, urdf_text=text))
    finger = _joint_out(profile, profile.joint("finger_joint"))
    assert (finger.type, finger.unit, finger.lower, finger.upper, finger.lower_deg) == ("prismatic", "mm", 0, 40, None)
    elbow = _joint_out(profile, profile.joint("elbow"))
    assert (elbow.type, elbow.unit) == ("revolute", "deg")
    assert elbow.lower_deg == pytest.approx(math.degrees(-3.1)) == pytest.approx(elbow.lower)
