"""The answers more than one router gives (Pydantic models, so that /openapi.json tells the truth), and the
functions that make them from the services' objects."""

from __future__ import annotations

import math

import numpy as np
from pydantic import BaseModel, Field, JsonValue

from calib_core import FrameStatus, Profile

from ...services.connection import Connection
from ...services.observe import Observed
from ...store import FrameInfo


class ObserveState(BaseModel):
    """The session observed and what its live view sees (app/services/observe.py); a field without a value yet
    is left out."""

    session: str
    autocapture: bool
    captured: int  # frames autocapture kept
    last_frame: int | None = Field(None, exclude_if=lambda v: v is None)  # the latest of them
    detection: str | None = Field(None, exclude_if=lambda v: v is None)  # the latest look's status, or "moving"
    reason: str | None = Field(None, exclude_if=lambda v: v is None)  # why it found nothing ("ok": it measured)
    message: str | None = Field(None, exclude_if=lambda v: v is None)  # the latest look's failure
    look: int | None = Field(None, exclude_if=lambda v: v is None)  # the latest look with an image (GET /robot/look)


def observe_state(observed: Observed | None) -> ObserveState | None:
    """What Observe sees as the API answers it (None: not observing)."""
    return None if observed is None else ObserveState.model_validate(observed)


class Figures(BaseModel):
    """A calibration's error figures over its observations (calib_core.estimation.Figures as the calibration
    file holds them: mean, RMS, max and median None when there were none)."""

    n: int
    mean: float | None
    rms: float | None
    max: float | None
    median: float | None
    unit: str
    rms_axes: list[float]  # per measurement coordinate (x, y, z or u, v; a pose's position)
    excluded: int = 0  # observations left out as outliers
    rms_rotation_deg: float | None = None  # a pose's orientation error, RMS of its angle (None: no pose)


class FrameOut(BaseModel):
    index: int
    joints: dict[str, float | None]  # deg, by joint name
    target: str
    status: FrameStatus
    reason: str
    images: dict[str, str]  # role -> URL
    detail: dict[str, JsonValue]  # the detector's own record (its figures; a session folder's, as it came)
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
    observing: ObserveState | None  # None: not observing


class JobStarted(BaseModel):
    job: str


class DryRunRow(BaseModel):
    index: int  # the frame index, or the 1-based position of a new configuration
    target: int
    ok: bool
    problem: str
    action: str  # "capture" | "skip" | "refuse"
    note: str  # how it is moved out of the safety margin ("": it is not)


class PredictedStd(BaseModel):
    name: str
    unit: str
    std: float | None  # predicted standard deviation, display unit (None: not determined)


class PredictedAccuracy(BaseModel):
    """What a calibration from the configurations is predicted to reach, from the noise model alone: the
    expected error over the workspace (None while the configurations do not determine every parameter)."""

    n: int
    unit: str
    mean: float | None
    rms: float | None
    max: float | None
    parameters: list[PredictedStd]
    held: list[str]  # parameters of the mode the configurations cannot determine (held at their base value)


class DryRun(BaseModel):
    ok: bool
    configurations: list[DryRunRow]
    mode: str | None = None  # the mode the accuracy is predicted for
    predicted: PredictedAccuracy | None = None  # of a calibration from the configurations it would capture


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


def robot_state(connection: Connection, robot: str | None) -> RobotState:
    """The state of `robot` (None: the connected one)."""
    name = connection.robot_name(robot)
    driver = connection.driver(name)
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
        observing=observe_state(connection.observing(name)),
    )
