"""The exports a driver takes, for every built-in profile: the calibrated URDF, read by yourdfpy (an
independent URDF reader) at the raw encoder readings, and the offsets YAML, added to the readings
and given to the nominal model, must both put every target point where the calibrated model does.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
import yaml
import yourdfpy

from calib_core.estimation.calibration import Calibration, parameter_estimate
from calib_core.io.export import calibrated_links, calibrated_urdf, offsets_geometry, offsets_yaml
from calib_core.io.ros_tf import link_names
from calib_core.io.urdf_export import to_urdf
from calib_core.model.kinematics import forward
from calib_core.model.loader import BUILTIN_PROFILES, load_profile
from calib_core.model.profile import Profile
from calib_core.units import length_factor

N_CONFIGS = 8


def _calibration(profile: Profile, p: np.ndarray, mode: str) -> Calibration:
    nominal = profile.nominal()
    params = [
        parameter_estimate(profile, i, p, nominal, estimated=bool(p[i] != nominal[i]), std=0.001)
        for i in range(len(profile.parameters))
    ]
    return Calibration(profile.name, mode, "lm", "2026-01-01T00:00:00Z", "test data", params, {}, {}, {})


def _perturbed(profile: Profile, seed: int) -> np.ndarray:
    """Nominal plus 1 deg / 1 cm errors on every kinematic parameter."""
    rng = np.random.default_rng(seed)
    p = profile.nominal()
    sizes = {"angle": math.radians(1.0), "length": 0.01 * length_factor("m", profile.length_unit)}
    for i, param in enumerate(profile.parameters):
        if param.kind in sizes:
            p[i] += rng.normal(0.0, sizes[param.kind])
    return p


def _offsets_only(profile: Profile, seed: int) -> np.ndarray:
    """Nominal with each joint offset by 1 deg-ish: every op a joint drives turns by the same angle
    (Motoman's torso axis turns four frames)."""
    delta = np.radians(np.random.default_rng(seed).normal(0.0, 1.0, len(profile.joints)))
    p = profile.nominal()
    for frame in profile.frames:
        for op in frame.ops:
            if op.joint >= 0:
                p[op.param] += delta[op.joint]
    return p


def _target_points(profile: Profile, p: np.ndarray, t: int) -> np.ndarray:
    """A target's points (K, 3) in its frame, profile units: a grid, fixed points or the calibrated point."""
    target = profile.targets[t]
    for fixed in (target.grid, getattr(target, "points", None)):
        if fixed is not None:
            return fixed
    assert target.point_params is not None
    return p[list(target.point_params)][None]


def _readings(profile: Profile, seed: int) -> np.ndarray:
    lower, upper = profile.joint_limits()
    return np.random.default_rng(seed).uniform(lower, upper, (N_CONFIGS, len(profile.joints)))


def _model_points(profile: Profile, p: np.ndarray, q: np.ndarray) -> dict[str, np.ndarray]:
    """Every target's points in the base frame (m), (N, K, 3), by calib_core's kinematics."""
    poses = forward(profile, p, q)
    scale = length_factor(profile.length_unit, "m")
    out = {}
    for t, target in enumerate(profile.targets):
        pts = _target_points(profile, p, t)
        f = target.frame
        out[target.name] = (np.einsum("nij,kj->nki", poses.R[f], pts) + poses.t[f][:, None]) * scale
    return out


def _urdf_points(profile: Profile, p: np.ndarray, urdf: yourdfpy.URDF, angles: np.ndarray) -> dict[str, np.ndarray]:
    """The same points by yourdfpy: each target's frame link, at the given joint angles (rad)."""
    scale = length_factor(profile.length_unit, "m")
    out = {t.name: [] for t in profile.targets}
    for a in angles:
        urdf.update_cfg(dict(zip(profile.joint_names, a, strict=True)))
        for t, target in enumerate(profile.targets):
            T = urdf.get_transform(frame_to=profile.frames[target.frame].name, frame_from=profile.base)
            out[target.name].append(_target_points(profile, p, t) * scale @ T[:3, :3].T + T[:3, 3])
    return {k: np.array(v) for k, v in out.items()}


def _load(tmp_path: Path, name: str, text: str) -> yourdfpy.URDF:
    path = tmp_path / name
    path.write_text(text, encoding="utf-8")
    return yourdfpy.URDF.load(str(path), build_scene_graph=True, load_meshes=False)


def _assert_same(a: dict[str, np.ndarray], b: dict[str, np.ndarray]) -> None:
    assert a.keys() == b.keys()
    for name in a:
        np.testing.assert_allclose(a[name], b[name], rtol=0, atol=1e-9, err_msg=name)


@pytest.mark.parametrize("name", BUILTIN_PROFILES)
def test_calibrated_urdf_is_the_calibrated_model_at_the_raw_readings(name: str, tmp_path: Path) -> None:
    profile = load_profile(name)
    p = _perturbed(profile, 1)
    text = calibrated_urdf(profile, _calibration(profile, p, "full"))
    assert "raw encoder readings" in text.split("<robot", 1)[1].split(">", 2)[1]  # the comment says how to use it
    urdf = _load(tmp_path, "calibrated.urdf", text)
    assert sorted(urdf.actuated_joint_names) == sorted(profile.joint_names)
    assert not any(j.calibration for j in urdf.robot.joints)  # no <calibration> tags: drivers ignore them
    q = _readings(profile, 2)
    _assert_same(_urdf_points(profile, p, urdf, q), _model_points(profile, p, q))
    # Every sensor's frame too (the hand-eye sample's camera mount, added to the user's URDF as a link).
    poses, scale = forward(profile, p, q), length_factor(profile.length_unit, "m")
    for k, angles in enumerate(q):
        urdf.update_cfg(dict(zip(profile.joint_names, angles, strict=True)))
        for f in {s.frame for s in profile.sensors}:
            T = urdf.get_transform(frame_to=profile.frames[f].name, frame_from=profile.base)
            np.testing.assert_allclose(T[:3, :3], poses.R[f][k], rtol=0, atol=1e-9)
            np.testing.assert_allclose(T[:3, 3], poses.t[f][k] * scale, rtol=0, atol=1e-9)


@pytest.mark.parametrize("name", BUILTIN_PROFILES)
def test_offsets_yaml_on_the_nominal_urdf_is_an_offsets_calibration(name: str, tmp_path: Path) -> None:
    """Only joint offsets changed: the nominal URDF (the shipped display model) at reading + offset."""
    profile = load_profile(name)
    p = _offsets_only(profile, 3)
    doc = yaml.safe_load(offsets_yaml(profile, _calibration(profile, p, "offsets")))
    assert doc["meaning"] == "angle used by the calibrated model = encoder reading + offset"
    assert list(doc["joints"]) == [j for j in _joint_order(profile)]
    assert doc["geometry"] == {}
    offsets = np.radians([doc["joints"][j]["offset"] for j in profile.joint_names])
    urdf = _load(tmp_path, "nominal.urdf", to_urdf(profile))
    q = _readings(profile, 4)
    _assert_same(_urdf_points(profile, p, urdf, q + offsets), _model_points(profile, p, q))


@pytest.mark.parametrize("name", BUILTIN_PROFILES)
def test_offsets_yaml_with_its_geometry_is_a_full_calibration(name: str) -> None:
    """Every parameter changed: the nominal model with the YAML's geometry and set-up, at reading + offset."""
    profile = load_profile(name)
    p = _perturbed(profile, 5)
    doc = yaml.safe_load(offsets_yaml(profile, _calibration(profile, p, "full")))
    offsets = np.radians([doc["joints"][j]["offset"] for j in profile.joint_names])
    g = profile.nominal()
    for pname, change in {**doc["geometry"], **doc.get("setup", {})}.items():
        i = profile.param(pname)
        assert change["unit"] == profile.unit(i)
        g[i] += profile.from_display(i, change["change"])
    np.testing.assert_allclose(g, offsets_geometry(profile, p), rtol=0, atol=1e-9)
    q = _readings(profile, 6)
    _assert_same(_model_points(profile, g, q + offsets), _model_points(profile, p, q))
    for joint, entry in doc["joints"].items():  # each joint's offset is its offset parameter's change
        i = profile.param(entry["parameter"])
        assert entry["offset"] == pytest.approx(math.degrees(p[i] - profile.nominal()[i]), abs=1e-9), joint
        assert doc["geometry"].get(entry["parameter"]) is None


def _joint_order(profile: Profile) -> list[str]:
    """Joints in the order the frames first use them."""
    seen: dict[str, None] = {}
    for f in profile.frames:
        if f.joint >= 0:
            seen.setdefault(profile.joints[f.joint].name)
    return list(seen)


# A camera's frame in calib_core's model of a profile (Motoman's), and in the user's URDF (the hand-eye arm's).
@pytest.mark.parametrize(("name", "frame"), [("motoman", "camera1"), ("arm-handeye", "camera_mount")])
def test_renamed_links_stand_where_they_stood_under_their_new_names(name: str, frame: str, tmp_path: Path) -> None:
    """A camera's frame, its parent's and the base renamed (the names a ROS robot's TF uses): every link at the same
    pose, every reference following, no old name left."""
    profile = load_profile(name)
    cal = _calibration(profile, _perturbed(profile, 4), "full")
    camera = profile.frames[profile.frame(frame)]
    names = {camera.name: "camera_optical_frame", profile.frames[camera.parent].name: "mount", profile.base: "world"}
    plain = calibrated_urdf(profile, cal)
    assert calibrated_links(profile) == link_names(plain)
    renamed = _load(tmp_path, "renamed.urdf", calibrated_urdf(profile, cal, names))
    original = _load(tmp_path, "plain.urdf", plain)
    assert set(renamed.link_map) == {names.get(link, link) for link in original.link_map}
    for angles in _readings(profile, 5)[:2]:
        cfg = dict(zip(profile.joint_names, angles, strict=True))
        original.update_cfg(cfg)
        renamed.update_cfg(cfg)
        for link in original.link_map:
            T = renamed.get_transform(frame_to=names.get(link, link), frame_from="world")
            np.testing.assert_allclose(T, original.get_transform(frame_to=link, frame_from=profile.base), atol=1e-12)
