"""A plain checkerboard (a `grid:` target) in a camera's image: OpenCV's `findChessboardCorners` on the image,
`cornerSubPix`, and each corner's vertex identity from the board itself where it can tell, else from the believed
kinematics.

The detector returns the corners row by row from one of the board's corners, and which one is the question.
The camera sees the printed face, so the image keeps the board's handedness: that fixes the mirror images. A board
whose inner corners' columns plus rows are odd has an even number of squares one way and an odd number the other:
turned by half a turn its squares change colour, so the colour of the squares between the corners fixes the rest
(the tile next to vertex 0, between vertices 0, 1, cols and cols + 1, is black, as the simulator draws it). No guess
is needed, and the believed kinematics' prediction is only compared with what was found (the detail's distance).
On a board whose columns plus rows are even, the half turn looks the same: the order comes from the prediction
(the board's mirror and half-turn symmetries resolved as for the NAO's sandals, `sandal_board.identify`), which
needs a guess of the board's and the camera's poses within tens of px, or a ChArUco board.

Rendered as the sandal board is (`render_board_image`: the tiles on the plate's -z face, a white margin, the
camera's blur, light and noise). The detector sees a board up to MAX_OBLIQUITY_DEG from its normal with its
corners at least MIN_CORNER_SPACING_PX apart; beyond, the classic detector loses most views.
"""

from __future__ import annotations

import cv2
import numpy as np

from ..sandal_board import identify, render_board_image
from ..sighting import Sighting
from ..stereo import StereoHead
from .base import BoardFinder, Rendered

MAX_OBLIQUITY_DEG = 60.0
MIN_CORNER_SPACING_PX = 8.0
SUBPIX_HALF_WINDOW_PX = (2, 7)  # cornerSubPix's half window: 40% of the corners' spacing, within these
MIN_CONTRAST = 20.0  # grey levels between the black and the white squares' means below which no colour is told
_SUBPIX = (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_MAX_ITER, 40, 0.001)


def asymmetric(rows: int, cols: int) -> bool:
    """Whether a board of rows x cols inner corners looks different turned by half a turn (cols + rows odd)."""
    return (rows + cols) % 2 == 1


def handedness(corners: np.ndarray, rows: int, cols: int) -> float:
    """The sign of the image's turn from the first row's direction to the first column's (u right, v down)."""
    a, b = corners[cols - 1] - corners[0], corners[(rows - 1) * cols] - corners[0]
    return float(np.sign(a[0] * b[1] - a[1] * b[0]))


def mirrored(corners: np.ndarray, rows: int, cols: int) -> np.ndarray:
    """The corners with each row reversed."""
    return corners.reshape(rows, cols, 2)[:, ::-1].reshape(-1, 2)


def tile_contrast(grey: np.ndarray, corners: np.ndarray, rows: int, cols: int) -> float:
    """The mean grey level of the squares between the corners that should be white less that of those that
    should be black, for the corners in vertex order (the tile between vertices 0, 1, cols, cols + 1 black):
    positive when the order is right, negative when it is turned by half a turn (an asymmetric board)."""
    g = corners.reshape(rows, cols, 2)
    # Each tile's inner half: the corners' midpoint pulled a quarter of the way towards each of its four corners.
    quad = np.stack([g[:-1, :-1], g[:-1, 1:], g[1:, 1:], g[1:, :-1]], axis=2)  # (rows - 1, cols - 1, 4, 2)
    centre = quad.mean(axis=2, keepdims=True)
    samples = (centre + 0.5 * (quad - centre)).reshape(-1, 2)
    samples = np.concatenate([samples, centre.reshape(-1, 2)]).astype(np.float32)
    values = cv2.remap(grey.astype(np.float32), samples[:, :1], samples[:, 1:], cv2.INTER_LINEAR).ravel()
    n_tiles = (rows - 1) * (cols - 1)
    per_tile = (values[: 4 * n_tiles].reshape(n_tiles, 4).sum(axis=1) + values[4 * n_tiles :]) / 5
    r, c = np.divmod(np.arange(n_tiles), cols - 1)
    black = (r + c) % 2 == 0
    return float(per_tile[~black].mean() - per_tile[black].mean())


class CheckerboardFinder(BoardFinder):
    """The board's face is its frame's -z side (the grid's vertices run along +x, rows along -y)."""

    max_obliquity_deg = MAX_OBLIQUITY_DEG
    min_spacing_px = MIN_CORNER_SPACING_PX

    def render(self, p: np.ndarray, q: np.ndarray, rng: np.random.Generator) -> Rendered:
        return Rendered({"image": render_board_image(self.profile, p, q, self.target, rng, sensor=self.sensor).image})

    def find(
        self, p_believed: np.ndarray, q: np.ndarray, images: dict[str, np.ndarray], head: StereoHead | None = None
    ) -> Sighting:
        """The whole board's corners, sub-pixel, in vertex order; "not found", or on a board that looks the same
        turned by half a turn, from the prediction, "far from prediction" or "ambiguous" (sandal_board.identify)."""
        rows, cols = self.shape
        image = images["image"]
        grey = image if image.ndim == 2 else cv2.cvtColor(image, cv2.COLOR_BGR2GRAY)
        flags = cv2.CALIB_CB_ADAPTIVE_THRESH | cv2.CALIB_CB_NORMALIZE_IMAGE
        found, corners = cv2.findChessboardCorners(grey, (cols, rows), flags=flags)
        if not found:
            return self.sighting(None, "not found", {"found": False, "reason": "not found"})
        grid = corners.reshape(rows, cols, 2)
        spacing = min(
            np.linalg.norm(np.diff(grid, axis=0), axis=2).min(), np.linalg.norm(np.diff(grid, axis=1), axis=2).min()
        )
        half = int(np.clip(0.4 * spacing, *SUBPIX_HALF_WINDOW_PX))
        refined = cv2.cornerSubPix(grey, corners, (half, half), (-1, -1), _SUBPIX).reshape(-1, 2).astype(float)
        predicted = self.predicted_px(p_believed, q)
        if asymmetric(rows, cols):
            return self._by_colour(grey, refined, predicted)
        ordered = identify(refined, cols, rows, predicted)
        detail = {"found": ordered.found, "reason": ordered.reason, "detail": ordered.detail}
        if not ordered.found or ordered.corners is None:
            detail["detail"] = (
                f"{ordered.detail}; a board of {cols} x {rows} inner corners looks the same turned by half a turn, "
                "so the order of its corners needs the believed poses within tens of px (a calibration or a "
                "profile's guess), or a board with an odd number of inner columns plus rows, or a ChArUco board"
            )
            return self.sighting(None, ordered.reason, detail)
        return self.sighting(ordered.corners, "ok", detail)

    def _by_colour(self, grey: np.ndarray, corners: np.ndarray, predicted: np.ndarray) -> Sighting:
        """An asymmetric board's corners in vertex order from the face's handedness and the squares' colours."""
        rows, cols = self.shape
        # The printed face towards the camera: the image turns from the rows' direction to the columns' as
        # face_sign times the board's +x to -y does seen from its -z side (counter-clockwise in the image).
        if handedness(corners, rows, cols) != -self.face_sign:
            corners = mirrored(corners, rows, cols)
        contrast = tile_contrast(grey, corners, rows, cols)
        if contrast < 0:
            corners, contrast = corners[::-1], -contrast
        detail = {"found": True, "reason": "ok", "contrast": round(contrast, 1)}
        if contrast < MIN_CONTRAST:
            detail.update(
                found=False,
                reason="ambiguous",
                detail=f"its black and white squares differ by {contrast:.1f} grey levels, fewer than {MIN_CONTRAST:g}",
            )
            return self.sighting(None, "ambiguous", detail)
        distance = float(np.linalg.norm(corners - predicted, axis=1).mean())
        if np.isfinite(distance):
            detail["prediction_px"] = round(distance, 2)
        return self.sighting(corners, "ok", detail)
