"""What the `calib` commands share: a command's parts, the robot and a calibration they read, the files they write
and the JSON they print.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

from calib_core import Calibration, InputError, load_profile
from calib_core.model import Profile


@dataclass(frozen=True)
class Command:
    """A subcommand: its name, its line in `calib --help`, its arguments (added to its own parser) and what runs
    it (its exit status)."""

    name: str
    help: str
    arguments: Callable[[argparse.ArgumentParser], None]
    run: Callable[[argparse.Namespace], int]


def load_robot(args: argparse.Namespace) -> Profile:
    """The --robot profile; what loading it tolerated (a URDF's quirks) goes to stderr as notes."""
    profile = load_profile(args.robot)
    for note in profile.notes:
        print(f"calib {args.command}: note: {note}", file=sys.stderr)
    return profile


def load_calibration(path: str, profile: Profile) -> Calibration:
    """A calibration file that fits the profile: its robot and every parameter name."""
    cal = Calibration.load(path)
    try:
        cal.params(profile)
    except InputError as exc:
        raise InputError(exc.message, file=path) from None
    return cal


def check_writable(path: str, session: bool = False) -> None:
    """Fail before the work, not after it, when the output cannot be written. A session folder may
    replace an earlier session folder, never any other folder."""
    target = Path(path)
    if session and target.is_dir() and not (target / "session.json").is_file():
        raise InputError("exists and is not a session folder; give a new folder name", file=path)
    if not session and target.is_dir():
        raise InputError("is a directory; give a file name", file=path)
    parent = target.parent if str(target.parent) else Path(".")
    if not parent.is_dir():
        raise InputError("its folder does not exist", file=path)
    if not os.access(parent, os.W_OK):
        raise InputError("its folder is not writable", file=path)


def save(path: str, write: Callable[[], object]) -> None:
    """write() the output at `path`; an OSError (a full disk, a folder gone) is the command's error naming it."""
    try:
        write()
    except OSError as exc:
        raise InputError(f"cannot be written ({exc.strerror})", file=path) from None


def print_json(obj: dict, one_line: bool) -> None:
    print(json.dumps(obj) if one_line else json.dumps(obj, indent=2))
