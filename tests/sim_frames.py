"""Frames without a store, for the review and scene tests and the scene benchmark: the attributes of
app.store.FrameInfo a review uses, made from a simulated session."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from calib_core import Dataset, SimulatedRobot


@dataclass
class Frame:
    """The attributes of app.store.FrameInfo a review uses."""

    index: int
    joints_rad: np.ndarray
    target: int
    status: str


def measured_frames(data: Dataset) -> list[Frame]:
    """A measured frame per configuration of `data` (the target of its first observation)."""
    _, first = np.unique(data.cfg, return_index=True)
    return [
        Frame(int(data.frame_ids[c]), data.joints[c], int(data.target[first[c]]), "measured")
        for c in range(data.n_configurations)
    ]


def unmeasured_frames(robot: SimulatedRobot, first: int, n: int) -> list[Frame]:
    """n frames numbered from `first` at new configurations of `robot`, whose detector found nothing."""
    if n == 0:
        return []
    q, targets = robot.configurations(n)
    return [Frame(first + k, robot.readings(q[k]), int(targets[k]), "not found") for k in range(n)]
