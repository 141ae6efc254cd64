"""The nodes a review scene made in viser, by name. viser has no public listing of a scene's nodes, so the scene
keeps its own registry, with what each points or segments node really holds (an empty one keeps one placeholder
point: viser needs one), and reports it through `state()`."""

from __future__ import annotations

from typing import Literal, NotRequired, TypedDict

import numpy as np
import viser

from ..framing import Target


class NodeState(TypedDict):
    """A node as `Nodes.state` reports it: what every node has, and what its kind holds (color and points of
    "points" and "rings", color and segments of "lines", text of "label")."""

    visible: bool
    shown: bool  # it and its ancestors visible
    position: list[float]
    wxyz: list[float]  # relative to its parent
    kind: Literal["frame", "points", "rings", "lines", "label"]
    color: NotRequired[list[int]]
    points: NotRequired[list[list[float]]]  # (N, 3)
    segments: NotRequired[list[list[list[float]]]]  # (N, 2, 3)
    text: NotRequired[str]


class Nodes:
    def __init__(self, target: Target) -> None:
        self.target = target
        self._handles: dict[str, viser.SceneNodeHandle] = {}
        self.counts: dict[str, int] = {}  # points or segments node -> how many it really holds
        self.centres: dict[str, np.ndarray] = {}  # a group's rings node -> the measurements it rings

    def __contains__(self, name: str) -> bool:
        return name in self._handles

    def __getitem__(self, name: str) -> viser.SceneNodeHandle:
        return self._handles[name]

    def __setitem__(self, name: str, handle: viser.SceneNodeHandle) -> None:
        self._handles[name] = handle

    def frame(self, name: str, *, wxyz: tuple[float, ...] = (1.0, 0.0, 0.0, 0.0), visible: bool = True) -> None:
        if name in self._handles:
            self._handles[name].wxyz = wxyz  # type: ignore[assignment]
            return
        self._handles[name] = self.target.scene.add_frame(name, show_axes=False, wxyz=wxyz, visible=visible)

    def label(self, name: str, text: str, position: tuple[float, float, float]) -> None:
        if name not in self._handles:
            self._handles[name] = self.target.scene.add_label(name, text, anchor="bottom-center")
        self._handles[name].text = text  # type: ignore[attr-defined]
        self._handles[name].position = position

    def shown(self, name: str) -> bool:
        """The node and its ancestors are visible."""
        parts = name.split("/")
        return all(
            self._handles[p].visible for k in range(2, len(parts) + 1) if (p := "/".join(parts[:k])) in self._handles
        )

    def state(self) -> dict[str, NodeState]:
        """{name: {kind ("frame", "points", "rings", "lines", "label"), visible, shown, position, wxyz, and color +
        points / segments of what it really holds, or text}}."""
        return {name: self._node_state(name, h) for name, h in self._handles.items()}

    def _node_state(self, name: str, h: viser.SceneNodeHandle) -> NodeState:
        out: NodeState = {
            "visible": bool(h.visible),
            "shown": self.shown(name),
            "position": [float(v) for v in h.position],
            "wxyz": [float(v) for v in h.wxyz],
            "kind": "frame",
        }
        if name in self.centres:  # a group's measurement rings: their centres
            out["kind"], out["color"] = "rings", _color(h)
            out["points"] = self.centres[name][: self.counts[name]].tolist()
        elif isinstance(h, viser.PointCloudHandle):
            out["kind"], out["color"] = "points", _color(h)
            out["points"] = h.points[: self.counts[name]].astype(float).tolist()
        elif isinstance(h, viser.LineSegmentsHandle):
            out["kind"], out["color"] = "lines", _color(h)
            out["segments"] = h.points[: self.counts[name]].astype(float).tolist()
        elif isinstance(h, viser.LabelHandle):
            out["kind"], out["text"] = "label", h.text
        return out


def _color(h: viser.SceneNodeHandle) -> list[int]:
    """The colour of a points, rings or lines node, as its first point has it."""
    return [int(v) for v in np.asarray(h.colors).reshape(-1, 3)[0]]
