"""A robot copy in viser (app/scene/robot_copy.py): every link where yourdfpy's kinematics put it, for each joint type,
and a pose step that sends only the frames of the joints that moved."""

from __future__ import annotations

import io
from pathlib import Path

import numpy as np
import pytest
import viser
import yourdfpy
from scene_nodes import node_pose

from app.scene.robot_copy import RobotCopy
from app.scene.robot_look import link_visuals

URDF = """<robot name="every_joint">
  <material name="grey"><color rgba="0.5 0.5 0.5 1"/></material>
  <link name="base"><visual><geometry><box size="0.1 0.1 0.1"/></geometry><material name="grey"/></visual></link>
  <link name="turn"/><link name="spin"/><link name="slide"/><link name="twin"/><link name="tool">
    <visual><origin xyz="0 0 0.02" rpy="0.3 0 0"/><geometry><sphere radius="0.01"/></geometry></visual></link>
  <joint name="j_turn" type="revolute"><parent link="base"/><child link="turn"/>
    <origin xyz="0 0 0.1" rpy="0.1 0.2 0.3"/><axis xyz="0 0 1"/><limit lower="-2" upper="2" effort="1" velocity="1"/>
  </joint>
  <joint name="j_spin" type="continuous"><parent link="turn"/><child link="spin"/>
    <origin xyz="0.2 0 0" rpy="0 0.5 0"/><axis xyz="0 1 1"/></joint>
  <joint name="j_slide" type="prismatic"><parent link="spin"/><child link="slide"/>
    <origin xyz="0 0.1 0" rpy="0 0 -0.4"/><axis xyz="1 0 0"/><limit lower="0" upper="0.3" effort="1" velocity="1"/>
  </joint>
  <joint name="j_twin" type="revolute"><parent link="slide"/><child link="twin"/>
    <origin xyz="0 0 0.05"/><axis xyz="1 0 0"/><limit lower="-2" upper="2" effort="1" velocity="1"/>
    <mimic joint="j_turn" multiplier="-0.5" offset="0.2"/></joint>
  <joint name="j_tool" type="fixed"><parent link="twin"/><child link="tool"/>
    <origin xyz="0.03 0 0" rpy="0 0 1"/></joint>
</robot>"""


def test_every_link_is_where_yourdfpys_kinematics_put_it(viser_server: viser.ViserServer) -> None:
    model = yourdfpy.URDF.load(io.StringIO(URDF))
    urdf = yourdfpy.URDF.load(io.StringIO(URDF), build_scene_graph=False, load_meshes=False)
    viser_server.scene.add_frame("/copy", show_axes=False)
    copy = RobotCopy(viser_server, urdf, "/copy")
    assert copy.joint_names == ["j_turn", "j_spin", "j_slide"]  # the mimic joint follows j_turn
    assert set(copy.links) == {"base", "turn", "spin", "slide", "twin", "tool"}
    assert copy.links["tool"] == "/copy/visual/turn/spin/slide/twin/tool"
    visuals, failed = link_visuals(urdf, Path("."))
    assert not failed
    added = copy.add_visuals(visuals, "body")
    rng = np.random.default_rng(3)
    for cfg in [np.zeros(3), *(rng.uniform([-2, -6, 0], [2, 6, 0.3]) for _ in range(5))]:
        copy.update_cfg(cfg)
        model.update_cfg(cfg)
        np.testing.assert_array_equal(copy.cfg, cfg)
        for link, node in copy.links.items():
            want = model.get_transform(frame_to=link, frame_from="base")
            np.testing.assert_allclose(node_pose(viser_server, node, "/copy/visual"), want, atol=1e-6, err_msg=link)
        sphere = next(name for name, v in added.items() if v.link == "tool")
        want = model.get_transform(frame_to="tool", frame_from="base") @ added[sphere].T_link_visual
        np.testing.assert_allclose(node_pose(viser_server, sphere, "/copy/visual"), want, atol=1e-6)


def test_a_step_sends_only_the_joints_that_moved(viser_server: viser.ViserServer) -> None:
    """Turning j_slide alone re-sends the slide frame's position and nothing else; the fixed tool joint and the
    unmoved joints' frames are never sent again."""
    urdf = yourdfpy.URDF.load(io.StringIO(URDF), build_scene_graph=False, load_meshes=False)
    viser_server.scene.add_frame("/copy", show_axes=False)
    copy = RobotCopy(viser_server, urdf, "/copy")
    copy.update_cfg(np.array([0.4, 1.0, 0.1]))
    handles = {link: viser_server.scene.get_handle_by_name(node) for link, node in copy.links.items()}
    before = {link: (tuple(h.wxyz), tuple(h.position)) for link, h in handles.items()}
    sent: list[tuple[str, str]] = []
    # Record every pose assignment through the handles' class: what a frame step sends to the browsers.
    cls = type(handles["slide"])
    names = {id(h): link for link, h in handles.items()}
    saved = {prop: getattr(cls, prop) for prop in ("wxyz", "position")}

    def recorder(prop: str) -> property:
        def setter(self, value: object) -> None:
            sent.append((names.get(id(self), "?"), prop))
            saved[prop].fset(self, value)

        return property(saved[prop].fget, setter)

    try:
        for prop in saved:
            setattr(cls, prop, recorder(prop))
        copy.update_cfg(np.array([0.4, 1.0, 0.25]))
        copy.update_cfg(np.array([0.4, 1.0, 0.25]))  # the same again: nothing to send
    finally:
        for prop, original in saved.items():
            setattr(cls, prop, original)
    assert sent == [("slide", "position")]
    after = {link: (tuple(h.wxyz), tuple(h.position)) for link, h in handles.items()}
    assert [link for link in handles if after[link] != before[link]] == ["slide"]


def test_a_urdf_with_two_root_links_is_refused_by_name(viser_server: viser.ViserServer) -> None:
    text = '<robot name="two"><link name="a"/><link name="b"/></robot>'
    urdf = yourdfpy.URDF.load(io.StringIO(text), build_scene_graph=False, load_meshes=False)
    with pytest.raises(ValueError, match=r"the URDF 'two' has 2 root links \(a, b\)"):
        RobotCopy(viser_server, urdf, "/copy")
