"""A simulated robot: hidden true parameters, realistic noise, datasets in the pinned CSV formats.

The truth comes from the profile's `simulation` section (the Robonaut paper's Table II, the means of
the NAO paper's Table 2). Joint readings are what the robot reports: the physical joint angle is
offset + reading, and the reading is rounded to the joint's encoder resolution (0.1 deg) before it is
written, so calibrations see the same rounding a real robot gives. Measurements carry sensor noise:
a stereo head triangulates from noisy pixels and a noisy disparity (depth noise grows with z^2);
a camera adds Gaussian pixel noise. Only configurations within joint limits whose targets the sensor
sees well enough for its detector are generated: what the true robot shows, by the one test of "in view"
(`calib_core.vision.visibility`), drawn as the profile's sampling says (`calib_core.vision.sampling`).
The simulator keeps the truth, the noise and the rendering.
"""

from __future__ import annotations

import fnmatch
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from ..dataset import Dataset
from ..frame_status import FrameStatus
from ..model.kinematics import sensor_points, target_points
from ..model.profile import Profile
from ..vision.finders import Finder, finder_for
from ..vision.sampling import Sampler
from ..vision.sighting import Capture, Sighting, dataset_from_captures
from ..vision.stereo import StereoHead
from ..vision.visibility import MIN_SPHERE_SHARE, VIEW_MARGIN_PX, Visibility
from .contact import contacts


@dataclass
class Simulation:
    """A generated dataset and the truth behind it."""

    data: Dataset
    true_params: np.ndarray
    true_joints: np.ndarray  # (N, n_joints) the unquantised readings (physical angle - offset)
    exact: np.ndarray  # (M, dim) the noise-free measurement
    outliers: np.ndarray  # (M,) bool: observations replaced by gross errors


@dataclass
class ImageSimulation:
    """A session measured from rendered images: the dataset of what the detectors found."""

    data: Dataset  # the measured frames only
    captures: list[Capture]  # every frame, found or not
    true_params: np.ndarray
    true_joints: np.ndarray  # (N, n_joints) unquantised readings of every frame
    targets: np.ndarray  # (N,) the target each frame shows
    noise: dict | None = None  # the detectors' noise model (profile `simulation.detected_noise`), for weighing

    def profile_for_data(self, profile: Profile) -> Profile:
        """The profile that weighs these detections by the detectors' own noise (if the profile states it)."""
        return profile if self.noise is None else profile.with_noise(self.noise)


@dataclass
class SimulatedRobot:
    profile: Profile
    true_params: np.ndarray
    pixel_noise: float = 0.0  # px
    disparity_noise: float = 0.0  # px (stereo sensors)
    quantise: bool = True  # round readings to each joint's encoder resolution (profile)
    margin: float = VIEW_MARGIN_PX  # px kept clear of the image border by what it shows
    seed: int = 0
    point_noise: float = 0.0  # profile length unit per axis: a point sensor without a camera (a laser tracker)
    sphere_share: float = MIN_SPHERE_SHARE  # of the sphere's outline each stereo camera must see (Visibility)
    rng: np.random.Generator = field(init=False)

    def __post_init__(self) -> None:
        self.rng = np.random.default_rng(self.seed)

    @classmethod
    def from_profile(cls, profile: Profile, seed: int = 0, truth: np.ndarray | None = None) -> SimulatedRobot:
        sim = profile.simulation
        noise = sim.get("noise", {})
        return cls(
            profile,
            profile.true_params() if truth is None else truth,
            pixel_noise=float(noise.get("pixel", 0.0)),
            disparity_noise=float(noise.get("disparity", 0.0)),
            seed=seed,
            point_noise=float(noise.get("point", 0.0)),
        )

    def drifted(self, seed: int) -> SimulatedRobot:
        """The same robot on a later day: joint offsets drifted (profile `simulation.offset_drift`)."""
        rng = np.random.default_rng(seed)
        drift = self.profile.simulation.get("offset_drift", {})
        offsets = sorted({op.param for f in self.profile.frames for op in f.ops if op.joint >= 0})
        names = self.profile.parameter_names
        offsets = [i for i in offsets if fnmatch.fnmatchcase(names[i], drift.get("pattern", "*"))]
        p = self.true_params.copy()
        p[offsets] += np.radians(rng.normal(0.0, float(drift.get("sigma", 2.0)), len(offsets)))
        return SimulatedRobot(
            self.profile,
            p,
            self.pixel_noise,
            self.disparity_noise,
            self.quantise,
            self.margin,
            seed,
            self.point_noise,
            self.sphere_share,
        )

    def on_day(self, day: int) -> SimulatedRobot:
        """The same robot on day `day` (1: as it is): drifted once for each later day, seeded by this robot's
        seed and the day (`calib simulate --day`, the desk's simulated robots and `calib sim-ros2` alike)."""
        robot = self
        for d in range(2, day + 1):
            robot = robot.drifted(seed=1000 * self.seed + d)
        return robot

    # --- configurations ---------------------------------------------------------------------------
    def _view(self) -> Visibility:
        """What the true robot shows its sensors (margin px clear of the border)."""
        return Visibility(self.profile, self.true_params, self.margin, self.sphere_share)

    def _sampler(self) -> Sampler:
        """Draws configurations the true robot shows, from this robot's stream."""
        return Sampler(self._view(), self.rng)

    def configurations(
        self, n: int | None = None, *, should_stop: Callable[[], bool] | None = None
    ) -> tuple[np.ndarray, np.ndarray]:
        """Joint readings (N, n_joints) the true robot shows its target in and, per configuration, the target
        (N,), as the profile's sampling says (`Sampler.configurations`)."""
        return self._sampler().configurations(n, should_stop=should_stop)

    def clustered(self, n: int, spread: float, wide_share: float) -> tuple[np.ndarray, np.ndarray]:
        """Configurations as a session on a real robot often takes them: most within `spread` (rad) of
        one visible configuration on every joint (a small workspace, a cube of poses), a share
        `wide_share` of them anywhere visible. The joints' readings (N, n_joints) and the targets (N,)."""
        q_wide, targets = self._sampler().uniform(n)
        lo, hi = self.profile.joint_limits()
        narrow = np.clip(q_wide[0] + self.rng.uniform(-spread, spread, q_wide.shape), lo, hi)
        wide = self.rng.random(n) < wide_share
        return np.where(wide[:, None], q_wide, narrow), targets

    # --- measuring --------------------------------------------------------------------------------
    def measure(
        self,
        q: np.ndarray,
        targets: np.ndarray,
        *,
        sensors: np.ndarray | None = None,
        outlier_rate: float = 0.0,
        outlier_size: float = 0.0,
    ) -> Simulation:
        """Observe configurations q (the robot's unquantised readings) as the sensors would:
        configuration n by sensor sensors[n] (default: every one by the data format's sensor)."""
        prof, p = self.profile, self.true_params
        sensors = np.full(len(q), prof.data.sensor) if sensors is None else np.asarray(sensors, int)
        noise = {"pixel": self.pixel_noise, "disparity": self.disparity_noise, "point": self.point_noise}
        width = max(prof.sensors[s].dim for s in set(sensors.tolist()))
        x: list[np.ndarray] = [np.zeros((0, 3))] * len(q)
        for s in set(sensors.tolist()):
            rows = np.flatnonzero(sensors == s)
            for n, xs in zip(rows, sensor_points(prof, p, q[rows], targets[rows], sensor=s), strict=True):
                x[n] = xs
        obs: dict[str, list] = {k: [] for k in ("cfg", "target", "sensor", "point", "vertex", "exact", "noisy")}
        for n in range(len(q)):
            t, sensor = int(targets[n]), prof.sensors[sensors[n]]
            grid = prof.targets[t].grid
            K = 1 if grid is None else len(grid)
            pad = np.full((K, width - sensor.dim), np.nan)
            obs["exact"].append(np.hstack([sensor.predict(p, x[n][:K])[0], pad]))
            obs["noisy"].append(np.hstack([sensor.simulate(p, x[n][:K], self.rng, noise), pad]))
            obs["cfg"] += [n] * K
            obs["target"] += [t] * K
            obs["sensor"] += [int(sensors[n])] * K
            obs["point"].append(np.full((K, 3), np.nan) if grid is None else grid)
            obs["vertex"] += [-1] * K if grid is None else list(range(K))
        exact, noisy = np.concatenate(obs["exact"]), np.concatenate(obs["noisy"])
        outliers = self.rng.random(len(noisy)) < outlier_rate
        if outliers.any():
            d = self.rng.normal(size=(outliers.sum(), noisy.shape[1]))
            noisy[outliers] += outlier_size * d / np.linalg.norm(d, axis=1, keepdims=True)
        data = Dataset(
            robot=prof.name,
            frame_ids=np.arange(1, len(q) + 1),
            joints=self.readings(q),
            cfg=np.array(obs["cfg"]),
            target=np.array(obs["target"]),
            point=np.concatenate(obs["point"]),
            vertex=np.array(obs["vertex"]),
            measured=noisy,
            sensor=np.array(obs["sensor"]),
            source="simulator",
        )
        return Simulation(data, p.copy(), q.copy(), exact, outliers)

    # --- seeing: rendered images and the detectors ------------------------------------------------
    def readings(self, q: np.ndarray) -> np.ndarray:
        """What the encoders report for true readings q: with each joint's own noise where it declares one (a
        controller's reported pose), rounded to its resolution."""
        noise = np.array([j.noise for j in self.profile.joints])
        if noise.any():
            q = q + self.rng.normal(size=q.shape) * noise
        step = np.array([j.resolution for j in self.profile.joints])
        if not self.quantise:
            return q.copy()
        return np.where(step > 0, np.round(q / np.where(step > 0, step, 1.0)) * step, q)

    def finder(self, target: int) -> Finder:
        """The data sensor's finder for `target` (ValueError: the sensor reads it directly, nothing to render)."""
        prof = self.profile
        finder = finder_for(prof, prof.data.sensor, target)
        if finder is None:
            sensor = prof.sensors[prof.data.sensor]
            raise ValueError(
                f"sensor '{sensor.name}' has no finder for target '{prof.targets[target].name}': "
                "there is no image to render"
            )
        return finder

    def render(self, q: np.ndarray, target: int) -> tuple[dict[str, np.ndarray], StereoHead | None]:
        """What the data sensor sees of `target` in configuration q (one row, true joint angles, rad), drawn by
        its finder: a stereo head's "left" and "right" images with the head that took them, or a camera's "image"."""
        rendered = self.finder(target).render(self.true_params, q, self.rng)
        return rendered.images, rendered.head

    def read(self, q: np.ndarray, target: int, sensor: int) -> Sighting:
        """What a sensor reads of a target directly, without images, at true joint angles q (one row, rad): the
        points of the target it sees (Visibility), each with its noise (`Sensor.simulate`: a tracker's
        `noise.point`, a camera's `noise.pixel`); "not found" when it sees none of them."""
        prof, p = self.profile, self.true_params
        t = prof.targets[target]
        local = target_points(prof, p, target)
        K = len(local)
        if t.point_params is not None:  # a calibrated point: no fixed coordinates, no vertex
            points, vertices = np.full((1, 3), np.nan), np.array([-1])
        else:
            points, vertices = local, (np.array([-1]) if K == 1 else np.arange(K))
        seen = self._view().points(q[None], np.array([target]), sensor)[0, :K]
        detail = {"sensor": "read directly"}
        if not seen.any():
            reason = f"{t.name} is not in view of {prof.sensors[sensor].name}"
            return Sighting(sensor, target, FrameStatus.NOT_FOUND, reason, None, points, vertices, detail)
        x = sensor_points(prof, p, q[None], np.array([target]), sensor=sensor)[0, :K]
        noise = {"pixel": self.pixel_noise, "disparity": self.disparity_noise, "point": self.point_noise}
        measured = prof.sensors[sensor].simulate(p, x[seen], self.rng, noise)
        return Sighting(sensor, target, FrameStatus.MEASURED, "ok", measured, points[seen], vertices[seen], detail)

    def capture(self, frame: int, q: np.ndarray, target: int, believed: np.ndarray) -> Capture:
        """Render what the sensor sees in configuration q (one row, rad) and run its finder,
        seeded by the calibration the robot believes in (`believed`, internal units)."""
        readings = self.readings(q)
        images, head = self.render(q, target)
        return Capture(frame, readings, self.finder(target).find(believed, readings, images, head), images)

    def simulate_images(self, n: int | None = None, believed: np.ndarray | None = None) -> ImageSimulation:
        """Random visible configurations, seen through rendered images and the detectors.
        `believed`: the calibration that seeds the detectors (default: the nominal model)."""
        prof = self.profile
        believed = prof.nominal() if believed is None else believed
        q, targets = self.configurations(n)
        captures = [self.capture(k + 1, q[k], int(targets[k]), believed) for k in range(len(q))]
        return ImageSimulation(
            dataset_from_captures(prof, captures, "simulator (images)"),
            captures,
            self.true_params.copy(),
            q,
            targets,
            prof.simulation.get("detected_noise"),
        )

    def simulate(self, n: int | None = None, **kwargs) -> Simulation:
        """Random visible configurations, observed (for plane constraints: configurations in
        contact with each plane, `n` per plane)."""
        if self.profile.simulation.get("sampling", {}).get("kind") == "contact":
            q, targets, sensors = contacts(self.profile, self.true_params, self.rng, n or 30)
            return self.measure(q, targets, sensors=sensors, **kwargs)
        q, targets = self.configurations(n)
        return self.measure(q, targets, **kwargs)
