"""The answers more than one router gives (Pydantic models, so that /openapi.json tells the truth), and the
functions that make them from the desk's objects."""

from __future__ import annotations

import math
from typing import Any

import numpy as np
from pydantic import BaseModel

from calib_core import Profile

from ..desk import Desk
from ..store import FrameInfo


class FrameOut(BaseModel):
    index: int
    joints: dict[str, float | None]  # deg, by joint name
    target: str
    status: str  # "measured" | "not found" | "skipped" | "pending"
    reason: str
    images: dict[str, str]  # role -> URL
    detail: dict[str, Any]  # what the detector reported
    captured: str
    observations: dict[str, int] = {}  # sensor name -> how many observations it made in this frame


class RobotState(BaseModel):
    """A drivable robot now."""

    robot: str
    connected: bool
    moving: bool
    joints: dict[str, float | None]  # deg
    target: str
    calibration: str | None  # the calibration the robot runs with (None: the nominal model)
    message: str
    observing: dict[str, Any] | None  # the session observed and what the live view sees


class JobStarted(BaseModel):
    job: str


def degrees(profile: Profile, q_rad: np.ndarray) -> dict[str, float | None]:
    return {
        name: (None if not math.isfinite(v) else round(math.degrees(v), 4))
        for name, v in zip(profile.joint_names, q_rad, strict=True)
    }


def frame_out(profile: Profile, f: FrameInfo, counts: dict[int | None, int] | None = None) -> FrameOut:
    """A frame as the API shows it; `counts`: its observations per sensor index (None: the data sensor)."""
    names = {profile.sensors[profile.data.sensor if s is None else s].name: n for s, n in (counts or {}).items()}
    return FrameOut(
        index=f.index,
        joints=degrees(profile, f.joints_rad),
        target=profile.targets[f.target].name,
        status=f.status,
        reason=f.reason,
        images={role: f"/api/files/{path}" for role, path in f.images.items()},
        detail=f.detail,
        captured=f.captured,
        observations=names,
    )


def robot_state(desk: Desk, robot: str | None) -> RobotState:
    """The state of `robot` (None: the connected one)."""
    name = desk.robot_name(robot)
    driver = desk.robots.driver(name)
    st = driver.status()
    profile = driver.profile
    return RobotState(
        robot=name,
        connected=st.connected,
        moving=st.moving,
        joints=degrees(profile, st.joints_rad),
        target=profile.targets[st.target].name,
        calibration=st.calibration_id,
        message=st.message,
        observing=desk.observing(),
    )
