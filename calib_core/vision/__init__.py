"""Finders: how a sensor sees a target (finders/: one per sensor model and target pattern, each renders it and
finds it), the detectors and renderers behind them, and what a sensor sees (Visibility).

The names below load their module on first use (calib_core/_lazy.py): OpenCV only when one needs it."""

from __future__ import annotations

from typing import TYPE_CHECKING

from .._lazy import lazy_exports

__getattr__ = lazy_exports(
    __name__,
    {
        "ballfinder": ("find_sphere",),
        "finders": ("FINDERS", "Finder", "finder_for", "finders_served", "found_targets"),
        "sampling": ("Sampler",),
        "sandal_board": ("MAX_IMAGE_PX", "detect_board", "render_board_image", "too_large"),
        "sighting": ("Detail", "Sighting", "predicted_points"),
        "stereo": ("StereoHead", "depth_from_pair", "render_pair"),
        "visibility": ("VIEW_MARGIN_PX", "Visibility"),
    },
)
__all__ = [
    "FINDERS",
    "MAX_IMAGE_PX",
    "VIEW_MARGIN_PX",
    "Detail",
    "Finder",
    "Sampler",
    "Sighting",
    "StereoHead",
    "Visibility",
    "depth_from_pair",
    "detect_board",
    "find_sphere",
    "finder_for",
    "finders_served",
    "found_targets",
    "predicted_points",
    "render_board_image",
    "render_pair",
    "too_large",
]

if TYPE_CHECKING:
    from .ballfinder import find_sphere
    from .finders import FINDERS, Finder, finder_for, finders_served, found_targets
    from .sampling import Sampler
    from .sandal_board import MAX_IMAGE_PX, detect_board, render_board_image, too_large
    from .sighting import Detail, Sighting, predicted_points
    from .stereo import StereoHead, depth_from_pair, render_pair
    from .visibility import VIEW_MARGIN_PX, Visibility
