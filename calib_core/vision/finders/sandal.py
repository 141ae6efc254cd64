"""The NAO's checkerboard sandals in its lower camera's image (calib_core/vision/sandal_board.py): boards seen
very obliquely under the feet, found by OpenCV's chessboard detectors in the predicted region stretched to
square-ish tiles, each vertex's identity taken from the believed kinematics.
"""

from __future__ import annotations

from typing import ClassVar

import numpy as np

from ..sandal_board import MAX_OBLIQUITY_DEG, MIN_VERTEX_SPACING_PX, detect_board, render_board_image
from ..sighting import Sighting
from ..stereo import StereoHead
from .base import BoundFinder, Rendered, board_shows


class SandalFinder(BoundFinder):
    images: ClassVar[tuple[str, ...]] = ("image",)

    def render(self, p: np.ndarray, q: np.ndarray, rng: np.random.Generator) -> Rendered:
        return Rendered({"image": render_board_image(self.profile, p, q, self.target, rng, sensor=self.sensor).image})

    def find(
        self, p_believed: np.ndarray, q: np.ndarray, images: dict[str, np.ndarray], head: StereoHead | None = None
    ) -> Sighting:
        """The sandal board detector, its vertex identities taken from the believed kinematics."""
        shape = self.profile.targets[self.target].grid_shape
        assert shape is not None  # a grid target has its shape
        rows, cols = shape
        found = detect_board(images["image"], cols, rows, predicted=self.predicted_px(p_believed, q))
        detail = {"found": found.found, "reason": found.reason, "residual_px": found.residual_px}
        if not found.found or found.corners is None:
            return self.sighting(None, found.reason, detail)
        return self.sighting(np.asarray(found.corners, float), "ok", detail)

    def shows(self, p: np.ndarray, x: np.ndarray) -> np.ndarray:
        """The board's face (-z, under the sole) towards the camera at most MAX_OBLIQUITY_DEG from its normal, its
        vertices MIN_VERTEX_SPACING_PX apart: what the detector measures reliably."""
        return board_shows(
            self.profile,
            p,
            self.sensor,
            self.target,
            x,
            face_sign=1.0,
            max_obliquity_deg=MAX_OBLIQUITY_DEG,
            min_spacing_px=MIN_VERTEX_SPACING_PX,
        )
