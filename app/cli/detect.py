"""The detectors on their own: detect-sphere (a depth map's sphere, the BallFinder) and detect-board (a
checkerboard's inner corners in an image).
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from calib_core import InputError

from .common import Command, print_json


def _detect_sphere_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--depth", required=True, help="float32 depth in metres (.npy), 0 or NaN for no data")
    for name in ("fx", "fy", "cx", "cy"):
        p.add_argument(f"--{name}", required=True, type=float, help=f"intrinsic {name}, px")
    p.add_argument("--radius", required=True, type=float, help="sphere radius, m")
    p.add_argument("--seed", help="predicted centre X,Y,Z in m, camera frame (write --seed=-0.1,0.2,0.8)")
    p.add_argument("--json", action="store_true", help="one line of JSON (default: indented JSON)")


def _detect_board_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--image", required=True, help="the camera image (PNG, JPEG, ...)")
    p.add_argument("--cols", required=True, type=int, help="inner corners per row (6 for the NAO sandals)")
    p.add_argument("--rows", required=True, type=int, help="inner corners per column (4 for the NAO sandals)")
    p.add_argument("--json", action="store_true", help="one line of JSON (default: indented JSON)")


def _detect_sphere(args: argparse.Namespace) -> int:
    depth = _load_depth(args.depth)
    for name in ("fx", "fy", "radius"):
        if not getattr(args, name) > 0:
            raise InputError(f"--{name} must be positive, got {getattr(args, name)}")
    seed = None
    if args.seed is not None:
        try:
            seed = np.array([float(v) for v in args.seed.split(",")])
        except ValueError:
            raise InputError(f"--seed '{args.seed}' is not three numbers X,Y,Z") from None
        if seed.shape != (3,) or not np.all(np.isfinite(seed)):
            raise InputError(f"--seed '{args.seed}' is not three finite numbers X,Y,Z")
    if seed is not None and seed[2] <= 0:
        raise InputError(f"--seed '{args.seed}' lies behind the camera (Z must be positive)")
    from calib_core.vision import find_sphere

    try:
        found = find_sphere(depth, args.fx, args.fy, args.cx, args.cy, args.radius, seed)
    except ValueError as exc:  # the finder's own checks of its arguments
        raise InputError(str(exc), file=args.depth) from None
    print_json(found.to_json(), args.json)
    return 0


def _detect_board(args: argparse.Namespace) -> int:
    if args.cols < 3 or args.rows < 3:
        raise InputError("--cols and --rows must be at least 3 (inner corners)")
    if not Path(args.image).is_file():
        raise InputError("image file does not exist", file=args.image)
    import cv2

    from calib_core.vision import MAX_IMAGE_PX, detect_board, too_large

    try:
        image = cv2.imread(args.image, cv2.IMREAD_GRAYSCALE)
    except cv2.error as exc:  # a damaged header: more pixels than OpenCV reads, say
        raise InputError(f"is not an image OpenCV can read ({exc.err})", file=args.image) from None
    if image is None:
        raise InputError("is not an image OpenCV can read", file=args.image)
    if image.size > MAX_IMAGE_PX:
        raise InputError(too_large(image.shape[1], image.shape[0]), file=args.image)
    print_json(detect_board(image, args.cols, args.rows).to_json(), args.json)
    return 0


def _load_depth(path: str) -> np.ndarray:
    try:
        depth = np.load(path, allow_pickle=False)
    except FileNotFoundError:
        raise InputError("depth file does not exist", file=path) from None
    except (OSError, ValueError, EOFError) as exc:  # EOFError: an empty or cut-off file
        raise InputError(f"is not a NumPy .npy array ({exc})", file=path) from None
    if not isinstance(depth, np.ndarray) or depth.ndim != 2 or not np.issubdtype(depth.dtype, np.floating):
        raise InputError("must hold a 2-D float array of depths in metres", file=path)
    if depth.size == 0:
        raise InputError(f"holds an empty depth map ({depth.shape[0]} x {depth.shape[1]})", file=path)
    return depth.astype(np.float32, copy=False)


# This module's subcommands, which app/cli/__init__.py's COMMANDS lists in calib --help's order.
DETECT_SPHERE = Command(
    "detect-sphere",
    "find the calibration sphere's centre in a depth map (BallFinder)",
    _detect_sphere_arguments,
    _detect_sphere,
)
DETECT_BOARD = Command(
    "detect-board", "find a checkerboard's inner corners in an image", _detect_board_arguments, _detect_board
)
