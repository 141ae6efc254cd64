"""A ChArUco board (`charuco:` target, specs handeye.md) in a camera's image: OpenCV's CharucoDetector.

Vertex k is OpenCV's ChArUco corner id k (`calib_core.model.boards.Charuco`); each marker names the corners
around it, so a partial view measures the corners found, and no symmetry needs the prediction to resolve it:
the believed kinematics' prediction is only compared with what was found (the detail's distance). A view with
fewer than MIN_CHARUCO_CORNERS corners is not found, with the count as the reason.

Rendering: OpenCV draws the board (`generateImage`, on a white margin of half a square); the board plane's
homography through the profile's camera (undistorted pinhole) warps it into the image, supersampled and
averaged down, behind it the dark room; then the camera's blur, uneven light, noise and 8-bit quantisation,
as the sandal board's renderer has them. The printed face is the board's -z side; from behind, the plate is
blank.
"""

from __future__ import annotations

import math
from functools import cache

import cv2
import numpy as np

from ...model.boards import MIN_CHARUCO_CORNERS, Charuco
from ...model.kinematics import forward
from ...sensors import Pinhole
from ..sandal_board import BLACK, REFINE_BLUR_PX, REFINE_TILE_PX, ROOM, WHITE, illumination, refine_on_board
from ..sighting import Detail, Sighting
from ..stereo import StereoHead
from .base import BoardFinder, Rendered

# What the detector measures reliably (tests/test_finders.py): the board at most MAX_OBLIQUITY_DEG from its
# normal, its squares at least MIN_SQUARE_PX apart in the image (a marker's bit is then about 2 px).
MAX_OBLIQUITY_DEG = 70.0
MIN_SQUARE_PX = 18.0
SUPERSAMPLE = 4  # rendered at up to this many times the image's resolution, then averaged down...
SUPERSAMPLED_MAX_PX = 20_000_000  # ...in at most this many px
TEXTURE_MAX_SQUARE_PX = 256  # the drawn board's resolution: at most this many px a square


@cache
def opencv_board(board: Charuco) -> cv2.aruco.CharucoBoard:
    """OpenCV's board for the profile's: CharucoBoard(squares, square, marker, dictionary)."""
    dictionary = cv2.aruco.getPredefinedDictionary(getattr(cv2.aruco, board.dictionary))
    return cv2.aruco.CharucoBoard(board.squares, board.square, board.marker, dictionary)


class CharucoFinder(BoardFinder):
    """The printed face is the board frame's -z side; its corners run along +x, rows along +y."""

    face_sign = -1.0
    max_obliquity_deg = MAX_OBLIQUITY_DEG
    min_spacing_px = MIN_SQUARE_PX

    @property
    def board(self) -> Charuco:
        board = self.profile.targets[self.target].charuco
        assert board is not None  # a charuco target has its board
        return board

    def render(
        self,
        p: np.ndarray,
        q: np.ndarray,
        rng: np.random.Generator,
        *,
        blur_px: float = 0.8,
        noise: float = 2.0,
        light: float = 0.35,
    ) -> Rendered:
        """What the camera sees of the board for parameters p and joint readings q (rad)."""
        camera = self.profile.sensors[self.sensor]
        if not isinstance(camera, Pinhole) or camera.image is None or camera.intrinsics is None:
            raise ValueError("rendering needs a pinhole sensor with intrinsics and an image size")
        if camera.distortion is not None and np.any(p[list(camera.distortion)] != 0):
            raise ValueError("rendering supports no lens distortion")
        width, height = camera.image
        board_to_px = self._board_to_px(p, q, camera)
        across, down = self.board.squares
        square = self.board.square
        # The texture's resolution: a square at least as many px as it spans in the supersampled image.
        outline = np.array(
            [[0, 0, 1], [across * square, 0, 1], [0, down * square, 1], [across * square, down * square, 1]]
        )
        seen = outline @ board_to_px.T
        in_front = seen[:, 2] > 0
        span_px = np.ptp(seen[in_front, :2] / seen[in_front, 2:], axis=0).max() if in_front.any() else 0.0
        square_px = int(np.clip(SUPERSAMPLE * span_px / min(across, down), 16, TEXTURE_MAX_SQUARE_PX))
        margin_px = square_px // 2
        texture = opencv_board(self.board).generateImage(
            (across * square_px + 2 * margin_px, down * square_px + 2 * margin_px), marginSize=margin_px, borderBits=1
        )
        # Texture px -> board (length unit): pixel centres at integers, the board's origin margin_px in.
        per_px = square / square_px  # the length unit per texture px
        to_board = np.array(
            [[per_px, 0, (0.5 - margin_px) * per_px], [0, per_px, (0.5 - margin_px) * per_px], [0, 0, 1]]
        )
        k = max(1, min(SUPERSAMPLE, int(math.sqrt(SUPERSAMPLED_MAX_PX / (width * height)))))
        to_fine = np.array([[k, 0, (k - 1) / 2], [0, k, (k - 1) / 2], [0, 0, 1]])  # image px -> supersampled px
        texture_to_fine = to_fine @ board_to_px @ to_board
        grey = np.where(texture > 127, WHITE, BLACK).astype(np.float32)
        fine = cv2.warpPerspective(
            grey, texture_to_fine, (width * k, height * k), flags=cv2.INTER_LINEAR, borderValue=ROOM
        )
        plate = cv2.warpPerspective(
            np.ones_like(grey), texture_to_fine, (width * k, height * k), flags=cv2.INTER_NEAREST, borderValue=0
        )
        # Rays that meet the board's plane behind the camera, or its blank back: the room.
        ahead = _ahead(np.linalg.inv(to_fine @ board_to_px)[2], width * k, height * k)
        face = self._faces_camera(p, q)
        fine = np.where(ahead & (plate > 0), fine if face else WHITE, ROOM)
        scene = cv2.resize(fine, (width, height), interpolation=cv2.INTER_AREA).astype(float)
        image = scene * illumination(width, height, light, rng)
        if blur_px > 0:
            image = cv2.GaussianBlur(image, (0, 0), blur_px)
        if noise > 0:
            image = image + rng.normal(0.0, noise, image.shape)
        return Rendered({"image": np.clip(np.rint(image), 0, 255).astype(np.uint8)})

    def _pose(self, p: np.ndarray, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The board frame in the camera's frame: rotation and position (length unit)."""
        board, camera = self.profile.targets[self.target].frame, self.profile.sensors[self.sensor].frame
        poses = forward(self.profile, p, np.asarray(q, float)[None], frames=[board, camera])
        Rb, tb, Rs, ts = poses.R[board][0], poses.t[board][0], poses.R[camera][0], poses.t[camera][0]
        return Rs.T @ Rb, Rs.T @ (tb - ts)

    def _board_to_px(self, p: np.ndarray, q: np.ndarray, camera: Pinhole) -> np.ndarray:
        """The homography from the board's plane (x, y, 1), length unit, to image px; its third row is the
        depth along the optical axis (positive in front of the camera)."""
        assert camera.intrinsics is not None  # render checked
        R, t = self._pose(p, q)
        fx, fy, cx, cy = (float(p[i]) for i in camera.intrinsics)
        K = np.array([[fx, 0, cx], [0, fy, cy], [0, 0, 1]])
        return K @ camera.R_frame_optical.T @ np.column_stack([R[:, 0], R[:, 1], t])

    def _faces_camera(self, p: np.ndarray, q: np.ndarray) -> bool:
        """Whether the camera is on the printed (-z) side of the board."""
        R, t = self._pose(p, q)
        return float((R.T @ -t)[2]) < 0

    def find(
        self, p_believed: np.ndarray, q: np.ndarray, images: dict[str, np.ndarray], head: StereoHead | None = None
    ) -> Sighting:
        """The corners OpenCV's CharucoDetector finds (by id), refined on the board's plane; not found below
        MIN_CHARUCO_CORNERS."""
        image = images["image"]
        grey = image if image.ndim == 2 else cv2.cvtColor(image, cv2.COLOR_BGR2GRAY)
        detector = cv2.aruco.CharucoDetector(opencv_board(self.board))
        corners, ids, _, marker_ids = detector.detectBoard(grey)
        n_markers = 0 if marker_ids is None else len(marker_ids)
        n = 0 if ids is None else len(ids)
        detail: Detail = {"markers": n_markers, "corners": n}
        if n < MIN_CHARUCO_CORNERS:
            reason = f"corners found: {n} ({n_markers} markers), fewer than {MIN_CHARUCO_CORNERS}"
            return self.sighting(None, "not found" if n == 0 else "partial", {**detail, "detail": reason})
        vertices = ids.ravel().astype(int)
        order = np.argsort(vertices)
        vertices, found = vertices[order], corners.reshape(-1, 2).astype(float)[order]
        # Refined on the board as the sandal board's corners are, the window within the white around a marker.
        cols = self.board.shape[1]
        lattice = np.stack([vertices % cols, vertices // cols], axis=1).astype(float)
        if np.linalg.matrix_rank(lattice - lattice.mean(axis=0)) < 2:  # no homography, no pose: a line of corners
            reason = f"the {n} corners found lie on one line of the board"
            return self.sighting(None, "partial", {**detail, "detail": reason})
        half_px = max(3, round(REFINE_TILE_PX * (self.board.square - self.board.marker) / (2 * self.board.square)))
        blurred = cv2.GaussianBlur(grey, (0, 0), REFINE_BLUR_PX)
        measured, residual_px = refine_on_board(blurred, found, lattice, half_px)
        detail["residual_px"] = round(residual_px, 3)
        predicted = self.predicted_px(p_believed, q)[vertices]
        detail["prediction_px"] = round(float(np.linalg.norm(measured - predicted, axis=1).mean()), 2)
        return self.sighting(measured, "ok", detail, vertices)


def _ahead(row: np.ndarray, width: int, height: int) -> np.ndarray | bool:
    """Which px (u, v) of a width x height image see the board's plane in front of the camera: where
    row . (u, v, 1) > 0 (the third row of the image -> plane homography). A linear function's sign over the image
    is its corners' when they agree clearly (so True or False for the whole image, as most views are); else
    per px, (height, width)."""
    a, b, c = (float(x) for x in row)
    corners = [a * u + b * v + c for u in (0, width - 1) for v in (0, height - 1)]
    scale = abs(a) * width + abs(b) * height + abs(c)
    if min(corners) > 1e-9 * scale:
        return True
    if max(corners) < -1e-9 * scale:
        return False
    u = np.arange(width, dtype=np.float32).astype(float)
    v = np.arange(height, dtype=np.float32).astype(float)
    return a * u[None, :] + b * v[:, None] + c > 0
