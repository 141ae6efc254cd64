"""What a browser gets of the scene: a node's pose composed from the viser handles above it."""

from __future__ import annotations

import numpy as np
import viser


def node_pose(server: viser.ViserServer, name: str, below: str) -> np.ndarray:
    """T_below_name: the product of the node poses from `below` (exclusive) down to `name`."""
    T = np.eye(4)
    parts = name.split("/")
    for k in range(len(below.split("/")) + 1, len(parts) + 1):
        handle = server.scene.get_handle_by_name("/".join(parts[:k]))
        assert handle is not None, "/".join(parts[:k])
        step = np.eye(4)
        step[:3, :3] = viser.transforms.SO3(np.asarray(handle.wxyz, float)).as_matrix()
        step[:3, 3] = handle.position
        T = T @ step
    return T
