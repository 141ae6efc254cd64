"""Detectors on real-looking images (BallFinder on stereo depth, the sandal board), their renderers, and what a
sensor sees (Visibility).

The names below load their module on first use (calib_core/_lazy.py): OpenCV only when one needs it."""

from __future__ import annotations

from typing import TYPE_CHECKING

from .._lazy import lazy_exports

__getattr__ = lazy_exports(
    __name__,
    {
        "ballfinder": ("find_sphere",),
        "sampling": ("Sampler",),
        "sandal_board": ("detect_board", "render_board_image"),
        "sighting": ("Sighting", "sight_board", "sight_fixture"),
        "stereo": ("StereoHead", "depth_from_pair", "render_pair"),
        "visibility": ("VIEW_MARGIN_PX", "Visibility"),
    },
)
__all__ = [
    "VIEW_MARGIN_PX",
    "Sampler",
    "Sighting",
    "StereoHead",
    "Visibility",
    "depth_from_pair",
    "detect_board",
    "find_sphere",
    "render_board_image",
    "render_pair",
    "sight_board",
    "sight_fixture",
]

if TYPE_CHECKING:
    from .ballfinder import find_sphere
    from .sampling import Sampler
    from .sandal_board import detect_board, render_board_image
    from .sighting import Sighting, sight_board, sight_fixture
    from .stereo import StereoHead, depth_from_pair, render_pair
    from .visibility import VIEW_MARGIN_PX, Visibility
