"""The URDF export must put every profile frame where calib_core.kinematics.forward puts it.

yourdfpy is an independent URDF reader, so agreement checks the op folding, the rpy conversion
(including pitch = ±90 deg) and the unit conversion, not just that our own numbers round-trip.
"""

from __future__ import annotations

import io
from pathlib import Path

import numpy as np
import pytest
import yaml
import yourdfpy

from calib_core.io.urdf_export import JOINT_SPHERE, to_urdf, write_urdf
from calib_core.model.kinematics import forward
from calib_core.model.loader import BUILTIN_PROFILES, load_profile
from calib_core.model.profile import Profile
from calib_core.units import length_factor

PROFILES_DIR = Path(__file__).resolve().parents[1] / "calib_core" / "model" / "profiles"
N_CONFIGS = 20


def _assert_matches_forward(profile: Profile, urdf: yourdfpy.URDF, p: np.ndarray) -> None:
    """Every frame (and every calibrated target point) at random joint readings within limits."""
    lower, upper = profile.joint_limits()
    q = np.random.default_rng(7).uniform(lower, upper, size=(N_CONFIGS, len(profile.joints)))
    poses = forward(profile, p, q)
    scale = length_factor(profile.length_unit, "m")
    for n in range(N_CONFIGS):
        urdf.update_cfg(dict(zip(profile.joint_names, q[n], strict=True)))
        for f, frame in enumerate(profile.frames):
            T = urdf.get_transform(frame_to=frame.name, frame_from=profile.base)
            np.testing.assert_allclose(T[:3, :3], poses.R[f][n], rtol=0, atol=1e-9)
            np.testing.assert_allclose(T[:3, 3], poses.t[f][n] * scale, rtol=0, atol=1e-9)
        for target in profile.targets:
            if target.point_params is not None:
                T = urdf.get_transform(frame_to=target.name, frame_from=profile.base)
                f = target.frame
                point = poses.R[f][n] @ p[list(target.point_params)] + poses.t[f][n]
                np.testing.assert_allclose(T[:3, 3], point * scale, rtol=0, atol=1e-9)


def _load(path: Path) -> yourdfpy.URDF:
    return yourdfpy.URDF.load(str(path), build_scene_graph=True, load_meshes=False)


@pytest.mark.parametrize("name", BUILTIN_PROFILES)
def test_shipped_urdf_matches_forward_kinematics(name: str) -> None:
    profile = load_profile(name)
    urdf = _load(PROFILES_DIR / f"{name}.urdf")
    assert sorted(urdf.actuated_joint_names) == sorted(profile.joint_names)
    _assert_matches_forward(profile, urdf, profile.nominal())


@pytest.mark.parametrize("name", BUILTIN_PROFILES)
def test_shipped_urdf_is_up_to_date(name: str) -> None:
    shipped = (PROFILES_DIR / f"{name}.urdf").read_text(encoding="utf-8")
    assert shipped == to_urdf(load_profile(name)), f"regenerate calib_core/model/profiles/{name}.urdf"


@pytest.mark.parametrize("name", BUILTIN_PROFILES)
def test_calibrated_urdf_matches_forward_kinematics(name: str, tmp_path: Path) -> None:
    """The export with corrected joint origins: the simulator's true robot, not the nominal one."""
    profile = load_profile(name)
    p = profile.true_params()
    assert not np.allclose(p, profile.nominal())
    path = tmp_path / f"{name}.urdf"
    write_urdf(profile, path, p)
    _assert_matches_forward(profile, _load(path), p)
    assert [f.name for f in tmp_path.iterdir()] == [path.name]  # no temporary file left behind


def test_standard_dh_frames_get_an_intermediate_link(tmp_path: Path) -> None:
    """Standard DH rotates first, then translates: the frame's link must sit after those ops."""
    doc = yaml.safe_load((PROFILES_DIR / "robonaut-a.yaml").read_text(encoding="utf-8"))
    for frame in doc["frames"]:
        frame["dh"] = frame.pop("mdh")
    doc["modes"] = {"all": {"free": ["*"]}}
    doc["simulation"] = {}
    source = tmp_path / "robonaut-dh.yaml"
    source.write_text(yaml.safe_dump(doc), encoding="utf-8")
    profile = load_profile(source)
    p = profile.nominal() + np.random.default_rng(3).normal(0.0, 0.05, len(profile.parameters))
    path = tmp_path / "robonaut-dh.urdf"
    path.write_text(to_urdf(profile, p), encoding="utf-8")
    urdf = _load(path)
    assert "wrist_pitch__wrist_pitch" in urdf.link_map
    _assert_matches_forward(profile, urdf, p)


@pytest.mark.parametrize("name", ["robonaut-a", "nao", "motoman"])
def test_display_bodies_keep_the_kinematics_and_look_like_a_robot(name: str) -> None:
    """bodies=True (the desk's 3-D view) changes what is drawn, never where: the same joints and origins; limbs
    thicker than the export's wire in proportion to the robot, a torso box on the base, a head on each sensor the
    robot carries, and no limb to an external device (the Motoman's laser tracker)."""
    profile = load_profile(name)
    plain = yourdfpy.URDF.load(_stream(to_urdf(profile)), build_scene_graph=False, load_meshes=False)
    body = yourdfpy.URDF.load(_stream(to_urdf(profile, bodies=True)), build_scene_graph=True, load_meshes=False)
    _assert_matches_forward(profile, body, profile.nominal())
    assert {j: tuple(plain.joint_map[j].origin.ravel()) for j in plain.joint_map} == {
        j: tuple(body.joint_map[j].origin.ravel()) for j in body.joint_map
    }
    limbs = [v.geometry.cylinder.radius for link in body.link_map.values() for v in link.visuals if v.geometry.cylinder]
    assert max(limbs) > 0.005 and max(limbs) <= 0.06
    base_boxes = [v for v in body.link_map[profile.base].visuals if v.geometry.box is not None]
    assert base_boxes and np.prod(base_boxes[0].geometry.box.size) > 1e-4  # a torso, not a speck
    on_robot = {profile.frames[s.frame].name for s in profile.sensors if not profile.frames[s.frame].registration}
    for frame in on_robot:
        spheres = [v.geometry.sphere.radius for v in body.link_map[frame].visuals if v.geometry.sphere]
        assert max(spheres) > 2 * max(limbs), (frame, spheres)
    for frame in (f.name for f in profile.frames if f.registration):  # the tracker stays a small marker
        assert all(
            v.geometry.sphere is None or v.geometry.sphere.radius <= JOINT_SPHERE for v in body.link_map[frame].visuals
        )


def _stream(text: str) -> io.StringIO:
    return io.StringIO(text)
