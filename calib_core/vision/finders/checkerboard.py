"""A plain checkerboard (a `grid:` target) in a camera's image: OpenCV's `findChessboardCorners` on the image,
`cornerSubPix`, and each corner's vertex identity taken from the believed kinematics (the board's mirror and
half-turn symmetries resolved as for the NAO's sandals, `sandal_board.identify`).

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
_SUBPIX = (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_MAX_ITER, 40, 0.001)


class CheckerboardFinder(BoardFinder):
    """The board's face is its frame's -z side (the grid's vertices run along +x, rows along -y)."""

    max_obliquity_deg = MAX_OBLIQUITY_DEG
    min_spacing_px = MIN_CORNER_SPACING_PX

    def render(self, p: np.ndarray, q: np.ndarray, rng: np.random.Generator) -> Rendered:
        return Rendered({"image": render_board_image(self.profile, p, q, self.target, rng, sensor=self.sensor).image})

    def find(
        self, p_believed: np.ndarray, q: np.ndarray, images: dict[str, np.ndarray], head: StereoHead | None = None
    ) -> Sighting:
        """The whole board's corners, sub-pixel, in vertex order; "not found" or, from the prediction, "far from
        prediction" or "ambiguous" (sandal_board.identify)."""
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
        ordered = identify(refined, cols, rows, self.predicted_px(p_believed, q))
        detail = {"found": ordered.found, "reason": ordered.reason, "detail": ordered.detail}
        if not ordered.found or ordered.corners is None:
            return self.sighting(None, ordered.reason, detail)
        return self.sighting(ordered.corners, "ok", detail)
