"""The base model of a first plan when the camera's or the board's pose is unknown (a hand-eye set-up).

A plan predicts what the camera sees with a model of the robot (calib_core.estimation.planning). A profile
whose camera or board hangs from a `registration: true` frame gives no pose, so its nominal model puts both
at their parent frames and sees nothing anywhere. Once the robot has a calibration, that calibration plans.
Before the first one, the plan starts from one view of the board:

1. the seed: a configuration where the camera sees the board (the robot where it stands; the desk looks
   through its camera and runs the board's finder on the live image);
2. PnP on the corners found gives the board's pose in the camera (`camera_registration`'s loop with one
   image); the registration that stands still in the world (the board on the table, or the camera in the
   room) is set so that the model predicts this view exactly, the one that moves with the arm (the camera on
   the flange, the board in the hand) stays at its parent frame;
3. the plan keeps within SEED_SPREAD_DEG of the seed on every joint (`planning.Around`): the moving
   registration is unknown, so the model's predictions drift from what the camera sees the further the
   joints turn; close to the seed they stay within the plan's 40 px margin from the image border and the
   finder's partial views.

The frames such a plan captures fix both registrations in closed form (`camera_starts`), so the first
calibration (`handeye`) can be made from them, and its plan then covers the whole workspace.
"""

from __future__ import annotations

import math

import numpy as np

from ..errors import InputError
from ..model.profile import Profile
from ..vision.sighting import Capture, Sighting, dataset_from_captures
from .camera_registration import is_camera, registration_frame, view_registration
from .planning import Around
from .registration import registration_params

# How far a first plan's configurations turn each joint from the seed: on the sample arm (docs/handeye.md), with
# the camera's mount unknown, 12 planned configurations within 15 deg of the seed were all measured.
SEED_SPREAD_DEG = 15.0


def needs_seed(profile: Profile) -> bool:
    """Whether the profile's data sensor is a camera whose pose, or that of a board it sees, is unknown
    (a registration frame) until a calibration estimates it."""
    return is_camera(profile, profile.data.sensor) and bool(registration_params(profile))


def seeded_model(profile: Profile, p: np.ndarray, q_rad: np.ndarray, sighting: Sighting) -> np.ndarray:
    """p with the still registration set so that the board is predicted where `sighting` found it at joint
    readings q_rad (module doc, step 2). InputError when the sighting does not fix the board's pose."""
    if sighting.measured is None:
        raise InputError(f"the board was not found: {sighting.reason}")
    s, t = sighting.sensor, sighting.target
    camera = registration_frame(profile, profile.sensors[s].frame)
    board = registration_frame(profile, profile.targets[t].frame)
    still = [f for f in (board, camera) if f is not None and not _moves(profile, f)]
    if not still:
        raise InputError(
            f"{profile.sensors[s].name} and {profile.targets[t].name} both move with the robot: a plan from one view "
            "needs one of them to stand still (on the table, in the room)"
        )
    data = dataset_from_captures(profile, [Capture(1, np.asarray(q_rad, float), sighting, {})], "the live image")
    return view_registration(profile, data, p, still[0])


def around_seed(q_rad: np.ndarray, spread_deg: float = SEED_SPREAD_DEG) -> Around:
    """The neighbourhood of a seed a first plan keeps to."""
    return Around(np.asarray(q_rad, float).copy(), math.radians(spread_deg))


def _moves(profile: Profile, frame: int) -> bool:
    """Whether a joint moves the frame (it is on the robot, not fixed in the world)."""
    return any(profile.frames[f].joint >= 0 for f in profile.chain(frame))
