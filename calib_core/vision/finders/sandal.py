"""The NAO's checkerboard sandals in its lower camera's image (calib_core/vision/sandal_board.py): boards seen
very obliquely under the feet, found by OpenCV's chessboard detectors in the predicted region stretched to
square-ish tiles, each vertex's identity taken from the believed kinematics.
"""

from __future__ import annotations

import numpy as np

from ..sandal_board import MAX_OBLIQUITY_DEG, MIN_VERTEX_SPACING_PX, detect_board
from ..sighting import Sighting
from ..stereo import StereoHead
from .checkerboard import CheckerboardFinder


class SandalFinder(CheckerboardFinder):
    """A checkerboard (rendered as one) under the NAO's foot, its face towards -z, under the sole; its detector
    measures it reliably up to MAX_OBLIQUITY_DEG from its normal, its vertices MIN_VERTEX_SPACING_PX apart."""

    max_obliquity_deg = MAX_OBLIQUITY_DEG
    min_spacing_px = MIN_VERTEX_SPACING_PX
    # A plan's boards keep this much below the limit with the base model: a NAO's camera pitch is degrees off
    # its nominal (the paper's -4.5), and a board seen at 85-86 deg is found with five times the pixel error of
    # one at 80 deg, or lost (benchmarks/nao_offsets.py: 53-58 of 60 planned frames found with no margin, 60 with
    # 2 deg, the offsets' standard deviations alike).
    plan_obliquity_margin_deg = 2.0

    def find(
        self, p_believed: np.ndarray, q: np.ndarray, images: dict[str, np.ndarray], head: StereoHead | None = None
    ) -> Sighting:
        """The sandal board detector, its vertex identities taken from the believed kinematics."""
        rows, cols = self.shape
        found = detect_board(images["image"], cols, rows, predicted=self.predicted_px(p_believed, q))
        detail = {"found": found.found, "reason": found.reason, "residual_px": found.residual_px}
        if not found.found or found.corners is None:
            return self.sighting(None, found.reason, detail)
        return self.sighting(np.asarray(found.corners, float), "ok", detail)
