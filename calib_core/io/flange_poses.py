"""What a hand-eye user holds (specs handeye-poses.md): the flange's poses as the controller reported them, the
camera's calibration file and the board's description, read and checked; a mistake is an InputError naming the
file, the line and the field.

Poses are 4 x 4 transforms of the flange in the base, in metres; the camera's intrinsics in px.
"""

from __future__ import annotations

import csv
import math
import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..errors import InputError
from ..safe_yaml import load_yaml

LENGTH_M = {"m": 1.0, "mm": 1e-3}
ANGLE_RAD = {"rad": 1.0, "deg": math.pi / 180.0}
DICTIONARIES = ("4X4_50", "4X4_100", "4X4_250", "4X4_1000", "5X5_50", "5X5_100", "5X5_250", "5X5_1000",
                "6X6_50", "6X6_100", "6X6_250", "6X6_1000", "ARUCO_ORIGINAL")  # fmt: skip


@dataclass(frozen=True)
class Camera:
    """A calibrated camera: its matrix (3, 3) px, OpenCV's distortion (k1, k2, p1, p2, k3) and image size."""

    matrix: np.ndarray
    distortion: np.ndarray
    size: tuple[int, int] | None  # width, height px (None: the file did not say)


@dataclass(frozen=True)
class BoardSpec:
    """`chessboard:COLSxROWS:SQUARE` or `charuco:SQUARES_XxSQUARES_Y:SQUARE:MARKER:DICTIONARY`, lengths in m."""

    kind: str  # "chessboard" | "charuco"
    cols: int  # inner corners across (chessboard) or squares across (charuco)
    rows: int
    square_m: float
    marker_m: float = 0.0
    dictionary: str = ""

    def points(self) -> np.ndarray:
        """The board's inner corners (K, 3) in its frame, m, in the detector's order (row by row): a chessboard's
        origin at its first inner corner, a ChArUco board's at its outer corner as OpenCV's CharucoBoard has it
        (its first inner corner one square in), the ids its detector gives."""
        if self.kind == "chessboard":
            c, r = np.meshgrid(np.arange(self.cols), np.arange(self.rows))
        else:
            c, r = np.meshgrid(np.arange(1, self.cols), np.arange(1, self.rows))
        return np.stack([c.ravel(), r.ravel(), np.zeros(c.size)], axis=1) * self.square_m


def parse_board(spec: str) -> BoardSpec:
    """--board's value; InputError saying the form expected."""
    chess = re.fullmatch(r"chessboard:(\d+)x(\d+):([0-9.]+)", spec)
    if chess:
        cols, rows, square = int(chess[1]), int(chess[2]), float(chess[3])
        if cols < 3 or rows < 3 or not square > 0:
            raise InputError(f"--board {spec}: at least 3 x 3 inner corners and a positive square (mm)")
        return BoardSpec("chessboard", cols, rows, square * 1e-3)
    charuco = re.fullmatch(r"charuco:(\d+)x(\d+):([0-9.]+):([0-9.]+):(\w+)", spec)
    if charuco:
        cols, rows, square, marker, name = (
            int(charuco[1]),
            int(charuco[2]),
            float(charuco[3]),
            float(charuco[4]),
            charuco[5],
        )
        if name.upper().removeprefix("DICT_") not in DICTIONARIES:
            raise InputError(f"--board {spec}: unknown dictionary {name!r} (known: {', '.join(DICTIONARIES)})")
        if cols < 3 or rows < 3 or not 0 < marker < square:
            raise InputError(f"--board {spec}: at least 3 x 3 squares, and a marker smaller than its square")
        return BoardSpec("charuco", cols, rows, square * 1e-3, marker * 1e-3, name.upper().removeprefix("DICT_"))
    raise InputError(
        f"--board {spec!r}: expected chessboard:COLSxROWS:SQUARE_MM (e.g. chessboard:9x6:18) or "
        "charuco:SQUARES_XxSQUARES_Y:SQUARE_MM:MARKER_MM:DICTIONARY (e.g. charuco:7x5:30:22:4X4_50)"
    )


def natural_key(name: str) -> list:
    """`2.png` before `10.png`: digits compared as numbers."""
    return [int(part) if part.isdigit() else part for part in re.split(r"(\d+)", name)]


def read_flange_poses(
    path: str | Path, images: list[str], length_unit: str = "m", angle_unit: str = "rad"
) -> dict[str, np.ndarray]:
    """Image name -> the flange's pose in the base (4, 4), m: a CSV (image, x, y, z and rx, ry, rz or qx, qy, qz,
    qw) or one row-major 4 x 4 matrix a line, paired with `images` in natural order."""
    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8-sig")
    except (OSError, UnicodeDecodeError) as exc:
        raise InputError(f"cannot be read ({exc.__class__.__name__})", file=str(path)) from None
    scale = LENGTH_M[length_unit]
    first = next((line for line in text.splitlines() if line.strip()), "")
    if re.match(r"\s*[-+0-9.eE]", first):
        return _matrix_lines(path, text, sorted(images, key=natural_key), scale)
    return _csv_poses(path, text, set(images), scale, ANGLE_RAD[angle_unit])


def _csv_poses(path: Path, text: str, images: set[str], scale: float, angle: float) -> dict[str, np.ndarray]:
    from scipy.spatial.transform import Rotation

    reader = csv.DictReader(text.splitlines())
    fields = set(reader.fieldnames or [])
    rotvec, quat = {"rx", "ry", "rz"} <= fields, {"qx", "qy", "qz", "qw"} <= fields
    missing = [f for f in ("image", "x", "y", "z") if f not in fields]
    if missing or not (rotvec or quat):
        need = ", ".join(missing) if missing else "rx, ry, rz (a rotation vector) or qx, qy, qz, qw"
        raise InputError(f"the header lacks {need}", file=str(path), line=1)
    out = {}
    for row in reader:
        line = reader.line_num
        name = (row.get("image") or "").strip()
        if name not in images:
            raise InputError(f"image: {name!r} is not in the images folder", file=str(path), line=line)
        if name in out:
            raise InputError(f"image: {name!r} has a pose already", file=str(path), line=line)
        keys = ["x", "y", "z", *(("rx", "ry", "rz") if rotvec else ("qx", "qy", "qz", "qw"))]
        values = []
        for key in keys:
            try:
                v = float(row[key])
            except (TypeError, ValueError):
                raise InputError(f"{key}: {row.get(key)!r} is not a number", file=str(path), line=line) from None
            if not math.isfinite(v):
                raise InputError(f"{key}: {v} is not a finite number", file=str(path), line=line)
            values.append(v)
        if rotvec:
            R = Rotation.from_rotvec(np.array(values[3:]) * angle).as_matrix()
        else:
            q = np.array(values[3:])
            if not 0.9 < np.linalg.norm(q) < 1.1:
                raise InputError(
                    f"qx, qy, qz, qw: a quaternion of norm {np.linalg.norm(q):.3g}, not 1", file=str(path), line=line
                )
            R = Rotation.from_quat(q / np.linalg.norm(q)).as_matrix()
        out[name] = _pose(R, np.array(values[:3]) * scale)
    if not out:
        raise InputError("holds no pose", file=str(path))
    return out


def _matrix_lines(path: Path, text: str, images: list[str], scale: float) -> dict[str, np.ndarray]:
    rows = [(k, line) for k, line in enumerate(text.splitlines(), start=1) if line.strip()]
    if len(rows) != len(images):
        raise InputError(
            f"{len(rows)} matrices for the {len(images)} images of the folder (a matrix a line, in the images' "
            "natural order)",
            file=str(path),
        )
    out = {}
    for (k, line), name in zip(rows, images, strict=True):
        try:
            values = np.array([float(v) for v in re.split(r"[,\s]+", line.strip())])
        except ValueError:
            raise InputError("expected 16 numbers (a row-major 4 x 4 matrix)", file=str(path), line=k) from None
        if values.size != 16 or not np.all(np.isfinite(values)):
            raise InputError(f"expected 16 finite numbers, got {values.size}", file=str(path), line=k)
        T = values.reshape(4, 4)
        R = T[:3, :3]
        if (
            not np.allclose(R @ R.T, np.eye(3), atol=1e-3)
            or np.linalg.det(R) < 0
            or not np.allclose(T[3], [0, 0, 0, 1])
        ):
            raise InputError("not a rigid transform (its rotation is not orthonormal)", file=str(path), line=k)
        out[name] = _pose(R, T[:3, 3] * scale)
    return out


def _pose(R: np.ndarray, t: np.ndarray) -> np.ndarray:
    T = np.eye(4)
    T[:3, :3], T[:3, 3] = R, t
    return T


def read_camera(path: str | Path) -> Camera:
    """ROS camera_calibration's YAML (camera_matrix, distortion_coefficients: {rows, cols, data}) or OpenCV's
    FileStorage YAML (camera_matrix, distortion_coefficients as !!opencv-matrix)."""
    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as exc:
        raise InputError(f"cannot be read ({exc.__class__.__name__})", file=str(path)) from None
    if text.lstrip().startswith("%YAML"):
        return _opencv_camera(path)
    d = load_yaml(text, str(path))
    if not isinstance(d, dict) or "camera_matrix" not in d:
        raise InputError("lacks camera_matrix (a ROS camera_info YAML or OpenCV's FileStorage)", file=str(path))
    K = _matrix(d["camera_matrix"], path, "camera_matrix", (3, 3))
    dist = d.get("distortion_coefficients", {"data": [0.0] * 5})
    D = _matrix(dist, path, "distortion_coefficients", None).ravel()
    size = (int(d["image_width"]), int(d["image_height"])) if "image_width" in d and "image_height" in d else None
    return _camera(K, D, size, path)


def _matrix(node: object, path: Path, field: str, shape: tuple[int, int] | None) -> np.ndarray:
    data = node.get("data") if isinstance(node, dict) else None
    try:
        M = np.array(data, float)
    except (TypeError, ValueError):
        raise InputError(f"{field}.data: expected numbers", file=str(path)) from None
    if M.ndim != 1 or (shape is not None and M.size != shape[0] * shape[1]) or not np.all(np.isfinite(M)):
        raise InputError(
            f"{field}.data: expected {shape[0] * shape[1] if shape else 'its'} finite numbers", file=str(path)
        )
    return M.reshape(shape) if shape else M


def _opencv_camera(path: Path) -> Camera:
    import cv2

    fs = cv2.FileStorage(str(path), cv2.FILE_STORAGE_READ)
    try:
        K, D = fs.getNode("camera_matrix").mat(), fs.getNode("distortion_coefficients").mat()
        width, height = fs.getNode("image_width"), fs.getNode("image_height")
        size = None if width.empty() or height.empty() else (int(width.real()), int(height.real()))
    finally:
        fs.release()
    if K is None or K.shape != (3, 3):
        raise InputError("camera_matrix: expected a 3 x 3 matrix", file=str(path))
    return _camera(K, np.zeros(5) if D is None else D.ravel(), size, path)


def _camera(K: np.ndarray, D: np.ndarray, size: tuple[int, int] | None, path: Path) -> Camera:
    if not (K[0, 0] > 0 and K[1, 1] > 0 and np.allclose(K[2], [0, 0, 1])):
        raise InputError("camera_matrix: expected [fx, 0, cx; 0, fy, cy; 0, 0, 1] with fx, fy > 0", file=str(path))
    if D.size not in (4, 5, 8):
        raise InputError(
            f"distortion_coefficients: {D.size} numbers; plumb_bob has 5 (k1, k2, p1, p2, k3)", file=str(path)
        )
    dist = np.zeros(5)
    dist[: min(D.size, 5)] = D[:5]
    return Camera(np.asarray(K, float), dist, size)
