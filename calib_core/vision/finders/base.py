"""How a sensor sees a target: the Finder protocol, and what the finders share.

A finder serves the sensor model and target pattern (`Target.pattern`) it is registered for (FINDERS), for a
sensor whose readings take the images it looks at (`images`, the sensor's `image_roles`). Bound to a profile,
a sensor and a target (`calib_core.vision.finders.finder_for`), it:

- `render(p, q, rng)`: draws what the sensor sees of the target for parameters p and joint readings q (the
  simulator's images, and the stereo head that took them);
- `find(p_believed, q, images, head)`: finds the target in the images (a depth map from a pair, or the
  camera's image), seeded by where the believed kinematics put it, and says what it measured: a `Sighting`
  (status and reason, measured rows, the points and vertices they are of, the detector's own figures);
- `shows(p, x)`: the detector's limits on a target whose points x lie in the field of view (a board's face,
  its obliquity, the spacing of its corners in the image): what `Visibility` asks of every view;
- `clear(p, q, margin_px, sphere_share)`: the costly limits (the arm hiding a stereo head's sphere), asked
  for whole views only, with the view's margins (`Visibility`'s, which asks the finders and is above them);
- `spacing_px(p, x)` and `min_spacing_px`: how far apart a board's neighbouring vertices are in the image, and the
  least its detector needs (None for a target that is not a board): why a board is seen nowhere (too small);
- `plan_margins`: what a plan's configurations keep clear with the base model (px from the border, the share
  of a sphere's outline the arm leaves free), when the detector needs more than `Visibility`'s defaults;
  `plan_obliquity_margin_deg`: how much less obliquely than its limit a plan's boards are seen.

A new board is one module with its finder and one line in `FINDERS` (calib_core/vision/finders/__init__.py).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING, ClassVar, Protocol

import numpy as np

from ...frame_status import FrameStatus
from ...model.profile import Profile
from ..sighting import Detail, Sighting, predicted_points

if TYPE_CHECKING:
    from ..stereo import StereoHead  # OpenCV and SciPy: loaded by the finders that render or read a stereo pair


@dataclass
class Rendered:
    """What a finder's renderer drew: the images by role, and the stereo head that took a pair."""

    images: dict[str, np.ndarray]
    head: StereoHead | None = None


class Finder(Protocol):
    """The protocol of a finder bound to a profile, a sensor and a target (see the module doc)."""

    images: ClassVar[tuple[str, ...]]
    plan_margins: ClassVar[tuple[float, float] | None]
    plan_obliquity_margin_deg: ClassVar[float]

    # Read-only: a finder stays bound to what it was made for (a frozen dataclass's fields conform), and a board's
    # finder says how far apart its detector needs the vertices (a class attribute of its own).
    @property
    def min_spacing_px(self) -> float | None: ...

    @property
    def profile(self) -> Profile: ...

    @property
    def sensor(self) -> int: ...

    @property
    def target(self) -> int: ...

    def render(self, p: np.ndarray, q: np.ndarray, rng: np.random.Generator) -> Rendered: ...

    def find(
        self, p_believed: np.ndarray, q: np.ndarray, images: dict[str, np.ndarray], head: StereoHead | None = None
    ) -> Sighting: ...

    def shows(self, p: np.ndarray, x: np.ndarray, obliquity_margin_deg: float = 0.0) -> np.ndarray: ...

    def clear(self, p: np.ndarray, q: np.ndarray, margin_px: float, sphere_share: float) -> np.ndarray: ...

    def spacing_px(self, p: np.ndarray, x: np.ndarray) -> np.ndarray | None: ...


class FinderClass(Protocol):
    """A finder's class as FINDERS names it: the images it looks at, and its finder bound to a profile's sensor and
    target."""

    images: tuple[str, ...]  # a class attribute of the finder's class

    def __call__(self, profile: Profile, sensor: int, target: int) -> Finder: ...


@dataclass(frozen=True)
class BoundFinder:
    """What every finder shares: the profile, sensor and target it is bound to, and the defaults."""

    profile: Profile
    sensor: int
    target: int

    plan_margins: ClassVar[tuple[float, float] | None] = None
    plan_obliquity_margin_deg: ClassVar[float] = 0.0
    min_spacing_px: ClassVar[float | None] = None  # not a board

    def shows(self, p: np.ndarray, x: np.ndarray, obliquity_margin_deg: float = 0.0) -> np.ndarray:
        """Whether the detector finds the target whose points x (N, K, 3) in the sensor frame are in view (N,)
        (a board at least `obliquity_margin_deg` less obliquely than its limit)."""
        return np.ones(len(x), bool)

    def clear(self, p: np.ndarray, q: np.ndarray, margin_px: float, sphere_share: float) -> np.ndarray:
        """Whether nothing hides the target from the detector in configurations q (N, n_joints) rad (N,), with
        parameters p, the target `margin_px` clear of the image's border and at least `sphere_share` of a sphere's
        outline free."""
        return np.ones(len(q), bool)

    def spacing_px(self, p: np.ndarray, x: np.ndarray) -> np.ndarray | None:
        """The least distance (px) between neighbouring vertices in the image of a board whose vertices x (N, K, 3)
        lie in the sensor frame (N,); None: not a board."""
        return None


class BoardFinder(BoundFinder):
    """A printed board in a camera's image: found where it shows its face (face_sign times (vertex 1 - vertex 0)
    x (vertex `cols` - vertex 0) points back to the camera), at most `max_obliquity_deg` from its normal, its
    neighbouring vertices at least `min_spacing_px` apart in the image."""

    images: ClassVar[tuple[str, ...]] = ("image",)
    face_sign: ClassVar[float] = 1.0
    max_obliquity_deg: ClassVar[float]
    min_spacing_px: ClassVar[float]

    @property
    def shape(self) -> tuple[int, int]:
        """Rows and columns of the board's vertices."""
        shape = self.profile.targets[self.target].grid_shape
        assert shape is not None  # a board has its shape
        return shape

    def predicted_px(self, p_believed: np.ndarray, q: np.ndarray) -> np.ndarray:
        """Where the believed kinematics put the target's points in the sensor's image (K, 2) px."""
        sensor = self.profile.sensors[self.sensor]
        return sensor.predict(p_believed, predicted_points(self.profile, p_believed, q, self.target, self.sensor))[0]

    def sighting(
        self,
        measured: np.ndarray | None,
        reason: str,
        detail: Detail,
        vertices: np.ndarray | None = None,
    ) -> Sighting:
        """A board's sighting: its corners `measured` (K, 2) px of `vertices` (default: every vertex in order),
        or none with the reason."""
        grid = self.profile.targets[self.target].grid
        assert grid is not None  # a board has its vertices
        vertices = np.arange(len(grid)) if vertices is None else np.asarray(vertices, int)
        status = FrameStatus.NOT_FOUND if measured is None else FrameStatus.MEASURED
        return Sighting(self.sensor, self.target, status, reason, measured, grid[vertices], vertices, detail)

    def shows(self, p: np.ndarray, x: np.ndarray, obliquity_margin_deg: float = 0.0) -> np.ndarray:
        """Whether the board (vertices x (N, K, 3) in the sensor frame) shows its face well enough (N,) bool, seen
        at least `obliquity_margin_deg` less obliquely than its limit."""
        n_cols = self.shape[1]
        c = x.mean(axis=1)
        face = self.face_sign * np.cross(x[:, 1] - x[:, 0], x[:, n_cols] - x[:, 0])
        towards = -np.einsum("ni,ni->n", face, c)  # the camera sits at the origin of these coordinates
        cos = towards / np.maximum(np.linalg.norm(face, axis=1) * np.linalg.norm(c, axis=1), 1e-300)
        ok = (towards > 0) & (cos >= math.cos(math.radians(self.max_obliquity_deg - obliquity_margin_deg)))
        spacing = self.spacing_px(p, x)
        if spacing is not None:
            ok &= spacing >= self.min_spacing_px
        return ok

    def spacing_px(self, p: np.ndarray, x: np.ndarray) -> np.ndarray | None:
        """The least distance (px) between neighbouring vertices in the image of a board whose vertices x
        (N, K, 3) lie in the sensor frame (N,); None for a sensor that does not project."""
        n_rows, n_cols = self.shape
        uv = self.profile.sensors[self.sensor].project(p, x.reshape(-1, 3))
        if uv is None:
            return None
        g = uv.reshape(len(x), n_rows, n_cols, 2)
        return np.minimum(
            np.linalg.norm(np.diff(g, axis=1), axis=3).min(axis=(1, 2)),
            np.linalg.norm(np.diff(g, axis=2), axis=3).min(axis=(1, 2)),
        )
