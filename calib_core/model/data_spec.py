"""A profile's `data:` section: the CSV format of its datasets (calib_core.io.csv_format reads and writes by it).

Which columns hold the joints, the sensor and target of a row, its measurement (and a pose's rotation), the
observed point and more markers, each checked against the sensors it names: as many numbers, in their unit.
"""

from __future__ import annotations

from ..sensors import Sensor
from ..sensors.pose6d import ROTATIONS
from ..units import ANGLE_IN_RAD, LENGTH_IN_M
from .field_reader import FieldReader
from .profile import DataFormat, Joint, Marker, Target


def compile_data_format(
    read: FieldReader, spec: dict, joints: list[Joint], targets: list[Target], sensors: list[Sensor]
) -> DataFormat:
    """`data:`, the CSV format, over the profile's joints, targets and sensors."""
    where = "data"
    jcols = {str(k): str(v) for k, v in read.get(spec, "joints", where).items()}
    joint_names = {j.name for j in joints}
    for jn in jcols:
        if jn not in joint_names:
            raise read.fail(f"{where}.joints", f"'{jn}' is not a joint")
    joint_unit = str(spec.get("joint_unit", "deg"))
    if joint_unit not in ANGLE_IN_RAD:
        raise read.fail(f"{where}.joint_unit", f"unknown unit '{joint_unit}' ({', '.join(ANGLE_IN_RAD)})")
    joint_length_unit = spec.get("joint_length_unit")
    if joint_length_unit is not None and str(joint_length_unit) not in LENGTH_IN_M:
        raise read.fail(f"{where}.joint_length_unit", f"unknown unit '{joint_length_unit}' ({', '.join(LENGTH_IN_M)})")
    sensor = read.index_of(read.get(spec, "sensor", where), sensors, f"{where}.sensor", "sensor")
    svalues = {
        str(k): read.index_of(v, sensors, f"{where}.sensors.{k}", "sensor")
        for k, v in (spec.get("sensors") or {}).items()
    }
    if svalues and not spec.get("sensor_column"):
        raise read.fail(where, "names sensors by value but has no sensor_column")
    target = spec.get("target")
    if target is not None:
        target = read.index_of(target, targets, f"{where}.target", "target")
    tvalues = {
        str(k): read.index_of(v, targets, f"{where}.targets.{k}", "target")
        for k, v in (spec.get("targets") or {}).items()
    }
    if target is None and not spec.get("target_column"):
        raise read.fail(where, "needs a target or a target_column")
    default = spec.get("target_default")
    if default is not None and str(default) not in tvalues:
        raise read.fail(f"{where}.target_default", f"'{default}' is not one of the targets' values")
    named = [sensors[i] for i in sorted({sensor, *svalues.values()})]
    rotation, rotation_unit = _rotation(read, spec, named, joint_unit)
    columns, unit = _measurement(read, spec, named, rotation)
    point_columns, point_unit = _point(read, spec)
    markers = _markers(read, spec, targets, sensors, len(columns), named[0])
    frame_column = spec.get("frame_column", "frame")
    return DataFormat(
        frame_column=None if frame_column is None else str(frame_column),
        joint_columns=jcols,
        joint_unit=joint_unit,
        sensor=sensor,
        target=target,
        target_column=spec.get("target_column"),
        target_values=tvalues,
        point_columns=point_columns,
        point_unit=point_unit,
        vertex_column=spec.get("vertex_column"),
        measurement_columns=columns,
        measurement_unit=unit,
        prediction_columns=read.columns(
            read.get(spec, "prediction_columns", where), f"{where}.prediction_columns", len(columns)
        ),
        target_default=None if default is None else tvalues[str(default)],
        sensor_column=spec.get("sensor_column"),
        sensor_values=svalues,
        joint_length_unit=None if joint_length_unit is None else str(joint_length_unit),
        rotation=rotation,
        rotation_unit=rotation_unit,
        markers=markers,
    )


def _rotation(read: FieldReader, spec: dict, named: list[Sensor], joint_unit: str) -> tuple[str | None, str]:
    """How the measurement columns give a pose's orientation (`measurement.rotation`: rotvec by default,
    quaternion or rpy) and the unit of its angles (`measurement.angle_unit`, default the joints'), for a
    format of pose sensors; (None, rad) for any other."""
    where = "data.measurement"
    meas = read.get(spec, "measurement", "data")
    poses = {bool(s.rotation_axes) for s in named}
    if len(poses) > 1:
        raise read.fail("data.sensors", "the sensors of one CSV format must all measure poses, or none")
    if not poses.pop():
        for key in ("rotation", "angle_unit"):
            if isinstance(meas, dict) and key in meas:
                raise read.fail(
                    f"{where}.{key}",
                    f"only a pose's measurement has one ({named[0].name} is a {named[0].kind} sensor)",
                )
        return None, "rad"
    rotation = str(meas.get("rotation", "rotvec"))
    if rotation not in ROTATIONS:
        raise read.fail(f"{where}.rotation", f"unknown rotation '{rotation}' ({', '.join(ROTATIONS)})")
    unit = str(meas.get("angle_unit", joint_unit))
    if unit not in ANGLE_IN_RAD:
        raise read.fail(f"{where}.angle_unit", f"unknown unit '{unit}' ({', '.join(ANGLE_IN_RAD)})")
    return rotation, unit


def _measurement(
    read: FieldReader, spec: dict, named: list[Sensor], rotation: str | None
) -> tuple[tuple[str, ...], str]:
    """The measurement columns and their unit, checked against every sensor the format names."""
    where = "data.measurement"
    meas = read.get(spec, "measurement", "data")
    columns = read.columns(read.get(meas, "columns", where), f"{where}.columns")
    for s in named:
        count = s.dim if rotation is None else 3 + ROTATIONS[rotation]
        if len(columns) != count:
            numbers = "1 number" if count == 1 else f"{count} numbers"
            how = "" if rotation is None else f" (x, y, z and a {rotation})"
            raise read.fail(
                f"{where}.columns",
                f"a {s.kind} sensor ('{s.name}') measures {numbers}{how}, not {len(columns)}",
            )
    units = {s.unit for s in named}
    if len(units) > 1:
        raise read.fail("data.sensors", f"the sensors of one CSV format must measure in one unit, not {units}")
    unit = str(meas.get("unit", next(iter(units))))
    if (unit != "px" and unit not in LENGTH_IN_M) or (unit == "px") != (named[0].unit == "px"):
        raise read.fail(f"{where}.unit", f"'{unit}' is not a unit of {named[0].name}'s measurements")
    return columns, unit


def _markers(
    read: FieldReader, spec: dict, targets: list[Target], sensors: list[Sensor], count: int, row_sensor: Sensor
) -> tuple[Marker, ...]:
    """`data.markers`: more measurements on each row, each `{columns: [...]}` of as many columns as the
    measurement, with an optional `target` (name), `vertex` (a point of it) and `sensor` (name, one
    that measures as the row's sensor does)."""
    value = spec.get("markers")
    if value is None:
        return ()
    if not isinstance(value, list) or not value:
        raise read.fail("data.markers", "expected a list of {columns: [...]}")
    out = []
    for k, m in enumerate(value):
        where = f"data.markers[{k}]"
        columns = read.columns(read.get(m, "columns", where), f"{where}.columns", count)
        unknown = sorted(set(m) - {"columns", "target", "vertex", "sensor"})
        if unknown:
            raise read.fail(f"{where}.{unknown[0]}", "not a field of a marker (columns, target, vertex, sensor)")
        target = None if m.get("target") is None else read.index_of(m["target"], targets, f"{where}.target", "target")
        sensor = None if m.get("sensor") is None else read.index_of(m["sensor"], sensors, f"{where}.sensor", "sensor")
        if sensor is not None and (sensors[sensor].dim, sensors[sensor].unit) != (row_sensor.dim, row_sensor.unit):
            raise read.fail(
                f"{where}.sensor",
                f"'{m['sensor']}' does not measure what {row_sensor.name} does (as many numbers, one unit)",
            )
        vertex = None
        if m.get("vertex") is not None:
            vertex = int(read.number(m["vertex"], f"{where}.vertex"))
            if vertex != m["vertex"] or vertex < 0:
                raise read.fail(f"{where}.vertex", f"expected a point's index (0, 1, ...), got {m['vertex']!r}")
        out.append(Marker(columns, target, vertex, sensor))
    return tuple(out)


def _point(read: FieldReader, spec: dict) -> tuple[tuple[str, ...] | None, str | None]:
    """The columns of the observed point in the target frame, and their length unit (or none)."""
    point = spec.get("point")
    if point is None:
        return None, None
    columns = read.columns(read.get(point, "columns", "data.point"), "data.point.columns", 3)
    unit = str(point.get("unit", read.length_unit))
    if unit not in LENGTH_IN_M:
        raise read.fail("data.point.unit", f"unknown unit '{unit}' ({', '.join(LENGTH_IN_M)})")
    return columns, unit
