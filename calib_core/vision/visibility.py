"""What a sensor sees of the robot's targets where a model of the robot puts them: the one test of "in view".

The simulator asks it with its hidden truth (which configurations it generates); the planner, the dry run,
a random replay and bag import ask it with the believed model (what to choose, what to skip, which board to
look for). It answers per point and per target:

- a point is in view when it lies in the sensor's field of view: in front of it, within its range and inside
  its image `margin_px` clear of the border (`Sensor.visible`);
- a board shows its face, seen at most MAX_OBLIQUITY_DEG from its normal, its neighbouring vertices at least
  MIN_VERTEX_SPACING_PX apart in the image (what the board detector measures reliably);
- a stereo head's sphere lies whole inside both images, right of the matcher's band without depth, and the
  arm and hand leave at least `sphere_share` of its outline free in each camera (`sphere_views`; the costly
  part: `occlusion=False` leaves it out, and a planner checks it only for what it picks).

It lives beside the detectors because the last two are theirs: it needs the model (kinematics), the sensor
(field of view) and the detectors' limits, and `vision` is the layer that has all three.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ..model.kinematics import sensor_points, target_points
from ..model.profile import Profile
from .sandal_board import MAX_OBLIQUITY_DEG, MIN_VERTEX_SPACING_PX
from .stereo import StereoHead, no_depth_band_px, sphere_views

# The share of the sphere's outline the arm and hand must leave free in each camera of a stereo head.
# On 240 rendered first-day frames the BallFinder found the sphere in 8 of 31 views with less than
# 70% free, 23 of 26 with 70-85% and 185 of 196 above (those missed: seeds over 20 cm off, or the
# sphere beyond 1 m).
MIN_SPHERE_SHARE = 0.85
VIEW_MARGIN_PX = 10.0  # kept clear of the image border by default


@dataclass(frozen=True)
class Visibility:
    """What each sensor of `profile` sees with parameters `p` (internal units): see the module doc."""

    profile: Profile
    p: np.ndarray
    margin_px: float = VIEW_MARGIN_PX
    sphere_share: float = MIN_SPHERE_SHARE

    def points(self, q: np.ndarray, targets: np.ndarray, sensor: int | None = None) -> np.ndarray:
        """Whether a sensor (default: the data format's) sees each point of each configuration's target
        (N, K) bool, configurations q (N, n_joints) rad, targets (N,): in its field of view, and a board's
        points only where the board shows its face well enough. K: the most points of those targets; False
        beyond a target's own."""
        prof = self.profile
        s = prof.data.sensor if sensor is None else sensor
        sens = prof.sensors[s]
        x = sensor_points(prof, self.p, q, targets, sensor=s)
        N, K, _ = x.shape
        ok = sens.visible(self.p, x.reshape(-1, 3), self.margin_px).reshape(N, K)
        for t in set(np.asarray(targets).tolist()):
            rows = np.flatnonzero(targets == t)
            n = len(target_points(prof, self.p, t))
            ok[rows, n:] = False
            if prof.targets[t].grid is not None:
                ok[rows, :n] &= self._board_ok(s, x[rows, :n], prof.targets[t].grid_shape)[:, None]
        return ok

    def sees(
        self, q: np.ndarray, targets: np.ndarray, sensor: int | None = None, *, occlusion: bool = True
    ) -> np.ndarray:
        """Whether a sensor (default: the data format's) sees each configuration's whole target well enough
        for its detector (N,) bool: every point in view (`points`) and a stereo head's sphere clear of the
        arm (`occlusion=False` leaves this, the costly part, out)."""
        prof = self.profile
        s = prof.data.sensor if sensor is None else sensor
        targets = np.asarray(targets, int)
        n_points = {t: len(target_points(prof, self.p, t)) for t in set(targets.tolist())}
        counts = np.array([n_points[t] for t in targets.tolist()], int)
        ok = self.points(q, targets, s)
        seen = np.all(ok | (np.arange(ok.shape[1])[None, :] >= counts[:, None]), axis=1)
        if prof.sensors[s].reading == "stereo" and occlusion:
            rows = np.flatnonzero(seen)
            seen[rows] = self._sees_sphere(q[rows], s)
        return seen

    def targets_in_view(self, q: np.ndarray, sensor: int | None = None) -> list[int]:
        """The targets a sensor (default: the data format's) sees whole in one configuration q (n_joints,) rad."""
        every = np.arange(len(self.profile.targets))
        seen = self.sees(np.repeat(np.asarray(q, float)[None], len(every), axis=0), every, sensor)
        return [int(t) for t in every[seen]]

    def _board_ok(self, sensor: int, x: np.ndarray, shape: tuple[int, int] | None) -> np.ndarray:
        """Whether a board (vertices x (N, K, 3) in the sensor frame) shows its face, not too obliquely,
        with its vertices far enough apart in the image to be told apart (N,) bool."""
        assert shape is not None  # a grid target has its shape
        sens = self.profile.sensors[sensor]
        n_rows, n_cols = shape
        c = x.mean(axis=1)
        # +x cross -y: the board's -z axis, the normal of its face (under the sole); it must point
        # back to the camera, which sits at the origin of these coordinates.
        face = np.cross(x[:, 1] - x[:, 0], x[:, n_cols] - x[:, 0])
        towards = -np.einsum("ni,ni->n", face, c)
        cos = towards / np.maximum(np.linalg.norm(face, axis=1) * np.linalg.norm(c, axis=1), 1e-300)
        ok = (towards > 0) & (cos >= math.cos(math.radians(MAX_OBLIQUITY_DEG)))
        uv = sens.project(self.p, x.reshape(-1, 3))
        if uv is not None and sens.reading == "image":
            g = uv.reshape(len(x), n_rows, n_cols, 2)
            spacing = np.minimum(
                np.linalg.norm(np.diff(g, axis=1), axis=3).min(axis=(1, 2)),
                np.linalg.norm(np.diff(g, axis=2), axis=3).min(axis=(1, 2)),
            )
            ok &= spacing >= MIN_VERTEX_SPACING_PX
        return ok

    def _sees_sphere(self, q: np.ndarray, sensor: int) -> np.ndarray:
        """Whether the stereo pair would show the sphere well enough to the BallFinder (N,) bool."""
        head = StereoHead.from_profile(self.profile, self.p, self.profile.sensors[sensor].name)
        view = sphere_views(self.profile, self.p, q, head)
        u_min, u_max, v_min, v_max = view.box_px.T
        m = self.margin_px
        with np.errstate(invalid="ignore"):  # NaN boxes: the sphere reaches behind the camera
            inside = (
                (u_min >= no_depth_band_px(head) + m)
                & (u_max <= head.width_px - 1 - m)
                & (v_min >= m)
                & (v_max <= head.height_px - 1 - m)
            )
        return inside & (view.visible.min(axis=1) >= self.sphere_share)
