"""One copy of a robot in viser, drawn from a URDF: a frame per link, nested as the kinematic tree, and the links'
visuals under their frames. Posing the copy re-sends only the frames of the joints that moved.

viser's ViserUrdf does the same drawing, but its update_cfg recomputes every joint through yourdfpy's scene
graph and sends a pose for each one, fixed joints too. For NAO that was 88% of a review frame step in the
server (14 moving joints of 20, on two copies). Here the tree is read once. A revolute joint's frame only
turns, so a step sends one rotation per revolute joint that moved, computed with numpy for all of them at once.
A prismatic joint's frame only shifts, so it sends one position.

Nodes are named as ViserUrdf names them: `ROOT/visual` is the root link, and below it each link is named by the
links from the root's child down to it (`ROOT/visual/torso/head`). A visual hangs under its link's frame.
Revolute, continuous and prismatic joints move; a mimic joint follows its joint (multiplier, offset); any
other type is drawn fixed at its origin.
"""

from __future__ import annotations

from collections.abc import Iterable
from typing import TYPE_CHECKING

import numpy as np
import viser

from .framing import Target
from .robot_look import LinkVisual

if TYPE_CHECKING:
    import yourdfpy

MOVING = ("revolute", "continuous", "prismatic")


class RobotCopy:
    def __init__(self, target: Target, urdf: yourdfpy.URDF, root: str) -> None:
        """Every link frame of `urdf` under node `root` (which must exist), at the joints' zero; no visuals yet."""
        self.target = target
        self.joint_names = [j.name for j in urdf.robot.joints if j.type in MOVING and j.mimic is None]
        self.cfg = np.zeros(len(self.joint_names))  # rad, a prismatic joint's in m
        parent = {j.child: j for j in urdf.robot.joints}
        roots = [link.name for link in urdf.robot.links if link.name not in parent]
        if len(roots) != 1:
            raise ValueError(f"the URDF '{urdf.robot.name}' has {len(roots)} root links ({', '.join(roots)}): one")
        self.links: dict[str, str] = {roots[0]: f"{root}/visual"}
        target.scene.add_frame(self.links[roots[0]], show_axes=False)
        children: dict[str, list[yourdfpy.Joint]] = {}
        for joint in urdf.robot.joints:
            children.setdefault(joint.parent, []).append(joint)
        moving: list[tuple[yourdfpy.Joint, viser.FrameHandle]] = []
        todo = [roots[0]]
        while todo:  # parents before children: viser makes a node's parent when it is missing
            link = todo.pop()
            for joint in children.get(link, []):
                T = np.eye(4) if joint.origin is None else np.asarray(joint.origin, float)
                name = f"{self.links[link]}/{joint.child}"
                self.links[joint.child] = name
                frame = self.target.scene.add_frame(
                    name, show_axes=False, wxyz=quaternion(T[:3, :3]), position=tuple(float(v) for v in T[:3, 3])
                )
                if joint.type in MOVING:
                    moving.append((joint, frame))
                todo.append(joint.child)
        self._frames = [frame for _, frame in moving]
        index = {name: k for k, name in enumerate(self.joint_names)}
        source = [index[j.name if j.mimic is None else j.mimic.joint] for j, _ in moving]
        self._source = np.array(source, int)
        self._multiplier = np.array([1.0 if j.mimic is None else (j.mimic.multiplier or 1.0) for j, _ in moving])
        self._offset = np.array([0.0 if j.mimic is None else (j.mimic.offset or 0.0) for j, _ in moving])
        self._prismatic = np.array([j.type == "prismatic" for j, _ in moving], bool)
        axes = np.array([_axis(j) for j, _ in moving]).reshape(-1, 3)
        origins = [np.eye(4) if j.origin is None else np.asarray(j.origin, float) for j, _ in moving]
        self._axis = axes
        self._origin_wxyz = np.array([quaternion(T[:3, :3]) for T in origins]).reshape(-1, 4)
        self._origin_t = np.array([T[:3, 3] for T in origins]).reshape(-1, 3)
        self._shift = np.einsum("kij,kj->ki", np.array([T[:3, :3] for T in origins]).reshape(-1, 3, 3), axes)
        self._sent = np.zeros(len(moving))  # each moving joint's value as its frame shows it

    def add_visuals(
        self, visuals: Iterable[LinkVisual], prefix: str, rgba: tuple[float, ...] | None = None
    ) -> dict[str, LinkVisual]:
        """Each visual under its link's frame (sent once; it moves with the link), named PREFIX<k>; `rgba`: the
        copy's colour instead of the visuals' own. A visual of a link the URDF does not have is left out."""
        added: dict[str, LinkVisual] = {}
        for k, visual in enumerate(visuals):
            link = self.links.get(visual.link)
            if link is None:
                continue
            color = tuple(visual.rgb) if rgba is None else tuple(rgba[:3])
            opacity = visual.opacity if rgba is None else rgba[3]
            name = f"{link}/{prefix}{k}"
            self.target.scene.add_mesh_simple(
                name,
                visual.vertices,
                visual.faces,
                color=color,  # type: ignore[arg-type]
                opacity=None if opacity >= 1.0 else float(opacity),
                wxyz=quaternion(visual.T_link_visual[:3, :3]),
                position=tuple(float(v) for v in visual.T_link_visual[:3, 3]),
            )
            added[name] = visual
        return added

    def update_cfg(self, cfg: np.ndarray) -> None:
        """Pose the copy: `cfg` holds the value of each of `joint_names` (rad, a prismatic joint's in m)."""
        cfg = np.asarray(cfg, float).reshape(len(self.joint_names))
        self.cfg = cfg.copy()
        value = self._multiplier * cfg[self._source] + self._offset if len(self._source) else np.zeros(0)
        changed = np.flatnonzero(np.abs(value - self._sent) > 1e-12)
        if not len(changed):
            return
        half = value[changed] / 2
        turn = np.concatenate([np.cos(half)[:, None], np.sin(half)[:, None] * self._axis[changed]], axis=1)
        wxyz = _multiply(self._origin_wxyz[changed], turn)
        position = self._origin_t[changed] + self._shift[changed] * value[changed, None]
        for k, q, t in zip(changed, wxyz, position, strict=True):
            if self._prismatic[k]:
                self._frames[k].position = (float(t[0]), float(t[1]), float(t[2]))
            else:
                self._frames[k].wxyz = (float(q[0]), float(q[1]), float(q[2]), float(q[3]))
        self._sent[changed] = value[changed]


def _axis(joint: yourdfpy.Joint) -> np.ndarray:
    axis = np.array([1.0, 0.0, 0.0]) if joint.axis is None else np.asarray(joint.axis, float)
    return axis / np.linalg.norm(axis)


def _multiply(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Hamilton products of (N, 4) wxyz quaternions."""
    w1, x1, y1, z1 = a.T
    w2, x2, y2, z2 = b.T
    return np.stack(
        [
            w1 * w2 - x1 * x2 - y1 * y2 - z1 * z2,
            w1 * x2 + x1 * w2 + y1 * z2 - z1 * y2,
            w1 * y2 - x1 * z2 + y1 * w2 + z1 * x2,
            w1 * z2 + x1 * y2 - y1 * x2 + z1 * w2,
        ],
        axis=1,
    )


def quaternion(R: np.ndarray) -> tuple[float, float, float, float]:
    """A rotation matrix's wxyz quaternion, as viser takes it."""
    w, x, y, z = (float(v) for v in viser.transforms.SO3.from_matrix(R).wxyz)
    return w, x, y, z
