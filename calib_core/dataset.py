"""A dataset: configurations (joint readings) and what one sensor measured in each.

One observation is one measured point (a 3-D point, a pixel, a distance). Observations of one
configuration share its joint readings; frame ids tie configurations across the datasets of several
sensors captured together (a session's cameras and tracker).
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np


@dataclass
class Dataset:
    """Observations of one sensor. Joint readings in rad; points and measurements in internal units."""

    robot: str
    frame_ids: np.ndarray  # (N,) int: one per configuration
    joints: np.ndarray  # (N, n_joints) rad; NaN where a row did not need the joint
    cfg: np.ndarray  # (M,) index of each observation's configuration
    target: np.ndarray  # (M,) target index
    point: np.ndarray  # (M, 3) observed point in the target frame; NaN: the target's own point
    vertex: np.ndarray  # (M,) vertex id or -1
    measured: np.ndarray  # (M, dim)
    source: str = "<memory>"
    lines: np.ndarray | None = None  # (M,) CSV line of each observation
    header: list[str] = field(default_factory=list)
    rows: list[list[str]] = field(default_factory=list)  # the raw rows, for `predict`

    @property
    def n_configurations(self) -> int:
        return len(self.frame_ids)

    @property
    def n_observations(self) -> int:
        return len(self.cfg)

    def select(self, configurations: np.ndarray) -> Dataset:
        """The observations of the given configuration indices (a bool mask or index array)."""
        keep = np.zeros(self.n_configurations, bool)
        keep[configurations] = True
        new_index = np.cumsum(keep) - 1
        obs = keep[self.cfg]
        return replace(
            self,
            frame_ids=self.frame_ids[keep],
            joints=self.joints[keep],
            cfg=new_index[self.cfg[obs]],
            target=self.target[obs],
            point=self.point[obs],
            vertex=self.vertex[obs],
            measured=self.measured[obs],
            lines=None if self.lines is None else self.lines[obs],
            rows=[r for r, k in zip(self.rows, obs, strict=False) if k] if self.rows else [],
        )

    def observations(self, keep: np.ndarray) -> Dataset:
        """The observations of a bool mask, with the configurations they belong to."""
        cfgs = np.unique(self.cfg[keep])
        out = self.select(cfgs)
        inner = keep[np.isin(self.cfg, cfgs)]
        return replace(
            out,
            cfg=out.cfg[inner],
            target=out.target[inner],
            point=out.point[inner],
            vertex=out.vertex[inner],
            measured=out.measured[inner],
            lines=None if out.lines is None else out.lines[inner],
            rows=[r for r, k in zip(out.rows, inner, strict=True) if k] if out.rows else [],
        )
