"""What a robot's driver takes: per-joint offsets (YAML) and a URDF with corrected joint origins.

Most drivers ignore URDF `<calibration>` tags, so the URDF carries the calibrated geometry in the
joint origins themselves (calib_core.urdf), and the offsets file says, per joint, what to add to the
encoder reading (deg) to get the angle the calibrated model uses.
"""

from __future__ import annotations

import math

import yaml

from .calibration import Calibration
from .profile import Profile
from .urdf import to_urdf


def offsets_yaml(profile: Profile, cal: Calibration) -> str:
    """The offsets file: joint -> offset to add to the reading, with the calibration's provenance."""
    p = cal.params(profile)
    std = {q.name: q.std for q in cal.parameters}
    names = profile.parameter_names
    joints = {}
    for frame in profile.frames:
        for op in frame.ops:
            if op.joint < 0:
                continue
            unit = "deg" if op.kind == "r" else profile.length_unit
            delta = float(p[op.param] - profile.nominal()[op.param])
            s = std.get(names[op.param])
            joints[profile.joints[op.joint].name] = {
                "offset": round(math.degrees(delta) if op.kind == "r" else delta, 6),
                "unit": unit,
                "std": None if s is None else round(float(s), 6),
                "parameter": names[op.param],
            }
    doc = {
        "robot": profile.name,
        "calibration": {"mode": cal.mode, "created": cal.created, "source": cal.source},
        "meaning": "angle used by the calibrated model = encoder reading + offset",
        "joints": joints,
    }
    return yaml.safe_dump(doc, sort_keys=False)


def calibrated_urdf(profile: Profile, cal: Calibration) -> str:
    """The robot's URDF with the calibration's geometry in its joint origins."""
    return to_urdf(profile, cal.params(profile))
