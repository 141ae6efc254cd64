"""A dataset: configurations (joint readings) and what the sensors measured in each.

One observation is one measured point (a 3-D point, a pixel, a distance) by one sensor. Observations
of one configuration share its joint readings, whichever sensor made them: a session's two cameras
and a laser tracker looking at one pose are one configuration with observations of three sensors.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np

# The per-observation arrays (M, ...), in the order of the fields.
_PER_OBSERVATION = ("cfg", "target", "point", "vertex", "measured", "sensor")


@dataclass
class Dataset:
    """Joint readings in rad; points and measurements in internal units (the profile's length unit,
    px). `measured` has as many columns as the largest dimension of its sensors; an observation of a
    sensor with fewer (a pixel among 3-D points) has NaN in the rest."""

    robot: str
    frame_ids: np.ndarray  # (N,) int: one per configuration
    joints: np.ndarray  # (N, n_joints) rad; NaN where a row did not need the joint
    cfg: np.ndarray  # (M,) index of each observation's configuration
    target: np.ndarray  # (M,) target index
    point: np.ndarray  # (M, 3) observed point in the target frame; NaN: the target's own point
    vertex: np.ndarray  # (M,) vertex id or -1
    measured: np.ndarray  # (M, dim)
    sensor: np.ndarray  # (M,) the index of each observation's sensor in the profile
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

    @property
    def sensors(self) -> list[int]:
        """The sensors that made observations, in the profile's order."""
        return np.unique(self.sensor).tolist()

    def select(self, configurations: np.ndarray) -> Dataset:
        """The observations of the given configuration indices (a bool mask or index array)."""
        keep = np.zeros(self.n_configurations, bool)
        keep[configurations] = True
        new_index = np.cumsum(keep) - 1
        out = self._subset(keep[self.cfg])
        return replace(out, frame_ids=self.frame_ids[keep], joints=self.joints[keep], cfg=new_index[out.cfg])

    def observations(self, keep: np.ndarray) -> Dataset:
        """The observations of a bool mask, with the configurations they belong to."""
        cfgs = np.unique(self.cfg[keep])
        out = self.select(cfgs)
        return out._subset(keep[np.isin(self.cfg, cfgs)])

    def of_sensor(self, sensor: int) -> Dataset:
        """The observations of one sensor."""
        return self.observations(self.sensor == sensor)

    def _subset(self, obs: np.ndarray) -> Dataset:
        """The observations of a bool mask; configurations as they are."""
        arrays = {name: getattr(self, name)[obs] for name in _PER_OBSERVATION}
        return replace(
            self,
            **arrays,
            lines=None if self.lines is None else self.lines[obs],
            rows=[r for r, k in zip(self.rows, obs, strict=True) if k] if self.rows else [],
        )


def merge(datasets: list[Dataset]) -> Dataset:
    """Datasets of one robot, as one: configurations with the same frame id are one configuration
    (their joint readings, NaN where a dataset did not need a joint, filled from each other)."""
    first = datasets[0]
    frame_ids = np.unique(np.concatenate([d.frame_ids for d in datasets]))
    position = {int(f): k for k, f in enumerate(frame_ids)}
    joints = np.full((len(frame_ids), first.joints.shape[1]), np.nan)
    width = max(d.measured.shape[1] for d in datasets)
    parts: dict[str, list[np.ndarray]] = {name: [] for name in _PER_OBSERVATION}
    for d in datasets:
        rows = np.array([position[int(f)] for f in d.frame_ids], dtype=int)
        joints[rows] = np.where(np.isnan(joints[rows]), d.joints, joints[rows])
        for name in _PER_OBSERVATION:
            value = getattr(d, name)
            if name == "cfg":
                value = rows[value]
            elif name == "measured" and value.shape[1] < width:
                value = np.hstack([value, np.full((len(value), width - value.shape[1]), np.nan)])
            parts[name].append(value)
    merged = {name: np.concatenate(v) for name, v in parts.items()}
    order = np.argsort(merged["cfg"], kind="stable")
    return Dataset(
        robot=first.robot,
        frame_ids=frame_ids,
        joints=joints,
        **{name: v[order] for name, v in merged.items()},
        source=" + ".join(dict.fromkeys(d.source for d in datasets)),
    )
