"""What a robot's driver takes: a URDF with corrected joint origins, or per-joint offsets (YAML).

One story for both files. The calibrated model turns an encoder reading q of joint j into the angle
`offset_j + q` about the joint's axis, after the joint's calibrated origin. Either file gives a
driver that model; use one of them, never both:

- the calibrated URDF: the offsets are folded into the joint origins (the origin's rotation is
  followed by the rotation about the axis by the offset) and the origin corrections are in them too,
  so the driver publishes the raw encoder readings as joint positions. Most drivers ignore URDF
  `<calibration>` tags, so none are used. For a profile loaded from a URDF it is the user's own file
  with only the changed `<origin>`s rewritten (meshes, inertials, materials, everything else kept) and the
  set-up's fixed frames it has no link for (a camera mount, a board) added on fixed joints;
  for the other profiles it is calib_core.urdf's model of the profile. Its links may be renamed to
  the names a ROS robot's TF uses (ros_tf.py). A comment in the file says what changed.
- the offsets YAML: per joint, what to add to the encoder reading (deg) before giving it to the
  robot's nominal model (the original URDF). That alone is the calibrated model when the calibration
  changed nothing but joint offsets; otherwise its `geometry` lists the other changes (those only
  the calibrated URDF carries), and the nominal model with those changes, driven by reading +
  offset, is again exactly the calibrated model.
"""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path

import numpy as np
import yaml
from lxml import etree

from ..estimation.calibration import Calibration
from ..model.kinematics import axis_angle
from ..model.profile import Frame, Profile
from ..model.urdf_import import UrdfRobot, profile_urdf, read_urdf
from ..units import length_factor
from .ros_tf import link_names, rename_links
from .urdf_export import rpy_angles, to_urdf, urdf_numbers

DIGITS = 10  # decimals of the YAML's values: far below any calibration, exact enough to 1e-9 m
UNCHANGED = 1e-12  # a parameter (internal units) that moved less than this is unchanged

USE_URDF = (
    "Joint positions for this file are the raw encoder readings: the calibrated joint offsets are "
    "folded into the joint origins (the origin's rotation, then the offset about the joint axis), so "
    "do not also add the offsets of the offsets YAML."
)
USE_YAML = (
    "With the robot's original (nominal) URDF: joint position = encoder reading + offset. "
    "The calibrated URDF already contains these offsets in its joint origins: with it, use the raw "
    "readings and not this file. 'geometry' lists what else the calibration changed in the robot (only "
    "the calibrated URDF has it); when it is empty the offsets alone give the calibrated robot. 'setup' "
    "(for a robot from a URDF): what the calibration found outside the robot's URDF (a tracker's pose, "
    "a tool point, a camera mount)."
)


def joint_offsets(profile: Profile, p: np.ndarray) -> dict[str, tuple[int, float]]:
    """Per joint: the parameter that is its offset (the first frame it drives, in profile order) and
    that parameter's change from nominal, internal units (rad; a prismatic joint's: length unit)."""
    nominal = profile.nominal()
    out: dict[str, tuple[int, float]] = {}
    for frame in profile.frames:
        for op in frame.ops:
            name = profile.joints[op.joint].name if op.joint >= 0 else None
            if name is not None and name not in out:
                out[name] = (op.param, float(p[op.param] - nominal[op.param]))
    return out


def offsets_geometry(profile: Profile, p: np.ndarray) -> np.ndarray:
    """The parameters the offsets YAML goes with: p less each joint's offset on every op that joint
    drives. forward(profile, offsets_geometry(p), q + offsets) is forward(profile, p, q)."""
    offsets = joint_offsets(profile, p)
    g = np.array(p, dtype=float)
    for frame in profile.frames:
        for op in frame.ops:
            if op.joint >= 0:
                g[op.param] -= offsets[profile.joints[op.joint].name][1]
    return g


def offsets_yaml(profile: Profile, cal: Calibration) -> str:
    """The offsets file: joint -> offset to add to the reading, with the calibration's provenance."""
    p = cal.params(profile)
    std = {q.name: q.std for q in cal.parameters}
    names = profile.parameter_names
    joints = {}
    for jname, (i, delta) in joint_offsets(profile, p).items():
        s = std.get(names[i])
        joints[jname] = {
            "offset": round(profile.to_display(i, delta), DIGITS),
            "unit": profile.unit(i),  # deg; a prismatic joint's: the profile's length unit
            "std": None if s is None else round(float(s), DIGITS),
            "parameter": names[i],
        }
    nominal = profile.nominal()
    g = offsets_geometry(profile, p)
    robot = profile_urdf(profile)
    in_urdf = None if robot is None else set(_urdf_params(profile, robot))
    geometry: dict[str, dict] = {}
    setup: dict[str, dict] = {}
    for i in np.flatnonzero(np.abs(g - nominal) > UNCHANGED):
        where = geometry if in_urdf is None or i in in_urdf else setup
        where[names[i]] = {"change": round(profile.to_display(i, g[i] - nominal[i]), DIGITS), "unit": profile.unit(i)}
    doc = {
        "robot": profile.name,
        "calibration": {"mode": cal.mode, "created": cal.created, "source": cal.source},
        "meaning": "angle used by the calibrated model = encoder reading + offset",
        "use": USE_YAML,
        **({"urdf": robot.path} if robot is not None else {}),
        "joints": joints,
        "geometry": geometry,
        **({"setup": setup} if robot is not None else {}),
    }
    return yaml.safe_dump(doc, sort_keys=False, width=100)


def estimated_offsets_deg(profile: Profile, cal: Calibration) -> dict[str, float]:
    """Per joint whose offset the calibration estimated (NAO's full mode: the 12 leg joints), the offset to add
    to its reading, deg (the paper's alpha)."""
    p = cal.params(profile)
    estimated = {q.name for q in cal.parameters if q.estimated}
    names = profile.parameter_names
    return {
        joint: round(float(np.degrees(delta)), DIGITS)
        for joint, (i, delta) in joint_offsets(profile, p).items()
        if names[i] in estimated and not profile.joints[profile.joint(joint)].prismatic
    }


def bhuman_joint_calibration(profile: Profile, cal: Calibration) -> str:
    """The joints of B-Human's jointCalibration.cfg (Config/Robots/<robot>/, the form most RoboCup SPL teams'
    code descends from): per joint `offset`, `minAngle`, `maxAngle`. B-Human subtracts `offset` from the
    sensor reading and adds it to the request, so its offset is minus the one added to the reading here."""
    offsets = estimated_offsets_deg(profile, cal)
    lines = [
        f"// B-Human joint calibration from robot-selfcal: robot '{profile.name}', mode '{cal.mode}', "
        f"created {cal.created}.",
        "// offset = -(the offset added to the reading): B-Human subtracts it from the sensor angle.",
        "joints = {",
    ]
    for k, joint in enumerate(profile.joints):
        lo, hi = (round(profile.joint_to_display(k, v), 4) for v in (joint.lower, joint.upper))
        offset = round(-offsets.get(joint.name, 0.0), 6) + 0.0  # no "-0"
        lines += [
            f"  {joint.name[0].lower()}{joint.name[1:]} = {{",
            f"    offset = {offset:.10g}deg;",
            f"    minAngle = {lo:g}deg;",
            f"    maxAngle = {hi:g}deg;",
            "  };",
        ]
    return "\n".join([*lines, "};", ""])


def calibrated_urdf(profile: Profile, cal: Calibration, links: Mapping[str, str] | None = None) -> str:
    """The robot's URDF with the calibration's geometry and offsets in its joint origins; `links` renames links
    (a profile frame -> the name a ROS robot's TF gives it; calibrated_links() are the names there are), every
    reference to them following."""
    p = cal.params(profile)
    header = (
        f"Calibrated by robot-selfcal: robot '{profile.name}', mode '{cal.mode}', created {cal.created}, "
        f"from {cal.source or 'unknown data'}. {USE_URDF}"
    )
    if links:
        header += f" Renamed links (profile frame -> link): {', '.join(f'{a} -> {b}' for a, b in links.items())}."
    return _calibrated(profile, p, header, links or {})


def calibrated_links(profile: Profile, urdf: str | Path | None = None) -> list[str]:
    """The links of the profile's calibrated URDF, none renamed: the same for every calibration (only numbers
    differ). `urdf`: the URDF file the profile was loaded with, when its profile file does not name it (`urdf: ros2`:
    a ROS 2 robot's, received from its graph)."""
    robot = profile_urdf(profile) if urdf is None else read_urdf(urdf)
    text = to_urdf(profile) if robot is None else corrected_urdf(profile, profile.nominal(), robot)
    return link_names(text)


def _calibrated(profile: Profile, p: np.ndarray, header: str, links: Mapping[str, str]) -> str:
    robot = profile_urdf(profile)
    if robot is None:
        return _with_comment(to_urdf(profile, p), header, links)
    return corrected_urdf(profile, p, robot, header, links)


def corrected_urdf(
    profile: Profile, p: np.ndarray, robot: UrdfRobot, header: str = USE_URDF, links: Mapping[str, str] | None = None
) -> str:
    """The user's URDF file with the joint origins of parameters p (a profile loaded from it), `links` renamed.

    Only the `<origin>` of a joint whose transform changed is rewritten (with a comment giving the
    old values and the changes); every other byte of meaning stays (links, meshes, inertials,
    materials, transmissions, gazebo tags, comments). Joints the profile left out are untouched."""
    root = etree.fromstring(robot.data, etree.XMLParser(resolve_entities=False, no_network=True))
    scale = length_factor(profile.length_unit, "m")
    nominal = profile.nominal()
    imported = {j.name: j for j in robot.joints}
    rewritten = []
    for el in root.findall("joint"):
        joint = imported.get(el.get("name", ""))
        if joint is None:
            continue
        frame = profile.frames[profile.frame(joint.child)]
        T = _origin(frame, p, scale)
        if np.allclose(T, _origin(frame, nominal, scale), rtol=0, atol=1e-15):
            continue
        origin = el.find("origin")
        old = "none" if origin is None else f'xyz="{origin.get("xyz", "0 0 0")}" rpy="{origin.get("rpy", "0 0 0")}"'
        if origin is None:
            origin = _append_indented(el, "origin")
        origin.set("xyz", urdf_numbers(T[:3, 3]))
        origin.set("rpy", urdf_numbers(rpy_angles(T[:3, :3])))
        changes = [
            f"{profile.parameter_names[op.param]} {_signed(profile, op.param, p[op.param] - nominal[op.param])}"
            + (" (offset, folded in about the axis)" if op.joint >= 0 else "")
            for op in frame.ops
            if abs(p[op.param] - nominal[op.param]) > UNCHANGED
        ]
        _comment_before(origin, f"calibrated: origin was {old}; changes: {', '.join(changes)}")
        rewritten.append(joint.name)
    added = _add_setup_frames(root, profile, p, scale)
    kept = set(_urdf_params(profile, robot)) | {op.param for f in added for op in profile.frames[f].ops}
    elsewhere = [profile.parameter_names[i] for i in np.flatnonzero(np.abs(p - nominal) > UNCHANGED) if i not in kept]
    note = f"{header} Rewritten origins: {', '.join(rewritten) or 'none'}."
    if added:
        names = ", ".join(profile.frames[f].name for f in added)
        note += f" Added links, each on a fixed joint '<link>_calibrated' (the set-up the calibration found): {names}."
    if elsewhere:
        note += f" Calibrated but not in this file (the set-up: see the calibration): {', '.join(elsewhere)}."
    comment = etree.Comment(_comment_text(note))
    root.insert(0, comment)
    comment.tail = root.text
    rename_links(root, links or {})
    return _document(root)


def _add_setup_frames(root: etree._Element, profile: Profile, p: np.ndarray, scale: float) -> list[int]:
    """Each fixed profile frame the URDF has no link for (a camera mount, a board, a tracker on a registration
    frame) appended as a link on a fixed joint to its parent, at its calibrated pose: a ROS user's camera frame
    comes with the robot's description, no numbers copied. The frames added, in profile order."""
    links = {el.get("name") for el in root.findall("link")}
    added: list[int] = []
    for f, frame in enumerate(profile.frames):
        parent = profile.base if frame.parent < 0 else profile.frames[frame.parent].name
        if frame.name in links or frame.joint >= 0 or parent not in links:
            continue
        T = _origin(frame, p, scale)
        _append_indented(root, "link").set("name", frame.name)
        joint = _append_indented(root, "joint")
        joint.set("name", f"{frame.name}_calibrated")
        joint.set("type", "fixed")
        etree.SubElement(joint, "parent").set("link", parent)
        etree.SubElement(joint, "child").set("link", frame.name)
        etree.SubElement(joint, "origin", xyz=urdf_numbers(T[:3, 3]), rpy=urdf_numbers(rpy_angles(T[:3, :3])))
        links.add(frame.name)
        added.append(f)
    return added


def _urdf_params(profile: Profile, robot: UrdfRobot) -> list[int]:
    """The parameters of the frames a profile imported from its URDF (those the URDF export holds)."""
    links = {j.child for j in robot.joints}
    return [op.param for f in profile.frames if f.name in links for op in f.ops]


def _origin(frame: Frame, p: np.ndarray, scale: float) -> np.ndarray:
    """The frame's ops at joint reading 0 (m): the URDF origin with the offset folded in."""
    T = np.eye(4)
    for op in frame.ops:
        step = np.eye(4)
        if op.kind == "t":
            step[:3, 3] = op.vector * p[op.param] * scale
        else:
            step[:3, :3] = axis_angle(op.vector, float(p[op.param]))
        T = T @ step
    return T


def _signed(profile: Profile, index: int, delta: float) -> str:
    return f"{profile.to_display(index, delta):+.6g} {profile.unit(index)}"


def _comment_text(text: str) -> str:
    """XML comments may not contain '--' nor end in '-'."""
    while "--" in text:
        text = text.replace("--", "- -")
    return f" {text} "


def _append_indented(parent: etree._Element, tag: str) -> etree._Element:
    """A new last child, on its own line and indented like its siblings."""
    element = etree.Element(tag)
    if len(parent):
        last = parent[-1]
        element.tail, last.tail = last.tail, parent.text
        last.addnext(element)
    else:
        parent.append(element)
    return element


def _document(root: etree._Element) -> str:
    """The document of `root` with an XML declaration, its doctype and the comments around <robot>
    each on a line of its own (lxml keeps no whitespace between top-level nodes)."""
    before: list[etree._Element] = []
    node = root.getprevious()
    while node is not None:
        before.insert(0, node)
        node = node.getprevious()
    after: list[etree._Element] = []
    node = root.getnext()
    while node is not None:
        after.append(node)
        node = node.getnext()
    doctype = root.getroottree().docinfo.doctype
    parts = ['<?xml version="1.0"?>', *([doctype] if doctype else [])]
    parts += [etree.tostring(n, encoding="unicode", with_tail=False) for n in [*before, root, *after]]
    return "\n".join(parts) + "\n"


def _comment_before(element: etree._Element, text: str) -> None:
    """A comment on its own line before `element`, indented like it."""
    previous = element.getprevious()
    parent = element.getparent()
    indent = (previous.tail if previous is not None else parent.text if parent is not None else None) or "\n"
    comment = etree.Comment(_comment_text(text))
    element.addprevious(comment)
    comment.tail = indent


def _with_comment(urdf_text: str, text: str, links: Mapping[str, str]) -> str:
    """calib_core.urdf's document with a comment first inside <robot>, `links` renamed."""
    root = etree.fromstring(urdf_text.encode("utf-8"))
    comment = etree.Comment(_comment_text(text))
    root.insert(0, comment)
    comment.tail = root.text
    rename_links(root, links)
    return _document(root)
