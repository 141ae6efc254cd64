"""A robot's profile on the desk: a built-in one by name or a profile file, named after the robot.

The profile is the model (five NAOs share `nao`); the robot on the desk is an instance of it and goes by
its own name, which replaces the profile's `name:` (as a ROS 2 connection file's `robot:` does), so
every dataset, calibration, driver message and export of that robot carries the instance's name.
"""

from __future__ import annotations

import re
from dataclasses import replace
from importlib import resources
from pathlib import Path

from calib_core import Profile, load_profile
from calib_core.model import BUILTIN_PROFILES

PROFILE_DIR = Path(str(resources.files("calib_core.model") / "profiles"))
_UNSAFE = re.compile(r"[^A-Za-z0-9_.-]")


def is_builtin(ref: str) -> bool:
    """A built-in profile's name (robonaut-a, nao, motoman), not a file."""
    return ref in BUILTIN_PROFILES


def load_model(ref: str, base: Path) -> Profile:
    """A built-in profile by name, or a profile file (a relative path is relative to `base`)."""
    return load_profile(ref if is_builtin(ref) else base / ref)


def as_instance(model: Profile, name: str) -> Profile:
    """The model as robot `name`'s profile."""
    return model if model.name == name else replace(model, name=name)


def instance_profile(ref: str, name: str, base: Path) -> Profile:
    """The profile `ref` (load_model) as robot `name`'s."""
    return as_instance(load_model(ref, base), name)


def builtin_urdf(ref: str) -> Path | None:
    """The URDF shipped with a built-in profile (the scene shows it), None for any other profile."""
    path = PROFILE_DIR / f"{ref}.urdf"
    return path if is_builtin(ref) and path.is_file() else None


def file_name(given: str | None, default: str) -> str:
    """A file name to keep an uploaded file under: its last part, other characters than letters, digits,
    '_', '.' and '-' as '_' (never a path, never hidden)."""
    name = _UNSAFE.sub("_", Path(given or "").name).lstrip(".")
    return name[:64] or default
