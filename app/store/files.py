"""Files under the data directory: written whole (temporary name, fsync, rename), and leftovers swept.

A file is written before the row that refers to it commits, so a crash leaves at most files no row
refers to; `remove_stale` takes those away once they are old enough not to be a write in flight.
"""

from __future__ import annotations

import os
import secrets
import shutil
import time
from pathlib import Path

import cv2
import numpy as np

from calib_core import InputError

JPEG_QUALITY = 90
SWEEP_AGE_S = 60.0  # leftovers younger than this may be a write in flight: the sweep leaves them


def write_bytes(path: Path, data: bytes, *, atomic: bool = True) -> None:
    """Write and fsync; `atomic` writes a temporary name first and renames it into place."""
    path.parent.mkdir(parents=True, exist_ok=True)
    target = path.with_name(f".{path.name}.{secrets.token_hex(3)}.tmp") if atomic else path
    try:
        with open(target, "wb") as fh:
            fh.write(data)
            fh.flush()
            os.fsync(fh.fileno())
        if atomic:
            os.replace(target, path)
    except BaseException:
        target.unlink(missing_ok=True)
        raise


def fsync_dir(path: Path) -> None:
    """Make renames and new names in `path` durable."""
    fd = os.open(path, os.O_RDONLY)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)


def remove_stale(path: Path) -> None:
    """Remove a file or folder no row refers to, unless it is younger than SWEEP_AGE_S."""
    try:
        if time.time() - path.stat().st_mtime < SWEEP_AGE_S:
            return
    except FileNotFoundError:
        return
    if path.is_dir():
        shutil.rmtree(path, ignore_errors=True)
    else:
        path.unlink(missing_ok=True)


def encode_jpeg(image: np.ndarray) -> bytes:
    img = np.asarray(image)
    if img.dtype != np.uint8 or not (img.ndim == 2 or (img.ndim == 3 and img.shape[2] in (1, 3))):
        raise InputError(f"an image must be uint8 grey (H, W) or BGR (H, W, 3), not {img.dtype} {img.shape}")
    ok, buf = cv2.imencode(".jpg", img, [cv2.IMWRITE_JPEG_QUALITY, JPEG_QUALITY])
    if not ok:
        raise InputError(f"the image ({img.shape}) cannot be encoded as JPEG")
    return buf.tobytes()
