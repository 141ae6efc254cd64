"""A URDF robot drawn with its own visuals in the review scene (app/scene/robot_look.py,
app/scene/review_scene/copies.py): meshes (STL, OBJ; package:// and relative paths) and primitives under the links
of both copies, posed by each calibration's kinematics; a mesh that cannot be found falls back to simple shapes with
one warning naming the file."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import trimesh
import viser
from fastapi.testclient import TestClient
from scene_nodes import node_pose
from sim_frames import measured_frames
from test_urdf_import import PROFILE as ARM_PROFILE

from app.robots.desk_config import load_desk_config
from app.scene.review import Review
from app.scene.review_scene.copies import GHOST_RGBA
from app.scene.review_scene.scene import ReviewScene
from app.scene.robot_look import cluster_vertices, read_look, robot_look
from app.web.server import create_app
from calib_core import SimulatedRobot, load_profile, to_csv
from calib_core.model.kinematics import forward
from calib_core.units import length_factor

URDF = """<?xml version="1.0"?>
<robot name="meshed_arm">
  <material name="orange"><color rgba="1 0.5 0 1"/></material>
  <link name="base_link">
    <visual><origin xyz="0 0 0.05"/><geometry><box size="0.2 0.2 0.1"/></geometry><material name="orange"/></visual>
  </link>
  <link name="shoulder">
    <visual><geometry><cylinder radius="0.05" length="0.1"/></geometry></visual>
  </link>
  <link name="upper">
    <visual>
      <origin xyz="0 0 0.15" rpy="0 0 0.3"/>
      <geometry><mesh filename="package://meshed_arm/meshes/upper.stl"/></geometry>
      <material name="orange"/>
    </visual>
  </link>
  <link name="fore">
    <visual>
      <origin xyz="0.01 0 0.125"/><geometry><mesh filename="../meshes/fore.obj" scale="1 1 2"/></geometry>
    </visual>
  </link>
  <link name="tool0"/>
  <joint name="j1" type="revolute"><parent link="base_link"/><child link="shoulder"/>
    <origin xyz="0 0 0.15"/><axis xyz="0 0 1"/><limit lower="-3" upper="3" effort="1" velocity="1"/></joint>
  <joint name="j2" type="revolute"><parent link="shoulder"/><child link="upper"/>
    <origin xyz="0 0 0.05"/><axis xyz="0 1 0"/><limit lower="-2" upper="2" effort="1" velocity="1"/></joint>
  <joint name="j3" type="revolute"><parent link="upper"/><child link="fore"/>
    <origin xyz="0 0 0.3"/><axis xyz="0 1 0"/><limit lower="-2.5" upper="2.5" effort="1" velocity="1"/></joint>
  <joint name="flange" type="fixed"><parent link="fore"/><child link="tool0"/><origin xyz="0 0 0.25"/></joint>
</robot>
"""

# The arm profile of docs/urdf-robots.md on this URDF, with a hidden true robot for the simulator.
PROFILE = ARM_PROFILE.replace("name: test-arm", "name: meshed-arm").replace("urdf: arm.urdf", "urdf: urdf/arm.urdf") + (
    "simulation:\n  noise: {point: 0.02}\n"
    "  truth: {tracker.x: 1500.0, tracker.yaw: 170.0, j2: 2.0, j3: -3.0, j3.z: 310.0}\n"
)


def meshed_arm(folder: Path, *, meshes: bool = True) -> Path:
    """A ROS-like description (meshed_arm/{urdf,meshes}) and its profile; `meshes`: write the mesh files (a few
    KB), else the URDF names files that are not there. The profile file's path."""
    root = folder / "meshed_arm"
    (root / "meshes").mkdir(parents=True)
    (root / "urdf").mkdir()
    if meshes:
        trimesh.creation.cylinder(radius=0.04, height=0.3, sections=16).export(root / "meshes" / "upper.stl")
        trimesh.creation.box(extents=(0.05, 0.05, 0.125)).export(root / "meshes" / "fore.obj")
    (root / "urdf" / "arm.urdf").write_text(URDF)
    (root / "arm.yaml").write_text(PROFILE)
    return root / "arm.yaml"


def write_text(path: Path, text: str) -> Path:
    path.write_text(text, encoding="utf-8")
    return path


def _review(profile_path: Path) -> Review:
    profile = load_profile(profile_path)
    sim = SimulatedRobot.from_profile(profile, seed=3).simulate(4)
    return Review.build(profile, measured_frames(sim.data), sim.data, profile.nominal(), sim.true_params)


def test_the_review_shows_the_urdf_visuals_where_each_calibration_puts_the_links(
    viser_server: viser.ViserServer, tmp_path: Path
) -> None:
    review = _review(meshed_arm(tmp_path))
    profile = review.profile
    look = robot_look(profile)
    assert look is not None and look.warning is None
    assert {v.what for v in look.visuals} == {
        "box",
        "cylinder",
        "mesh package://meshed_arm/meshes/upper.stl",
        "mesh ../meshes/fore.obj",
    }
    fore = next(v for v in look.visuals if v.link == "fore")
    np.testing.assert_allclose(np.ptp(fore.vertices, axis=0), [0.05, 0.05, 0.25], atol=1e-6)  # scale="1 1 2"
    scene = ReviewScene(viser_server)
    scene.load(review)
    index = int(review.indices[2])
    scene.select(index)
    state = scene.state()
    joints = review.frame_geometry(index).joints_rad
    to_m = length_factor(profile.length_unit, "m")
    for side in ("old", "new"):
        looks = state["urdf"][side]["looks"]
        assert sorted(v["link"] for v in looks.values()) == ["base_link", "fore", "shoulder", "upper"]
        p = review.sides[side].p
        poses = forward(profile, p, joints[None])
        for name, v in looks.items():
            visual = next(x for x in look.visuals if x.link == v["link"] and x.what == v["what"])
            T_base_link = np.eye(4)
            if v["link"] != profile.base:
                f = profile.frame(v["link"])
                T_base_link[:3, :3], T_base_link[:3, 3] = poses.R[f][0], poses.t[f][0] * to_m
            want = T_base_link @ visual.T_link_visual
            got = node_pose(viser_server, name, f"/review/{side}/base")
            np.testing.assert_allclose(got, want, atol=1e-6, err_msg=f"{side} {name}")
    # The copies differ where the calibrations differ (j2, j3 offsets and j3's origin): the forearm's mesh.
    fore_nodes = {
        s: next(n for n, v in state["urdf"][s]["looks"].items() if v["link"] == "fore") for s in ("old", "new")
    }
    old, new = (node_pose(viser_server, fore_nodes[s], f"/review/{s}/base")[:3, 3] for s in ("old", "new"))
    assert np.linalg.norm(new - old) > 0.01
    # A frame step moves the link frames; the mesh nodes stay the ones sent at the load (none sent again).
    handles = {name: viser_server.scene.get_handle_by_name(name) for name in state["urdf"]["new"]["looks"]}
    scene.select(int(review.indices[0]))
    assert set(scene.state()["urdf"]["new"]["looks"]) == set(handles)
    assert all(viser_server.scene.get_handle_by_name(name) is h for name, h in handles.items())
    # The overlay's translucent old copy has them too, in its tint.
    scene.set_overlay(True)
    ghost = scene.state()["urdf"]["ghost"]["looks"]
    assert sorted(v["link"] for v in ghost.values()) == ["base_link", "fore", "shoulder", "upper"]
    assert all(viser_server.scene.get_handle_by_name(name).opacity == GHOST_RGBA[3] for name in ghost)
    # The generated bodies of links with their own visuals are gone; the reflector (the profile's) stays.
    robot = scene.copies["new"].urdf  # the copy's model as the scene drew it
    materials = {v.material.name for link in robot.robot.links for v in link.visuals if v.material is not None}
    assert "body" not in materials and "target" in materials


def test_a_missing_mesh_falls_back_to_simple_shapes_with_one_warning(
    viser_server: viser.ViserServer, tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    path = meshed_arm(tmp_path, meshes=False)
    with caplog.at_level("WARNING", logger="app.scene.robot_look"):
        review = _review(path)
        scene = ReviewScene(viser_server)
        scene.load(review)
        scene.select(int(review.indices[1]))
        scene.load(review)  # again: read once, said once
    look = robot_look(review.profile)
    assert look is not None
    assert look.warning == (
        "arm.urdf: mesh package://meshed_arm/meshes/upper.stl cannot be found (link 'upper'); "
        "mesh ../meshes/fore.obj cannot be found (link 'fore'): their 2 links are drawn with simple shapes"
    )
    assert [r.getMessage() for r in caplog.records] == [look.warning]
    state = scene.state()
    for side in ("old", "new"):
        looks = state["urdf"][side]["looks"]
        assert sorted(v["link"] for v in looks.values()) == ["base_link", "shoulder"]  # the primitives still
    # upper and fore keep the frame tree's simple bodies.
    robot = scene.copies["new"].urdf
    bodies = {link.name for link in robot.robot.links for v in link.visuals if v.material and v.material.name == "body"}
    assert {"upper", "fore"} <= bodies and not bodies & {"base_link", "shoulder"}


def test_a_huge_mesh_is_thinned_to_the_limit(tmp_path: Path) -> None:
    path = meshed_arm(tmp_path)
    sphere = trimesh.creation.icosphere(subdivisions=6, radius=0.05)  # 81,920 triangles
    sphere.export(tmp_path / "meshed_arm" / "meshes" / "upper.stl")
    look = read_look(path.parent / "urdf" / "arm.urdf", max_faces=5000)
    assert look is not None and look.faces_read > 80_000
    assert 2500 < look.faces <= 5000
    upper = next(v for v in look.visuals if v.link == "upper")
    radii = np.linalg.norm(upper.vertices, axis=1)
    assert np.all(np.abs(radii - 0.05) < 0.005)  # still the sphere
    v, f = cluster_vertices(sphere.vertices, sphere.faces, 80_000)
    assert len(f) <= 80_000 and f.max() < len(v)


def test_the_review_answer_names_the_mesh_that_cannot_be_read(tmp_path: Path) -> None:
    """The desk's review answer carries the look's warning (the page shows it in the Review tab)."""
    path = meshed_arm(tmp_path, meshes=False)
    (tmp_path / "meshed_arm" / "meshes" / "upper.stl").write_text("solid broken\n  facet normal x\n")  # not an STL
    config = load_desk_config(write_text(tmp_path / "desk.yaml", f"robots: [{{name: arm, profile: {path}}}]"))
    profile = load_profile(path)
    csv = to_csv(profile, SimulatedRobot.from_profile(profile, seed=1).simulate(5).data)
    with TestClient(create_app(tmp_path / "data", config=config, sample_dir=None)) as client:
        r = client.post("/api/sessions/import", data={"robot": "arm", "name": "day 1"}, files={"data": ("a.csv", csv)})
        assert r.status_code == 201, r.text
        review = client.post("/api/review", json={"session": r.json()["id"], "old": None})
        assert review.status_code == 200, review.text
        (warning,) = review.json()["warnings"]
        assert warning == (
            "arm.urdf: mesh package://meshed_arm/meshes/upper.stl holds no triangles (link 'upper'); mesh "
            "../meshes/fore.obj cannot be found (link 'fore'): their 2 links are drawn with simple shapes"
        )


def test_a_collada_mesh_keeps_its_own_colour_and_the_urdf_colour_wins(tmp_path: Path) -> None:
    """A DAE (read through pycollada) without a URDF material is drawn in its own colour; one with is drawn in the
    URDF's."""
    path = meshed_arm(tmp_path)
    box = trimesh.creation.box(extents=(0.05, 0.05, 0.1))
    box.visual.face_colors = [20, 120, 220, 255]
    box.export(tmp_path / "meshed_arm" / "meshes" / "fore.dae")
    urdf = path.parent / "urdf" / "arm.urdf"
    urdf.write_text(URDF.replace("../meshes/fore.obj", "package://meshed_arm/meshes/fore.dae"))
    look = read_look(urdf)
    assert look is not None and look.warning is None
    colours = {v.link: v.rgb for v in look.visuals}
    assert colours["fore"] == (20, 120, 220)  # the file's own
    assert colours["upper"] == (255, 128, 0)  # the URDF's <material name="orange">, defined at the top
