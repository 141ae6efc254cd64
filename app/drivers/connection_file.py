"""What every robot's connection file (`calib serve --ros2 FILE`, `--naoqi FILE`) starts with: a YAML mapping of
known fields, the robot's name on the desk and its profile (a built-in one or a file relative to this file)."""

from __future__ import annotations

from collections.abc import Iterable
from pathlib import Path
from typing import Any

from calib_core import InputError
from calib_core.model import BUILTIN_PROFILES
from calib_core.safe_yaml import read_yaml

from ..store.validation import check_id


def read_connection(path: Path, what: str, shape: str, fields: Iterable[str]) -> dict[str, Any]:
    """The file's mapping (`what`: "ROS 2 connection file"; `shape`: its fields for a message), its fields known
    and its robot's name valid; InputError naming the file and the field."""
    file = str(path)
    doc = read_yaml(path, what)
    if not isinstance(doc, dict):
        raise InputError(f"a {what} is a YAML mapping ({shape})", file=file)
    fields = tuple(fields)
    unknown = sorted(set(doc) - set(fields))
    if unknown:
        raise InputError(f"{unknown[0]}: no such field (fields: {', '.join(fields)})", file=file)
    try:
        check_id("robot name", doc.get("robot"))
    except InputError as exc:
        raise InputError(f"robot: {exc.message}", file=file) from None
    return doc


def profile_ref(ref: str, path: Path) -> str:
    """A built-in profile's name, or the profile file `ref` relative to the connection file as an absolute path
    (InputError when it is neither)."""
    profile = ref if ref in BUILTIN_PROFILES else str((path.parent / ref).resolve())
    if profile not in BUILTIN_PROFILES and not Path(profile).is_file():
        raise InputError(
            f"profile: {ref} does not exist (relative to this file) and is no built-in profile", file=str(path)
        )
    return profile
