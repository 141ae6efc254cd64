"""GET /api/health; the robots on the desk: list, add (a profile uploaded or named), remove."""

from __future__ import annotations

import asyncio
import math
from typing import Annotated

from fastapi import APIRouter, File, Form, UploadFile
from pydantic import BaseModel

from calib_core import Profile

from ...robots.roster import Robot
from ...services.robots import NewRobot, Upload
from .deps import DeskDep, LimitsDep, RobotsDep, RobotServiceDep, read_upload

VERSION = "0.4.0"
router = APIRouter()


class Health(BaseModel):
    status: str
    version: str
    viser_port: int  # the viser server's, on 127.0.0.1 only: browsers reach the scene under /scene on this port
    instance: str  # this server process: another after a restart (the page then reloads its scene)


@router.get("/health")
def health(desk: DeskDep) -> Health:
    return Health(status="ok", version=VERSION, viser_port=desk.viser_port_number, instance=desk.instance)


class JointOut(BaseModel):
    name: str
    lower_deg: float | None  # None for a prismatic joint: see lower, upper, velocity in unit
    upper_deg: float | None
    velocity_deg_s: float | None
    type: str = "revolute"  # or "prismatic"
    unit: str = "deg"  # of lower, upper (and velocity per s): deg, or the profile's length unit
    lower: float = 0.0
    upper: float = 0.0
    velocity: float = 0.0


class ModeOut(BaseModel):
    name: str
    description: str


class SensorOut(BaseModel):
    kind: str  # "pinhole" | "point3d"
    unit: str  # of its measurements
    image: list[int] | None  # width, height in px (None: no image, a laser tracker)


class RobotOut(BaseModel):
    """A robot on the desk: an instance of a profile (`model`), with a driver or none (real data only)."""

    name: str
    title: str
    model: str  # the profile's own name (nao for nao-1 ... nao-5)
    driver: str | None  # the driver's kind, None: real data only
    drivable: bool  # has a driver that can move it (connect, move, observe, capture, replay)
    simulated: bool  # its driver is the simulated robot
    origin: str  # "builtin" (the desk's defaults), "config" (its configuration file), "api" (added here)
    joints: list[JointOut]
    margin_deg: float | None = None  # its driver's safety margin: no move closer to a joint limit (None: no driver)
    margin_m: float | None = None  # the same for a prismatic joint, in m
    modes: list[ModeOut]
    targets: list[str]
    sensor: SensorOut
    notes: list[str] = []  # what loading its profile tolerated (a URDF's quirks), for the user to read


def _joint_out(p: Profile, k: int) -> JointOut:
    j = p.joints[k]
    revolute = not j.prismatic
    return JointOut(
        name=j.name,
        lower_deg=math.degrees(j.lower) if revolute else None,
        upper_deg=math.degrees(j.upper) if revolute else None,
        velocity_deg_s=math.degrees(j.velocity) if revolute else None,
        type="prismatic" if j.prismatic else "revolute",
        unit=p.joint_display_unit(k),
        lower=p.joint_to_display(k, j.lower),
        upper=p.joint_to_display(k, j.upper),
        velocity=p.joint_to_display(k, j.velocity),
    )


def robot_out(robot: Robot) -> RobotOut:
    p = robot.profile
    sensor = p.sensors[p.data.sensor]
    return RobotOut(
        name=robot.name,
        title=p.title,
        model=robot.model,
        driver=robot.driver_kind,
        drivable=robot.drivable,
        simulated=robot.simulated,
        origin=robot.origin,
        joints=[_joint_out(p, k) for k in range(len(p.joints))],
        margin_deg=None if robot.driver is None else math.degrees(robot.driver.margin_rad),
        margin_m=None if robot.driver is None else robot.driver.margin_m,
        notes=list(p.notes),
        modes=[ModeOut(name=m.name, description=m.description) for m in p.offered_modes()],
        targets=[t.name for t in p.targets],
        sensor=SensorOut(
            kind=sensor.kind,
            unit=sensor.unit,
            image=list(sensor.image) if getattr(sensor, "image", None) else None,
        ),
    )


@router.get("/robots")
def robots(robots: RobotsDep) -> list[RobotOut]:
    """Every robot on the desk: the drivable ones can be connected, moved, observed and replayed; the others
    (real data only) have sessions imported from CSV, calibrations and reviews."""
    return [robot_out(r) for r in robots.all()]


# Its docstring is the API document's description, kept as written (app/profile_meshes.py: now
# app/robots/profile_meshes.py).
@router.post("/robots", status_code=201)
async def add_robot(
    service: RobotServiceDep,
    limits: LimitsDep,
    name: Annotated[str, Form(min_length=1, max_length=64)],
    profile: Annotated[str | None, Form(max_length=4096)] = None,
    profile_file: Annotated[UploadFile | None, File()] = None,
    urdf_file: Annotated[UploadFile | None, File()] = None,
    driver: Annotated[str | None, Form(max_length=64)] = None,
    driver_options: Annotated[str | None, Form(max_length=4096)] = None,
    meshes_zip: Annotated[UploadFile | None, File()] = None,
) -> RobotOut:
    """Add a robot to the running desk, kept after a restart: `name`, and its profile either uploaded
    (`profile_file`, with `urdf_file` when the profile says `urdf: ...`, and `meshes_zip`: a zip of the URDF's
    meshes, its paths relative to the profile's folder, the description package's root) or named in `profile`
    (a built-in profile, or on a desk bound to loopback a profile file on this machine). `driver`: a driver
    kind (`simulated`), none for real data only; `driver_options`: its options as a JSON object (the simulated
    driver's `{"seed": 2, "day": 3}`), checked by the kind (422 naming `driver_options.<option>`), kept with the
    robot and used again after a restart. A broken profile or zip answers 422 naming its file and field
    or entry; a zip larger unpacked than the desk's limit 413. A profile file named brings its URDF's meshes
    (app/profile_meshes.py): 413 when they are more or larger together than a zip may hold."""

    async def read(upload: UploadFile | None) -> Upload | None:
        return None if upload is None else Upload(upload.filename, await read_upload(limits, upload))

    new = NewRobot(
        name,
        profile=profile,
        profile_file=await read(profile_file),
        urdf_file=await read(urdf_file),
        meshes_zip=await read(meshes_zip),
        driver=driver,
        driver_options=driver_options,
    )
    return robot_out(await asyncio.to_thread(service.add, new))


class Deleted(BaseModel):
    deleted: str


@router.delete("/robots/{name}")
def remove_robot(service: RobotServiceDep, name: str) -> Deleted:
    """Take a robot added here off the desk (one with sessions or calibrations stays: they name it)."""
    service.remove(name)
    return Deleted(deleted=name)
