"""Robot profiles: the built-in ones reproduce the pinned specs; broken ones fail with an InputError that
names the file and the field."""

from __future__ import annotations

import math
import re
from importlib import resources
from pathlib import Path

import numpy as np
import pytest
import yaml
from spec_tables import RN_JOINTS, RN_TABLE_I, RN_TABLE_II

from calib_core import InputError, load_profile
from calib_core.model.loader import BUILTIN_PROFILES

NAO_21 = [
    "CamYaw",
    "CamPitch",
    "CamRoll",
    *(s + j for s in "LR" for j in ("HipYawPitch", "HipRoll", "HipPitch", "KneePitch", "AnklePitch", "AnkleRoll")),
    *(s + k for s in "LR" for k in ("RotZ", "TransX", "TransY")),
]


def _builtin_text(name: str) -> str:
    return (resources.files("calib_core.model") / "profiles" / f"{name}.yaml").read_text(encoding="utf-8")


# --- the built-in profiles ------------------------------------------------------------------------------


@pytest.mark.parametrize("name", BUILTIN_PROFILES)
def test_builtin_profiles_load(name: str) -> None:
    profile = load_profile(name)
    assert profile.name == name
    assert profile.parameters and profile.frames and profile.joints and profile.sensors and profile.targets
    assert len(set(profile.parameter_names)) == len(profile.parameter_names)
    for mode in profile.modes.values():
        assert mode.free


def test_unknown_builtin_is_an_input_error() -> None:
    with pytest.raises(InputError, match="unknown robot 'robonaut-b'"):
        load_profile("robonaut-b")


def test_robonaut_nominal_and_truth_are_the_papers_tables() -> None:
    profile = load_profile("robonaut-a")
    assert profile.length_unit == "cm"
    nominal = profile.params_to_display(profile.nominal())
    truth = profile.params_to_display(profile.true_params())
    for field, values in RN_TABLE_I.items():
        for joint, value in zip(RN_JOINTS, values, strict=True):
            assert nominal[f"{joint}.{field}"] == pytest.approx(value, abs=1e-12), (joint, field)
    for field, values in RN_TABLE_II.items():
        for joint, value in zip(RN_JOINTS, values, strict=True):
            assert truth[f"{joint}.{field}"] == pytest.approx(value, abs=1e-12), (joint, field)
    for k, v in zip("xyz", (10.0, 0.0, 0.0), strict=True):
        assert nominal[f"fixture.{k}"] == v
    # Internally angles are radians, lengths the profile unit; display converts angles only.
    i = profile.param("wrist_pitch.theta")
    assert profile.nominal()[i] == pytest.approx(-math.pi / 2)
    assert profile.to_display(i, profile.nominal()[i]) == pytest.approx(-90.0)
    j = profile.param("shoulder_roll.d")
    assert profile.to_display(j, 30.48) == 30.48 and profile.from_display(j, 30.48) == 30.48


def test_nao_parameters_start_at_zero_and_camera_is_the_papers() -> None:
    profile = load_profile("nao")
    assert profile.length_unit == "mm"
    nominal = profile.params_to_display(profile.nominal())
    for name in NAO_21:
        assert nominal[name] == 0.0, name
    values = profile.params_to_display(profile.nominal())
    assert [values[f"lower_camera.{k}"] for k in ("fx", "fy", "cx", "cy")] == [562.5, 562.5, 324.0, 189.0]
    assert profile.sensors[profile.data.sensor].image == (640, 480)


# --- modes ----------------------------------------------------------------------------------------------


def _names(profile, indices) -> set[str]:
    return {profile.parameters[i].name for i in indices}


def test_robonaut_full_mode_is_the_pinned_scheme() -> None:
    profile = load_profile("robonaut-a")
    mode = profile.mode("full")
    thetas = {f"{j}.theta" for j in RN_JOINTS}
    ds = {f"{j}.d" for j, v in zip(RN_JOINTS, RN_TABLE_I["d"], strict=True) if v != 0}
    as_ = {f"{j}.a" for j, v in zip(RN_JOINTS, RN_TABLE_I["a"], strict=True) if v != 0}
    fixture = {"fixture.x", "fixture.y", "fixture.z"}
    ties = {(profile.parameters[t.follower].name, profile.parameters[t.leader].name, t.sign) for t in mode.ties}
    pinned = {
        frozenset({"shoulder_pitch.a", "shoulder_roll.a"}): -1.0,
        frozenset({"elbow_pitch.a", "elbow_roll.a"}): -1.0,
        frozenset({"wrist_roll.d", "elbow_roll.d"}): 1.0,
    }
    assert {frozenset({f, lead}): sign for f, lead, sign in ties} == pinned
    followers = {f for f, _, _ in ties}
    free = _names(profile, mode.free)
    # Every theta, every non-zero d and a, the fixture: each pair one dimension of the search.
    assert free | followers == thetas | ds | as_ | fixture
    assert not free & followers
    assert len(free) == 10 + 6 + 7 + 3 - 3
    assert not any(n.endswith(".alpha") for n in free | followers)
    assert not any(n.startswith("eye.") for n in free)
    # The pinned ties hold in the paper's tables.
    for values in (profile.nominal(), profile.true_params()):
        for t in mode.ties:
            assert values[t.follower] == pytest.approx(t.sign * values[t.leader], abs=1e-12)


def test_robonaut_daily_mode_is_the_joint_offsets() -> None:
    profile = load_profile("robonaut-a")
    mode = profile.mode("daily")
    assert _names(profile, mode.free) == {f"{j}.theta" for j in RN_JOINTS}
    assert mode.ties == ()


def test_nao_modes_are_the_21_parameters_and_the_head_offsets() -> None:
    profile = load_profile("nao")
    assert _names(profile, profile.mode("full").free) == set(NAO_21)
    assert _names(profile, profile.mode("full+head").free) == set(NAO_21) | {"HeadYaw", "HeadPitch"}
    with pytest.raises(InputError, match="unknown mode 'daily'"):
        profile.mode("daily")


# --- broken profiles ------------------------------------------------------------------------------------


def _sub(text: str, pattern: str, replacement: str) -> str:
    new, n = re.subn(pattern, replacement, text, count=1, flags=re.MULTILINE)
    assert n == 1, pattern
    return new


BROKEN = {
    # name: (profile, pattern, replacement, the field the message must name, other text it must contain)
    "missing sensor model": ("robonaut-a", r"^    model: point3d\n", "", "sensors[0].model", "missing"),
    "missing frame parent": (
        "robonaut-a",
        r"\{name: elbow_roll, +parent: shoulder_pitch, ",
        "{name: elbow_roll, ",
        "frames[2].parent",
        "missing",
    ),
    "unknown parent frame": (
        "robonaut-a",
        r"parent: shoulder_pitch, joint: elbow_roll",
        "parent: shoulder_ptch, joint: elbow_roll",
        "frames[2].parent",
        "shoulder_ptch",
    ),
    "bad number in a DH table": ("robonaut-a", r"d: 30\.48,", "d: 30.48cm,", "frames[0].mdh.d", "30.48cm"),
    "bad joint limit": (
        "robonaut-a",
        r"shoulder_roll:  \{lower: -90,",
        "shoulder_roll:  {lower: .nan,",
        "joints.shoulder_roll.lower",
        "finite number",
    ),
    "bad target point": ("robonaut-a", r"point: \{x: 10\.0,", "point: {x: ten,", "targets[0].point.x", "ten"),
    "unknown mode parameter (free)": (
        "robonaut-a",
        r'free: \["\*\.theta", \{pattern',
        'free: ["*.thetaa", {pattern',
        "modes.full.free[0]",
        "*.thetaa",
    ),
    "unknown mode parameter (tie)": (
        "robonaut-a",
        r"leader: shoulder_roll\.a,",
        "leader: shoulder_rol.a,",
        "modes.full.ties[0]",
        "shoulder_rol.a",
    ),
    "unknown mode parameter (prior)": (
        "robonaut-a",
        r"^    ties:\n",
        "    priors: {neck_yaw.e: 1.0}\n    ties:\n",
        "modes.full.priors",
        "neck_yaw.e",
    ),
    "unknown data target": (
        "nao",
        r"targets: \{left: left_board, right: right_board\}",
        "targets: {left: left_board, right: right_bord}",
        "data.targets.right",
        "right_bord",
    ),
    "measurement columns not the sensor's dimension": (
        "robonaut-a",
        r"measurement: \{columns: \[x, y, z\]",
        "measurement: {columns: [x, y]",
        "data.measurement.columns",
        "a point3d sensor ('eye') measures 3 numbers, not 2",
    ),
    "unknown joint unit": ("robonaut-a", r"joint_unit: deg", "joint_unit: degrees", "data.joint_unit", "degrees"),
    "unknown sensor model": ("nao", r"model: pinhole", "model: fisheye", "sensors[0].model", "fisheye"),
    "unknown mode sensor": (
        "motoman",
        r"sensors: \[tracker\]",
        "sensors: [laser]",
        "modes.offsets.sensors[0]",
        "laser",
    ),
    "unknown camera frame": (
        "nao",
        r"    frame: lower_camera\n    model: pinhole",
        "    frame: upper_camera\n    model: pinhole",
        "sensors[0].frame",
        "upper_camera",
    ),
}


@pytest.mark.parametrize("case", sorted(BROKEN))
def test_broken_profile_names_file_and_field(case: str, tmp_path: Path) -> None:
    name, pattern, replacement, field, detail = BROKEN[case]
    path = tmp_path / f"{name}-broken.yaml"
    path.write_text(_sub(_builtin_text(name), pattern, replacement), encoding="utf-8")
    with pytest.raises(InputError) as info:
        load_profile(path)
    message = str(info.value)
    assert str(path) in message, message
    assert field in message, message
    assert detail in message, message


def test_yaml_syntax_error_names_file_and_line(tmp_path: Path) -> None:
    text = _builtin_text("robonaut-a")
    lines = text.splitlines(keepends=True)
    k = next(i for i, line in enumerate(lines) if line.startswith("joints:"))
    lines[k + 1] = "  shoulder_roll:  {lower: -90, upper: 90\n"  # an unclosed flow mapping
    path = tmp_path / "robonaut-syntax.yaml"
    path.write_text("".join(lines), encoding="utf-8")
    with pytest.raises(InputError) as info:
        load_profile(path)
    err = info.value
    assert str(path) in str(err) and "YAML" in str(err)
    assert err.line is not None and k + 1 <= err.line <= k + 4, (err.line, k + 2)
    assert f"line {err.line}" in str(err)


def test_missing_profile_file(tmp_path: Path) -> None:
    path = tmp_path / "nope.yaml"
    with pytest.raises(InputError) as info:
        load_profile(path)
    assert str(path) in str(info.value)


def test_a_fixed_profile_loads_again(tmp_path: Path) -> None:
    """The broken-profile cases fail for the change, not for being a copy: the copy itself loads (with the URDF
    it names, copied beside it)."""
    for name in BUILTIN_PROFILES:
        path = tmp_path / f"{name}-copy.yaml"
        path.write_text(_builtin_text(name), encoding="utf-8")
        urdf = yaml.safe_load(_builtin_text(name)).get("urdf")
        if urdf:
            (tmp_path / urdf).write_bytes((resources.files("calib_core.model") / "profiles" / urdf).read_bytes())
        copy, builtin = load_profile(path), load_profile(name)
        assert copy.parameter_names == builtin.parameter_names
        np.testing.assert_array_equal(copy.nominal(), builtin.nominal())
