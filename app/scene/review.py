"""Review: a session's frames seen through an old and a new calibration, precomputed for the page and the scene.

Everything is computed once per (session, old, new) with batched kinematics; a frame's figures,
marks and 3-D geometry are then array slices. Each side is a whole model: its URDF (the profile's
frame tree at that side's parameters, `calib_core.urdf.to_urdf`) puts the joint offsets and link
lengths into the joint origins, so both URDF copies are driven by the same joint readings and
still show where each calibration believes every link is.

Errors are the papers' figure: the distance between prediction and measurement per observation
(cm in the eye frame for Robonaut, px for NAO); a frame's error is the mean over its observations.
The summary and the histogram count observations, like `Calibration.figures`, so the numbers agree
with the calibration's own on the same data.

A frame's change (new - old) is "better" or "worse" only beyond CHANGE_BANDS times its band, how far the
calibrations' own uncertainty moves the frame's predictions (`calib_core.estimation.change`: each side with
a covariance, in quadrature; the nominal model and files written before covariances were kept have none),
"same" within it: the uncertainty moves all of a frame's points together, so noise over sqrt(points)
would call most frames of two equally good calibrations changed.

Where the points are in 3-D (base frame, metres) and in the image: each sensor places its own measurement
(`Sensor.place`, `Sensor.measured_pixels`) through that side's sensor pose. A 3-D sensor's measurement is
the point; a camera measures only directions, so a measured pixel is back-projected onto the plane of the
board as that side's calibration predicts it; a plane's distance moves the predicted point along the
plane's normal. Nothing here asks which kind a sensor is.
"""

from __future__ import annotations

import math
from collections.abc import Iterable
from dataclasses import dataclass
from typing import Literal, Protocol, TypedDict

import numpy as np

from calib_core import Dataset, FrameStatus, Profile
from calib_core.estimation import Covariance, figures, frame_band, local_points
from calib_core.io import to_urdf
from calib_core.model import forward, to_sensor
from calib_core.sensors import Sensor
from calib_core.units import length_factor

from ..errors import NotFound

HISTOGRAM_BINS = 20
CHANGE_BANDS = 2.0  # a frame's change is "better" or "worse" beyond this many bands


Side = Literal["old", "new"]
Verdict = Literal["better", "worse", "same"]


class ReviewRow(TypedDict):
    """A frame of the review's table (see `Review.table`)."""

    index: int
    status: FrameStatus
    target: int
    err_old: float | None  # None: not measured
    err_new: float | None  # None: not measured, or no new calibration
    heldout: bool
    band: float | None  # None: no covariance, or not measured
    verdict: Verdict | None  # None: no new calibration, or no band


class Marks(TypedDict):
    """The 2-D split view of one frame (see `Review.marks`): [u, v] px per point, None where there is none."""

    index: int
    role: str | None  # the image the marks belong to (None: the sensor takes no image)
    width: int | None
    height: int | None
    measured: list[list[float] | None]
    old: list[list[float] | None]
    new: list[list[float] | None] | None  # None: no new calibration


class Figures(TypedDict):
    """The distances between prediction and measurement of the measured observations (None: none measured)."""

    mean: float | None
    rms: float | None
    max: float | None
    n: int


class Histogram(TypedDict):
    """The observations' errors in HISTOGRAM_BINS bins (no bins: nothing measured, or no error at all)."""

    edges: list[float]
    old: list[int]
    new: list[int] | None  # None: no new calibration


class ChangeBand(TypedDict):
    """What a frame's change is read against: k bands, of the sides with a covariance, their median."""

    k: float
    of: list[str]  # the sides ("old", "new") with a covariance
    median: float | None  # over the measured frames (None: no band)


class ReviewSummary(TypedDict):
    """The session's figures (see `Review.summary`)."""

    unit: str
    frames: int
    measured: int
    heldout_frames: int
    old: Figures
    new: Figures | None  # None: no new calibration
    heldout_old: Figures | None  # None: no held-out frame measured
    heldout_new: Figures | None  # None: that, or no new calibration
    histogram: Histogram
    band: ChangeBand


class SightingLike(Protocol):
    """What a live view needs of one sensor's sighting (calib_core.vision.sighting.Sighting)."""

    sensor: int
    target: int
    points: np.ndarray
    measured: np.ndarray | None


class FrameLike(Protocol):
    """What a review needs of a stored frame (app.store.FrameInfo)."""

    index: int
    joints_rad: np.ndarray
    target: int
    status: FrameStatus


@dataclass(frozen=True)
class FrameGeometry:
    """One frame as the scene shows it. Points are in the robot's base frame, metres, row-aligned:
    `measured_m[side][k]` is the measurement of the point predicted at `predicted_m[side][k]`
    (NaN rows: nothing measured, e.g. a frame whose detector found nothing)."""

    index: int
    joints_rad: np.ndarray  # (n_joints,) the readings, profile joint order: both URDF copies show these
    predicted_m: dict[str, np.ndarray]  # side ("old", "new") -> (K, 3)
    measured_m: dict[str, np.ndarray]  # side -> (K, 3)


@dataclass
class _Side:
    """One calibration's view of every observation (rows of the review's observation list)."""

    p: np.ndarray
    predicted: np.ndarray  # (M, dim) sensor units (cm or px)
    predicted_m: np.ndarray  # (M, 3) base frame, m
    measured_m: np.ndarray  # (M, 3) base frame, m (NaN where nothing was measured)
    image_px: np.ndarray  # (M, 2) the prediction in the image (NaN: no image or behind the camera)
    error: np.ndarray  # (M,) |prediction - measurement| (NaN where nothing was measured)
    frame_error: np.ndarray  # (N,) mean over the frame's observations (NaN: not measured)


class Review:
    def __init__(
        self,
        profile: Profile,
        indices: np.ndarray,
        statuses: list[FrameStatus],
        targets: np.ndarray,
        joints_rad: np.ndarray,
        start: np.ndarray,
        measured: np.ndarray,
        measured_px: np.ndarray,
        sides: dict[str, _Side],
        heldout: np.ndarray,
        bounds_m: np.ndarray,
        sensor: int,
        band: np.ndarray,
        band_of: list[str],
    ) -> None:
        self.profile = profile
        self.indices = indices
        self.statuses = statuses
        self.targets = targets
        self.joints_rad = joints_rad
        self.start = start
        self.measured = measured
        self.measured_px = measured_px
        self.sides = sides
        self.heldout = heldout
        self.bounds_m = bounds_m
        self.band = band
        self.band_of = band_of
        self._row = {int(i): r for r, i in enumerate(indices)}
        self.sensor_index = sensor
        self.sensor = profile.sensors[sensor]
        self.unit = self.sensor.unit
        self.urdf = {side: to_urdf(profile, s.p, bodies=True) for side, s in sides.items()}

    @classmethod
    def build(
        cls,
        profile: Profile,
        frames: list[FrameLike],
        data: Dataset | None,
        old_p: np.ndarray,
        new_p: np.ndarray | None,
        *,
        heldout_frames: Iterable[int] = frozenset(),
        sensor: int | None = None,
        covariances: dict[str, Covariance | None] | None = None,
    ) -> Review:
        """Precompute every frame for both calibrations, as one sensor (default: the data format's) sees
        it. `data`: the session's measured frames (frame_ids = frame indices), None when nothing was
        measured; frames without an observation of the sensor get no error. `covariances`: per side ("old",
        "new"), its calibration's covariance (None or missing: it has none), what a frame's band is of."""
        sensor = profile.data.sensor if sensor is None else sensor
        if data is not None:
            data = data.of_sensor(sensor) if sensor in data.sensors else None
        frames = sorted(frames, key=lambda f: f.index)
        n = len(frames)
        indices = np.array([f.index for f in frames], dtype=int)
        targets = np.array([f.target for f in frames], dtype=int)
        joints = np.array([np.asarray(f.joints_rad, float) for f in frames]).reshape(n, len(profile.joints))
        rows, target, point, measured = _observations(profile, indices, targets, joints, data, sensor)
        joints = np.nan_to_num(joints)  # joints the frame's chains do not use do not matter
        order = np.argsort(rows, kind="stable")
        rows, target, point, measured = rows[order], target[order], point[order], measured[order]
        start = np.searchsorted(rows, np.arange(n + 1))
        measured_px = profile.sensors[sensor].measured_pixels(new_p if new_p is not None else old_p, measured)
        params = {"old": old_p} | ({} if new_p is None else {"new": new_p})
        sides = {
            side: _side(profile, p, joints, rows, target, point, measured, n, sensor) for side, p in params.items()
        }
        heldout = np.isin(indices, np.fromiter(heldout_frames, dtype=int))
        bounds = frame_bounds_m(profile, old_p, joints, [s.predicted_m for s in sides.values()])
        with_cov = {k: v for k, v in (covariances or {}).items() if v is not None and k in params}
        band = np.zeros(n)
        if data is not None and with_cov:
            row_of = np.array([np.searchsorted(indices, f) for f in data.frame_ids])
            known = np.isin(data.frame_ids, indices)
            for side, cov in with_cov.items():
                band[row_of[known]] += frame_band(profile, data, params[side], cov)[known] ** 2
        return cls(
            profile,
            indices,
            [f.status for f in frames],
            targets,
            joints,
            start,
            measured,
            measured_px,
            sides,
            heldout,
            bounds,
            sensor,
            np.sqrt(band) if with_cov else np.full(n, np.nan),
            sorted(with_cov, key=["old", "new"].index),
        )

    # --- per frame ------------------------------------------------------------------------------
    def row(self, index: int) -> int:
        """The position of frame `index` (its 1-based frame number) in the review."""
        try:
            return self._row[int(index)]
        except KeyError:
            known = f"frames {self.indices[0]}..{self.indices[-1]}" if len(self.indices) else "no frames"
            raise NotFound(f"frame {index} is not in this review ({known})") from None

    def table(self) -> list[ReviewRow]:
        """Per frame: {index, status, target, err_old, err_new, heldout, band, verdict}; errors None when not
        measured, band None without a covariance, verdict "better", "worse", "same" or None (see the module)."""
        old = self.sides["old"].frame_error
        new = self.sides["new"].frame_error if "new" in self.sides else None
        return [
            {
                "index": int(i),
                "status": self.statuses[r],
                "target": int(self.targets[r]),
                "err_old": _num(old[r]),
                "err_new": None if new is None else _num(new[r]),
                "heldout": bool(self.heldout[r]),
                "band": _num(self.band[r]) if math.isfinite(old[r]) else None,
                "verdict": None if new is None else _verdict(new[r] - old[r], self.band[r]),
            }
            for r, i in enumerate(self.indices)
        ]

    def marks(self, index: int) -> Marks:
        """The 2-D split view: {index, role, width, height, measured, old, new}, [u, v] px per point,
        row-aligned (None where nothing was measured or a point is behind the camera); new is None
        without a new calibration. role: the image the marks belong to ("left" of a stereo head,
        "image" of a camera; None: the sensor takes no image)."""
        r = self.row(index)
        s = slice(self.start[r], self.start[r + 1])
        width, height = self.sensor.image_size_px() or (None, None)
        roles = self.sensor.image_roles
        return {
            "index": int(index),
            "role": roles[0] if roles else None,
            "width": width,
            "height": height,
            "measured": image_pixels(self.measured_px[s]),
            "old": image_pixels(self.sides["old"].image_px[s]),
            "new": image_pixels(self.sides["new"].image_px[s]) if "new" in self.sides else None,
        }

    def frame_geometry(self, index: int) -> FrameGeometry:
        r = self.row(index)
        s = slice(self.start[r], self.start[r + 1])
        return FrameGeometry(
            int(index),
            self.joints_rad[r],
            {side: v.predicted_m[s] for side, v in self.sides.items()},
            {side: v.measured_m[s] for side, v in self.sides.items()},
        )

    def all_points(self, side: str) -> tuple[np.ndarray, np.ndarray]:
        """(measured, predicted) base-frame points (M, 3) m of every measured observation of the session."""
        got = np.isfinite(self.sides[side].measured_m[:, 0])
        return self.sides[side].measured_m[got], self.sides[side].predicted_m[got]

    # --- the session ----------------------------------------------------------------------------
    def summary(self) -> ReviewSummary:
        """{unit, frames, measured, heldout_frames, old, new, heldout_old, heldout_new, histogram, band}.
        Figures are {mean, rms, max, n} over observations (n = 0 and None figures when there are
        none); new and heldout_* are None when there is no new calibration or no held-out frame. band:
        {k, of (the sides whose covariance it is of), median (over measured frames; None: no band)}."""
        obs_heldout = np.repeat(self.heldout, np.diff(self.start))
        has_heldout = bool(np.any(self.heldout & self._measured_frames()))
        old, new = self.sides["old"], self.sides.get("new")
        measured = self._measured_frames() & np.isfinite(self.band)
        return {
            "unit": self.unit,
            "frames": len(self.indices),
            "measured": int(self._measured_frames().sum()),
            "heldout_frames": int(self.heldout.sum()),
            "old": _figures(old.error),
            "heldout_old": _figures(old.error[obs_heldout]) if has_heldout else None,
            "new": None if new is None else _figures(new.error),
            "heldout_new": _figures(new.error[obs_heldout]) if new is not None and has_heldout else None,
            "histogram": self._histogram(),
            "band": {
                "k": CHANGE_BANDS,
                "of": self.band_of,
                "median": float(np.median(self.band[measured])) if measured.any() else None,
            },
        }

    def _measured_frames(self) -> np.ndarray:
        return np.isfinite(self.sides["old"].frame_error)

    def _histogram(self) -> Histogram:
        errors = {side: s.error[np.isfinite(s.error)] for side, s in self.sides.items()}
        top = max((float(e.max()) for e in errors.values() if len(e)), default=0.0)
        if top <= 0.0:
            return {"edges": [], "old": [], "new": None if "new" not in errors else []}
        edges = np.linspace(0.0, top, HISTOGRAM_BINS + 1)
        counts = {side: np.histogram(e, bins=edges)[0].tolist() for side, e in errors.items()}
        return {"edges": edges.tolist(), "old": counts["old"], "new": counts.get("new")}


def live_geometry(
    profile: Profile, p: np.ndarray, q_rad: np.ndarray, sightings: Iterable[SightingLike]
) -> FrameGeometry:
    """One live look (Observe) through calibration p, as side "old": each sighting's points in its target frame
    (NaN: the target's calibrated point), as its own sensor predicts and places them, one after the other."""
    q = np.nan_to_num(np.asarray(q_rad, float))[None]
    predicted, measured = [np.zeros((0, 3))], [np.zeros((0, 3))]
    for s in sightings:
        k = len(s.points)
        dim = profile.sensors[s.sensor].dim
        meas = np.full((k, dim), np.nan) if s.measured is None else np.asarray(s.measured, float)
        side = _side(
            profile, p, q, np.zeros(k, int), np.full(k, s.target), np.asarray(s.points, float), meas, 1, s.sensor
        )
        predicted.append(side.predicted_m)
        measured.append(side.measured_m)
    return FrameGeometry(0, q[0], {"old": np.concatenate(predicted)}, {"old": np.concatenate(measured)})


# --- computation --------------------------------------------------------------------------------


def _observations(
    profile: Profile, indices: np.ndarray, targets: np.ndarray, joints: np.ndarray, data: Dataset | None, sensor: int
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Every frame's observed points: the dataset's for measured frames (their joint readings fill
    the frame's; a row that names only a board's vertex or a marker gets that point, as the solver reads it, and
    a calibrated point stays NaN for each side to fill), the whole target, unmeasured (NaN), for the others, so a
    frame whose detector found nothing still shows where its target was predicted. Returns (row, target, point,
    measured)."""
    dim = profile.sensors[sensor].dim
    row_of = {int(i): r for r, i in enumerate(indices)}
    rows, target, point, measured = [], [], [], []
    seen = np.zeros(len(indices), bool)
    if data is not None and data.n_observations:
        cfg_row = np.array([row_of.get(int(f), -1) for f in data.frame_ids])
        keep = cfg_row[data.cfg] >= 0
        obs_rows = cfg_row[data.cfg[keep]]
        rows.append(obs_rows)
        target.append(data.target[keep])
        points = data.point.copy()
        for t in np.unique(data.target).tolist():
            if profile.targets[t].point_params is None:
                obs = np.flatnonzero(data.target == t)
                points[obs] = local_points(profile, data, obs, t, profile.nominal())
        point.append(points[keep])
        measured.append(data.measured[keep, :dim])
        seen[obs_rows] = True
        for c, r in enumerate(cfg_row):
            if r >= 0:
                joints[r] = np.where(np.isnan(data.joints[c]), joints[r], data.joints[c])
    for r in np.flatnonzero(~seen):
        t = profile.targets[int(targets[r])]
        # The whole target: a board's grid, fixed points (markers, a reflector at its frame's origin), or
        # the calibrated point (NaN).
        pts = t.grid if t.grid is not None else t.points if t.points is not None else np.full((1, 3), np.nan)
        rows.append(np.full(len(pts), r))
        target.append(np.full(len(pts), targets[r]))
        point.append(pts)
        measured.append(np.full((len(pts), dim), np.nan))
    if not rows:
        return np.zeros(0, int), np.zeros(0, int), np.zeros((0, 3)), np.zeros((0, dim))
    return np.concatenate(rows), np.concatenate(target), np.concatenate(point), np.concatenate(measured)


def _side(
    profile: Profile,
    p: np.ndarray,
    joints: np.ndarray,
    rows: np.ndarray,
    target: np.ndarray,
    point: np.ndarray,
    measured: np.ndarray,
    n_frames: int,
    sensor_index: int,
) -> _Side:
    sensor = profile.sensors[sensor_index]
    to_m = length_factor(profile.length_unit, "m")
    used = sorted(set(target.tolist()))
    poses = forward(profile, p, joints, frames=sorted({profile.targets[t].frame for t in used} | {sensor.frame}))
    P = np.zeros((len(rows), 3))  # the points in the base frame, profile length unit
    x = np.zeros((len(rows), 3))  # ... and in the sensor frame
    normal = np.zeros((len(rows), 3))  # the target frame's z axis (a board's normal)
    R_base_target = np.zeros((len(rows), 3, 3))  # the target frame's orientation (what a pose sensor measures)
    for t in used:
        sel = np.flatnonzero(target == t)
        tg = profile.targets[t]
        local = point[sel]
        if tg.point_params is not None:
            local = np.where(np.isnan(local), p[list(tg.point_params)], local)
        P[sel], x[sel], _, R_base_target[sel] = to_sensor(poses, tg.frame, sensor.frame, rows[sel], local)
        normal[sel] = R_base_target[sel, :, 2]
    R_base_sensor = poses.R[sensor.frame][rows]
    t_base_sensor = poses.t[sensor.frame][rows]
    rotation = R_base_sensor.transpose(0, 2, 1) @ R_base_target if sensor.rotation_axes else None
    predicted = sensor.predict_pose(p, x, rotation)[0] if len(x) else np.zeros((0, measured.shape[1]))
    normal_sensor = np.einsum("nji,nj->ni", R_base_sensor, normal)
    x_measured = sensor.place(p, measured, x, normal_sensor)
    measured_base = (R_base_sensor @ x_measured[:, :, None])[:, :, 0] + t_base_sensor
    # A pose's error is its position's (the figure's unit); its rotation is in the calibration's figures.
    error = np.linalg.norm(sensor.error(predicted, measured)[:, : sensor.dim - sensor.rotation_axes], axis=1)
    got = np.isfinite(error)
    counts = np.bincount(rows[got], minlength=n_frames)
    sums = np.bincount(rows[got], weights=error[got], minlength=n_frames)
    with np.errstate(invalid="ignore", divide="ignore"):
        frame_error = np.where(counts > 0, sums / np.maximum(counts, 1), np.nan)
    return _Side(
        p=np.asarray(p, float).copy(),
        predicted=predicted,
        predicted_m=P * to_m,
        measured_m=measured_base * to_m,
        image_px=_image(sensor, p, x),
        error=error,
        frame_error=frame_error,
    )


def _image(sensor: Sensor, p: np.ndarray, x: np.ndarray) -> np.ndarray:
    """Pixels (M, 2) of sensor-frame points x in the sensor's (left) image; NaN behind the camera
    or when the sensor makes no image."""
    uv = sensor.project(p, x)
    return np.full((len(x), 2), np.nan) if uv is None else uv


def frame_bounds_m(
    profile: Profile, p: np.ndarray, joints: np.ndarray, points_m: Iterable[np.ndarray] = ()
) -> np.ndarray:
    """(2, 3) min and max, base frame, m, of every frame origin in every configuration and every point.
    An external device's frame (a laser tracker's registration, metres away) is not the robot's extent."""
    to_m = length_factor(profile.length_unit, "m")
    q = joints if len(joints) else np.zeros((1, len(profile.joints)))
    robot = [f for f, frame in enumerate(profile.frames) if not frame.registration]
    poses = forward(profile, p, q, frames=robot)
    pts = [np.concatenate([poses.t[f] for f in robot]) * to_m, np.zeros((1, 3))] + [x for x in points_m if len(x)]
    allp = np.concatenate(pts)
    allp = allp[np.isfinite(allp).all(axis=1)]
    return np.stack([allp.min(axis=0), allp.max(axis=0)])


def _figures(error: np.ndarray) -> Figures:
    """{mean, rms, max, n} of the measured observations' distances (calib_core's figures; None when none)."""
    e = error[np.isfinite(error)][:, None]
    f = figures(e, np.zeros_like(e), "")
    if f.n == 0:
        return {"mean": None, "rms": None, "max": None, "n": 0}
    return {"mean": f.mean, "rms": f.rms, "max": f.max, "n": f.n}


def _verdict(delta: float, band: float) -> Verdict | None:
    """A frame's new - old error read against its band: None when either is missing."""
    if not (math.isfinite(delta) and math.isfinite(band)):
        return None
    if abs(delta) <= CHANGE_BANDS * band:
        return "same"
    return "better" if delta < 0 else "worse"


def _num(v: float) -> float | None:
    return float(v) if math.isfinite(v) else None


def image_pixels(uv: np.ndarray) -> list[list[float] | None]:
    """[u, v] px per row of uv (M, 2), None where it has no pixel (NaN: behind the camera, nothing measured)."""
    return [[float(u), float(v)] if math.isfinite(u) and math.isfinite(v) else None for u, v in uv]
