"""The nodes a review scene made in viser, by name. viser has no public listing of a scene's nodes, so the scene
keeps its own registry, with what each points or segments node really holds (an empty one keeps one placeholder
point: viser needs one), and reports it through `state()`."""

from __future__ import annotations

from typing import Any

import numpy as np
import viser

from ..framing import Target


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

    def state(self) -> dict[str, dict[str, Any]]:
        """{name: {kind ("frame", "points", "rings", "lines", "label"), visible, shown, position, wxyz, and color +
        points / segments of what it really holds, or text}}."""
        return {name: self._node_state(name, h) for name, h in self._handles.items()}

    def _node_state(self, name: str, h: viser.SceneNodeHandle) -> dict[str, Any]:
        out: dict[str, Any] = {
            "visible": bool(h.visible),
            "shown": self.shown(name),
            "position": [float(v) for v in h.position],
            "wxyz": [float(v) for v in h.wxyz],
        }
        if name in self.centres:  # a group's measurement rings: their centres
            held = self.centres[name][: self.counts[name]].tolist()
            out |= {"kind": "rings", "color": [int(v) for v in np.asarray(h.colors).reshape(-1, 3)[0]], "points": held}
        elif isinstance(h, viser.PointCloudHandle | viser.LineSegmentsHandle):
            kind, key = ("points", "points") if isinstance(h, viser.PointCloudHandle) else ("lines", "segments")
            held = h.points[: self.counts[name]].astype(float).tolist()
            out |= {"kind": kind, "color": [int(v) for v in np.asarray(h.colors).reshape(-1, 3)[0]], key: held}
        elif isinstance(h, viser.LabelHandle):
            out |= {"kind": "label", "text": h.text}
        else:
            out |= {"kind": "frame"}
        return out
