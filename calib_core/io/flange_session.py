"""A desk session from images and reported flange poses: the robot that is its flange pose, and what it saw.

`calib handeye` answers from images and poses alone. The desk wants a robot and a session: this builds both from
the same input (specs handeye-poses.md), so that the page reviews such a set frame by frame, calibrates it in any
of its modes, and applies the result as for any other robot. The robot's profile is
calib_core.model.flange_pose's: six joints read from each image's pose, a registration frame for the camera and one
for the board. Its declared noise is what the images show: the corners' scatter and the reported poses' error per
axis, estimated together by the variance components of `calibrate_flange` on every image with a board and a pose;
where its cross-validation finds the images predicted better with the poses taken as exact (a camera file that is
off, pose errors that follow the arm's configuration: all three real sets of benchmarks/README.md), the poses
declare no noise, and each image's scatter is the desk's per-frame scale (edit the profile's `noise` to your
controller's figures if you know them better).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from datetime import datetime
from pathlib import Path

import numpy as np

from ..dataset import Dataset
from ..errors import InputError
from ..estimation.flange_handeye import View, calibrate_flange
from ..frame_status import FrameStatus
from ..model.flange_pose import (
    flange_pose_profile,
    is_flange_pose,
    profile_reference,
    readings,
    reference_rotation,
    setup_of,
)
from ..model.loader import compile_profile
from ..model.profile import Profile
from .flange_poses import BoardSpec, Camera, natural_key
from .session import CARRIED_PROFILE, FrameRecord, write_session


@dataclass
class FlangeSession:
    """A flange-pose robot's profile (its document and compiled) and its session's observations and frames."""

    doc: dict | None  # the profile's document, for a new robot (None: the robot's own)
    profile: Profile
    data: Dataset
    frames: list[FrameRecord]
    image_of: dict[int, str]  # frame -> the image's file name as given


def board_target(board: BoardSpec) -> dict:
    """The profile's target form of a board (lengths mm): a chessboard's inner corners as a grid, a ChArUco
    board as OpenCV's."""
    if board.kind == "chessboard":
        grid = {"cols": board.cols, "rows": board.rows, "spacing": _mm(board.square_m)}
        return {"grid": grid, "pattern": "checkerboard"}
    charuco = {"squares": [board.cols, board.rows], "square": _mm(board.square_m), "marker": _mm(board.marker_m)}
    return {"charuco": charuco | {"dictionary": f"DICT_{board.dictionary}"}}


def flange_pose_session(
    robot: str,
    views: dict[str, View],
    poses: dict[str, np.ndarray],
    camera: Camera,
    board: BoardSpec,
    setup: str,
    profile: Profile | None = None,
) -> FlangeSession:
    """The robot `robot` and its session from each image's board (`find_views`) and reported flange pose (m): one
    frame per image with a pose, in the images' natural order; measured where its board was found. A chessboard's
    corners are put in the order the poses agree with (`calibrate_flange`, in place). `profile`: the robot's, when
    it is on the desk already (another day's images: read against its reference, its noise as it declares);
    default a new one from these images."""
    names = [n for n in sorted(views, key=natural_key) if n in poses]
    T = np.array([poses[n] for n in names])
    if profile is not None:
        calibrate_flange(views, poses, camera, board, setup, pose_errors=False)  # orders a chessboard's corners
        if not is_flange_pose(profile):
            raise InputError(f"robot: '{profile.name}' is not a robot known by its flange pose")
        if setup_of(profile) != setup:
            raise InputError(f"setup: robot '{profile.name}' is {setup_of(profile)}, not {setup}")
        return _session(robot, None, profile, views, names, T, profile_reference(profile))
    fit = calibrate_flange(views, poses, camera, board, setup)  # the noise the images show; orders the corners
    errors = bool(fit.flange_errors["fitted"])
    reference = reference_rotation(T[:, :3, :3])
    doc = flange_pose_profile(
        robot,
        setup,
        camera_matrix=camera.matrix,
        distortion=camera.distortion,
        image_size=camera.size,
        board=board_target(board),
        reference=reference,
        pixel_sd=fit.noise["corner_px"],
        flange_sd_mm=fit.noise["flange_mm"] if errors else 0.0,
        flange_sd_deg=fit.noise["flange_deg"] if errors else 0.0,
    )
    return _session(robot, doc, compile_profile(doc, f"<{robot}>"), views, names, T, reference)


def _session(
    robot: str,
    doc: dict | None,
    profile: Profile,
    views: dict[str, View],
    names: list[str],
    T: np.ndarray,
    reference: np.ndarray,
) -> FlangeSession:
    q = readings(T, reference)
    q[:, 3:] = np.radians(q[:, 3:])
    obs: dict[str, list] = {"cfg": [], "vertex": [], "measured": []}
    frames, image_of = [], {}
    for c, name in enumerate(names):
        v = views[name]
        frame = c + 1
        image_of[frame] = name
        joints = {
            j.name: float(q[c, k]) if j.prismatic else math.degrees(q[c, k]) for k, j in enumerate(profile.joints)
        }
        if v.corners is None:
            frames.append(FrameRecord(frame, joints, FrameStatus.NOT_FOUND, v.reason, {}, {"image": name}))
            continue
        obs["cfg"] += [c] * len(v.corners)
        obs["vertex"] += np.asarray(v.ids, int).tolist()
        obs["measured"].append(np.asarray(v.corners, float))
        detail = {"image": name, "corners": len(v.corners)}
        frames.append(FrameRecord(frame, joints, FrameStatus.MEASURED, "ok", {}, detail))
    m = len(obs["cfg"])
    data = Dataset(
        robot,
        np.arange(1, len(names) + 1),
        q,
        np.array(obs["cfg"], int),
        np.zeros(m, int),
        np.full((m, 3), np.nan),
        np.array(obs["vertex"], int),
        np.concatenate(obs["measured"]) if obs["measured"] else np.zeros((0, 2)),
        np.zeros(m, int),
        source=robot,
    )
    return FlangeSession(doc, profile, data, frames, image_of)


def write_flange_session(
    folder: str | Path,
    session: FlangeSession,
    images: dict[str, np.ndarray],
    *,
    name: str,
    made_by: str,
    measured: datetime | None = None,
) -> None:
    """The session folder (calib-session/1, `write_session`) with the robot's profile beside it (CARRIED_PROFILE),
    each frame's image as `image`."""
    import yaml

    frame_images = {f: {"image": images[n]} for f, n in session.image_of.items() if n in images}
    found = sum(fr.status == FrameStatus.MEASURED for fr in session.frames)
    write_session(
        folder,
        session.profile,
        name=name,
        description=(
            f"{len(session.frames)} images with the flange pose the controller reported, {found} with the board "
            "found (a robot known by its flange pose: no URDF, no joint angles)"
        ),
        made_by=made_by,
        data=session.data,
        frames=session.frames,
        images=frame_images,
        measured=measured,
        extra={} if session.doc is None else {CARRIED_PROFILE: yaml.safe_dump(session.doc, sort_keys=False)},
    )


def _mm(metres: float) -> float:
    return float(f"{metres * 1000.0:.10g}")
