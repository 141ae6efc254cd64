"""The CSV formats of a profile's `data` section (specs/robonaut-a.md, specs/nao.md, specs/motoman.md):
reading a file into a Dataset and writing one back.

One CSV row is one observation. Rows with the same frame id share one configuration; a format
without a frame column (the Motoman tracker files) makes every row a configuration of its own. A
format may name each row's sensor in a column (several cameras, several planes of one kind). Every
problem with a file is reported as an InputError naming the file, the line and the column.
"""

from __future__ import annotations

import csv
import io
from pathlib import Path

import numpy as np

from ..dataset import Dataset
from ..errors import InputError
from ..files import read_text_file
from ..model.profile import DataFormat, Marker, Profile
from ..sensors.pose6d import pose_from_columns, pose_to_columns
from ..units import ANGLE_IN_RAD, length_factor
from .rows import Row, require_columns, table

MAX_CSV_BYTES = 512 * 1024 * 1024  # the largest CSV read from a file (100,000 rows are about 10 MB)


def read_dataset(profile: Profile, path: str | Path) -> Dataset:
    """Read a CSV in the profile's data format. Raises InputError naming file, line and column."""
    return parse_dataset(profile, read_text_file(path, MAX_CSV_BYTES, "CSV file"), str(path))


def _required(fmt: DataFormat, col: dict[str, int]) -> list[str]:
    out = [*fmt.measurement_columns, *(c for m in fmt.markers for c in m.columns), *fmt.joint_columns.values()]
    optional = [
        fmt.frame_column,
        _target_column(fmt, col),
        fmt.sensor_column,
        fmt.vertex_column,
        *(fmt.point_columns or ()),
    ]
    return out + [c for c in optional if c]


def _target_column(fmt: DataFormat, col: dict[str, int]) -> str | None:
    """The column that picks each row's target: absent from the file is fine when there is a default."""
    return fmt.target_column if fmt.target_column in col or fmt.target_default is None else None


def joint_factors(profile: Profile) -> np.ndarray:
    """Per joint, what turns a reading in the CSV into internal units: the format's joint_unit to rad,
    or (prismatic joints) its joint_length_unit to the profile's length unit."""
    fmt = profile.data
    lengths = length_factor(fmt.joint_length_unit or profile.length_unit, profile.length_unit)
    return np.array([lengths if j.prismatic else ANGLE_IN_RAD[fmt.joint_unit] for j in profile.joints])


def parse_dataset(profile: Profile, text: str, name: str = "<data>") -> Dataset:
    fmt = profile.data
    header_line, header, body = table(text, name)
    col = {h: i for i, h in enumerate(header)}
    require_columns(profile.name, _required(fmt, col), col, name, header_line)
    target_column = _target_column(fmt, col)
    joint_factor = joint_factors(profile)
    meas_factor = 1.0 if fmt.measurement_unit == "px" else length_factor(fmt.measurement_unit, profile.length_unit)
    point_factor = length_factor(fmt.point_unit, profile.length_unit) if fmt.point_unit else 1.0

    frames = _Frames()
    obs: dict[str, list] = {k: [] for k in ("cfg", "target", "sensor", "point", "vertex", "measured", "line")}
    joint_columns = [(profile.joint(jname), c) for jname, c in fmt.joint_columns.items()]
    needed_by: dict[tuple[int, int], list[tuple[int, str]]] = {}  # (target, sensor): the joint columns it reads
    groups = [Marker(fmt.measurement_columns), *fmt.markers]
    raw: list[list[str]] = []  # each observation's row
    for ln, fields in body:
        row = Row(name, ln, fields, col)
        fid = _frame_id(row, fmt, len(frames.joints) + 1)
        row_target = row.choice(target_column, fmt.target_values) if target_column else fmt.target
        if row_target is None:
            row_target = fmt.target_default
        row_sensor = row.choice(fmt.sensor_column, fmt.sensor_values) if fmt.sensor_column else fmt.sensor
        assert row_target is not None  # the loader requires a target, a target column or a default
        seen = []  # (group, target, sensor, vertex, measured) of each measurement the row has
        for g, group in enumerate(groups):
            measured = _measurement(row, fmt, group.columns, meas_factor, optional=bool(fmt.markers))
            if measured is None:
                continue
            ti = row_target if group.target is None else group.target
            si = row_sensor if group.sensor is None else group.sensor
            vertex = _vertex(row, fmt, profile, ti) if group.vertex is None else _fixed_vertex(row, group, profile, ti)
            seen.append((g, ti, si, vertex, measured))
        if not seen:
            raise row.fail("measures nothing: the columns of every marker are empty", fmt.measurement_columns[0])
        q = np.full(len(profile.joints), np.nan)
        for _, ti, si, _, _ in seen:
            if (ti, si) not in needed_by:
                needed = profile.joints_between(ti, si)
                needed_by[ti, si] = [(j, c) for j, c in joint_columns if j in needed]
            for j, c in needed_by[ti, si]:
                q[j] = row.number(c) * joint_factor[j]
        cfg = frames.add(fid, q, row)
        for g, ti, si, vertex, measured in seen:
            if fmt.point_columns and g == 0:
                point = [row.number(c) * point_factor for c in fmt.point_columns]
            else:
                fixed = profile.targets[ti].points
                point = [np.nan] * 3 if fixed is None else fixed[max(vertex, 0)]
            obs["cfg"].append(cfg)
            obs["target"].append(ti)
            obs["sensor"].append(si)
            obs["point"].append(point)
            obs["vertex"].append(vertex)
            obs["measured"].append(measured)
            obs["line"].append(ln)
            raw.append(fields)
    joints = np.array(frames.joints).reshape(-1, len(profile.joints))
    check_joint_unit(profile, joints, name, list(frames.first_line.values()))
    return Dataset(
        robot=profile.name,
        frame_ids=np.array(list(frames.index), dtype=int),
        joints=np.array(frames.joints),
        cfg=np.array(obs["cfg"], dtype=int),
        target=np.array(obs["target"], dtype=int),
        point=np.array(obs["point"], dtype=float),
        vertex=np.array(obs["vertex"], dtype=int),
        measured=np.array(obs["measured"], dtype=float),
        sensor=np.array(obs["sensor"], dtype=int),
        source=name,
        lines=np.array(obs["line"], dtype=int),
        header=header,
        rows=raw,
    )


RADIAN_RANGE = 3.2  # every reading of a radian file is within +-pi
MIN_READINGS = 10  # fewer readings do not tell the units apart
MIN_ROW_READINGS = 3  # a configuration with fewer angle readings does not tell them apart
HOME_DEG = 0.5  # a configuration whose every reading is within this of zero is a home pose in either unit
MIXED_ROWS = 0.05  # configurations in the other unit, as a share of the file, beyond which it is refused
SHOWN_LINES = 10


def check_joint_unit(profile: Profile, q: np.ndarray, name: str, lines: list[int]) -> None:
    """Joint readings in the other angle unit than the profile's `data.joint_unit`, in the whole file or in
    some of its configurations: surely wrong, so refused naming the lines. Only revolute joints are looked
    at: a prismatic joint reads a length (data.joint_length_unit), never an angle.

    Degrees read as radians: a reading beyond 2 pi that is also beyond its joint's limits (no joint
    turns that far). Radians read as degrees: a calibration needs the joints to move by tens of
    degrees, so when at least MIN_READINGS readings all lie within +-3.2 (the radians' +-pi) while
    the joints' limits allow far more, they are radians; and in a file of degrees, configurations whose
    every reading lies within +-3.2, none of them a home pose, are radians pasted in (more than a few of
    them: one such configuration may be a pose near home). `q`: (N, n_joints) in rad, NaN where unread;
    `lines`: each configuration's first line."""
    fmt = profile.data
    factor = ANGLE_IN_RAD[fmt.joint_unit]
    lo, hi = profile.joint_limits()
    columns = {
        profile.joint(j): c for j, c in fmt.joint_columns.items() if not profile.joints[profile.joint(j)].prismatic
    }
    read = [j for j in columns if np.isfinite(q[:, j]).any()] if len(q) else []
    if not read:
        return
    raw = q[:, read] / factor
    if fmt.joint_unit == "rad":
        beyond = (np.abs(raw) > 2 * np.pi) & ((q[:, read] < lo[read]) | (q[:, read] > hi[read]))
        if beyond.any():
            n, k = np.argwhere(beyond)[0]
            raise InputError(
                f"joint readings look like degrees but the profile says joint_unit: rad ({raw[n, k]:g} is beyond "
                f"2 pi and the joint's limits); convert them, or set data.joint_unit: deg in the profile",
                file=name,
                line=lines[n],
                column=columns[read[k]],
            )
    elif fmt.joint_unit == "deg" and np.isfinite(raw).sum() >= MIN_READINGS:
        spans = np.nanmax(raw, axis=0) - np.nanmin(raw, axis=0)
        room = np.degrees(hi[read] - lo[read])
        if room.max() <= 4 * RADIAN_RANGE:
            return  # joints that cannot turn further than radians would: nothing tells the units apart
        if np.nanmax(np.abs(raw)) <= RADIAN_RANGE and spans.max() > 0:
            widest = columns[read[int(np.argmax(spans))]]
            raise InputError(
                f"joint readings look like radians but the profile says joint_unit: deg (every reading within "
                f"+-{RADIAN_RANGE}, where the joints can turn by {room.max():.0f} deg); convert them, or set "
                "data.joint_unit: rad in the profile",
                file=name,
                column=widest,
            )
        _check_rows_in_radians(raw, name, lines)


def _check_rows_in_radians(raw_deg: np.ndarray, name: str, lines: list[int]) -> None:
    """Configurations of a file in degrees that read like radians (see check_joint_unit)."""
    with np.errstate(invalid="ignore"):
        largest = np.nanmax(np.abs(raw_deg), axis=1, initial=0.0)
    counted = np.isfinite(raw_deg).sum(axis=1) >= MIN_ROW_READINGS
    suspect = counted & (largest <= RADIAN_RANGE) & (largest > HOME_DEG)
    n = int(suspect.sum())
    if n < 2 or n <= MIXED_ROWS * int(counted.sum()) or suspect.all():
        return
    shown = [lines[i] for i in np.flatnonzero(suspect)[:SHOWN_LINES]]
    more = f" and {n - len(shown)} more" if n > len(shown) else ""
    raise InputError(
        f"{n} of {int(counted.sum())} configurations read like radians although the profile says joint_unit: deg "
        f"(every reading within +-{RADIAN_RANGE}, while the other configurations reach "
        f"{float(np.max(largest[~suspect])):.0f} deg): lines {', '.join(map(str, shown))}{more}; convert them to "
        "degrees, or leave them out",
        file=name,
    )


class _Frames:
    """The configurations of a file: rows with one frame id share one, and must agree on every joint
    both read (a joint one row does not need is NaN there and filled from another)."""

    def __init__(self) -> None:
        self.index: dict[int, int] = {}  # frame id -> configuration
        self.first_line: dict[int, int] = {}
        self.joints: list[np.ndarray] = []

    def add(self, fid: int, q: np.ndarray, row: Row) -> int:
        if fid not in self.index:
            self.index[fid] = len(self.joints)
            self.first_line[fid] = row.line
            self.joints.append(q)
            return self.index[fid]
        prev = self.joints[self.index[fid]]
        both = ~np.isnan(prev) & ~np.isnan(q)
        if np.any(np.abs(prev[both] - q[both]) > 1e-9):
            raise row.fail(f"frame {fid} has other joint angles than on line {self.first_line[fid]}")
        fill = np.isnan(prev)
        prev[fill] = q[fill]
        return self.index[fid]


def readings_beyond_limits(profile: Profile, data: Dataset, most: int = 5) -> list[str]:
    """Joint readings outside their joint's limits, as notes naming file, line and column (at most `most`,
    then how many more). Not refused: a drifted encoder (what a daily calibration corrects) can read past a
    limit the joint itself never passes; but a profile whose limits or columns are wrong shows here first."""
    if not len(data.frame_ids) or data.lines is None:
        return []
    lo, hi = profile.joint_limits()
    q = data.joints
    with np.errstate(invalid="ignore"):
        beyond = (q < lo - 1e-9) | (q > hi + 1e-9)
    if not beyond.any():
        return []
    _, first = np.unique(data.cfg, return_index=True)  # each configuration's first observation
    columns = {profile.joint(j): c for j, c in profile.data.joint_columns.items()}
    notes = []
    for n, j in np.argwhere(beyond)[:most]:
        joint = profile.joints[j]
        side, limit = ("lower", lo[j]) if q[n, j] < lo[j] else ("upper", hi[j])
        unit = profile.joint_display_unit(j)
        value, limit = profile.joint_to_display(j, q[n, j]), profile.joint_to_display(j, limit)
        notes.append(
            f"{data.source}, line {int(data.lines[first[n]])}, column '{columns.get(j, joint.name)}': "
            f"{joint.name} reads {value:.2f} {unit}, beyond its {side} limit {limit:.2f} {unit}"
        )
    if int(beyond.sum()) > most:
        notes.append(f"{data.source}: {int(beyond.sum()) - most} more readings beyond their joint's limits")
    return notes


def _frame_id(row: Row, fmt: DataFormat, default: int) -> int:
    if not fmt.frame_column:
        return default
    f = row.number(fmt.frame_column)
    if f != int(f):
        raise row.fail(f"frame id {f} is not an integer", fmt.frame_column)
    return int(f)


def _measurement(
    row: Row, fmt: DataFormat, columns: tuple[str, ...], factor: float, optional: bool
) -> list[float] | None:
    """One measurement of the row in internal units (a pose's rotation as a rotation vector in rad); None
    when every one of its columns is empty and that is allowed (a marker the tracker did not see)."""
    if optional and not any(row.text(c) for c in columns):
        return None
    empty = [c for c in columns if not row.text(c)]
    if optional and empty:
        raise row.fail(f"is empty, but {len(columns) - len(empty)} other columns of its measurement are not", empty[0])
    if fmt.rotation is None:
        return [row.number(c) * factor for c in columns]
    values = np.array([row.number(c) for c in columns])
    values[:3] *= factor
    try:
        return pose_from_columns(values[None], fmt.rotation, ANGLE_IN_RAD[fmt.rotation_unit])[0].tolist()
    except ValueError as exc:
        raise row.fail(str(exc), columns[3]) from None


def _fixed_vertex(row: Row, marker: Marker, profile: Profile, target: int) -> int:
    """A marker's own vertex, checked against its target's points."""
    assert marker.vertex is not None
    t = profile.targets[target]
    points = t.grid if t.points is None else t.points
    if points is None or marker.vertex >= len(points):
        raise row.fail(f"the format's marker vertex {marker.vertex} is not a point of {t.name}", marker.columns[0])
    return marker.vertex


def _vertex(row: Row, fmt: DataFormat, profile: Profile, target: int) -> int:
    if not fmt.vertex_column:
        return -1
    v = row.number(fmt.vertex_column)
    t = profile.targets[target]
    grid = t.grid if t.points is None else t.points
    if v != int(v) or v < 0 or (grid is not None and v >= len(grid)):
        raise row.fail(f"vertex {row.text(fmt.vertex_column)} is not a vertex id", fmt.vertex_column)
    return int(v)


def select_rows(data: Dataset, where: dict[str, str]) -> Dataset:
    """The observations whose CSV row has every given column equal to the given value (one tracker
    set-up of a file that holds several, one arm, one source file)."""
    col = {h: i for i, h in enumerate(data.header)}
    for c in where:
        if c not in col:
            raise InputError(f"no column '{c}' to select rows by", file=data.source, column=c)
    keep = np.array([all(row[col[c]].strip() == v for c, v in where.items()) for row in data.rows], bool)
    if not keep.any():
        said = ", ".join(f"{c}={v}" for c, v in where.items())
        raise InputError(f"no row has {said}", file=data.source)
    return data.observations(keep)


def to_csv(profile: Profile, data: Dataset, extra: dict[str, np.ndarray] | None = None) -> str:
    """The dataset in the profile's CSV format (joints in the format's unit), plus extra columns. One row
    per observation: in a format with markers, in the columns of the first measurement (the row's own, or
    a marker's) whose target, vertex and sensor it is, the others' left empty."""
    fmt = profile.data
    names = {v: k for k, v in fmt.sensor_values.items()} if fmt.sensor_column else {fmt.sensor: ""}
    stray = sorted(set(data.sensors) - set(names) - {m.sensor for m in fmt.markers})
    if stray:
        raise InputError(
            f"the {profile.name} CSV format holds observations of {', '.join(profile.sensors[s].name for s in names)}, "
            f"not of {profile.sensors[stray[0]].name}"
        )
    joint_factor = joint_factors(profile)
    point_factor = length_factor(profile.length_unit, fmt.point_unit or profile.length_unit)
    groups = [Marker(fmt.measurement_columns), *fmt.markers]
    extra = extra or {}
    header = [c for c in (fmt.frame_column, fmt.target_column, fmt.sensor_column, fmt.vertex_column) if c]
    header += [*(c for g in groups for c in g.columns), *(fmt.point_columns or ()), *fmt.joint_columns.values(), *extra]
    values = _texts(measurement_values(profile, data.measured[:, : profile.sensors[fmt.sensor].dim]))
    tnames = {v: k for k, v in fmt.target_values.items()}
    # A configuration's joint columns are the same in each of its rows (NAO's 24 corners a stance): written once.
    joints = [profile.joint(name) for name in fmt.joint_columns]
    readings = data.joints[:, joints] / np.array([joint_factor[j] for j in joints])
    joint_texts = _texts(np.where(np.isfinite(readings), readings, 0.0))
    points = _texts(data.point * point_factor) if fmt.point_columns else None
    extras = [_texts(v) for v in extra.values()]
    blanks = [[""] * len(g.columns) for g in groups]
    group_of: dict[tuple[int, int, int], int] = {}
    out = io.StringIO()
    w = csv.writer(out, lineterminator="\n")
    w.writerow(header)
    for m in range(data.n_observations):
        c = data.cfg[m]
        key = (int(data.target[m]), int(data.sensor[m]), int(data.vertex[m]))
        g = group_of.get(key)
        if g is None:
            g = group_of[key] = _group_of(profile, groups, *key)
        row: list[object] = [int(data.frame_ids[c])] if fmt.frame_column else []
        if fmt.target_column:  # read with every row: a marker with a target of its own takes any valid one
            row.append(tnames.get(key[0], next(iter(tnames), "")))
        if fmt.sensor_column:
            row.append(names.get(key[1], next(iter(names.values()))))
        if fmt.vertex_column:
            row.append(key[2])
        for k in range(len(groups)):
            row += values[m] if k == g else blanks[k]
        if points is not None:
            row += points[m]
        row += joint_texts[c]
        row += [texts[m] for texts in extras]
        w.writerow(row)
    return out.getvalue()


def measurement_values(profile: Profile, measured: np.ndarray) -> np.ndarray:
    """Measurements or predictions (M, dim) in internal units as the format's measurement columns give
    them: its length unit, a pose's rotation as the format says (rotation vector, quaternion, roll, pitch,
    yaw) in its angle unit."""
    fmt = profile.data
    factor = 1.0 if fmt.measurement_unit == "px" else length_factor(profile.length_unit, fmt.measurement_unit)
    if fmt.rotation is None:
        return measured * factor
    out = pose_to_columns(measured, fmt.rotation, ANGLE_IN_RAD[fmt.rotation_unit])
    out[:, :3] *= factor
    return out


def _group_of(profile: Profile, groups: list[Marker], target: int, sensor: int, vertex: int) -> int:
    """The first measurement of a row (0: the row's own, k: marker k - 1) an observation can be written in."""
    fmt = profile.data
    for k, g in enumerate(groups):
        targets = {g.target} if g.target is not None else None if fmt.target_column else {fmt.target}
        sensors = {g.sensor} if g.sensor is not None else set(fmt.sensor_values.values()) or {fmt.sensor}
        vertices = {g.vertex} if g.vertex is not None else None if fmt.vertex_column else {-1}
        if (targets is None or target in targets) and sensor in sensors and (vertices is None or vertex in vertices):
            return k
    raise InputError(
        f"the {profile.name} CSV format has no measurement columns for an observation of "
        f"{profile.targets[target].name} (vertex {vertex}) by {profile.sensors[sensor].name}"
    )


def _fmt(v: float) -> str:
    return f"{v:.6f}".rstrip("0").rstrip(".") if v != 0 else "0"


def _texts(values: np.ndarray) -> list:
    """`_fmt` of every value of an array, nested as the array is (a list of lists for rows), of plain floats (a
    NumPy scalar formats several times slower)."""
    values = np.asarray(values, float)
    if values.ndim > 1:
        return [_texts(row) for row in values]
    return [_fmt(v) for v in values.tolist()]


def plan_csv(profile: Profile, q: np.ndarray, targets: np.ndarray) -> str:
    """Planned configurations (rad) as CSV: one row each, numbered from 1 in the frame column, the target
    column when the format has one (a profile whose frames are stances also names it `leg`, specs/cli.md),
    then the joint columns in the format's joint unit. No measurement columns: nothing is measured yet."""
    fmt = profile.data
    stances = profile.simulation.get("sampling", {}).get("kind") == "stances"
    header = [fmt.frame_column or "frame"]
    if fmt.target_column:
        header += ["leg"] if stances and fmt.target_column != "leg" else []
        header.append(fmt.target_column)
    header += list(fmt.joint_columns.values())
    tnames = {v: k for k, v in fmt.target_values.items()}
    factor = joint_factors(profile)
    out = io.StringIO()
    w = csv.writer(out, lineterminator="\n")
    w.writerow(header)
    for k, (qk, t) in enumerate(zip(q, targets, strict=True)):
        row: list[object] = [k + 1]
        if fmt.target_column:
            row += [tnames[int(t)]] * (len(header) - 1 - len(fmt.joint_columns))
        row += [_fmt(qk[profile.joint(j)] / factor[profile.joint(j)]) for j in fmt.joint_columns]
        w.writerow(row)
    return out.getvalue()
