"""Loading robot profiles: a built-in one by name or a YAML file, compiled to a Profile.

Every problem with a file is an InputError naming the file and the field
(`frames[3].mdh.alpha: expected a finite number`). A profile that says `urdf: robot.urdf` gets its
frames, joints and default modes from that URDF first (calib_core.model.urdf_import).

`compile_profile` reads the document's sections one step after another, in the order they depend on one another;
each step takes the FieldReader (field_reader.py: the file, the units, the parameters added so far) and what the
steps before it made. The chain's steps are in chain_spec.py, the CSV format's in data_spec.py, the rest here.
"""

from __future__ import annotations

import fnmatch
from dataclasses import replace
from importlib import resources
from pathlib import Path
from typing import Any

import numpy as np

from ..errors import InputError
from ..files import read_text_file
from ..safe_yaml import MAX_YAML_BYTES, load_yaml
from ..sensors import SENSOR_MODELS, Sensor
from ..units import ANGLE_IN_RAD, LENGTH_IN_M
from .boards import read_charuco
from .chain_spec import compile_frames, compile_joints
from .data_spec import compile_data_format
from .field_reader import FieldReader
from .profile import Frame, Mode, Profile, Target, Tie

BUILTIN_PROFILES = ("robonaut-a", "nao", "motoman", "arm-handeye")

GRID_PATTERNS = ("checkerboard", "sandal")  # what a grid target may be: a plain board, the NAO's sandal
# A mode's `free: ["cam.intrinsics"]`: the camera's fx, fy, cx, cy and its distortion coefficients.
INTRINSICS_SUFFIX = ".intrinsics"
PLAN_GOALS = ("task", "offsets")  # a mode's `plan`: what a plan for it makes accurate (Mode.plan)


def load_profile(name_or_path: str | Path, *, urdf: str | Path | None = None) -> Profile:
    """A built-in profile by name (`robonaut-a`, `nao`) or a profile YAML file by path. `urdf`: the URDF
    file to use instead of the one its `urdf:` names (a ROS 2 robot's, received from its graph, for a
    profile that says `urdf: ros2`)."""
    text, source = _read_profile_text(name_or_path)
    doc = load_yaml(text, source)
    if not isinstance(doc, dict):
        raise InputError("a robot profile must be a YAML mapping", file=source)
    try:
        if "urdf" in doc and urdf is not None:
            doc = {**doc, "urdf": str(Path(urdf).resolve())}
        if "urdf" in doc:  # frames, joints and default modes from a URDF file
            from .urdf_import import compile_urdf_profile  # lxml: only for a profile built on a URDF

            profile = compile_urdf_profile(doc, source, lambda d: compile_profile(d, source))
        else:
            profile = compile_profile(doc, source)
        return replace(profile, notes=profile.notes + _truth_notes(profile))
    except InputError:
        raise
    except (TypeError, AttributeError, KeyError, ValueError, IndexError) as exc:
        # A shape the field checks did not anticipate (a list where a mapping belongs, ...).
        raise InputError(f"malformed robot profile ({exc.__class__.__name__}: {exc})", file=source) from None


def _read_profile_text(name_or_path: str | Path) -> tuple[str, str]:
    name = str(name_or_path)
    if name in BUILTIN_PROFILES:
        res = resources.files("calib_core.model") / "profiles" / f"{name}.yaml"
        return res.read_text(encoding="utf-8"), f"{name} (built-in)"
    path = Path(name)
    if not path.suffix and not path.exists():
        known = ", ".join(BUILTIN_PROFILES)
        raise InputError(f"unknown robot '{name}' (built-in: {known}; or give a profile file)")
    return read_text_file(path, MAX_YAML_BYTES, "robot profile file"), str(path)


def compile_profile(doc: dict, source: str) -> Profile:
    """A profile's YAML document as a Profile: its sections read in the order they depend on one another (the
    units; the chain: joints, then the frames they drive; the targets and sensors on those frames; the CSV format
    that names all of these; the modes over the parameters every step before added to `read`)."""
    read = FieldReader(source)
    name = str(read.get(doc, "name", "profile"))
    read = _in_units(read, doc)
    joints = compile_joints(read, doc)
    frames = compile_frames(read, doc, joints)
    targets = [_compile_target(read, t, f"targets[{i}]", frames) for i, t in enumerate(doc.get("targets", []))]
    sensors = _compile_sensors(read, doc, frames)
    if not sensors or not targets:
        raise read.fail("profile", "needs at least one sensor and one target")
    data = compile_data_format(read, read.get(doc, "data", "profile"), joints, targets, sensors)
    modes = {
        str(k): _compile_mode(read, str(k), v, f"modes.{k}", sensors)
        for k, v in read.get(doc, "modes", "profile").items()
    }
    return Profile(
        name=name,
        title=str(doc.get("title", name)),
        source=source,
        length_unit=read.length_unit,
        base=str(doc.get("base", "base")),
        parameters=read.params,
        frames=frames,
        joints=joints,
        targets=targets,
        sensors=sensors,
        modes=modes,
        data=data,
        simulation=doc.get("simulation", {}) or {},
    )


def _in_units(read: FieldReader, doc: dict) -> FieldReader:
    """The reader in the profile's `units:` (default m and deg), which every length and angle after is in."""
    units = read.get(doc, "units", "profile", {"length": "m", "angle": "deg"})
    length_unit = read.get(units, "length", "units", "m")
    angle_unit = read.get(units, "angle", "units", "deg")
    if length_unit not in LENGTH_IN_M:
        raise read.fail("units.length", f"unknown unit '{length_unit}' (m, cm, mm)")
    if angle_unit not in ANGLE_IN_RAD:
        raise read.fail("units.angle", f"unknown unit '{angle_unit}' (deg, rad)")
    return replace(read, length_unit=length_unit, to_rad=ANGLE_IN_RAD[angle_unit])


def _compile_target(read: FieldReader, spec: dict, where: str, frames: list[Frame]) -> Target:
    """One of `targets:`: a point (its own parameters, or a frame's origin), points, a grid or a ChArUco board on a
    frame, what a sensor looks for on it, and a sphere's radius."""
    tname = str(read.get(spec, "name", where))
    frame = read.index_of(read.get(spec, "frame", where), frames, f"{where}.frame", "frame")
    point_params = None
    grid = None
    shape = None
    points = None
    charuco = None
    if sum(k in spec for k in ("point", "grid", "points", "charuco")) > 1:
        raise read.fail(where, "needs at most one of point, grid, points, charuco")
    if "points" in spec:
        pts = spec["points"]
        if not isinstance(pts, list) or not pts:
            raise read.fail(f"{where}.points", "expected a list of [x, y, z]")
        points = np.array([read.vector(v, f"{where}.points[{k}]") for k, v in enumerate(pts)])
    elif not any(k in spec for k in ("point", "grid", "charuco")):
        points = np.zeros((1, 3))  # the frame's origin (a reflector at the end of a DH row)
    if "point" in spec:
        point_params = read.add_params(tname, "length", spec["point"], ("x", "y", "z"), f"{where}.point")
    if "grid" in spec:
        g = spec["grid"]
        cols = int(read.number(read.get(g, "cols", f"{where}.grid"), f"{where}.grid.cols"))
        rows = int(read.number(read.get(g, "rows", f"{where}.grid"), f"{where}.grid.rows"))
        s = read.number(read.get(g, "spacing", f"{where}.grid"), f"{where}.grid.spacing")
        c = read.vector(g.get("center", [0, 0, 0]), f"{where}.grid.center")
        r, k = np.divmod(np.arange(rows * cols), cols)
        grid = np.stack(
            [
                c[0] + s * (k - (cols - 1) / 2),
                c[1] + s * ((rows - 1) / 2 - r),
                np.full(r.shape, c[2]),
            ],
            axis=1,
        )
        shape = (rows, cols)
    if "charuco" in spec:
        charuco = read_charuco(spec["charuco"], read, f"{where}.charuco")
        grid, shape = charuco.corners(), charuco.shape
    radius = spec.get("radius")
    return Target(
        tname,
        frame,
        point_params,
        grid,
        shape,
        None if radius is None else read.number(radius, f"{where}.radius"),
        points,
        _pattern(read, spec, where),
        charuco,
    )


def _pattern(read: FieldReader, spec: dict, where: str) -> str:
    """What a sensor looks for on a target (`Target.pattern`): a grid's `pattern` (checkerboard, or the
    NAO's sandal), else what the target is."""
    if "pattern" in spec:
        if "grid" not in spec:
            raise read.fail(f"{where}.pattern", "only a grid target has a pattern (checkerboard or sandal)")
        if spec["pattern"] not in GRID_PATTERNS:
            raise read.fail(f"{where}.pattern", f"expected one of {', '.join(GRID_PATTERNS)}, got {spec['pattern']!r}")
        return str(spec["pattern"])
    if "charuco" in spec:
        return "charuco"
    if "grid" in spec:
        return "checkerboard"
    return "sphere" if "radius" in spec else "point"


def _compile_sensors(read: FieldReader, doc: dict, frames: list[Frame]) -> list[Sensor]:
    """`sensors:`, each by its measurement model (SENSOR_MODELS); a pinhole camera whose intrinsics a mode frees
    with distortion coefficients."""
    freed = _intrinsics_freed(doc)
    return [
        _compile_sensor(read, with_distortion(s) if _sensor_name(s) in freed else s, f"sensors[{i}]", frames)
        for i, s in enumerate(doc.get("sensors", []))
    ]


def _intrinsics_freed(doc: dict) -> set[str]:
    """The sensors whose `<name>.intrinsics` some mode frees (their lens is calibrated with the arm)."""
    out = set()
    for mode in (doc.get("modes") or {}).values():
        for item in (mode.get("free") or []) if isinstance(mode, dict) else []:
            if isinstance(item, str) and item.endswith(INTRINSICS_SUFFIX):
                out.add(item.removesuffix(INTRINSICS_SUFFIX))
    return out


def _sensor_name(spec: Any) -> str | None:
    return str(spec.get("name")) if isinstance(spec, dict) else None


def with_distortion(spec: Any) -> Any:
    """A pinhole camera whose intrinsics a mode frees, with OpenCV's five distortion coefficients (zero) where the
    profile gives none: a camera nobody calibrated has none to write, and the calibration estimates them."""
    if isinstance(spec, dict) and spec.get("model") == "pinhole" and "distortion" not in spec:
        return {**spec, "distortion": {}}
    return spec


def _compile_sensor(read: FieldReader, spec: dict, where: str, frames: list[Frame]) -> Sensor:
    sname = str(read.get(spec, "name", where))
    frame = read.index_of(read.get(spec, "frame", where), frames, f"{where}.frame", "frame")
    model = str(read.get(spec, "model", where))
    if model not in SENSOR_MODELS:
        raise read.fail(f"{where}.model", f"unknown sensor model '{model}' ({', '.join(SENSOR_MODELS)})")
    try:
        return SENSOR_MODELS[model].from_spec(spec, read, sname, frame, where)
    except InputError as exc:  # a noise model's check names the field, not the file
        raise InputError(exc.message, file=read.source) from None


def _compile_mode(read: FieldReader, name: str, spec: dict, where: str, sensors: list[Sensor]) -> Mode:
    """One of `modes:`: which parameters it estimates (`free`: names or glob patterns, a camera's
    `<name>.intrinsics`), ties, priors and bounds, the sensors it uses and what a plan for it makes accurate."""
    names = list(read.index)

    def expand(patterns: list, w: str) -> list[int]:
        """Names or glob patterns, in order; {pattern: P, nonzero: true} skips zero nominals."""
        out = []
        for k, item in enumerate(patterns):
            pat, nonzero = (item.get("pattern"), bool(item.get("nonzero"))) if isinstance(item, dict) else (item, False)
            hits = [n for n in names if fnmatch.fnmatchcase(n, str(pat))] or _lens_params(read, sensors, str(pat))
            if not hits:
                raise read.fail(f"{w}[{k}]", f"'{pat}' matches no parameter")
            out += [read.index[h] for h in hits if not nonzero or read.params[read.index[h]].nominal != 0.0]
        return out

    free = expand(spec.get("free", []), f"{where}.free")
    ties = []
    for k, t in enumerate(spec.get("ties", []) or []):
        w = f"{where}.ties[{k}]"
        f, lead = str(read.get(t, "follower", w)), str(read.get(t, "leader", w))
        for n in (f, lead):
            if n not in read.index:
                raise read.fail(w, f"unknown parameter '{n}'")
        ties.append(Tie(read.index[f], read.index[lead], read.number(t.get("sign", 1), f"{w}.sign")))
    followers = {t.follower for t in ties}
    free = list(dict.fromkeys(i for i in free if i not in followers))
    priors = _per_parameter(read, spec, "priors", names, where)
    bounds = _per_parameter(read, spec, "bounds", names, where)
    used = None
    if "sensors" in spec:
        listed = spec["sensors"]
        if not isinstance(listed, list) or not listed:
            raise read.fail(f"{where}.sensors", f"expected a list of sensor names, got {listed!r}")
        used = tuple(read.index_of(n, sensors, f"{where}.sensors[{k}]", "sensor") for k, n in enumerate(listed))
    plan = str(spec.get("plan", "task"))
    if plan not in PLAN_GOALS:
        raise read.fail(f"{where}.plan", f"expected one of {', '.join(PLAN_GOALS)}, got {plan!r}")
    return Mode(name, str(spec.get("description", "")), tuple(free), tuple(ties), priors, bounds, used, plan)


def _lens_params(read: FieldReader, sensors: list[Sensor], pattern: str) -> list[str]:
    """`<sensor>.intrinsics`: the names of that sensor's intrinsics and distortion coefficients."""
    sensor = next((s for s in sensors if f"{s.name}{INTRINSICS_SUFFIX}" == pattern), None)
    return [] if sensor is None else [read.params[i].name for i in sensor.direct_params()]


def _per_parameter(read: FieldReader, spec: dict, key: str, names: list[str], where: str) -> dict[int, float]:
    """{name or glob pattern: positive number in the profile's units} -> {index: internal units}."""
    out = {}
    for pname, value in (spec.get(key) or {}).items():
        hits = [n for n in names if fnmatch.fnmatchcase(n, str(pname))]
        if not hits:
            raise read.fail(f"{where}.{key}", f"'{pname}' matches no parameter")
        v = read.number(value, f"{where}.{key}.{pname}")
        if v <= 0:
            raise read.fail(f"{where}.{key}.{pname}", f"must be positive, got {v}")
        for i in (read.index[h] for h in hits):
            out[i] = v * (read.to_rad if read.params[i].kind == "angle" else 1.0)
    return out


# A truth value ten times nearer zero than its nominal value, and further from it than these, reads like an error
# written in place of the value (the Robonaut paper's truth moves link lengths by 4 cm, but to 1/5 of them at most).
TRUTH_ERROR_DEG = 10.0
TRUTH_ERROR_MM = 20.0
TRUTH_SHRINK = 10.0


def _truth_notes(profile: Profile) -> tuple[str, ...]:
    """`simulation.truth` holds the hidden robot's parameter values (nominal plus error), in display units. A
    value far nearer zero than its nominal and far from it (TRUTH_*) reads like an error written
    in place of the value (`elbow.z: 0.5` for an elbow.z of 419.5 mm): a note saying so, with the value meant."""
    truth = profile.simulation.get("truth")
    if not isinstance(truth, dict):
        return ()
    bound = {"angle": TRUTH_ERROR_DEG, "length": TRUTH_ERROR_MM * 1e-3 / LENGTH_IN_M[profile.length_unit]}
    notes = []
    for name, value in truth.items():
        try:
            i = profile.param(str(name))
            v = float(value)
        except (InputError, TypeError, ValueError):
            continue  # named when the simulator reads it
        nominal = profile.to_display(i, profile.parameters[i].nominal)
        far = bound.get(profile.parameters[i].kind)
        if far is not None and abs(v) * TRUTH_SHRINK < abs(nominal) and abs(v - nominal) > far:
            unit = profile.unit(i)
            notes.append(
                f"simulation.truth.{name}: {v:g} {unit} is {abs(v - nominal):.4g} {unit} from its nominal value "
                f"{nominal:.6g} {unit}; truth values are the hidden robot's parameter values, not their errors "
                f"(an error of {v:g} {unit} is {nominal + v:.6g})"
            )
    return tuple(notes)
