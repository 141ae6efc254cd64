"""A simulated robot: hidden true parameters, realistic noise, datasets in the pinned CSV formats.

The truth comes from the profile's `simulation` section (the Robonaut paper's Table II, the means of
the NAO paper's Table 2). Joint readings are what the robot reports: the physical joint angle is
offset + reading, and the reading is rounded to the joint's encoder resolution (0.1 deg) before it is
written, so calibrations see the same rounding a real robot gives. Measurements carry sensor noise:
a stereo head triangulates from noisy pixels and a noisy disparity (depth noise grows with z^2);
a camera adds Gaussian pixel noise. Only configurations within joint limits whose targets the sensor
sees well enough for its detector are generated (`SimulatedRobot.visible`: inside the image and in
range; a board's face towards the camera, not too oblique; a sphere not hidden by the arm and clear of
the stereo matcher's band without depth).
"""

from __future__ import annotations

import fnmatch
import math
from dataclasses import dataclass, field

import numpy as np

from ..dataset import Dataset
from ..errors import InputError
from ..model.kinematics import forward, sensor_points, target_points
from ..model.profile import Profile
from ..sensors.measurement import optical_rotation, predict, project_to_image
from ..vision.sandal_board import MAX_OBLIQUITY_DEG, MIN_VERTEX_SPACING_PX, render_board_image
from ..vision.sighting import Sighting, sight_board, sight_fixture
from ..vision.stereo import StereoHead, depth_from_pair, no_depth_band_px, render_pair, sphere_views

# The share of the sphere's outline the arm and hand must leave free in each camera of a stereo head.
# On 240 rendered first-day frames the BallFinder found the sphere in 8 of 31 views with less than
# 70% free, 23 of 26 with 70-85% and 185 of 196 above (those missed: seeds over 20 cm off, or the
# sphere beyond 1 m).
MIN_SPHERE_SHARE = 0.85


@dataclass
class Simulation:
    """A generated dataset and the truth behind it."""

    data: Dataset
    true_params: np.ndarray
    true_joints: np.ndarray  # (N, n_joints) the unquantised readings (physical angle - offset)
    exact: np.ndarray  # (M, dim) the noise-free measurement
    outliers: np.ndarray  # (M,) bool: observations replaced by gross errors


@dataclass
class Capture:
    """One configuration looked at through the simulated cameras."""

    frame: int
    readings: np.ndarray  # (n_joints,) rad: what the robot reports (quantised)
    sighting: Sighting
    images: dict[str, np.ndarray]  # "left", "right" (stereo) or "image" (a camera)


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
    margin: float = 10.0  # px kept clear of the image border
    seed: int = 0
    point_noise: float = 0.0  # profile length unit per axis: a point sensor without a camera (a laser tracker)
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
        )

    # --- configurations ---------------------------------------------------------------------------
    def configurations(self, n: int | None = None) -> tuple[np.ndarray, np.ndarray]:
        """Joint readings (N, n_joints) and, per configuration, the target it shows (N,)."""
        sampling = self.profile.simulation.get("sampling", {"kind": "uniform"})
        if sampling.get("kind") == "stances":
            return self._stances(sampling, n)
        return self._uniform(n or 100)

    def _uniform(self, n: int) -> tuple[np.ndarray, np.ndarray]:
        lo, hi = self.profile.joint_limits()
        target = self.profile.data.target if self.profile.data.target is not None else 0
        found: list[np.ndarray] = []
        for _ in range(200):
            q = self.rng.uniform(lo, hi, (max(4 * n, 64), len(lo)))
            ok = self.visible(q, np.full(len(q), target))
            found += list(q[ok])
            if len(found) >= n:
                break
        if len(found) < n:
            raise InputError(f"found only {len(found)} visible configurations of the {n} asked: ask for fewer")
        return np.array(found[:n]), np.full(n, target)

    def _stances(self, sampling: dict, n: int | None) -> tuple[np.ndarray, np.ndarray]:
        prof = self.profile
        lo, hi = prof.joint_limits()
        postures = int(sampling.get("postures", 3))
        per_target = int(sampling.get("stances_per_target", 24))
        if n is not None:
            per_target = max(1, math.ceil(n / (postures * len(sampling["stance"]))))
        look = prof.joint(sampling["look_at"])
        post = prof.joint(sampling["posture_joint"])
        p_lo, p_hi = (math.radians(v) for v in sampling["posture_range"])
        batch = 32  # stances drawn and checked at once
        qs, targets = [], []
        for tname, ranges in sampling["stance"].items():
            ti = prof.target(tname)
            got = 0
            for _ in range(per_target * 200 // batch + 1):
                if got == per_target:
                    break
                q = np.zeros((batch, len(lo)))
                for jname, (a, b) in ranges.items():
                    j = prof.joint(jname)
                    q[:, j] = self.rng.uniform(max(math.radians(a), lo[j]), min(math.radians(b), hi[j]), batch)
                pitches = np.linspace(p_lo, p_hi, postures) + self.rng.uniform(-0.02, 0.02, (batch, postures))
                stances = np.repeat(q, postures, axis=0)  # stance b's postures are rows b * postures ...
                stances[:, post] = np.clip(pitches.ravel(), lo[post], hi[post])
                stances[:, look] = self._aim(stances, look, ti)
                stances[:, look] += self.rng.uniform(-0.05, 0.05, len(stances))
                stances[:, look] = np.clip(stances[:, look], lo[look], hi[look])
                seen = self.visible(stances, np.full(len(stances), ti)).reshape(batch, postures).all(axis=1)
                for b in np.flatnonzero(seen)[: per_target - got]:
                    qs += list(stances[b * postures : (b + 1) * postures])
                    targets += [ti] * postures
                    got += 1
            if got < per_target:
                raise InputError(
                    f"found only {got} visible stances for {tname} of the {per_target} needed: "
                    "ask for fewer configurations or another seed"
                )
        return np.array(qs), np.array(targets)

    def _aim(self, q: np.ndarray, joint: int, target: int) -> np.ndarray:
        """For each configuration (row of q), the angle of `joint` that puts the target's centre in the
        image's centre column."""
        prof, p = self.profile, self.true_params
        lo, hi = prof.joint_limits()
        candidates = np.linspace(max(lo[joint], -1.2), min(hi[joint], 1.2), 121)
        qs = np.repeat(q, len(candidates), axis=0)
        qs[:, joint] = np.tile(candidates, len(q))
        sensor = prof.sensors[prof.data.sensor]
        tf = prof.targets[target].frame
        if any(op.joint == joint for f in prof.chain(tf) for op in prof.frames[f].ops):
            x = self._sensor_points(qs, np.full(len(qs), target), p, center_only=True)
        else:  # only the sensor turns: the target's centre once per row, the sensor's chain per candidate
            centre = target_points(prof, p, target).mean(axis=0, keepdims=True)
            poses = forward(prof, p, q, frames=[tf])
            P = np.repeat(poses.R[tf] @ centre.T + poses.t[tf][:, :, None], len(candidates), axis=0)
            poses = forward(prof, p, qs, frames=[sensor.frame])
            Rs, ts = poses.R[sensor.frame], poses.t[sensor.frame]
            x = (Rs.transpose(0, 2, 1) @ (P - ts[:, :, None]))[:, :, 0]  # as kinematics.sensor_points
        uv = project_to_image(sensor, self.true_params, x)
        ahead = (x @ optical_rotation(sensor))[:, 2] > 0
        cost = np.where(ahead, np.abs(uv[:, 0] - sensor.image[0] / 2), np.inf) if sensor.image else np.zeros(len(x))
        return candidates[np.argmin(cost.reshape(len(q), len(candidates)), axis=1)]

    # --- what the sensor sees ---------------------------------------------------------------------
    def _sensor_points(
        self, q: np.ndarray, targets: np.ndarray, p: np.ndarray, center_only: bool = False
    ) -> np.ndarray:
        """Target points in the sensor frame: (N, 3) with center_only, else (N, K, 3)."""
        return sensor_points(self.profile, p, q, targets, center_only=center_only)

    def visible(self, q: np.ndarray, targets: np.ndarray) -> np.ndarray:
        """Whether the sensor sees each configuration's target well enough for its detector (N,) bool.

        Every point in front of the sensor, in its range and inside its image (margin px clear of the
        border). A board shows its face, seen at most MAX_OBLIQUITY_DEG from its normal with neighbouring
        vertices at least MIN_VERTEX_SPACING_PX apart. A stereo head's sphere lies whole inside both
        images, right of the matcher's band without depth, and the arm and hand leave at least
        MIN_SPHERE_SHARE of its outline free in each camera (`_sees_sphere`)."""
        prof = self.profile
        sensor = prof.sensors[prof.data.sensor]
        x = self._sensor_points(q, targets, self.true_params)
        N, K, _ = x.shape
        flat = x.reshape(-1, 3)
        X = flat @ optical_rotation(sensor)
        ok = X[:, 2] > 1e-6
        if sensor.range is not None:
            ok &= (X[:, 2] >= sensor.range[0]) & (X[:, 2] <= sensor.range[1])
        if sensor.image is not None and (sensor.model == "pinhole" or sensor.intrinsics is not None):
            uv = project_to_image(
                sensor,
                self.true_params,
                np.where(ok[:, None], flat, [0.0, 0.0, 1.0] @ optical_rotation(sensor).T),
            )
            w, h = sensor.image
            m = self.margin
            ok &= (uv[:, 0] >= m) & (uv[:, 0] <= w - 1 - m) & (uv[:, 1] >= m) & (uv[:, 1] <= h - 1 - m)
        ok = ok.reshape(N, K)
        for t in set(targets.tolist()):
            grid = prof.targets[t].grid
            rows = np.flatnonzero(targets == t)
            if grid is None:
                ok[rows, 1:] = True
            else:
                ok[rows, len(grid) :] = True
                # The board's face (its -z side, under the sole) must look at the camera.
                c = x[rows, : len(grid)].mean(axis=1)
                normal = x[rows, 1] - x[rows, 0]
                across = x[rows, prof.targets[t].grid_shape[1]] - x[rows, 0]
                # +x cross -y: the board's -z axis, the normal of its face; it must point back to
                # the camera, which sits at the origin of these coordinates.
                face = np.cross(normal, across)
                towards = -np.einsum("ni,ni->n", face, c)
                ok[rows] &= (towards > 0)[:, None]
                # Not too oblique: the angle between the face's normal and the ray to the board's centre.
                cos = towards / np.maximum(np.linalg.norm(face, axis=1) * np.linalg.norm(c, axis=1), 1e-300)
                ok[rows] &= (cos >= math.cos(math.radians(MAX_OBLIQUITY_DEG)))[:, None]
                if sensor.image is not None and sensor.model == "pinhole":
                    n_rows, n_cols = prof.targets[t].grid_shape
                    g = uv.reshape(N, K, 2)[rows, : len(grid)].reshape(len(rows), n_rows, n_cols, 2)
                    spacing = np.minimum(
                        np.linalg.norm(np.diff(g, axis=1), axis=3).min(axis=(1, 2)),
                        np.linalg.norm(np.diff(g, axis=2), axis=3).min(axis=(1, 2)),
                    )
                    ok[rows] &= (spacing >= MIN_VERTEX_SPACING_PX)[:, None]
        seen = ok.all(axis=1)
        if sensor.model == "point3d" and sensor.baseline is not None and sensor.intrinsics is not None:
            rows = np.flatnonzero(seen)
            seen[rows] = self._sees_sphere(q[rows])
        return seen

    def _sees_sphere(self, q: np.ndarray) -> np.ndarray:
        """Whether the rendered stereo pair shows the sphere well enough to the BallFinder (N,) bool."""
        sensor = self.profile.sensors[self.profile.data.sensor]
        head = StereoHead.from_profile(self.profile, self.true_params, sensor.name)
        view = sphere_views(self.profile, self.true_params, q, head)
        u_min, u_max, v_min, v_max = view.box_px.T
        m = self.margin
        with np.errstate(invalid="ignore"):  # NaN boxes: the sphere reaches behind the camera
            inside = (
                (u_min >= no_depth_band_px(head) + m)
                & (u_max <= head.width_px - 1 - m)
                & (v_min >= m)
                & (v_max <= head.height_px - 1 - m)
            )
        return inside & (view.visible.min(axis=1) >= MIN_SPHERE_SHARE)

    # --- measuring --------------------------------------------------------------------------------
    def measure(
        self,
        q: np.ndarray,
        targets: np.ndarray,
        *,
        outlier_rate: float = 0.0,
        outlier_size: float = 0.0,
    ) -> Simulation:
        """Observe configurations q (the robot's unquantised readings) as the sensor would."""
        prof = self.profile
        sensor = prof.sensors[prof.data.sensor]
        x = self._sensor_points(q, targets, self.true_params)
        cfg, tgt, point, vertex, exact, noisy = [], [], [], [], [], []
        for n in range(len(q)):
            t = int(targets[n])
            grid = prof.targets[t].grid
            K = 1 if grid is None else len(grid)
            xs = x[n, :K]
            h = predict(sensor, self.true_params, xs)[0]
            exact.append(h)
            noisy.append(self._noisy(sensor, xs, h))
            cfg += [n] * K
            tgt += [t] * K
            point.append(np.full((K, 3), np.nan) if grid is None else grid)
            vertex += [-1] * K if grid is None else list(range(K))
        exact_a = np.concatenate(exact)
        noisy_a = np.concatenate(noisy)
        outliers = self.rng.random(len(noisy_a)) < outlier_rate
        if outliers.any():
            d = self.rng.normal(size=(outliers.sum(), noisy_a.shape[1]))
            noisy_a[outliers] += outlier_size * d / np.linalg.norm(d, axis=1, keepdims=True)
        readings = self.readings(q)
        data = Dataset(
            robot=prof.name,
            frame_ids=np.arange(1, len(q) + 1),
            joints=readings,
            cfg=np.array(cfg),
            target=np.array(tgt),
            point=np.concatenate(point),
            vertex=np.array(vertex),
            measured=noisy_a,
            source="simulator",
        )
        return Simulation(data, self.true_params.copy(), q.copy(), exact_a, outliers)

    def _noisy(self, sensor, xs: np.ndarray, h: np.ndarray) -> np.ndarray:
        if sensor.model == "pinhole":
            return h + self.rng.normal(0.0, self.pixel_noise, h.shape)
        if sensor.intrinsics is None or sensor.baseline is None:
            return h + self.rng.normal(0.0, self.point_noise, h.shape)
        # Triangulate from the left pixel and the disparity, each with its own noise.
        fx, fy, cx, cy = (self.true_params[i] for i in sensor.intrinsics)
        X = xs @ sensor.R_frame_optical
        u = fx * X[:, 0] / X[:, 2] + cx + self.rng.normal(0.0, self.pixel_noise, len(X))
        v = fy * X[:, 1] / X[:, 2] + cy + self.rng.normal(0.0, self.pixel_noise, len(X))
        disparity = fx * sensor.baseline / X[:, 2] + self.rng.normal(0.0, self.disparity_noise, len(X))
        z = fx * sensor.baseline / disparity
        X_noisy = np.stack([(u - cx) * z / fx, (v - cy) * z / fy, z], axis=1)
        return X_noisy @ sensor.R_frame_optical.T

    # --- seeing: rendered images and the detectors ------------------------------------------------
    def readings(self, q: np.ndarray) -> np.ndarray:
        """What the encoders report for true readings q: rounded to each joint's resolution."""
        step = np.array([j.resolution for j in self.profile.joints])
        if not self.quantise:
            return q.copy()
        return np.where(step > 0, np.round(q / np.where(step > 0, step, 1.0)) * step, q)

    def capture(self, frame: int, q: np.ndarray, target: int, believed: np.ndarray) -> Capture:
        """Render what the sensor sees in configuration q (one row, rad) and run its detector,
        seeded by the calibration the robot believes in (`believed`, internal units)."""
        prof = self.profile
        sensor = prof.sensors[prof.data.sensor]
        readings = self.readings(q)
        if sensor.model == "point3d" and sensor.baseline is not None:
            head = StereoHead.from_profile(prof, self.true_params, sensor.name)
            pair = render_pair(prof, self.true_params, q, head, self.rng)
            depth = depth_from_pair(pair.left, pair.right, head)
            sighting = sight_fixture(prof, believed, readings, depth, head)
            return Capture(frame, readings, sighting, {"left": pair.left, "right": pair.right})
        if sensor.model == "pinhole":
            board = render_board_image(prof, self.true_params, q, target, self.rng)
            sighting = sight_board(prof, believed, readings, target, board.image)
            return Capture(frame, readings, sighting, {"image": board.image})
        raise ValueError(f"no renderer for a '{sensor.model}' sensor without a stereo baseline")

    def simulate_images(self, n: int | None = None, believed: np.ndarray | None = None) -> ImageSimulation:
        """Random visible configurations, seen through rendered images and the detectors.
        `believed`: the calibration that seeds the detectors (default: the nominal model)."""
        prof = self.profile
        believed = prof.nominal() if believed is None else believed
        q, targets = self.configurations(n)
        captures = [self.capture(k + 1, q[k], int(targets[k]), believed) for k in range(len(q))]
        return ImageSimulation(
            dataset_from_captures(prof, captures),
            captures,
            self.true_params.copy(),
            q,
            targets,
            prof.simulation.get("detected_noise"),
        )

    def simulate(self, n: int | None = None, **kwargs) -> Simulation:
        """Random visible configurations, observed."""
        q, targets = self.configurations(n)
        return self.measure(q, targets, **kwargs)


def dataset_from_captures(profile: Profile, captures: list[Capture]) -> Dataset:
    """The dataset of the measured captures (frames whose detector found nothing are left out)."""
    got = [c for c in captures if c.sighting.measured is not None]
    if not got:
        raise ValueError("no capture was measured")
    counts = [len(c.sighting.measured) for c in got]  # type: ignore[arg-type]
    return Dataset(
        robot=profile.name,
        frame_ids=np.array([c.frame for c in got]),
        joints=np.array([c.readings for c in got]),
        cfg=np.repeat(np.arange(len(got)), counts),
        target=np.repeat([c.sighting.target for c in got], counts),
        point=np.concatenate([c.sighting.points for c in got]),
        vertex=np.concatenate([c.sighting.vertices for c in got]),
        measured=np.concatenate([c.sighting.measured for c in got]),  # type: ignore[misc]
        source="simulator (images)",
    )
