"""The NAOqi connection file (specs naoqi.md) and what `calib serve --naoqi` makes of it: a robot on the desk.

    robot: nao-3                 # the robot's name on the desk
    profile: nao                 # the built-in NAO profile, or a profile file relative to this file
    url: tcp://127.0.0.1:9559    # the robot's NAOqi address
    camera: 1                    # ALVideoDevice camera index: 1 = the lower camera (the paper's)

Extensions (optional, with their defaults): the naoqi driver's other options (app/drivers/naoqi/driver.py):
`color_space: 9`, `fps: 15`, `margin_deg: 1.0`, `tolerance_deg: 0.5`, `still_deg: 0.05`, `timeout_s: 1.0`,
`measurement_wait_s: 5.0`, `call_timeout_s: 2.0` (a call to NAOqi not answered within this: the robot is not
responding), `settle_s: 0.3` (a capture looks once the readings stayed still this long; `calib
sim-naoqi --speed N` writes 0.3 / N, its NAO settling N times as fast).
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

from calib_core import InputError, Profile, load_profile

from ..connection_file import profile_ref, read_connection

FIELDS = ("robot", "profile")


@dataclass(frozen=True)
class Connection:
    path: Path
    robot: str
    profile: str  # a built-in profile's name or an absolute path
    options: dict[str, Any]  # the naoqi driver's, checked

    def load_profile(self) -> Profile:
        return replace(load_profile(self.profile), name=self.robot)


def load_connection(path: Path) -> Connection:
    """Read and check a connection file; InputError naming the file and the field."""
    from . import driver

    path = Path(path).resolve()
    file = str(path)
    doc = read_connection(path, "NAOqi connection file", "robot, profile, url, camera", FIELDS + tuple(driver.OPTIONS))
    ref = doc.get("profile", "nao")
    if not isinstance(ref, str) or not ref.strip():
        raise InputError(f"profile: expected the built-in nao or a profile file, got {ref!r}", file=file)
    profile = profile_ref(ref, path)
    conn = Connection(path, doc["robot"], profile, {})
    try:
        model = conn.load_profile()
        options = driver.check(model, {k: v for k, v in doc.items() if k not in FIELDS}, "profile", "connection")
    except InputError as exc:
        where = exc.message.removeprefix("connection.")
        raise InputError(where, file=exc.file or file, line=exc.line) from None
    return replace(conn, options=options)
