"""A session from images and reported flange poses, imported whole: the desk's front door for hand-eye.

What `calib handeye` takes (specs handeye-poses.md: the poses file, the images, the camera file, the board, the
set-up) becomes a robot known by its flange pose (calib_core.model.flange_pose), added to the desk when it is new,
and one session of it (calib_core.io.flange_session), so that the page calibrates, reviews and applies it as any
other. Another day's images of a robot already on the desk are read against its own profile. Everything is read
and checked before anything is written; a failure after the robot was added takes it off again.
"""

from __future__ import annotations

import tempfile
import zipfile
from collections.abc import Callable
from dataclasses import dataclass
from datetime import datetime
from io import BytesIO
from pathlib import Path, PurePosixPath
from typing import TypeVar

import numpy as np

from calib_core import InputError
from calib_core.estimation import find_views
from calib_core.io import flange_pose_session, parse_board, read_camera, read_flange_poses, write_flange_session

from ..store import ProfileFiles
from ..store.importers import import_session_folder
from ..store.meshes import checked_entries
from .roster import Robots

T = TypeVar("T")
IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg", ".bmp", ".tif", ".tiff")
MIN_FOUND = 3  # images with the board found and a pose: fewer leave the hand-eye equations undetermined


@dataclass(frozen=True)
class FlangeUpload:
    """What the user holds: the poses file, the camera file and the images (name -> bytes; one zip of them is
    unpacked), with the board, the set-up and the poses' units as `calib handeye` takes them."""

    poses: tuple[str, bytes]
    camera: tuple[str, bytes]
    images: dict[str, bytes]
    board: str
    setup: str
    length_unit: str = "m"
    angle_unit: str = "rad"


@dataclass(frozen=True)
class FlangeImported:
    id: str  # the session
    robot: str
    added: bool  # the robot is new on the desk
    notes: list[str]  # images left out, and why


def import_flange_session(
    robots: Robots,
    robot: str,
    name: str,
    upload: FlangeUpload,
    *,
    measured: datetime | None = None,
    max_unpacked_bytes: int,
) -> FlangeImported:
    """The session `name` of robot `robot` (added when new) from `upload`; InputError naming the file (and line or
    field) for anything wrong, nothing written then."""
    images = _images(upload.images, max_unpacked_bytes)
    board = parse_board(upload.board)
    with tempfile.TemporaryDirectory(prefix="flange-import-") as tmp:
        work = Path(tmp)
        camera = _named(lambda: read_camera(_put(work, *upload.camera)), upload.camera[0])
        poses = _named(
            lambda: read_flange_poses(_put(work, *upload.poses), list(images), upload.length_unit, upload.angle_unit),
            upload.poses[0],
        )
        grey = {n: _grey(n, data) for n, data in images.items()}
        views = find_views(grey, board, camera)
        found = [n for n, v in views.items() if v.corners is not None and n in poses]
        if len(found) < MIN_FOUND:
            raise InputError(
                f"the board ({upload.board}) is found in {len(found)} of {len(images)} images with a pose: a hand-eye "
                f"calibration needs {MIN_FOUND} at least"
            )
        existing = robot in robots.names()
        profile = robots.get(robot).profile if existing else None
        session = flange_pose_session(robot, views, poses, camera, board, upload.setup, profile)
        colour = {n: _colour(n, data) for n, data in images.items()}
        folder = work / "session"
        made_by = "the desk's import of images and poses"
        write_flange_session(folder, session, colour, name=name, made_by=made_by, measured=measured)
        if not existing:
            assert session.doc is not None
            text = (folder / "profile.yaml").read_bytes()
            robots.add(robot, profile=None, files=ProfileFiles("profile.yaml", text), driver=None)
        try:
            sid = import_session_folder(robots.store, folder, robots=[robot])
        except BaseException:
            if not existing:
                robots.remove(robot)
            raise
    notes = [f"{v.image}: the board {v.reason}; left out" for v in views.values() if v.corners is None]
    notes += [f"{n}: no pose for it; left out" for n in images if n not in poses]
    return FlangeImported(sid, robot, not existing, notes)


def _images(files: dict[str, bytes], max_unpacked_bytes: int) -> dict[str, bytes]:
    """The images by file name: the files given, or the images inside the one zip given (its folders flattened);
    InputError when none is an image or two share a name."""
    if len(files) == 1 and next(iter(files)).lower().endswith(".zip"):
        zip_name, data = next(iter(files.items()))
        try:
            with zipfile.ZipFile(BytesIO(data)) as zf:
                entries = checked_entries(zip_name, zf.infolist(), max_unpacked_bytes)
                files = {}
                for path, info in entries:
                    base = PurePosixPath(path).name
                    if base.lower().endswith(IMAGE_SUFFIXES) and not base.startswith("."):
                        if base in files:
                            raise InputError(f"two images are named {base}", file=zip_name)
                        files[base] = zf.read(info)
        except (zipfile.BadZipFile, zipfile.LargeZipFile, ValueError, EOFError, NotImplementedError) as exc:
            raise InputError(f"not a readable zip ({exc})", file=zip_name) from None
    images = {Path(n).name: d for n, d in files.items() if n.lower().endswith(IMAGE_SUFFIXES)}
    if not images:
        raise InputError(f"images: none of the {len(files)} files is an image ({', '.join(IMAGE_SUFFIXES)})")
    return images


def _put(folder: Path, name: str, data: bytes) -> Path:
    path = folder / (Path(name).name or "upload")
    path.write_bytes(data)
    return path


def _named(read: Callable[[], T], name: str) -> T:
    """`read()`, its InputError naming the file as uploaded (not where the desk kept it meanwhile)."""
    try:
        return read()
    except InputError as exc:
        if exc.file is None:
            raise
        raise InputError(exc.message, file=Path(name).name, line=exc.line, column=exc.column) from None


def _decode(name: str, data: bytes, flag: int) -> np.ndarray:
    import cv2

    image = cv2.imdecode(np.frombuffer(data, np.uint8), flag)
    if image is None:
        raise InputError("is not an image OpenCV can read", file=name)
    return image


def _grey(name: str, data: bytes) -> np.ndarray:
    import cv2

    return _decode(name, data, cv2.IMREAD_GRAYSCALE)


def _colour(name: str, data: bytes) -> np.ndarray:
    import cv2

    return _decode(name, data, cv2.IMREAD_COLOR)
