"""A robot from its URDF: the profile's frames, joints and default modes read from a URDF file.

A profile YAML may say `urdf: robot.urdf` (relative to the profile file) instead of listing frames
and joints. Every URDF joint becomes one frame, named after the joint's child link, hanging from
the frame of its parent link (the URDF's root link is the profile's base), as urdf-style ops:

    Trans(x, y, z) Rot_z(yaw) Rot_y(pitch) Rot_x(roll) Rot_axis(offset + q)

with the parameters named after the joint: `<joint>` is the joint's offset (what the calibrated
model adds to the encoder reading) and `<joint>.x`, `.y`, `.z`, `.roll`, `.pitch`, `.yaw` correct
its origin. Fixed joints get the origin parameters and no offset. Values are converted from the
URDF's metres and radians to the profile's `units`; joint limits come from `<limit>` (continuous
joints: +-360 deg), the speed from `<limit velocity>` (else 1 rad/s). The profile's own `frames`
follow the URDF's (a tracker, a camera mount, a tool), its `joints` entries add to or override the
URDF's (an encoder `resolution`, narrower limits).

Only revolute, continuous and fixed joints can be calibrated (the data's joint readings are
angles): a prismatic, planar or floating joint, or a mimic joint, is left out with every link below
it; a profile that puts a target, sensor or frame there is told which joint cuts it off.

Without a `modes` section the profile gets two, for the joints on the chains the data use:
`offsets` (the set-up the profile adds - a tracker's pose, a camera mount, the points of the
targets, the registrations first - and the joint offsets) and `origins` (the same, then every such
joint's origin correction with a weak prior of ORIGIN_PRIOR_MM / ORIGIN_PRIOR_DEG towards the URDF,
so that the combinations the data barely determine stay physical). The order matters: what the data
cannot tell apart is held by the identifiability check at its base value, and it holds the later
parameter, so a joint offset an external tracker cannot see (the first axis, about which the
tracker's pose turns too) stays 0 and the set-up absorbs it, and an origin correction that an offset
already explains stays 0. A profile whose sensor or target hangs from a `registration: true` frame
(a camera and a board whose poses nobody measured: specs/handeye.md) gets a third, first: `handeye`,
the registrations alone.

The file is read with lxml (line numbers for every complaint); the tests check the result against
yourdfpy, an independent URDF reader.
"""

from __future__ import annotations

import math
import re
from collections.abc import Callable
from dataclasses import dataclass, replace
from importlib import resources
from pathlib import Path
from typing import Any

import numpy as np
from lxml import etree

from ..errors import InputError
from ..files import read_regular_file, read_text_file
from ..safe_yaml import MAX_YAML_BYTES, load_yaml
from ..units import ANGLE_IN_RAD, LENGTH_IN_M
from .profile import Mode, Profile

SUPPORTED = ("revolute", "continuous", "prismatic", "fixed")
JOINT_TYPES = ("revolute", "continuous", "prismatic", "fixed", "floating", "planar")
CONTINUOUS_LIMIT_RAD = 2.0 * math.pi  # a continuous joint's readings: one turn either way
DEFAULT_VELOCITY_RAD_S = 1.0  # when the URDF gives no <limit velocity>
DEFAULT_SPEED_M_S = 0.1  # ... of a prismatic joint
XML_DECLARATION = re.compile(rb"<\?xml\s[^>]*?\?>")
ORIGIN_PRIOR_MM = 5.0  # the `origins` mode's prior sigma on each origin translation
ORIGIN_PRIOR_DEG = 1.0  # ... and on each origin rotation
ORIGIN_FIELDS = ("x", "y", "z", "roll", "pitch", "yaw")
BUILTIN_SUFFIX = " (built-in)"
MAX_URDF_BYTES = 64 * 1024 * 1024  # the largest URDF read (a humanoid's is a few hundred kB; meshes are other files)


@dataclass(frozen=True)
class UrdfJoint:
    """One imported URDF joint (revolute, continuous, prismatic or fixed); URDF units: m, rad."""

    name: str
    kind: str
    parent: str  # link
    child: str  # link: the name of its profile frame
    xyz: tuple[float, float, float]  # m
    rpy: tuple[float, float, float]  # rad
    axis: tuple[float, float, float] | None  # None for a fixed joint
    lower: float | None  # rad, m for a prismatic joint (None: fixed)
    upper: float | None
    velocity: float | None  # rad/s, m/s for a prismatic joint
    line: int
    limits_given: bool = True  # False: <limit> has no lower or upper, so both are 0 (the URDF default)

    @property
    def movable(self) -> bool:
        return self.kind != "fixed"

    @property
    def prismatic(self) -> bool:
        return self.kind == "prismatic"


@dataclass(frozen=True)
class UrdfRobot:
    """A URDF file's kinematic tree as far as it can be calibrated."""

    path: str
    data: bytes  # the file as read, its XML put right (exports rewrite its joint origins, keep the rest)
    name: str
    root: str  # the root link: the profile's base
    joints: tuple[UrdfJoint, ...]  # imported joints, every parent before its children
    left_out: dict[str, str]  # link -> why it is not in the profile ("below joint 'j' (planar)")
    notes: tuple[str, ...] = ()  # what reading it tolerated (a non-1.0 XML declaration, default limits)

    def joint(self, name: str) -> UrdfJoint:
        return next(j for j in self.joints if j.name == name)


# --- reading ------------------------------------------------------------------------------------


def read_urdf(path: str | Path) -> UrdfRobot:
    """Parse and check a URDF file; InputError naming the file, the line and the joint or link."""
    name = str(path)
    data = read_regular_file(path, MAX_URDF_BYTES, "URDF file")
    root, notes, data = _parse_xml(data, name)
    if root.tag != "robot":
        raise InputError(f"not a URDF: the root element is <{root.tag}>, not <robot>", file=name, line=root.sourceline)
    robot = _Reader(name, data, root).read()
    return replace(robot, notes=tuple(notes) + robot.notes)


def _parse_xml(data: bytes, name: str) -> tuple[etree._Element, list[str], bytes]:
    """The root element, notes on what was tolerated when the strict parse failed (an XML
    declaration that is not version 1.0 or not at the start, after comments or blank lines; NUL
    bytes after the root element) and the bytes parsed, so put right. Other XML errors stay errors,
    with the strict parser's line."""
    parser = etree.XMLParser(resolve_entities=False, no_network=True, remove_comments=False)
    try:
        root, notes = etree.fromstring(data, parser=parser), []
    except etree.XMLSyntaxError as exc:
        data, notes = _tolerated(data, name)
        root = None
        if notes:
            try:
                root = etree.fromstring(data, parser=parser)
            except etree.XMLSyntaxError:
                root = None
        if root is None:
            line = exc.lineno if exc.lineno else None
            raise InputError(f"not valid XML ({exc.msg})", file=name, line=line) from None
    if root is None:
        raise InputError("not valid XML (no root element)", file=name)
    return root, notes, data


def _tolerated(data: bytes, name: str) -> tuple[bytes, list[str]]:
    """The file with what many URDFs in the wild get wrong put right (line numbers kept), and a note
    for each thing put right."""
    notes: list[str] = []
    body = data.rstrip(b"\0\t\r\n ")
    if b"\0" in data[len(body) :]:
        notes.append(f"{name}: NUL bytes after the root element, ignored")
        data = body + b"\n"
    match = XML_DECLARATION.search(data)
    if match is None:
        return data, notes
    declaration = match.group()
    line = data.count(b"\n", 0, match.start()) + 1
    version = re.search(rb"""version\s*=\s*["']([^"']*)["']""", declaration)
    if match.start() > 0 and data[: match.start()].strip(b"\xef\xbb\xbf"):
        what = "comments" if b"<!--" in data[: match.start()] else "blank lines"
        notes.append(
            f"{name}, line {line}: the XML declaration is not at the start of the file (after {what}), moved there"
        )
    elif version is not None and version.group(1) != b"1.0":
        said = version.group(1).decode(errors="replace")
        notes.append(f'{name}, line {line}: the XML declaration says version="{said}", read as XML 1.0')
    else:
        return data, notes
    encoding = re.search(rb"""encoding\s*=\s*["']([^"']*)["']""", declaration)
    fixed = b'<?xml version="1.0"' + (b' encoding="' + encoding.group(1) + b'"' if encoding else b"") + b"?>"
    blank = b"\n" * declaration.count(b"\n")
    return fixed + data[: match.start()].lstrip(b"\xef\xbb\xbf") + blank + data[match.end() :], notes


class _Reader:
    def __init__(self, path: str, data: bytes, root: etree._Element) -> None:
        self.path = path
        self.data = data
        self.root = root

    def fail(self, message: str, element: etree._Element | None = None) -> InputError:
        return InputError(message, file=self.path, line=None if element is None else element.sourceline)

    def numbers(self, element: etree._Element | None, attr: str, default: str, what: str) -> tuple[float, ...]:
        text = default if element is None else element.get(attr, default)
        try:
            values = tuple(float(v) for v in text.split())
        except ValueError:
            values = ()
        if len(values) != 3 or not all(math.isfinite(v) for v in values):
            raise self.fail(f'{what} {attr}="{text}" is not three finite numbers', element)
        return values

    def limit(self, element: etree._Element | None, attr: str, what: str) -> float | None:
        text = None if element is None else element.get(attr)
        if text is None:
            return None
        try:
            value = float(text)
        except ValueError:
            raise self.fail(f'{what} <limit {attr}="{text}"> is not a number', element) from None
        if not math.isfinite(value):
            raise self.fail(f'{what} <limit {attr}="{text}"> is not a finite number', element)
        return value

    def read(self) -> UrdfRobot:
        links: dict[str, etree._Element] = {}
        for el in self.root.findall("link"):
            lname = el.get("name")
            if not lname:
                raise self.fail("a <link> has no name", el)
            if lname in links:
                raise self.fail(f"link '{lname}' is defined twice", el)
            links[lname] = el
        if not links:
            raise self.fail("not a URDF: it has no <link>", self.root)

        elements: dict[str, etree._Element] = {}
        parent_of: dict[str, str] = {}  # child link -> joint
        children: dict[str, list[str]] = {}  # parent link -> joints
        for el in self.root.findall("joint"):
            jname = el.get("name")
            if not jname:
                raise self.fail("a <joint> has no name", el)
            if jname in elements:
                raise self.fail(f"joint '{jname}' is defined twice", el)
            kind = el.get("type")
            if kind not in JOINT_TYPES:
                raise self.fail(f"joint '{jname}': type '{kind}' is not one of {', '.join(JOINT_TYPES)}", el)
            ends = {}
            for end in ("parent", "child"):
                sub = el.find(end)
                link = None if sub is None else sub.get("link")
                if not link:
                    raise self.fail(f"joint '{jname}' has no <{end} link=...>", el)
                if link not in links:
                    raise self.fail(f"joint '{jname}': {end} link '{link}' is not a <link> of this file", sub)
                ends[end] = link
            if ends["child"] in parent_of:
                raise self.fail(
                    f"link '{ends['child']}' is the child of two joints, '{parent_of[ends['child']]}' and "
                    f"'{jname}' (a URDF is a tree)",
                    el,
                )
            elements[jname] = el
            parent_of[ends["child"]] = jname
            children.setdefault(ends["parent"], []).append(jname)

        def ends_of(jname: str) -> tuple[str, str]:
            el = elements[jname]
            return el.find("parent").get("link"), el.find("child").get("link")

        roots = [lname for lname in links if lname not in parent_of]
        if len(roots) > 1:
            raise self.fail(
                f"has {len(roots)} root links ({', '.join(roots)}): every link but one must be the child of a joint"
            )
        if roots:
            root = roots[0]
            order: list[str] = []  # joints, parents first
            stack = list(reversed(children.get(root, [])))
            while stack:
                jname = stack.pop()
                order.append(jname)
                stack += reversed(children.get(ends_of(jname)[1], []))
        else:
            root, order = "", []
        if len(order) < len(elements):
            message, first = self._loop(set(elements) - set(order), parent_of, ends_of)
            raise self.fail(message, elements[first])

        joints: list[UrdfJoint] = []
        left_out: dict[str, str] = {}
        for jname in order:
            el = elements[jname]
            parent, child = ends_of(jname)
            if parent in left_out:
                left_out[child] = left_out[parent]
                continue
            kind = el.get("type")
            if kind not in SUPPORTED or el.find("mimic") is not None:
                why = f"{kind}, mimic" if el.find("mimic") is not None else kind
                left_out[child] = f"below joint '{jname}' ({why})"
                continue
            joints.append(self.joint(jname, kind, parent, child, el))
        return UrdfRobot(self.path, self.data, self.root.get("name", ""), root, tuple(joints), left_out)

    def _loop(self, unreached: set[str], parent_of: dict[str, str], ends_of: Callable) -> tuple[str, str]:
        """The message naming the joints of a loop among those the root does not reach, and one of them."""
        start = min(unreached)
        seen: list[str] = []
        jname = start
        while jname not in seen:
            seen.append(jname)
            parent = ends_of(jname)[0]
            if parent not in parent_of:
                break
            jname = parent_of[parent]
        loop = seen[seen.index(jname) :] if jname in seen else seen
        names = ", ".join(f"'{j}'" for j in reversed(loop))
        return f"joints {names} form a loop (a URDF is a tree hanging from one root link)", loop[-1]

    def joint(self, jname: str, kind: str, parent: str, child: str, el: etree._Element) -> UrdfJoint:
        what = f"joint '{jname}':"
        origin = el.find("origin")
        xyz = self.numbers(origin, "xyz", "0 0 0", f"{what} origin")
        rpy = self.numbers(origin, "rpy", "0 0 0", f"{what} origin")
        axis = None
        lower = upper = velocity = None
        given = True
        if kind != "fixed":
            axis = self.numbers(el.find("axis"), "xyz", "1 0 0", f"{what} axis")
            if math.hypot(*axis) < 1e-9:
                raise self.fail(f"{what} the axis must not be zero", el.find("axis"))
            lim = el.find("limit")
            velocity = self.limit(lim, "velocity", what)
            if kind == "continuous":
                lower, upper = -CONTINUOUS_LIMIT_RAD, CONTINUOUS_LIMIT_RAD
            else:  # revolute, prismatic: a missing lower or upper is 0 (the URDF spec's default)
                lower = self.limit(lim, "lower", what)
                upper = self.limit(lim, "upper", what)
                given = lower is not None and upper is not None
                lower, upper = lower or 0.0, upper or 0.0
        line = el.sourceline or 0
        return UrdfJoint(jname, kind, parent, child, xyz, rpy, axis, lower, upper, velocity, line, given)


# --- the profile's frames and joints --------------------------------------------------------------


def offset_param(joint: str) -> str:
    return joint


def origin_param(joint: str, fieldname: str) -> str:
    return f"{joint}.{fieldname}"


def profile_frames(robot: UrdfRobot, length_unit: str = "m", angle_unit: str = "deg") -> tuple[list[dict], dict]:
    """The URDF as the profile YAML's `frames` list and `joints` mapping, in the given units."""
    to_length = 1.0 / LENGTH_IN_M.get(length_unit, 1.0)
    to_angle = 1.0 / ANGLE_IN_RAD.get(angle_unit, 1.0)
    frames: list[dict[str, Any]] = []
    joints: dict[str, dict[str, float]] = {}
    for j in robot.joints:
        body: dict[str, Any] = {"xyz": [v * to_length for v in j.xyz], "rpy": [v * to_angle for v in j.rpy]}
        names = {f: origin_param(j.name, f) for f in ORIGIN_FIELDS}
        frame: dict[str, Any] = {"name": j.child, "parent": j.parent}
        if j.movable:
            assert j.axis is not None and j.lower is not None and j.upper is not None
            body["axis"] = list(j.axis)
            names["offset"] = offset_param(j.name)
            frame["joint"] = j.name
            if j.prismatic:  # limits and speed in the profile's length unit
                speed = j.velocity if j.velocity else DEFAULT_SPEED_M_S
                limits = {"lower": j.lower * to_length, "upper": j.upper * to_length, "velocity": speed * to_length}
                joints[j.name] = {"type": "prismatic", **limits}
            else:
                velocity = j.velocity if j.velocity else DEFAULT_VELOCITY_RAD_S
                joints[j.name] = {
                    "lower": j.lower * to_angle,
                    "upper": j.upper * to_angle,
                    "velocity": velocity * to_angle,
                }
        frame["urdf"] = body
        frame["names"] = names
        frames.append(frame)
    return frames, joints


def compile_urdf_profile(doc: dict, source: str, compile_doc: Callable[[dict], Profile]) -> Profile:
    """The hook of calib_core.profile.load_profile for a profile that says `urdf: <file>`: the URDF's
    frames and joints go before the profile's own, then `compile_doc` compiles the whole."""
    robot = read_urdf(urdf_path(doc, source))
    fname = Path(robot.path).name

    def fail(where: str, message: str) -> InputError:
        return InputError(f"{where}: {message}", file=source)

    units = doc.get("units") if isinstance(doc.get("units"), dict) else {}
    frames, joints = profile_frames(robot, str(units.get("length", "m")), str(units.get("angle", "deg")))
    out = dict(doc)
    base = str(doc.get("base", robot.root))
    if base != robot.root:
        raise fail("base", f"'{base}' is not the root link '{robot.root}' of {fname}")
    out["base"] = robot.root

    own = doc.get("frames") or []
    if not isinstance(own, list):
        raise fail("frames", "expected a list")
    links = {robot.root, *(f["name"] for f in frames)}
    for i, spec in enumerate(own):
        if not isinstance(spec, dict):
            continue
        if str(spec.get("name")) in links:
            raise fail(f"frames[{i}].name", f"'{spec.get('name')}' is already a link of {fname}")
        _check_kept(robot, spec.get("parent"), f"frames[{i}].parent", fail)
    out["frames"] = frames + own

    own_joints = doc.get("joints") or {}
    if not isinstance(own_joints, dict):
        raise fail("joints", "expected a mapping")
    merged: dict[str, Any] = dict(joints)
    for jname, spec in own_joints.items():
        merged[str(jname)] = {**merged[str(jname)], **spec} if str(jname) in joints and isinstance(spec, dict) else spec
    out["joints"] = merged
    notes = list(robot.notes) + _limit_notes(robot, own_joints)

    for key in ("targets", "sensors"):
        for i, spec in enumerate(doc.get(key) or []):
            if isinstance(spec, dict):
                _check_kept(robot, spec.get("frame"), f"{key}[{i}].frame", fail)

    data = doc.get("data")
    if isinstance(data, dict) and "joints" not in data:
        out["data"] = {**data, "joints": {j: j for j in _chain_joints(out)}}
    defaults = "modes" not in doc
    if defaults:
        out["modes"] = {}
    profile = compile_doc(out)
    if defaults:
        profile = replace(profile, modes=default_modes(profile, robot))
    return replace(profile, notes=tuple(notes + _stuck_notes(profile, robot)))


def _limit_notes(robot: UrdfRobot, own_joints: dict) -> list[str]:
    """A note per joint whose URDF <limit> lacks lower or upper (both 0, the URDF default) that the
    profile's `joints` do not give both; InputError for limits the wrong way round that the profile
    does not override (the profile's own are checked with its other fields)."""
    notes = []
    for j in robot.joints:
        if j.kind not in ("revolute", "prismatic"):
            continue
        spec = own_joints.get(j.name)
        overridden = {k for k in ("lower", "upper") if isinstance(spec, dict) and k in spec}
        if not j.limits_given and len(overridden) < 2:
            notes.append(
                f"{robot.path}, line {j.line}: joint '{j.name}' ({j.kind}) has no <limit lower=... upper=...>: "
                "both 0, the URDF default"
            )
        if not overridden and j.lower is not None and j.upper is not None and j.lower > j.upper:
            raise InputError(
                f"joint '{j.name}': <limit> lower {j.lower:g} is above upper {j.upper:g} "
                "(or give its limits under the profile's joints)",
                file=robot.path,
                line=j.line,
            )
    return notes


def _stuck_notes(profile: Profile, robot: UrdfRobot) -> list[str]:
    """A note per URDF joint that cannot move (lower == upper) while a mode estimates its offset: the
    data then see the offset only as a constant, and a planner has nowhere to move it."""
    notes = []
    urdf = {j.name for j in robot.joints if j.movable}
    for k, joint in enumerate(profile.joints):
        if joint.name not in urdf or joint.lower != joint.upper:
            continue
        params = {op.param for f in profile.frames for op in f.ops if op.joint == k}
        modes = [m.name for m in profile.modes.values() if params & set(m.free)]
        if modes:
            value = f"{profile.joint_to_display(k, joint.lower):g} {profile.joint_display_unit(k)}"
            notes.append(
                f"joint '{joint.name}' cannot move (lower = upper = {value}) but mode(s) {', '.join(modes)} "
                f"estimate its offset; give it limits under the profile's joints: {{{joint.name}: "
                "{lower: ..., upper: ...}}"
            )
    return notes


def urdf_path(doc: dict, source: str) -> Path:
    """The URDF a profile names, relative to the profile file's folder."""
    ref = doc.get("urdf")
    if not isinstance(ref, str) or not ref.strip():
        raise InputError(f"urdf: expected the path of a URDF file, got {ref!r}", file=source)
    path = Path(ref)
    if path.is_absolute():
        return path
    if source.endswith(BUILTIN_SUFFIX):
        return Path(str(resources.files("calib_core.model") / "profiles")) / path
    return Path(source).parent / path


def _check_kept(robot: UrdfRobot, frame: Any, where: str, fail: Callable[[str, str], InputError]) -> None:
    if frame is not None and str(frame) in robot.left_out:
        raise fail(
            where,
            f"link '{frame}' hangs {robot.left_out[str(frame)]}, which cannot be calibrated "
            f"(only {', '.join(SUPPORTED)} joints can, and no mimic joint)",
        )


def _chain_joints(doc: dict) -> list[str]:
    """The joints between the base and the targets and the data's sensor, in frame order."""
    frames = [f for f in doc.get("frames") or [] if isinstance(f, dict)]
    parent = {str(f.get("name")): str(f.get("parent")) for f in frames}
    data = doc.get("data") or {}
    ends = [str(t.get("frame")) for t in doc.get("targets") or [] if isinstance(t, dict)]
    sensors = [s for s in doc.get("sensors") or [] if isinstance(s, dict)]
    ends += [str(s.get("frame")) for s in sensors if s.get("name") == data.get("sensor")] or [
        str(s.get("frame")) for s in sensors
    ]
    on_chain: set[str] = set()
    for name in ends:
        while name in parent and name not in on_chain:
            on_chain.add(name)
            name = parent[name]
    return [str(f["joint"]) for f in frames if "joint" in f and str(f.get("name")) in on_chain]


# --- default modes --------------------------------------------------------------------------------


def default_modes(profile: Profile, robot: UrdfRobot) -> dict[str, Mode]:
    """`offsets` and `origins` for the joints on the chains the data use, and `handeye` first when the data's
    sensor or a target hangs from a registration frame (see the module doc)."""
    fmt = profile.data
    used = {fmt.target, getattr(fmt, "target_default", None), *fmt.target_values.values()} - {None}
    targets = [profile.targets[t] for t in sorted(used)] or list(profile.targets)
    sensor = profile.sensors[fmt.sensor]
    frames = sorted(set(profile.chain(sensor.frame)).union(*(profile.chain(t.frame) for t in targets)))
    from_urdf = {j.child: j for j in robot.joints}
    offsets: list[int] = []
    setup: list[int] = []
    origins: list[int] = []
    for f in frames:
        frame = profile.frames[f]
        joint = from_urdf.get(frame.name)
        for op in frame.ops:
            if op.joint >= 0:
                offsets.append(op.param)
            elif joint is None:
                setup.append(op.param)
            elif joint.movable:
                origins.append(op.param)
    for t in targets:
        setup += list(t.point_params or ())
    registered = [op.param for f in frames if profile.frames[f].registration for op in profile.frames[f].ops]
    setup = registered + [i for i in setup if i not in registered]  # the registrations first
    names = [profile.joints[op.joint].name for f in frames for op in profile.frames[f].ops if op.joint >= 0]
    groups = dict.fromkeys(profile.parameter_names[i].rpartition(".")[0] or profile.parameter_names[i] for i in setup)
    what = f"the set-up ({', '.join(groups)}) and " if setup else ""
    what += f"the offsets of {', '.join(names) or 'no joint'}"
    length_sigma = ORIGIN_PRIOR_MM * LENGTH_IN_M["mm"] / LENGTH_IN_M[profile.length_unit]
    angle_sigma = math.radians(ORIGIN_PRIOR_DEG)
    priors = {i: angle_sigma if profile.parameters[i].kind == "angle" else length_sigma for i in origins}
    handeye = {}
    if registered:
        where = ", ".join(profile.frames[f].name for f in frames if profile.frames[f].registration)
        handeye["handeye"] = Mode("handeye", f"where {where} stand (the registrations) only", tuple(registered), (), {})
    return handeye | {
        "offsets": Mode("offsets", what, tuple(setup + offsets), (), {}),
        "origins": Mode(
            "origins",
            f"{what}, and each joint's origin correction (x, y, z, roll, pitch, yaw; "
            f"prior sigma {ORIGIN_PRIOR_MM:g} mm, {ORIGIN_PRIOR_DEG:g} deg towards the URDF)",
            tuple(setup + offsets + origins),
            (),
            priors,
        ),
    }


# --- the URDF behind a loaded profile ------------------------------------------------------------


def profile_urdf_path(profile: Profile) -> Path | None:
    """The URDF file a profile names (read again from its profile file), or None: a profile of its own
    frames, or a profile file that cannot be read any more."""
    source = profile.source
    try:
        if source.endswith(BUILTIN_SUFFIX):
            res = resources.files("calib_core.model") / "profiles" / f"{source[: -len(BUILTIN_SUFFIX)]}.yaml"
            text = res.read_text(encoding="utf-8")
        else:
            text = read_text_file(source, MAX_YAML_BYTES, "robot profile file")
        doc = load_yaml(text, source)
        if not isinstance(doc, dict) or "urdf" not in doc:
            return None
        return urdf_path(doc, source)
    except (OSError, UnicodeDecodeError, InputError):
        return None


def profile_urdf(profile: Profile) -> UrdfRobot | None:
    """The URDF a profile was loaded from (read again from its profile file), or None.

    It must still be the URDF the profile was compiled from: every imported joint's origin and axis
    as the profile's nominal values say (else InputError: the file changed since)."""
    path = profile_urdf_path(profile)
    if path is None:
        return None
    robot = read_urdf(path)
    nominal = profile.nominal()
    to_length = 1.0 / LENGTH_IN_M[profile.length_unit]
    for j in robot.joints:
        try:
            frame = profile.frames[profile.frame(j.child)]
            values = [nominal[profile.param(origin_param(j.name, f))] for f in ORIGIN_FIELDS]
        except (KeyError, InputError):
            values, frame = [], None
        want = [v * to_length for v in j.xyz] + list(j.rpy)
        same = frame is not None and np.allclose(values, want, rtol=1e-9, atol=1e-9)
        if same and j.axis is not None:
            axis = next((op.vector for op in frame.ops if op.joint >= 0), None)
            same = axis is not None and np.allclose(axis, np.array(j.axis) / np.linalg.norm(j.axis), atol=1e-12)
        if not same:
            raise InputError(
                f"joint '{j.name}' is not what the profile '{profile.name}' was loaded with: "
                "the URDF changed since; load the profile again",
                file=robot.path,
                line=j.line,
            )
    return robot
