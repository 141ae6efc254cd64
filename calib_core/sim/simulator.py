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
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from ..dataset import Dataset
from ..errors import InputError
from ..estimation.solver import Cancelled
from ..model.kinematics import forward, sensor_points, target_points, to_sensor
from ..model.profile import Profile
from ..sensors import Sensor
from ..vision.sandal_board import MAX_OBLIQUITY_DEG, MIN_VERTEX_SPACING_PX, render_board_image
from ..vision.sighting import Sighting, sight_board, sight_fixture
from ..vision.stereo import StereoHead, depth_from_pair, no_depth_band_px, render_pair, sphere_views
from .contact import contacts

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
    sphere_share: float = MIN_SPHERE_SHARE  # of the sphere's outline each stereo camera must see (`visible`)
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
    def configurations(
        self, n: int | None = None, *, should_stop: Callable[[], bool] | None = None
    ) -> tuple[np.ndarray, np.ndarray]:
        """Joint readings (N, n_joints) and, per configuration, the target it shows (N,). `should_stop`: asked
        before each batch drawn (thousands of NAO's take a minute); Cancelled once it says yes."""
        stop = should_stop or (lambda: False)
        sampling = self.profile.simulation.get("sampling", {"kind": "uniform"})
        if sampling.get("kind") == "stances":
            return self._stances(sampling, n, stop)
        return self._uniform(n or 100, stop)

    def clustered(self, n: int, spread: float, wide_share: float) -> tuple[np.ndarray, np.ndarray]:
        """Configurations as a session on a real robot often takes them: most within `spread` (rad) of
        one visible configuration on every joint (a small workspace, a cube of poses), a share
        `wide_share` of them anywhere visible. The joints' readings (N, n_joints) and the targets (N,)."""
        q_wide, targets = self._uniform(n)
        lo, hi = self.profile.joint_limits()
        narrow = np.clip(q_wide[0] + self.rng.uniform(-spread, spread, q_wide.shape), lo, hi)
        wide = self.rng.random(n) < wide_share
        return np.where(wide[:, None], q_wide, narrow), targets

    def _uniform(self, n: int, stop: Callable[[], bool] = lambda: False) -> tuple[np.ndarray, np.ndarray]:
        lo, hi = self.profile.joint_limits()
        target = self.profile.data.target if self.profile.data.target is not None else 0
        found: list[np.ndarray] = []
        for _ in range(200):
            if stop():
                raise Cancelled("the draw was cancelled")
            q = self.rng.uniform(lo, hi, (max(4 * n, 64), len(lo)))
            ok = self.visible(q, np.full(len(q), target))
            found += list(q[ok])
            if len(found) >= n:
                break
        if len(found) < n:
            raise InputError(f"found only {len(found)} visible configurations of the {n} asked: ask for fewer")
        return np.array(found[:n]), np.full(n, target)

    def _stances(
        self, sampling: dict, n: int | None, stop: Callable[[], bool] = lambda: False
    ) -> tuple[np.ndarray, np.ndarray]:
        prof = self.profile
        postures = int(sampling.get("postures", 3))
        per_target = int(sampling.get("stances_per_target", 24))
        if n is not None:
            per_target = max(1, math.ceil(n / (postures * len(sampling["stance"]))))
        batch = 32  # stances drawn and checked at once
        qs, targets = [], []
        for tname, ranges in sampling["stance"].items():
            ti = prof.target(tname)
            got = 0
            for _ in range(per_target * 200 // batch + 1):
                if got == per_target:
                    break
                if stop():
                    raise Cancelled("the draw was cancelled")
                stances, seen = self._stance_batch(sampling, ranges, ti, batch, postures)
                whole = seen.reshape(batch, postures).all(axis=1)
                for b in np.flatnonzero(whole)[: per_target - got]:
                    qs += list(stances[b * postures : (b + 1) * postures])
                    targets += [ti] * postures
                    got += 1
            if got < per_target:
                raise InputError(
                    f"found only {got} visible stances for {tname} of the {per_target} needed: "
                    "ask for fewer configurations or another seed"
                )
        return np.array(qs), np.array(targets)

    def stance_frames(self, batches: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Frames of the profile's stance structure, each on its own (a planner picks among them): per
        target, `batches` x 32 stances in the stance ranges, each in the head postures, aimed at the board.
        The visible ones: readings (N, n_joints), targets (N,) and each frame's stance id (N,)."""
        sampling = self.profile.simulation["sampling"]
        postures = int(sampling.get("postures", 3))
        batch = 32
        qs, targets, ids = [], [], []
        for tname, ranges in sampling["stance"].items():
            ti = self.profile.target(tname)
            for _ in range(batches):
                stances, seen = self._stance_batch(sampling, ranges, ti, batch, postures)
                qs.append(stances[seen])
                targets.append(np.full(int(seen.sum()), ti))
                ids.append(len(ids) * batch + np.flatnonzero(seen) // postures)
        return np.concatenate(qs), np.concatenate(targets), np.concatenate(ids)

    def _stance_batch(
        self, sampling: dict, ranges: dict, target: int, batch: int, postures: int
    ) -> tuple[np.ndarray, np.ndarray]:
        """`batch` stances in `ranges`, each in `postures` head postures aimed at the target: the
        configurations (batch * postures, n_joints), stance b's postures in rows b * postures ..., and
        whether each is visible."""
        prof = self.profile
        lo, hi = prof.joint_limits()
        look = prof.joint(sampling["look_at"])
        post = prof.joint(sampling["posture_joint"])
        p_lo, p_hi = (math.radians(v) for v in sampling["posture_range"])
        q = np.zeros((batch, len(lo)))
        for jname, (a, b) in ranges.items():
            j = prof.joint(jname)
            q[:, j] = self.rng.uniform(max(math.radians(a), lo[j]), min(math.radians(b), hi[j]), batch)
        pitches = np.linspace(p_lo, p_hi, postures) + self.rng.uniform(-0.02, 0.02, (batch, postures))
        stances = np.repeat(q, postures, axis=0)
        stances[:, post] = np.clip(pitches.ravel(), lo[post], hi[post])
        stances[:, look] = self._aim(stances, look, target)
        stances[:, look] += self.rng.uniform(-0.05, 0.05, len(stances))
        stances[:, look] = np.clip(stances[:, look], lo[look], hi[look])
        return stances, self.visible(stances, np.full(len(stances), target))

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
            x = sensor_points(prof, p, qs, np.full(len(qs), target), center_only=True)
        else:  # only the sensor turns: the target's centre once per row, the sensor's chain per candidate
            centre = target_points(prof, p, target).mean(axis=0, keepdims=True)
            at_target = forward(prof, p, q, frames=[tf])
            poses = forward(prof, p, qs, frames=[sensor.frame])
            poses.R[tf] = np.repeat(at_target.R[tf], len(candidates), axis=0)  # the target's pose per candidate
            poses.t[tf] = np.repeat(at_target.t[tf], len(candidates), axis=0)
            x = to_sensor(poses, tf, sensor.frame, np.arange(len(qs)), np.repeat(centre, len(qs), axis=0))[1]
        uv = sensor.project(p, x)
        if uv is None or sensor.image is None:
            return np.zeros(len(q))
        cost = np.where(np.isfinite(uv[:, 0]), np.abs(uv[:, 0] - sensor.image[0] / 2), np.inf)
        return candidates[np.argmin(cost.reshape(len(q), len(candidates)), axis=1)]

    # --- what the sensor sees ---------------------------------------------------------------------
    def visible(
        self, q: np.ndarray, targets: np.ndarray, sensor: int | None = None, *, occlusion: bool = True
    ) -> np.ndarray:
        """Whether a sensor (default: the data format's) sees each configuration's target well enough
        for its detector (N,) bool.

        Every point where the sensor sees (in front, in its range and inside its image, margin px
        clear of the border). A board shows its face, seen at most MAX_OBLIQUITY_DEG from its normal
        with neighbouring vertices at least MIN_VERTEX_SPACING_PX apart. A stereo head's sphere lies
        whole inside both images, right of the matcher's band without depth, and the arm and hand
        leave at least `sphere_share` of its outline free in each camera (`_sees_sphere`; `occlusion=False`
        leaves this, the costly part, out: a planner checks it only for the configurations it picks)."""
        prof = self.profile
        s = prof.data.sensor if sensor is None else sensor
        sens = prof.sensors[s]
        x = sensor_points(prof, self.true_params, q, targets, sensor=s)
        N, K, _ = x.shape
        ok = sens.visible(self.true_params, x.reshape(-1, 3), self.margin).reshape(N, K)
        for t in set(targets.tolist()):
            rows = np.flatnonzero(targets == t)
            n = len(target_points(prof, self.true_params, t))
            ok[rows, n:] = True
            if prof.targets[t].grid is not None:
                ok[rows, :n] &= self._board_ok(sens, x[rows, :n], prof.targets[t].grid_shape)[:, None]
        seen = ok.all(axis=1)
        if sens.reading == "stereo" and occlusion:
            rows = np.flatnonzero(seen)
            seen[rows] = self._sees_sphere(q[rows])
        return seen

    def _board_ok(self, sensor: Sensor, x: np.ndarray, shape: tuple[int, int] | None) -> np.ndarray:
        """Whether a board (vertices x (N, K, 3) in the sensor frame) shows its face, not too
        obliquely, with its vertices far enough apart in the image to be told apart."""
        assert shape is not None  # a grid target has its shape
        n_rows, n_cols = shape
        c = x.mean(axis=1)
        # +x cross -y: the board's -z axis, the normal of its face (under the sole); it must point
        # back to the camera, which sits at the origin of these coordinates.
        face = np.cross(x[:, 1] - x[:, 0], x[:, n_cols] - x[:, 0])
        towards = -np.einsum("ni,ni->n", face, c)
        cos = towards / np.maximum(np.linalg.norm(face, axis=1) * np.linalg.norm(c, axis=1), 1e-300)
        ok = (towards > 0) & (cos >= math.cos(math.radians(MAX_OBLIQUITY_DEG)))
        uv = sensor.project(self.true_params, x.reshape(-1, 3))
        if uv is not None and sensor.reading == "image":
            g = uv.reshape(len(x), n_rows, n_cols, 2)
            spacing = np.minimum(
                np.linalg.norm(np.diff(g, axis=1), axis=3).min(axis=(1, 2)),
                np.linalg.norm(np.diff(g, axis=2), axis=3).min(axis=(1, 2)),
            )
            ok &= spacing >= MIN_VERTEX_SPACING_PX
        return ok

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
        return inside & (view.visible.min(axis=1) >= self.sphere_share)

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
        """What the encoders report for true readings q: rounded to each joint's resolution."""
        step = np.array([j.resolution for j in self.profile.joints])
        if not self.quantise:
            return q.copy()
        return np.where(step > 0, np.round(q / np.where(step > 0, step, 1.0)) * step, q)

    def render(self, q: np.ndarray, target: int) -> tuple[dict[str, np.ndarray], StereoHead | None]:
        """What the data sensor sees in configuration q (one row, true joint angles, rad): a stereo head's
        "left" and "right" images with the head that took them, or a camera's "image" of the board `target`."""
        prof = self.profile
        sensor = prof.sensors[prof.data.sensor]
        if sensor.reading == "stereo":
            head = StereoHead.from_profile(prof, self.true_params, sensor.name)
            pair = render_pair(prof, self.true_params, q, head, self.rng)
            return {"left": pair.left, "right": pair.right}, head
        if sensor.reading == "image":
            return {"image": render_board_image(prof, self.true_params, q, target, self.rng).image}, None
        raise ValueError(f"sensor '{sensor.name}' reads its measurements directly: there is no image to render")

    def capture(self, frame: int, q: np.ndarray, target: int, believed: np.ndarray) -> Capture:
        """Render what the sensor sees in configuration q (one row, rad) and run its detector,
        seeded by the calibration the robot believes in (`believed`, internal units)."""
        readings = self.readings(q)
        images, head = self.render(q, target)
        if head is not None:
            depth = depth_from_pair(images["left"], images["right"], head)
            return Capture(frame, readings, sight_fixture(self.profile, believed, readings, depth, head), images)
        return Capture(frame, readings, sight_board(self.profile, believed, readings, target, images["image"]), images)

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
        """Random visible configurations, observed (for plane constraints: configurations in
        contact with each plane, `n` per plane)."""
        if self.profile.simulation.get("sampling", {}).get("kind") == "contact":
            q, targets, sensors = contacts(self.profile, self.true_params, self.rng, n or 30)
            return self.measure(q, targets, sensors=sensors, **kwargs)
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
        sensor=np.full(sum(counts), profile.data.sensor),
        source="simulator (images)",
    )
