"""calib handeye: a camera against an arm from images of a board and the flange poses its controller reported
(specs handeye-poses.md; no URDF).
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

from calib_core import InputError, write_atomic

from .common import Command, check_writable, save

IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg", ".bmp", ".tif", ".tiff")


def _handeye_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument(
        "--poses", required=True, help="CSV (image, x, y, z, rx, ry, rz or qx, qy, qz, qw), or a 4 x 4 matrix a line"
    )
    p.add_argument("--images", required=True, help="the folder of the board's images")
    p.add_argument(
        "--camera", required=True, help="the camera's calibration: ROS camera_info YAML or OpenCV's FileStorage"
    )
    p.add_argument(
        "--board",
        required=True,
        help="chessboard:COLSxROWS:SQUARE_MM or charuco:SQUARES_XxSQUARES_Y:SQUARE_MM:MARKER_MM:DICT",
    )
    p.add_argument("--setup", required=True, choices=["eye-in-hand", "eye-to-hand"])
    p.add_argument("--out", required=True, help="the calibration (JSON, specs handeye-poses.md)")
    p.add_argument("--holdout-images", help="images never fitted, comma-separated; the output gives their error")
    p.add_argument("--intrinsics", choices=["fixed", "free"], default="fixed", help="free: estimated with the poses")
    p.add_argument("--length-unit", choices=["m", "mm"], default="m", help="the poses' positions (default m)")
    p.add_argument("--angle-unit", choices=["rad", "deg"], default="rad", help="a rotation vector's (default rad)")


def _handeye(args: argparse.Namespace) -> int:
    """specs handeye-poses.md: images, flange poses, the camera and the board; no pose guessed anywhere."""
    import cv2

    from calib_core.estimation import calibrate_flange, find_views
    from calib_core.io import parse_board, read_camera, read_flange_poses

    folder = Path(args.images)
    if not folder.is_dir():
        raise InputError("is not a folder of images", file=args.images)
    names = sorted(p.name for p in folder.iterdir() if p.suffix.lower() in IMAGE_SUFFIXES)
    if not names:
        raise InputError(f"holds no image ({', '.join(IMAGE_SUFFIXES)})", file=args.images)
    board = parse_board(args.board)
    camera = read_camera(args.camera)
    poses = read_flange_poses(args.poses, names, args.length_unit, args.angle_unit)
    heldout = {n.strip() for n in (args.holdout_images or "").split(",") if n.strip()}
    unknown = sorted(heldout - set(names))
    if unknown:
        raise InputError(f"--holdout-images: {unknown[0]} is not an image of {args.images}")
    check_writable(args.out)
    images = {}
    for name in names:
        grey = cv2.imread(str(folder / name), cv2.IMREAD_GRAYSCALE)
        if grey is None:
            raise InputError("is not an image OpenCV can read", file=str(folder / name))
        images[name] = grey
    views = find_views(images, board, camera)
    for v in views.values():
        if v.corners is None:
            print(f"calib handeye: note: {v.image}: board {v.reason}; left out", file=sys.stderr)
    start = time.perf_counter()
    cal = calibrate_flange(
        views, poses, camera, board, args.setup, heldout=heldout, intrinsics_free=args.intrinsics == "free"
    )
    out = cal.to_json()
    save(args.out, lambda: write_atomic(Path(args.out), json.dumps(out, indent=2) + "\n"))
    for warning in out["warnings"]:
        print(f"calib handeye: warning: {warning}", file=sys.stderr)
    name = "camera_in_flange" if args.setup == "eye-in-hand" else "camera_in_base"
    t, sd = np.array(out[name]["matrix"])[:3, 3], out[name]["std"]
    used = sum(i["used"] for i in cal.images)
    errors = cal.flange_errors
    cv = errors["cross_validation_px"]
    print(
        f"{len(names)} images, {used} fitted ({cal.start} start, {cal.iterations} iterations, "
        f"{time.perf_counter() - start:.2f} s): {name} at ({t[0]:.2f}, {t[1]:.2f}, {t[2]:.2f}) mm "
        f"+/- ({sd['x']:.2f}, {sd['y']:.2f}, {sd['z']:.2f}); corners fitted to {cal.fitted_rms_px:.3f} px RMS"
        + (f", held out {cal.heldout_rms_px:.3f} px" if cal.heldout_rms_px is not None else "")
        + ("; the flange poses' errors fitted" if errors["fitted"] else "; the flange poses taken as exact")
        + (
            f" (cross-validation: {cv['fitted']:.3f} px with their errors fitted, {cv['exact']:.3f} px as exact)"
            if cv
            else f" ({errors['chosen_by']})"
        )
        + f": {args.out}"
    )
    return 0


# This module's subcommands, which app/cli/__init__.py's COMMANDS lists in calib --help's order.
HANDEYE = Command(
    "handeye",
    "a camera against an arm from images of a board and the flange poses the controller reported (no URDF)",
    _handeye_arguments,
    _handeye,
)
