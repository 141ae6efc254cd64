"""The observations format: any dataset of a profile as one CSV, every sensor's observations in it.

The pinned formats (specs/robonaut-a.md, specs/nao.md, specs/motoman.md) hold one kind of measurement
each. A session with several sensors (the Motoman's tracker and two cameras looking at one pose) is
written in this long format instead, one row per observation:

    frame,sensor,target,vertex,m0,m1,m2,point_x,point_y,point_z,<joint>,<joint>,...

- `sensor` and `target` by name; `vertex` the grid vertex or marker point (-1: none);
- `m0 m1 m2` the measurement in its sensor's unit (the profile's length unit, or px), as many as the
  sensor measures (the rest empty); a profile with a 6-D pose sensor (pose6d) adds `m3 m4 m5` after
  `m2`: a pose is its position and its rotation vector in rad;
- `point_*` the observed point in the target frame, profile length unit (empty: the target's own);
- one column per joint of the profile, the reading in deg (empty where the observation does not need it).
"""

from __future__ import annotations

import csv
import io
import math

import numpy as np

from ..dataset import Dataset
from ..model.profile import Profile
from .rows import Row, require_columns, table

MEASURES = ("m0", "m1", "m2")
POSE_MEASURES = ("m3", "m4", "m5")  # only in the file of a profile with a sensor of six numbers
POINT = ("point_x", "point_y", "point_z")


def to_observations_csv(profile: Profile, data: Dataset) -> str:
    """The dataset in the observations format (joint readings in deg)."""
    out = io.StringIO()
    w = csv.writer(out, lineterminator="\n")
    measures = _measures(profile)
    w.writerow(["frame", "sensor", "target", "vertex", *measures, *POINT, *profile.joint_names])
    for m in range(data.n_observations):
        sensor = profile.sensors[int(data.sensor[m])]
        c = int(data.cfg[m])
        measured = [_num(v) for v in data.measured[m, : sensor.dim]] + [""] * (len(measures) - sensor.dim)
        joints = [_num(math.degrees(v)) for v in data.joints[c]]
        point = [_num(v) for v in data.point[m]]
        target = profile.targets[int(data.target[m])].name
        w.writerow([int(data.frame_ids[c]), sensor.name, target, int(data.vertex[m]), *measured, *point, *joints])
    return out.getvalue()


def parse_observations(profile: Profile, text: str, name: str = "<observations>") -> Dataset:
    """A dataset from the observations format; InputError naming file, line and column."""
    header_line, header, body = table(text, name)
    col = {h: i for i, h in enumerate(header)}
    measures = _measures(profile)
    required = ("frame", "sensor", "target", "vertex", *measures, *POINT, *profile.joint_names)
    require_columns(profile.name, required, col, name, header_line)
    sensors = {s.name: i for i, s in enumerate(profile.sensors)}
    targets = {t.name: i for i, t in enumerate(profile.targets)}
    frames: dict[int, int] = {}
    joints: list[np.ndarray] = []
    obs: dict[str, list] = {k: [] for k in ("cfg", "sensor", "target", "vertex", "measured", "point", "line")}
    for ln, fields in body:
        row = Row(name, ln, fields, col)
        s, t = row.choice("sensor", sensors), row.choice("target", targets)
        fid = row.number("frame")
        if fid != int(fid):
            raise row.fail(f"frame id {fid} is not an integer", "frame")
        q = np.radians([row.number(j, optional=True) for j in profile.joint_names])
        missing = [profile.joints[j].name for j in profile.joints_between(t, s) if np.isnan(q[j])]
        if missing:
            raise row.fail("is empty, but the observation needs it", missing[0])
        k = frames.setdefault(int(fid), len(frames))
        if k == len(joints):
            joints.append(q)
        else:
            joints[k] = np.where(np.isnan(joints[k]), q, joints[k])
        vertex = row.number("vertex")
        if vertex != int(vertex) or not -1 <= vertex < _points_of(profile, t):
            raise row.fail(f"vertex {vertex:g} is not a point of {profile.targets[t].name}", "vertex")
        dim = profile.sensors[s].dim
        obs["cfg"].append(k)
        obs["sensor"].append(s)
        obs["target"].append(t)
        obs["vertex"].append(int(vertex))
        obs["measured"].append([row.number(c) for c in measures[:dim]] + [math.nan] * (len(measures) - dim))
        obs["point"].append([row.number(c, optional=True) for c in POINT])
        obs["line"].append(ln)
    width = max(profile.sensors[s].dim for s in set(obs["sensor"]))
    return Dataset(
        robot=profile.name,
        frame_ids=np.array(list(frames), dtype=int),
        joints=np.array(joints),
        cfg=np.array(obs["cfg"], dtype=int),
        target=np.array(obs["target"], dtype=int),
        point=np.array(obs["point"], dtype=float),
        vertex=np.array(obs["vertex"], dtype=int),
        measured=np.array(obs["measured"], dtype=float)[:, :width],
        sensor=np.array(obs["sensor"], dtype=int),
        source=name,
        lines=np.array(obs["line"], dtype=int),
    )


def _measures(profile: Profile) -> tuple[str, ...]:
    """The measurement columns of the profile's file: m0 m1 m2, and m3 m4 m5 when a sensor measures six."""
    return MEASURES + (POSE_MEASURES if max(s.dim for s in profile.sensors) > len(MEASURES) else ())


def _points_of(profile: Profile, target: int) -> int:
    """How many points a target has that a vertex can name (a grid's vertices, fixed points)."""
    t = profile.targets[target]
    return len(t.grid) if t.grid is not None else len(t.points) if t.points is not None else 0


def _num(v: float) -> str:
    return "" if not math.isfinite(v) else f"{v:.12g}"
