"""Calibrations: one (parameters, figures, warnings), apply it to its robot, export it for the robot's driver."""

from __future__ import annotations

import json
from typing import Annotated, Literal

import numpy as np
from fastapi import APIRouter, Query, Response
from pydantic import BaseModel, Field

from calib_core import Calibration, Profile
from calib_core.estimation import Correlation, Diagnostic, DiagnosticGroup, HeldParameter, Outlier, ParameterEstimate
from calib_core.io import calibrated_urdf, export_handeye, flange_calibration_json, offsets_yaml

from .deps import ApplyDep, CalibrationsDep, RobotsDep
from .models import Figures

router = APIRouter()


class NoiseTest(BaseModel):
    """One sensor's residuals against its declared noise (calib_core.estimation.NoiseTest)."""

    sensor: str
    factor: float  # residual RMS over the declared noise
    rows: int
    dof: float
    p_value: float
    level: float
    rejected: bool  # p_value < level: the residuals are clearly above the declared noise


class Solver(BaseModel):
    """How the solver stopped (calib_core.estimation.SolverReport): `status` a code, `message` in words."""

    method: str  # "lm" | "nelder-mead"
    status: str
    iterations: int
    evaluations: int
    solve_seconds: float
    robust: bool
    cost_history: list[float]
    sigma: float | None  # scale of the whitened residuals at the solution
    folds: int  # k of the k-fold cross-validation (0: none)
    cv_seconds: float | None
    minimal: bool  # a minimal identifiable parameter set, without the mode's priors
    noise_tests: list[NoiseTest]
    starts: int
    start: str  # the start whose solution was kept
    message: str
    converged: bool
    fits_noise: bool | None  # None: not tested


class Identifiability(BaseModel):
    """What the data determine (calib_core.estimation.IdentifiabilityReport)."""

    free: list[str]
    held_fixed: list[HeldParameter]
    singular_values: list[float]
    rank: int
    condition: float | None  # None: infinite
    o1: float | None
    correlations: list[Correlation]
    inflation: dict[str, float]  # per parameter: its standard deviation over what it would be alone
    note: str


class CandidateOut(BaseModel):
    """One model mode `auto` compared (calib_core.estimation.reports.Candidate)."""

    mode: str
    prior_scale: float | None  # the mode's priors' standard deviations times this (None: the mode has none)
    score: float | None  # cross-validated mean squared error per row, weighed by the declared noise (None: refused)
    figures: Figures | None  # the same cross-validated errors in the sensors' units
    refused: str | None  # why it was not compared


class ModelChoiceOut(BaseModel):
    """What mode `auto` chose and why (calib_core.estimation.reports.ModelChoice)."""

    candidates: list[CandidateOut]
    chosen: int  # the index of the one chosen: the least score
    folds: int
    shuffles: int  # of the training configurations, each cut into `folds` parts
    compared: int  # predicted observations compared (those every competitive candidate's fit explains)
    held_out: int  # predicted observations
    seconds: float


class CalibrationOut(BaseModel):
    """The calibration file (format calib-calibration/1, calib_core.estimation.Calibration: every parameter with
    its unit and standard deviation, the figures before and after, the solver, identifiability, outliers,
    diagnostics) and where it came from."""

    id: str
    robot: str  # the robot it was made for and may be applied to
    mode: str
    session: str | None
    base: str | None
    holdout: float
    parameters: list[ParameterEstimate]  # display units
    figures: dict[str, Figures]  # before, after; holdout_before, holdout_after; cv_after
    warnings: list[str]  # the messages of the diagnostics of severity warning
    method: str
    created: str
    source: str
    solver: Solver
    identifiability: Identifiability
    outliers: list[Outlier]
    diagnostics: list[Diagnostic]
    diagnostic_groups: list[DiagnosticGroup]  # the diagnostics one line per kind, those that change a decision first
    frames: dict[str, list[int]]  # "holdout": the frames held out
    sensor_figures: dict[str, dict[str, Figures]]  # with several sensors: each one's figures, by name
    format: str
    converged: bool
    fits_noise: bool | None
    solve_seconds: float
    iterations: int
    choice: ModelChoiceOut | None = None  # mode `auto`: every candidate's cross-validated figures (None: a named mode)


@router.get("/calibrations/{cal_id}")
def calibration(calibrations: CalibrationsDep, cal_id: str) -> CalibrationOut:
    info = calibrations.info(cal_id)
    cal = calibrations.load(cal_id)
    groups = [g.to_dict() for g in cal.diagnostic_groups()]
    return CalibrationOut.model_validate(
        {
            **cal.to_dict(),
            "diagnostic_groups": groups,
            "id": cal_id,
            "session": info.session_id,
            "base": info.base_id,
            "holdout": info.holdout,
        }
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
def apply(service: ApplyDep, cal_id: str, body: ApplyRequest | None = None) -> Applied:
    """Make the calibration its robot's active one (recorded, then pushed to the robot's driver). Only the robot
    whose session it was made from takes it."""
    body = body or ApplyRequest()
    return Applied.model_validate(service.apply(cal_id, body.note, confirm=body.confirm))


EXPORTS = {
    "json": ("json", "application/json"),
    "yaml": ("offsets.yaml", "application/yaml"),
    "urdf": ("urdf", "application/xml"),
    # A robot known by its flange pose: its camera where a ROS robot takes it (calib_core/io/handeye_export.py).
    "handeye": ("handeye.json", "application/json"),
    "ros2-static-tf": ("launch.py", "text/x-python"),
    "urdf-joint": ("joint.urdf", "application/xml"),
    "easy-handeye": ("easy_handeye.yaml", "application/yaml"),
}


@router.get(
    "/calibrations/{cal_id}/export",
    responses={200: {"content": {"application/json": {}, "application/yaml": {}, "application/xml": {}}}},
)
def export(
    calibrations: CalibrationsDep,
    robots: RobotsDep,
    cal_id: str,
    format: Literal["json", "yaml", "urdf", "handeye", "ros2-static-tf", "urdf-joint", "easy-handeye"] = "json",
    parent: Annotated[str | None, Query(max_length=200)] = None,
    child: Annotated[str, Query(max_length=200)] = "camera_optical_frame",
) -> Response:
    """What the robot's driver takes: the calibration JSON, an offsets YAML or a URDF with corrected origins. For a
    robot known by its flange pose (imported from images and poses) also where its camera goes: `handeye`, `calib
    handeye`'s output form (specs handeye-poses.md), and `ros2-static-tf`, `urdf-joint`, `easy-handeye` as `calib
    export` writes them, the camera's optical frame `child` in `parent` (default tool0 eye-in-hand, base_link
    eye-to-hand); a 422 for another robot."""
    info = calibrations.info(cal_id)
    cal = calibrations.load(cal_id)
    profile = robots.get(info.robot).profile
    if format == "json":
        text = json.dumps(cal.to_dict(), indent=2) + "\n"
    elif format == "yaml":
        text = offsets_yaml(profile, cal)
    elif format == "urdf":
        text = calibrated_urdf(profile, cal)
    else:
        text = _handeye_export(profile, cal, format, parent, child)
    suffix, media = EXPORTS[format]
    name = f"{cal.robot}-{cal.mode}-{cal_id}.{suffix}"
    return Response(text, media_type=media, headers={"Content-Disposition": f'attachment; filename="{name}"'})


def _handeye_export(profile: Profile, cal: Calibration, fmt: str, parent: str | None, child: str) -> str:
    """A flange-pose robot's calibration in calib handeye's form, or its camera as `calib export` writes it."""
    form = flange_calibration_json(profile, cal)
    if fmt == "handeye":
        return json.dumps(form, indent=2) + "\n"
    setup = form["setup"]
    camera = np.array(form["camera_in_flange" if setup == "eye-in-hand" else "camera_in_base"]["matrix"])
    camera[:3, 3] /= 1000.0  # mm -> m, as ROS takes it
    return export_handeye(setup, camera, fmt, parent or ("tool0" if setup == "eye-in-hand" else "base_link"), child)
