"""A sphere in a stereo head's depth map (Robonaut): the pair rendered, SGBM depth, the BallFinder.

The BallFinder is seeded by where the believed kinematics put the sphere's centre and measures that centre
as one 3-D point in the sensor frame. The arm and hand must leave enough of the sphere's outline free in each
camera (`Visibility.sphere_share`, which it passes to `clear`), and the sphere must lie whole inside both images,
right of the matcher's band without depth.
"""

from __future__ import annotations

from typing import ClassVar

import numpy as np

from ...frame_status import FrameStatus
from ...units import length_factor
from ..ballfinder import find_sphere
from ..sighting import Sighting, predicted_points
from ..stereo import StereoHead, depth_from_pair, no_depth_band_px, render_pair, sphere_views
from .base import BoundFinder, Rendered

# What a plan for a stereo head's sphere picks keeps more clear: its configurations lie at the edges of what
# the head sees (near, the arm close to the view ray), and on a Robonaut 13 cm off the nominal model the
# sphere moves up to 100 px and the arm hides more of it. With 40 px and the detector's own 85% share, 14% of
# a 32-configuration plan was lost on the true robot; with these, 6% (benchmarks/planning.py). A board
# camera's plans (NAO) keep the planner's default: a wider margin there lost more of NAO's frames, not fewer.
STEREO_PLAN_MARGIN_PX = 80.0
STEREO_PLAN_SPHERE_SHARE = 0.97


class SphereFinder(BoundFinder):
    images: ClassVar[tuple[str, ...]] = ("left", "right")
    plan_margins: ClassVar[tuple[float, float] | None] = (STEREO_PLAN_MARGIN_PX, STEREO_PLAN_SPHERE_SHARE)

    def head(self, p: np.ndarray) -> StereoHead:
        return StereoHead.from_profile(self.profile, p, self.profile.sensors[self.sensor].name)

    def render(self, p: np.ndarray, q: np.ndarray, rng: np.random.Generator) -> Rendered:
        head = self.head(p)
        pair = render_pair(self.profile, p, q, head, rng)
        return Rendered({"left": pair.left, "right": pair.right}, head)

    def find(
        self, p_believed: np.ndarray, q: np.ndarray, images: dict[str, np.ndarray], head: StereoHead | None = None
    ) -> Sighting:
        """The BallFinder on the pair's depth (`head`: the pair's, default the believed one), seeded by where the
        believed kinematics put the sphere."""
        profile, target = self.profile, self.target
        head = self.head(p_believed) if head is None else head
        radius = profile.targets[target].radius
        assert radius is not None  # a sphere target has its radius
        to_m = length_factor(profile.length_unit, "m")
        seed_m = (predicted_points(profile, p_believed, q, target, self.sensor)[0] @ head.R_frame_optical) * to_m
        depth_m = depth_from_pair(images["left"], images["right"], head)
        found = find_sphere(depth_m, head.fx_px, head.fy_px, head.cx_px, head.cy_px, radius * to_m, seed_m)
        detail = found.to_json()
        points, vertices = np.full((1, 3), np.nan), np.array([-1])
        if not found.found or found.center_m is None:
            return Sighting(self.sensor, target, FrameStatus.NOT_FOUND, found.reason, None, points, vertices, detail)
        measured = (head.R_frame_optical @ found.center_m) / to_m
        return Sighting(self.sensor, target, FrameStatus.MEASURED, "ok", measured[None], points, vertices, detail)

    def clear(self, p: np.ndarray, q: np.ndarray, margin_px: float, sphere_share: float) -> np.ndarray:
        """Whether the pair would show the sphere well enough to the BallFinder (N,) bool: whole inside both
        images, `margin_px` clear of their borders and of the band without depth, and at least `sphere_share` of
        its outline free of the arm in each camera."""
        head = self.head(p)
        seen = sphere_views(self.profile, p, q, head, least_share=sphere_share)
        u_min, u_max, v_min, v_max = seen.box_px.T
        m = margin_px
        with np.errstate(invalid="ignore"):  # NaN boxes: the sphere reaches behind the camera
            inside = (
                (u_min >= no_depth_band_px(head) + m)
                & (u_max <= head.width_px - 1 - m)
                & (v_min >= m)
                & (v_max <= head.height_px - 1 - m)
            )
        return inside & (seen.visible.min(axis=1) >= sphere_share)
