"""What a sensor sees of the robot's targets where a model of the robot puts them: the one test of "in view".

The simulator asks it with its hidden truth (which configurations it generates); the planner, the dry run,
a random replay and bag import ask it with the believed model (what to choose, what to skip, which board to
look for). It answers per point and per target:

- a point is in view when it lies in the sensor's field of view: in front of it, within its range and inside
  its image `margin_px` clear of the border (`Sensor.visible`);
- the sensor's finder for the target (`calib_core.vision.finders`) can find it there (`Finder.shows`): a board
  shows its face, not too obliquely, its neighbouring vertices far enough apart in the image;
- nothing hides it from the finder (`Finder.clear`): a stereo head's sphere lies whole inside both images,
  right of the matcher's band without depth, and the arm and hand leave at least `sphere_share` of its outline
  free in each camera (the costly part: `occlusion=False` leaves it out, and a planner checks it only for what
  it picks).

A target of many points (a board's corners) is first checked at its outline alone (`Visibility.outline`): every
point in view needs its extreme points in view, and those few cost a fraction of the whole board. A random draw
mostly misses (a wrist camera sees its board in 2 of 1000 uniform draws of the hand-eye arm's joints), so `sees`
checks the whole board, its face and what hides it only where the outline is in view: the same answers
(tests/test_visibility.py), and with `Sampler.uniform`'s batches checked ahead the hand-eye arm's draws take a fifth
of the CPU they took (benchmarks/visibility.py).

It lives beside the finders because the last two are theirs: it needs the model (kinematics), the sensor
(field of view) and the finders' limits, and `vision` is the layer that has all three.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..model.kinematics import forward, sensor_points, target_points, to_sensor
from ..model.profile import Profile
from .finders import finder_for

# The share of the sphere's outline the arm and hand must leave free in each camera of a stereo head.
# On 240 rendered first-day frames the BallFinder found the sphere in 8 of 31 views with less than
# 70% free, 23 of 26 with 70-85% and 185 of 196 above (those missed: seeds over 20 cm off, or the
# sphere beyond 1 m).
MIN_SPHERE_SHARE = 0.85
VIEW_MARGIN_PX = 10.0  # kept clear of the image border by default
OUTLINE_POINTS = 8  # a target of more points than this is checked at its outline first (`Visibility.outline`)
# The outline's check keeps this much more of the image than `points` does: the round-off of another batch never
# makes it refuse a point that `points` sees.
OUTLINE_SLACK_PX = 0.5
# The outline of a target: its extreme points along these directions (a flat board's four corners among them).
_CORNER_DIRECTIONS = np.array([[a, b, c] for a in (-1, 1) for b in (-1, 1) for c in (-1, 1)], float)


@dataclass(frozen=True)
class Visibility:
    """What each sensor of `profile` sees with parameters `p` (internal units): see the module doc."""

    profile: Profile
    p: np.ndarray
    margin_px: float = VIEW_MARGIN_PX
    sphere_share: float = MIN_SPHERE_SHARE
    obliquity_margin_deg: float = 0.0  # a board seen at least this much less obliquely than its finder's limit

    def points(self, q: np.ndarray, targets: np.ndarray, sensor: int | None = None) -> np.ndarray:
        """Whether a sensor (default: the data format's) sees each point of each configuration's target
        (N, K) bool, configurations q (N, n_joints) rad, targets (N,): in its field of view, and only where its
        finder can find the target there (a board's face, obliquity and spacing). K: the most points of those
        targets; False beyond a target's own."""
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
            finder = finder_for(prof, s, t)
            if finder is not None:
                ok[rows, :n] &= finder.shows(self.p, x[rows, :n], self.obliquity_margin_deg)[:, None]
        return ok

    def sees(
        self, q: np.ndarray, targets: np.ndarray, sensor: int | None = None, *, occlusion: bool = True
    ) -> np.ndarray:
        """Whether a sensor (default: the data format's) sees each configuration's whole target well enough
        for its finder (N,) bool: every point in view (`points`) and nothing hiding it from the finder (a stereo
        head's sphere clear of the arm; `occlusion=False` leaves this, the costly part, out)."""
        prof = self.profile
        s = prof.data.sensor if sensor is None else sensor
        targets = np.asarray(targets, int)
        used = np.unique(targets)
        n_points = np.zeros(used.max(initial=0) + 1, int)
        n_points[used] = [len(target_points(prof, self.p, t)) for t in used.tolist()]
        rows = np.flatnonzero(self.outline(q, targets, s))
        seen = np.zeros(len(targets), bool)
        if len(rows):
            ok = self.points(q[rows], targets[rows], s)
            seen[rows] = np.all(ok | (np.arange(ok.shape[1])[None, :] >= n_points[targets[rows], None]), axis=1)
        return self.clear(q, targets, s, among=seen) if occlusion else seen

    def outline(self, q: np.ndarray, targets: np.ndarray, sensor: int | None = None) -> np.ndarray:
        """Whether a sensor (default: the data format's) has the outline of each configuration's target in view
        (N,) bool: its extreme points (a board's corners) in the field of view, OUTLINE_SLACK_PX less clear of the
        border than `points` asks. A target of OUTLINE_POINTS or fewer points, or seen by a sensor without an image
        (a tracker: nearly everything in view), counts as in view: `points` checks it whole. A configuration whose
        outline is not in view has a point `points` does not see."""
        prof = self.profile
        s = prof.data.sensor if sensor is None else sensor
        sens = prof.sensors[s]
        targets = np.asarray(targets, int)
        out = np.ones(len(targets), bool)
        big = [t for t in np.unique(targets).tolist() if len(target_points(prof, self.p, t)) > OUTLINE_POINTS]
        if not big or getattr(sens, "image", None) is None:
            return out
        rows = np.flatnonzero(np.isin(targets, big))
        poses = forward(prof, self.p, q[rows], frames=sorted({prof.targets[t].frame for t in big} | {sens.frame}))
        for t in big:
            mine = np.flatnonzero(targets[rows] == t)
            pts = target_points(prof, self.p, t)
            corners = pts[np.unique(np.argmax(pts @ _CORNER_DIRECTIONS.T, axis=0))]
            cfg, local = np.repeat(mine, len(corners)), np.tile(corners, (len(mine), 1))
            x = to_sensor(poses, prof.targets[t].frame, sens.frame, cfg, local)[1]
            ok = sens.visible(self.p, x, self.margin_px - OUTLINE_SLACK_PX)
            out[rows[mine]] = ok.reshape(len(mine), len(corners)).all(axis=1)
        return out

    def clear(
        self, q: np.ndarray, targets: np.ndarray, sensor: int | None = None, *, among: np.ndarray | None = None
    ) -> np.ndarray:
        """Whether nothing hides each configuration's target from the sensor's finder (N,) bool (a stereo head's
        sphere clear of the arm), of configurations whose target is in view: `among` (bool), default all (those
        that `sees(occlusion=False)` passed already)."""
        s = self.profile.data.sensor if sensor is None else sensor
        targets = np.asarray(targets, int)
        seen = np.ones(len(targets), bool) if among is None else among.copy()
        for t in set(targets[seen].tolist()):
            finder = finder_for(self.profile, s, t)
            if finder is not None:
                rows = np.flatnonzero(seen & (targets == t))
                seen[rows] = finder.clear(self.p, q[rows], self.margin_px, self.sphere_share)
        return seen

    def too_small(self, q: np.ndarray, target: int) -> str:
        """Why a board is seen in none of configurations q (N, n_joints) rad, when it is too small: "" unless every
        configuration that puts it whole in the field of view gives neighbouring vertices closer in the image than
        its finder needs; else a sentence with the numbers."""
        prof = self.profile
        s = prof.data.sensor
        finder = finder_for(prof, s, target)
        if finder is None or finder.min_spacing_px is None:
            return ""
        spacing_px = finder.min_spacing_px
        n = len(target_points(prof, self.p, target))
        x = sensor_points(prof, self.p, q, np.full(len(q), target), sensor=s)[:, :n]
        whole = prof.sensors[s].visible(self.p, x.reshape(-1, 3), self.margin_px).reshape(len(q), n).all(axis=1)
        spacing = finder.spacing_px(self.p, x[whole]) if whole.any() else None
        if spacing is None or spacing.max() >= spacing_px:
            return ""
        grid = prof.targets[target].grid
        apart = float(np.linalg.norm(grid[1] - grid[0])) if grid is not None and len(grid) > 1 else float("nan")
        distance = np.linalg.norm(x[whole].mean(axis=1), axis=1)
        unit = prof.length_unit
        return (
            f"; target '{prof.targets[target].name}' is too small to be seen: in the {int(whole.sum())} of {len(q)} "
            f"configurations that put it in view of '{prof.sensors[s].name}' ({distance.min():.0f}-"
            f"{distance.max():.0f} {unit} away) its corners, {apart:g} {unit} apart, are at most "
            f"{spacing.max():.1f} px apart in the image, and its finder needs {spacing_px:g} px: a bigger board "
            "or a closer camera"
        )

    def targets_in_view(self, q: np.ndarray, sensor: int | None = None) -> list[int]:
        """The targets a sensor (default: the data format's) sees whole in one configuration q (n_joints,) rad."""
        every = np.arange(len(self.profile.targets))
        seen = self.sees(np.repeat(np.asarray(q, float)[None], len(every), axis=0), every, sensor)
        return [int(t) for t in every[seen]]
