"""The checks every door of the desk shares: ids and names, frame numbers, joint names and angles, targets.

The API's Pydantic models check shapes and ranges; these check what needs a robot's profile or must hold
the same for the store, the importers and the API. Each raises InputError with one sentence naming the
value (the API answers 422).
"""

from __future__ import annotations

import math
import re
from collections.abc import Mapping

import numpy as np

from calib_core import InputError, Profile

ID = re.compile(r"[A-Za-z0-9][A-Za-z0-9_.-]{0,63}")  # a session id or a robot's name: also a folder name
ROLE = re.compile(r"[a-z][a-z0-9_]{0,31}")  # an image's role in a frame (left, right, image)
IMAGE_NAME = re.compile(r"\d{4}_[a-z0-9_]+\.jpg")  # a stored frame image's file name
# A frame number as the store keeps it (SQLite INTEGER): beyond it a 422, not an overflow deep inside.
FRAME_MIN, FRAME_MAX = -(2**63), 2**63 - 1


def check_id(kind: str, value: str) -> str:
    """`value` as an id of a `kind` ("session id", "robot name"): 1-64 letters, digits, '_', '.', '-'."""
    if not isinstance(value, str) or not ID.fullmatch(value):
        raise InputError(f"{kind} '{value}' must be 1-64 letters, digits, '_', '.' or '-' (first a letter or digit)")
    return value


def check_role(role: str) -> str:
    if not ROLE.fullmatch(role):
        raise InputError(f"image role '{role}' must be a short lower-case name (e.g. left, right, image)")
    return role


def check_joints_rad(profile: Profile, joints_rad: np.ndarray) -> np.ndarray:
    """One finite reading (rad) per joint of the profile, in its order."""
    q = np.asarray(joints_rad, dtype=float).ravel()
    if q.shape != (len(profile.joints),):
        raise InputError(f"a {profile.name} frame has {len(profile.joints)} joint readings, not {q.size}")
    if not np.all(np.isfinite(q)):
        raise InputError("joint readings must be finite numbers")
    return q


def joints_from_deg(profile: Profile, start_rad: np.ndarray, joints_deg: Mapping[str, float]) -> np.ndarray:
    """`start_rad` with the named joints set (deg); an unknown name or a non-finite angle is refused."""
    names = profile.joint_names
    q = np.array(start_rad, dtype=float)
    for name, value in joints_deg.items():
        if name not in names:
            raise InputError(f"joints.{name}: no such joint (known: {', '.join(names)})")
        if not math.isfinite(value):
            raise InputError(f"joints.{name}: {value} is not a finite angle")
        q[names.index(name)] = math.radians(value)
    return q


def check_target(profile: Profile, target: int) -> int:
    if not 0 <= int(target) < len(profile.targets):
        raise InputError(f"target {target} is not one of the {len(profile.targets)} targets of {profile.name}")
    return int(target)
