"""Datasets: configurations (joint readings) and what the sensor measured in each, read from and
written to the CSV formats of a profile's `data` section (specs/robonaut-a.md, specs/nao.md).

One CSV row is one observation. Rows with the same frame id share one configuration; a format
without a frame column (the Motoman tracker files) makes every row a configuration of its own. Every problem
with a file is reported as an InputError naming the file, the line and the column.
"""

from __future__ import annotations

import csv
import io
import math
from pathlib import Path

import numpy as np

from ..dataset import Dataset
from ..errors import InputError
from ..model.profile import Profile
from ..sensors.measurement import dimension
from ..units import ANGLE_IN_RAD, length_factor

# No joint angle, length or pixel in a calibration dataset comes near this; beyond it, arithmetic
# on squares overflows, so such a value is reported as bad input rather than computed with.
MAX_MAGNITUDE = 1e9


def read_dataset(profile: Profile, path: str | Path) -> Dataset:
    """Read a CSV in the profile's data format. Raises InputError naming file, line and column."""
    name = str(path)
    try:
        with open(path, newline="", encoding="utf-8-sig") as fh:
            text = fh.read()
    except FileNotFoundError:
        raise InputError("file does not exist", file=name) from None
    except IsADirectoryError:
        raise InputError("is a directory, not a CSV file", file=name) from None
    except UnicodeDecodeError:
        raise InputError("is not a UTF-8 text (CSV) file", file=name) from None
    except OSError as exc:
        raise InputError(f"cannot be read ({exc.strerror})", file=name) from None
    return parse_dataset(profile, text, name)


def parse_dataset(profile: Profile, text: str, name: str = "<data>") -> Dataset:
    fmt = profile.data
    sensor = profile.sensors[fmt.sensor]
    dim = dimension(sensor)
    try:
        table = list(csv.reader(io.StringIO(text)))
    except csv.Error as exc:
        raise InputError(f"not a valid CSV file ({exc})", file=name) from None
    lines = [(i + 1, r) for i, r in enumerate(table) if any(c.strip() for c in r)]
    if not lines:
        raise InputError("file is empty (a header line and data rows are required)", file=name)
    header_line, header = lines[0]
    header = [h.strip() for h in header]
    col = {h: i for i, h in enumerate(header)}
    required = [*fmt.measurement_columns, *fmt.joint_columns.values()]
    if fmt.frame_column:
        required.append(fmt.frame_column)
    target_column = fmt.target_column if fmt.target_column in col or fmt.target_default is None else None
    if target_column:
        required.append(target_column)
    if fmt.point_columns:
        required += list(fmt.point_columns)
    if fmt.vertex_column:
        required.append(fmt.vertex_column)
    for c in required:
        if c not in col:
            raise InputError(f"missing column '{c}' in the header", file=name, line=header_line, column=c)
    body = lines[1:]
    if not body:
        raise InputError("has a header but no data rows", file=name, line=header_line)

    joint_factor = ANGLE_IN_RAD[fmt.joint_unit]
    meas_factor = 1.0 if fmt.measurement_unit == "px" else length_factor(fmt.measurement_unit, profile.length_unit)
    point_factor = length_factor(fmt.point_unit, profile.length_unit) if fmt.point_unit else 1.0
    needed = joints_needed(profile)

    frame_index: dict[int, int] = {}
    frame_first_line: dict[int, int] = {}
    joints_rows: list[np.ndarray] = []
    cfg, target, point, vertex, measured, line_no, raw = [], [], [], [], [], [], []
    n_joints = len(profile.joints)
    for ln, row in body:
        if len(row) != len(header):
            raise InputError(f"has {len(row)} fields but the header has {len(header)}", file=name, line=ln)

        def number(c: str, ln: int = ln, row: list[str] = row) -> float:
            s = row[col[c]].strip()
            try:
                v = float(s)
            except ValueError:
                what = "is empty" if not s else f"'{s}' is not a number"
                raise InputError(what, file=name, line=ln, column=c) from None
            if not math.isfinite(v):
                raise InputError(f"'{s}' is not a finite number", file=name, line=ln, column=c)
            if abs(v) > MAX_MAGNITUDE:
                raise InputError(f"'{s}' is implausibly large (beyond {MAX_MAGNITUDE:g})", file=name, line=ln, column=c)
            return v

        if fmt.frame_column:
            f = number(fmt.frame_column)
            if f != int(f):
                raise InputError(f"frame id {f} is not an integer", file=name, line=ln, column=fmt.frame_column)
            fid = int(f)
        else:
            fid = len(measured) + 1
        if target_column:
            tv = row[col[target_column]].strip()
            if tv not in fmt.target_values:
                known = ", ".join(fmt.target_values)
                raise InputError(f"'{tv}' is not one of {known}", file=name, line=ln, column=target_column)
            ti = fmt.target_values[tv]
        else:
            ti = fmt.target if fmt.target is not None else fmt.target_default
            assert ti is not None
        q = np.full(n_joints, np.nan)
        for jname, c in fmt.joint_columns.items():
            j = profile.joint(jname)
            if j in needed[ti]:
                q[j] = number(c) * joint_factor
        if fid in frame_index:
            prev = joints_rows[frame_index[fid]]
            both = ~np.isnan(prev) & ~np.isnan(q)
            if np.any(np.abs(prev[both] - q[both]) > 1e-9):
                raise InputError(
                    f"frame {fid} has other joint angles than on line {frame_first_line[fid]}",
                    file=name,
                    line=ln,
                )
            fill = np.isnan(prev)
            prev[fill] = q[fill]
        else:
            frame_index[fid] = len(joints_rows)
            frame_first_line[fid] = ln
            joints_rows.append(q)
        if fmt.point_columns:
            point.append([number(c) * point_factor for c in fmt.point_columns])
        if fmt.vertex_column:
            v = number(fmt.vertex_column)
            grid = profile.targets[ti].grid if profile.targets[ti].points is None else profile.targets[ti].points
            if v != int(v) or v < 0 or (grid is not None and v >= len(grid)):
                raise InputError(
                    f"vertex {row[col[fmt.vertex_column]].strip()} is not a vertex id",
                    file=name,
                    line=ln,
                    column=fmt.vertex_column,
                )
            vertex.append(int(v))
        else:
            vertex.append(-1)
        if not fmt.point_columns:
            fixed = profile.targets[ti].points
            point.append([np.nan] * 3 if fixed is None else fixed[max(vertex[-1], 0)])
        measured.append([number(c) * meas_factor for c in fmt.measurement_columns])
        cfg.append(frame_index[fid])
        target.append(ti)
        line_no.append(ln)
        raw.append(row)
    assert len(measured[0]) == dim
    return Dataset(
        robot=profile.name,
        frame_ids=np.array(list(frame_index), dtype=int),
        joints=np.array(joints_rows),
        cfg=np.array(cfg, dtype=int),
        target=np.array(target, dtype=int),
        point=np.array(point, dtype=float),
        vertex=np.array(vertex, dtype=int),
        measured=np.array(measured, dtype=float),
        source=name,
        lines=np.array(line_no, dtype=int),
        header=header,
        rows=raw,
    )


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


def joints_needed(profile: Profile) -> dict[int, set[int]]:
    """For each target, the joints on the chains from the base to it and to the data's sensor."""
    sensor_frame = profile.sensors[profile.data.sensor].frame
    out = {}
    for ti, t in enumerate(profile.targets):
        frames = set(profile.chain(t.frame)) | set(profile.chain(sensor_frame))
        out[ti] = {profile.frames[f].joint for f in frames if profile.frames[f].joint >= 0}
    return out


def to_csv(profile: Profile, data: Dataset, extra: dict[str, np.ndarray] | None = None) -> str:
    """The dataset in the profile's CSV format (joints in the format's unit), plus extra columns."""
    fmt = profile.data
    joint_factor = ANGLE_IN_RAD[fmt.joint_unit]
    meas_factor = 1.0 if fmt.measurement_unit == "px" else length_factor(profile.length_unit, fmt.measurement_unit)
    header = [fmt.frame_column] if fmt.frame_column else []
    if fmt.target_column:
        header.append(fmt.target_column)
    if fmt.vertex_column:
        header.append(fmt.vertex_column)
    header += list(fmt.measurement_columns)
    if fmt.point_columns:
        header += list(fmt.point_columns)
    header += list(fmt.joint_columns.values())
    extra = extra or {}
    header += list(extra)
    tnames = {v: k for k, v in fmt.target_values.items()}
    out = io.StringIO()
    w = csv.writer(out, lineterminator="\n")
    w.writerow(header)
    for m in range(data.n_observations):
        c = data.cfg[m]
        row: list[object] = [int(data.frame_ids[c])] if fmt.frame_column else []
        if fmt.target_column:
            row.append(tnames[int(data.target[m])])
        if fmt.vertex_column:
            row.append(int(data.vertex[m]))
        row += [_fmt(v * meas_factor) for v in data.measured[m]]
        if fmt.point_columns:
            pf = length_factor(profile.length_unit, fmt.point_unit or profile.length_unit)
            row += [_fmt(v * pf) for v in data.point[m]]
        for jname in fmt.joint_columns:
            v = data.joints[c, profile.joint(jname)]
            row.append(_fmt(v / joint_factor) if np.isfinite(v) else "0")
        row += [_fmt(v[m]) for v in extra.values()]
        w.writerow(row)
    return out.getvalue()


def _fmt(v: float) -> str:
    return f"{v:.6f}".rstrip("0").rstrip(".") if v != 0 else "0"
