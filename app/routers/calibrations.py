"""Calibrations: one (parameters, figures, warnings), apply it to its robot, export it for the robot's driver."""

from __future__ import annotations

import json
from typing import Any, Literal

from fastapi import APIRouter, Response
from pydantic import BaseModel, ConfigDict, Field

from calib_core.io import calibrated_urdf, offsets_yaml

from .deps import DeskDep, RobotsDep, StoreDep

router = APIRouter()


class CalibrationOut(BaseModel):
    """The calibration file (format calib-calibration/1: every parameter with its unit and standard deviation,
    the figures before and after, the solver, identifiability, outliers, warnings) and where it came from."""

    model_config = ConfigDict(extra="allow")

    id: str
    robot: str  # the robot it was made for and may be applied to
    mode: str
    session: str | None
    base: str | None
    holdout: float
    parameters: list[dict[str, Any]]
    figures: dict[str, Any]
    warnings: list[Any]


@router.get("/calibrations/{cal_id}")
def calibration(store: StoreDep, cal_id: str) -> CalibrationOut:
    info = store.calibrations.info(cal_id)
    body = store.calibrations.load(cal_id).to_dict()
    return CalibrationOut.model_validate(
        {**body, "id": cal_id, "session": info.session_id, "base": info.base_id, "holdout": info.holdout}
    )


class ApplyRequest(BaseModel):
    note: str = Field("", max_length=500)
    confirm: bool = False  # apply even if it is worse than the active one or moves beyond sane bounds


class ApplyConcerns(BaseModel):
    """409: what needs the operator's confirmation (re-post with {"confirm": true})."""

    detail: str
    reasons: list[str]


class Applied(BaseModel):
    active: str
    previous: str | None  # the robot's active calibration before (None: the nominal model)
    robot: str
    recorded: bool  # a history row was added (False: it was already active, pushed to the driver again)
    deployed: str | None = None  # what the driver did with it (a ROS 2 robot: the parameter it set); else absent


# `deployed` only when a driver put the calibration on the robot (a ROS 2 robot): other answers stay as they were.
@router.post(
    "/calibrations/{cal_id}/apply", responses={409: {"model": ApplyConcerns}}, response_model_exclude_unset=True
)
def apply(desk: DeskDep, cal_id: str, body: ApplyRequest | None = None) -> Applied:
    """Make the calibration its robot's active one (recorded, then pushed to the robot's driver). Only the robot
    whose session it was made from takes it."""
    body = body or ApplyRequest()
    return Applied.model_validate(desk.apply.apply(cal_id, body.note, confirm=body.confirm))


EXPORTS = {
    "json": ("json", "application/json"),
    "yaml": ("offsets.yaml", "application/yaml"),
    "urdf": ("urdf", "application/xml"),
}


@router.get(
    "/calibrations/{cal_id}/export",
    responses={200: {"content": {"application/json": {}, "application/yaml": {}, "application/xml": {}}}},
)
def export(
    store: StoreDep, robots: RobotsDep, cal_id: str, format: Literal["json", "yaml", "urdf"] = "json"
) -> Response:
    """What the robot's driver takes: the calibration JSON, an offsets YAML or a URDF with corrected origins."""
    info = store.calibrations.info(cal_id)
    cal = store.calibrations.load(cal_id)
    profile = robots.get(info.robot).profile
    if format == "json":
        text = json.dumps(cal.to_dict(), indent=2) + "\n"
    elif format == "yaml":
        text = offsets_yaml(profile, cal)
    else:
        text = calibrated_urdf(profile, cal)
    suffix, media = EXPORTS[format]
    name = f"{cal.robot}-{cal.mode}-{cal_id}.{suffix}"
    return Response(text, media_type=media, headers={"Content-Disposition": f'attachment; filename="{name}"'})
