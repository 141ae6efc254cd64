"""The Robonaut head as a real stereo pair: render what its two cameras see, and measure depth from the images.

The measurement path of a real head starts from pixels, not from the fixture centre the simulator knows. So
this module ray casts the scene the eye sees (the textured calibration sphere held in the hand, the arm, a
table, the floor and a wall) into a rectified 640 x 480 pair with shading, noise and a small photometric
difference between the cameras, and computes depth from the pair with OpenCV's semi-global block matching,
with the holes and noisy edges that brings. Everything inside is in metres (`_m`) and pixels (`_px`); the
profile's length unit is converted at the edge.

Geometry: the left camera's optical centre is the eye frame's origin and its axes are the sensor's OpenCV
optical frame (x right, y down, z forward); the right camera is the left one moved by +baseline along the
left optical x axis, so a point at depth z has disparity u_left - u_right = fx * baseline / z. Rays are cast
in the left optical frame with directions ((u - cx) / fx, (v - cy) / fy, 1), so the ray parameter of a hit is
its depth along the optical axis.
"""

from __future__ import annotations

import itertools
import math
from dataclasses import dataclass
from functools import cache

import cv2
import numpy as np

from ..errors import InputError
from ..model.kinematics import forward
from ..model.profile import Profile
from ..sensors import Point3D
from ..units import length_factor

# object_id values: what each pixel shows.
NONE, SPHERE, HAND, ARM, TABLE, FLOOR, WALL = range(7)
OBJECT_NAMES = ("none", "sphere", "hand", "arm", "table", "floor", "wall")

_ARM_FRAMES = ("shoulder_roll", "shoulder_pitch", "elbow_roll", "elbow_pitch", "wrist_roll", "wrist_pitch", "wrist_yaw")
_UPPER_ARM_RADIUS_M = 0.04
_FOREARM_RADIUS_M = 0.04
_HAND_RADIUS_M = 0.03
# The background in the chest frame (y points down, the eye looks down and towards +x at the hand): a table
# top below every reachable hand position, the floor below it and a wall ahead, all far enough to lie
# behind the hand in the image.
_TABLE_Y_M = 1.08
_TABLE_X_M = (-0.15, 1.10)
_TABLE_Z_M = (-0.90, 0.90)
_FLOOR_Y_M = 1.75
_WALL_X_M = 1.60
_LIGHT_CHEST = np.array([-0.3, -1.0, 0.4]) / np.linalg.norm([-0.3, -1.0, 0.4])  # towards the light: above, behind
_AMBIENT = 0.35
_LENS_BLUR_PX = 0.6  # the optics' point spread (Gaussian sigma); also keeps the one-ray-per-pixel edges honest
_RIGHT_GAIN = 1.04  # the right camera's photometric difference (gain, offset in grey levels)
_RIGHT_OFFSET_GREY = -3.0
# SGBM's search: depths from _NEAR_M (closer than the 40 cm of the eye's range) out to the floor.
_NEAR_M = 0.38
_FAR_M = 2.9


@dataclass(frozen=True)
class StereoHead:
    """A rectified stereo pair: shared intrinsics and orientation, right camera at +baseline along x."""

    fx_px: float
    fy_px: float
    cx_px: float
    cy_px: float
    width_px: int
    height_px: int
    baseline_m: float
    R_frame_optical: np.ndarray  # the left camera's optical axes (columns) in the sensor frame E
    frame: int  # the sensor frame's index in the profile

    @classmethod
    def from_profile(cls, profile: Profile, p: np.ndarray, sensor: str = "eye") -> StereoHead:
        """The head of the profile's sensor `sensor` with the intrinsics in p (internal units)."""
        s = next((s for s in profile.sensors if s.name == sensor), None)
        if not isinstance(s, Point3D) or s.reading != "stereo" or s.image is None:
            raise ValueError(f"robot '{profile.name}' has no stereo head '{sensor}' (intrinsics, image, baseline)")
        assert s.intrinsics is not None and s.baseline is not None  # a stereo reading has them
        fx, fy, cx, cy = (float(p[i]) for i in s.intrinsics)
        width, height = s.image
        return cls(
            fx,
            fy,
            cx,
            cy,
            width,
            height,
            s.baseline * length_factor(profile.length_unit, "m"),
            s.R_frame_optical,
            s.frame,
        )

    def disparity_px(self, depth_m: np.ndarray | float) -> np.ndarray | float:
        """The disparity u_left - u_right of a point at depth_m along the optical axis."""
        return self.fx_px * self.baseline_m / depth_m


@dataclass
class StereoImages:
    """One rendered frame. The truth (depth_true, object ids) is for tests and benchmarks, not for measuring."""

    left: np.ndarray  # (H, W) uint8
    right: np.ndarray  # (H, W) uint8
    depth_true: np.ndarray  # (H, W) float32 m along the left optical axis, NaN: no hit (tests, benchmarks only)
    object_id: np.ndarray  # (H, W) uint8, what each left pixel shows (OBJECT_NAMES)
    object_id_right: np.ndarray  # (H, W) uint8, the same for the right image


# --- the scene, in the left optical frame; points are (3, N) arrays ------------------------------------------

_TEXELS_PER_CM = 4.0


@cache
def _lattice() -> np.ndarray:
    """A fixed random 3-D lattice for value noise: the same scene texture on every frame and every run."""
    return np.random.default_rng(20240611).random(64**3)


def _noise(x: np.ndarray) -> np.ndarray:
    """Smooth value noise in [0, 1] at points x (3, N) in lattice cells (trilinear with smoothstep)."""
    lat = _lattice()
    cell = np.floor(x)
    f = x - cell
    f = f * f * (3 - 2 * f)
    i = cell.astype(np.int64) & 63  # the lattice wraps every 64 cells
    j = (i + 1) & 63
    out = np.zeros(x.shape[1])
    for corner in range(8):
        a, b, c = (j[k] if (corner >> k) & 1 else i[k] for k in range(3))
        w0, w1, w2 = (f[k] if (corner >> k) & 1 else 1 - f[k] for k in range(3))
        out += w0 * w1 * w2 * lat[(a * 64 + b) * 64 + c]
    return out


@cache
def _plane_texture() -> np.ndarray:
    """A periodic 512 x 512 grey texture (1.28 m period) for the planes: mottled at two scales, like stone."""
    from scipy.ndimage import gaussian_filter  # here: SciPy's import is a sixth of a desk's start

    rng = np.random.default_rng(7)
    tex = np.zeros((512, 512), np.float32)
    for weight, sigma in ((0.6, 6.0), (0.4, 2.0)):
        layer = gaussian_filter(rng.random((512, 512), np.float32), sigma, mode="wrap")
        tex += weight * (layer - layer.mean()) / layer.std()
    return (0.5 + 0.12 * tex).clip(0.05, 0.95)


def _lookup(texture: np.ndarray, texel: np.ndarray) -> np.ndarray:
    """Bilinear samples of a periodic texture at texel (2, N) (x, y), with OpenCV's remap."""
    n = texel.shape[1]
    rows = -(-n // 1024)  # remap wants images under 32767 px wide: fold the samples into rows of 1024
    grid = np.zeros((rows * 1024, 2), np.float32)
    period = texture.shape[0]
    grid[:n, 0], grid[:n, 1] = texel - period * np.floor(texel / period)  # remap's 16-bit fixed point: fold
    return cv2.remap(texture, grid.reshape(rows, 1024, 2), None, cv2.INTER_LINEAR, borderMode=cv2.BORDER_WRAP).ravel()[
        :n
    ]


@dataclass(frozen=True)
class _Rays:
    """Pixel rays of a block of the image, directions d = (dx, dy, 1) in the optical frame.

    dx depends on the column only (1, w) and dy on the row only (h, 1): products with d broadcast to
    (h, w) without storing (3, h, w) arrays, and the ray parameter of a hit is its depth.
    """

    dx: np.ndarray
    dy: np.ndarray

    @classmethod
    def of(cls, head: StereoHead) -> _Rays:
        dx = (np.arange(head.width_px) - head.cx_px) / head.fx_px
        dy = (np.arange(head.height_px) - head.cy_px) / head.fy_px
        return cls(dx[None, :], dy[:, None])

    def dot(self, v: np.ndarray) -> np.ndarray:
        return v[0] * self.dx + v[1] * self.dy + v[2]

    def norm2(self) -> np.ndarray:
        return self.dx * self.dx + self.dy * self.dy + 1.0

    def block(self, rows: slice, cols: slice) -> _Rays:
        return _Rays(self.dx[:, cols], self.dy[rows, :])


def _hit_ball(o: np.ndarray, d: _Rays, centre: np.ndarray, radius: float) -> np.ndarray:
    """Ray parameter of the first hit (inf: none) for rays o + t d."""
    oc = o - centre
    a = d.norm2()
    b = d.dot(oc)
    h = b * b - a * (oc @ oc - radius * radius)
    t = (-b - np.sqrt(np.maximum(h, 0.0))) / a
    return np.where((h >= 0) & (t > 0), t, np.inf)


@dataclass(frozen=True)
class _Sphere:
    """The calibration sphere, its blotches fixed to the hand frame (R_local: the hand's axes)."""

    centre: np.ndarray  # (3,) m
    radius: float  # m
    R_local: np.ndarray
    object_id: int = SPHERE

    def bound(self) -> list[tuple[np.ndarray, float]] | None:
        return [(self.centre, self.radius)]

    def hit(self, o: np.ndarray, d: _Rays) -> np.ndarray:
        return _hit_ball(o, d, self.centre, self.radius)

    def normal(self, x: np.ndarray, origin: np.ndarray) -> np.ndarray:
        """Outward unit normals (3, N): a convex body's first hits face the camera."""
        return (x - self.centre[:, None]) / self.radius

    def albedo(self, x: np.ndarray) -> np.ndarray:
        # High-contrast blotches about 1 cm across with soft edges: what block matching locks on to.
        local_cm = self.R_local.T @ (x - self.centre[:, None]) * 100
        blotch = _noise(local_cm / 1.1 + 7.3) + 0.5 * _noise(local_cm / 0.45 + 19.1)
        return 0.08 + 0.84 / (1 + np.exp(-10 * (blotch - 0.75)))


@dataclass(frozen=True)
class _Capsule:
    """A link: the points within `radius` of the segment a-b, mildly textured in the link's frame."""

    a: np.ndarray  # (3,) m
    b: np.ndarray
    radius: float
    R_local: np.ndarray
    object_id: int

    def bound(self) -> list[tuple[np.ndarray, float]] | None:
        """The end balls: the capsule is their convex hull, so its image lies in their images' box."""
        return [(self.a, self.radius), (self.b, self.radius)]

    def hit(self, o: np.ndarray, d: _Rays) -> np.ndarray:
        """The cylinder's side where the hit lies between the ends, else the cap on that side."""
        ba, oa = self.b - self.a, o - self.a
        baba, baoa = ba @ ba, ba @ oa
        bard = d.dot(ba)
        qa = baba * d.norm2() - bard * bard
        qb = baba * d.dot(oa) - baoa * bard
        qc = baba * (oa @ oa) - baoa * baoa - self.radius**2 * baba
        h = qb * qb - qa * qc
        t = (-qb - np.sqrt(np.maximum(h, 0.0))) / qa
        y = baoa + t * bard
        side = (h >= 0) & (y > 0) & (y < baba) & (t > 0)
        cap = np.where(y <= 0, _hit_ball(o, d, self.a, self.radius), _hit_ball(o, d, self.b, self.radius))
        return np.where(side, t, np.where(h >= 0, cap, np.inf))

    def normal(self, x: np.ndarray, origin: np.ndarray) -> np.ndarray:
        ba = self.b - self.a
        s = np.clip(ba @ (x - self.a[:, None]) / (ba @ ba), 0.0, 1.0)
        return (x - self.a[:, None] - s * ba[:, None]) / self.radius

    def albedo(self, x: np.ndarray) -> np.ndarray:
        return 0.55 + 0.25 * (_noise(self.R_local.T @ (x - self.a[:, None]) * (100 / 2.5)) - 0.5)


@dataclass(frozen=True)
class _Plane:
    """A plane normal . x = offset (m), optionally a rectangle in its (u, v) axes; textured in the chest frame."""

    normal_: np.ndarray  # (3,) unit
    offset: float
    uv_axes: np.ndarray  # (3, 2) in-plane axes
    uv_origin: np.ndarray  # (3,) where (u, v) = (0, 0): a chest-fixed point, so the texture stays put
    bounds: tuple[float, float, float, float] | None  # (u_min, u_max, v_min, v_max) m; None: unbounded
    object_id: int

    def bound(self) -> list[tuple[np.ndarray, float]] | None:
        return None

    def hit(self, o: np.ndarray, d: _Rays) -> np.ndarray:
        with np.errstate(divide="ignore", invalid="ignore"):
            t = (self.offset - self.normal_ @ o) / d.dot(self.normal_)
        t = np.where(t > 0, t, np.inf)
        if self.bounds is None:
            return t
        u_min, u_max, v_min, v_max = self.bounds
        ts = np.where(np.isfinite(t), t, 0.0)
        u = self.uv_axes[:, 0] @ (o - self.uv_origin) + ts * d.dot(self.uv_axes[:, 0])
        v = self.uv_axes[:, 1] @ (o - self.uv_origin) + ts * d.dot(self.uv_axes[:, 1])
        return np.where((u >= u_min) & (u <= u_max) & (v >= v_min) & (v <= v_max), t, np.inf)

    def normal(self, x: np.ndarray, origin: np.ndarray) -> np.ndarray:
        """The one normal (3, 1) of the side the camera at `origin` is on."""
        return self.normal_[:, None] * (1.0 if self.normal_ @ origin > self.offset else -1.0)

    def albedo(self, x: np.ndarray) -> np.ndarray:
        A = self.uv_axes.T * (100 * _TEXELS_PER_CM)  # m -> texels
        texel = A[:, 0:1] * x[0] + A[:, 1:2] * x[1] + A[:, 2:3] * x[2] - (A @ self.uv_origin)[:, None]
        texel[0] += 97.0 * self.object_id  # each plane its own part of the texture
        return _lookup(_plane_texture(), texel)


_Primitive = _Sphere | _Capsule | _Plane


@dataclass(frozen=True)
class _Scene:
    primitives: list[_Primitive]
    light: np.ndarray  # (3,) unit vector towards the light, left optical frame


@dataclass(frozen=True)
class _Body:
    """The sphere and the arm's links in N configurations, in the left camera's optical frame (m)."""

    R_cam: np.ndarray  # (N, 3, 3) chest <- optical
    t_cam: np.ndarray  # (N, 3) the left camera in the chest frame
    centre: np.ndarray  # (N, 3) the sphere's centre
    radius: float
    R_hand: np.ndarray  # (N, 3, 3) optical <- hand
    links: list[tuple[np.ndarray, np.ndarray, float, np.ndarray, int]]  # a, b (N, 3), radius, R_local, object id


def _body(profile: Profile, p: np.ndarray, q: np.ndarray, head: StereoHead) -> _Body:
    """The sphere and the capsules of the arm (_ARM_FRAMES) and hand for joint readings q (N, n_joints)."""
    k = length_factor(profile.length_unit, "m")
    poses = forward(profile, p, np.asarray(q, dtype=float))
    R_cam = poses.R[head.frame] @ head.R_frame_optical  # chest <- optical
    t_cam = poses.t[head.frame] * k

    def point(x_chest_m: np.ndarray) -> np.ndarray:
        return np.einsum("nji,nj->ni", R_cam, x_chest_m - t_cam)

    def axes(R_chest: np.ndarray) -> np.ndarray:
        return np.einsum("nji,njk->nik", R_cam, R_chest)

    target = next((t for t in profile.targets if t.name == "fixture"), None)
    missing = [n for n in _ARM_FRAMES if n not in {f.name for f in profile.frames}]
    if target is None or target.point_params is None or target.radius is None or missing:
        raise InputError(
            f"robot '{profile.name}': the stereo renderer draws an arm of the frames {', '.join(_ARM_FRAMES)} "
            "holding a sphere target 'fixture' (a calibrated point with a radius), as Robonaut's"
        )
    R_hand, t_hand = poses.R[target.frame], poses.t[target.frame] * k
    centre_hand_m = p[list(target.point_params)] * k
    links = []
    frames = [profile.frame(n) for n in _ARM_FRAMES]
    for i, (f0, f1) in enumerate(itertools.pairwise(frames)):
        a, b = poses.t[f0] * k, poses.t[f1] * k
        if np.linalg.norm(b - a, axis=1).max() > 1e-6:  # coincident origins (wrist roll and pitch) need no capsule
            radius = _UPPER_ARM_RADIUS_M if i < 3 else _FOREARM_RADIUS_M if i < 5 else _HAND_RADIUS_M
            links.append((point(a), point(b), radius, axes(poses.R[f0]), ARM))
    # The hand: from the wrist towards the sphere, ending where the sphere's surface begins.
    towards = centre_hand_m / np.linalg.norm(centre_hand_m)
    reach_m = max(float(np.linalg.norm(centre_hand_m)) - target.radius * k - _HAND_RADIUS_M, 0.0)
    tip = R_hand @ (reach_m * towards) + t_hand
    links.append((point(t_hand), point(tip), _HAND_RADIUS_M, axes(R_hand), HAND))
    centre = point(R_hand @ centre_hand_m + t_hand)
    return _Body(R_cam, t_cam, centre, target.radius * k, axes(R_hand), links)


def _scene(profile: Profile, p: np.ndarray, q: np.ndarray, head: StereoHead) -> _Scene:
    """The primitives for one configuration q (n_joints,), in the left camera's optical frame (m)."""
    body = _body(profile, p, np.asarray(q, dtype=float)[None], head)
    R_cam, t_cam = body.R_cam[0], body.t_cam[0]
    prims: list[_Primitive] = [_Sphere(body.centre[0], body.radius, body.R_hand[0])]
    prims += [_Capsule(a[0], b[0], radius, R[0], object_id) for a, b, radius, R, object_id in body.links]
    origin = R_cam.T @ -t_cam  # the chest's origin
    ex, ey, ez = (R_cam.T @ e for e in np.eye(3))  # the chest's axes
    # A chest plane y = Y is ey . x = Y - t_cam[1] in the optical frame (x_chest = R_cam x + t_cam).
    prims += [
        _Plane(ey, _TABLE_Y_M - t_cam[1], np.stack([ex, ez], 1), origin, (*_TABLE_X_M, *_TABLE_Z_M), TABLE),
        _Plane(ey, _FLOOR_Y_M - t_cam[1], np.stack([ex, ez], 1), origin, None, FLOOR),
        _Plane(ex, _WALL_X_M - t_cam[0], np.stack([ez, ey], 1), origin, None, WALL),
    ]
    return _Scene(prims, R_cam.T @ _LIGHT_CHEST)


# --- ray casting and shading ----------------------------------------------------------------------------------


def _window(head: StereoHead, origin: np.ndarray, balls: list[tuple[np.ndarray, float]] | None) -> tuple[slice, slice]:
    """Image rows and columns where the convex hull of balls (centre, radius) seen from `origin` can appear.

    Conservative: each ball lies in its box x, y in c +- r, z in c_z +- r, whose image the extreme ratios
    x / z and y / z bound; the whole image when no bound is given or a ball reaches behind the camera.
    """
    if balls is None or any(c[2] - origin[2] - r < 0.01 for c, r in balls):
        return slice(0, head.height_px), slice(0, head.width_px)
    xs, ys = [], []
    for centre, radius in balls:
        c = centre - origin
        for z in (c[2] - radius, c[2] + radius):
            xs += [(c[0] - radius) / z, (c[0] + radius) / z]
            ys += [(c[1] - radius) / z, (c[1] + radius) / z]
    u0, u1 = head.fx_px * min(xs) + head.cx_px, head.fx_px * max(xs) + head.cx_px
    v0, v1 = head.fy_px * min(ys) + head.cy_px, head.fy_px * max(ys) + head.cy_px
    cols = slice(int(np.clip(math.floor(u0), 0, head.width_px)), int(np.clip(math.ceil(u1) + 1, 0, head.width_px)))
    rows = slice(int(np.clip(math.floor(v0), 0, head.height_px)), int(np.clip(math.ceil(v1) + 1, 0, head.height_px)))
    return rows, cols


def _cast(scene: _Scene, head: StereoHead, origin: np.ndarray, rays: _Rays) -> tuple[np.ndarray, np.ndarray]:
    """Depth (H, W) of the nearest hit (inf: none) and the index of the primitive hit (-1: none)."""
    depth = np.full((head.height_px, head.width_px), np.inf)
    index = np.full((head.height_px, head.width_px), -1, np.int16)
    for i, prim in enumerate(scene.primitives):
        rows, cols = _window(head, origin, prim.bound())
        t = prim.hit(origin, rays.block(rows, cols))
        nearer = t < depth[rows, cols]
        depth[rows, cols][nearer] = t[nearer]
        index[rows, cols][nearer] = i
    return depth, index


def _shade(scene: _Scene, origin: np.ndarray, rays: _Rays, depth: np.ndarray, index: np.ndarray) -> np.ndarray:
    """Grey levels (H, W) float: Lambertian with an ambient term and one directional light, then lens blur."""
    r, c = np.nonzero(index >= 0)
    order = np.argsort(index[r, c], kind="stable")  # pixels grouped by primitive: each group a slice
    r, c = r[order], c[order]
    t = depth[r, c]
    x_all = np.stack([origin[0] + t * rays.dx[0, c], origin[1] + t * rays.dy[r, 0], origin[2] + t])
    ends = np.cumsum(np.bincount(index[r, c], minlength=len(scene.primitives)))
    grey = np.empty(len(t))
    for prim, start, end in zip(scene.primitives, np.r_[0, ends[:-1]], ends, strict=True):
        if end > start:
            x = x_all[:, start:end]
            lambert = np.maximum(scene.light @ prim.normal(x, origin), 0.0)
            grey[start:end] = 255 * prim.albedo(x) * (_AMBIENT + (1 - _AMBIENT) * lambert)
    image = np.zeros(depth.shape)
    image[r, c] = grey
    return cv2.GaussianBlur(image, (0, 0), _LENS_BLUR_PX)


def render_pair(
    profile: Profile, p: np.ndarray, q: np.ndarray, head: StereoHead, rng: np.random.Generator, noise: float = 2.0
) -> StereoImages:
    """What the two cameras see for configuration q (n_joints,) rad and true parameters p (internal units).

    `noise` is the Gaussian photometric noise in grey levels (each camera independently); the right camera
    also has a small gain and offset, as two real sensors do. The scene is Robonaut's: the arm joints of
    _ARM_FRAMES and the profile's `fixture` target (the sphere) in the hand.
    """
    scene = _scene(profile, p, q, head)
    rays = _Rays.of(head)
    object_of = np.array([prim.object_id for prim in scene.primitives] + [NONE], np.uint8)  # index -1: none
    out = []
    for origin, gain, offset in (
        (np.zeros(3), 1.0, 0.0),
        (np.array([head.baseline_m, 0.0, 0.0]), _RIGHT_GAIN, _RIGHT_OFFSET_GREY),
    ):
        depth, index = _cast(scene, head, origin, rays)
        grey = (
            gain * _shade(scene, origin, rays, depth, index)
            + offset
            + noise * rng.standard_normal(depth.shape, np.float32)
        )
        out.append((np.clip(np.rint(grey), 0, 255).astype(np.uint8), depth, object_of[index]))
    (left, depth_m, ids_left), (right, _, ids_right) = out
    depth_true = np.where(np.isfinite(depth_m), depth_m, np.nan).astype(np.float32)
    return StereoImages(left, right, depth_true, ids_left, ids_right)


# --- what the cameras can see of the sphere, without rendering ---------------------------------------------------


@dataclass(frozen=True)
class SphereViews:
    """How the pair sees the calibration sphere in N configurations: from the scene, not from images."""

    centre_px: np.ndarray  # (N, 2) the centre's image in the left camera
    box_px: np.ndarray  # (N, 4) the outline's extent in the left image: u_min, u_max, v_min, v_max
    visible: np.ndarray  # (N, 2) share of the outline's area where the sphere is the nearest surface (left, right)


_VIEW_RAYS = 128  # rays through the outline per camera: a visible share to within a few per cent
_CHUNK = 256  # configurations at a time (memory: chunk x rays x links)


@cache
def _unit_disc(n: int) -> np.ndarray:
    """n points (n, 2) spread evenly over the unit disc (a sunflower)."""
    k = np.arange(n) + 0.5
    r, phi = np.sqrt(k / n), k * math.pi * (3 - math.sqrt(5))
    return np.stack([r * np.cos(phi), r * np.sin(phi)], axis=1)


def _from_camera(d0: np.ndarray, p1: np.ndarray, d1: np.ndarray) -> np.ndarray:
    """Shortest distance between the segments s d0 (from the camera at the origin) and p1 + t d1 (s, t in [0, 1]);
    broadcast (3, ...), the components first: a sphere's rays times the links near them are thousands of segment
    pairs a check, and the products over (..., 3) arrays' last axes took most of its time."""
    r = -p1
    a, e = _dot(d0, d0), np.maximum(_dot(d1, d1), 1e-18)  # a link of no length is its end ball
    b, c, f = _dot(d0, d1), _dot(d0, r), _dot(d1, r)
    denom = a * e - b * b
    with np.errstate(divide="ignore", invalid="ignore"):
        s = np.where(denom > 1e-12 * a * e, np.clip((b * f - c * e) / denom, 0.0, 1.0), 0.0)
        t = (b * s + f) / e
        s = np.where(t < 0, np.clip(-c / a, 0.0, 1.0), np.where(t > 1, np.clip((b - c) / a, 0.0, 1.0), s))
    t = np.clip(t, 0.0, 1.0)
    # Component by component: s d0 - t d1 at once broadcasts both ways, and numpy then loops over the 3 components
    # innermost (ten times as long as all the rest).
    gap = [r[i] + s * d0[i] - t * d1[i] for i in range(3)]
    return np.sqrt(gap[0] * gap[0] + gap[1] * gap[1] + gap[2] * gap[2])


def _dot(x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """x . y of (3, ...) arrays, the components first."""
    return x[0] * y[0] + x[1] * y[1] + x[2] * y[2]


def sphere_views(
    profile: Profile, p: np.ndarray, q: np.ndarray, head: StereoHead, least_share: float = 0.0
) -> SphereViews:
    """Where the sphere appears in the left image and how much of it each camera sees past the arm and
    the hand (the capsules `render_pair` draws), for joint readings q (N, n_joints) rad and parameters p.
    `least_share`: the right camera's share is worked out only where the left camera's reaches it, and is 0
    elsewhere (a check that needs both to: `SphereFinder.clear`, which refuses most of what it checks).

    A ray through the sphere's outline is hidden when the segment from the camera to where it meets the
    sphere passes within a link's radius of the link's axis. The background planes lie behind the
    sphere whenever the sphere is above the table and before the wall (the camera is); where it is not,
    the sphere counts as hidden. A sphere reaching behind a camera is hidden."""
    q = np.atleast_2d(np.asarray(q, dtype=float))
    out = [_sphere_views(profile, p, q[i : i + _CHUNK], head, least_share) for i in range(0, len(q), _CHUNK)]
    if not out:
        return SphereViews(np.zeros((0, 2)), np.zeros((0, 4)), np.zeros((0, 2)))
    return SphereViews(
        np.concatenate([v.centre_px for v in out]),
        np.concatenate([v.box_px for v in out]),
        np.concatenate([v.visible for v in out]),
    )


def _sphere_views(profile: Profile, p: np.ndarray, q: np.ndarray, head: StereoHead, least_share: float) -> SphereViews:
    body = _body(profile, p, q, head)
    n, radius = len(q), body.radius
    centre_chest = np.einsum("nij,nj->ni", body.R_cam, body.centre) + body.t_cam
    background_behind = (centre_chest[:, 1] + radius < _TABLE_Y_M) & (centre_chest[:, 0] + radius < _WALL_X_M)
    disc = 0.97 * _unit_disc(_VIEW_RAYS)  # just inside the outline, where one ray decides a pixel
    angles = np.linspace(0.0, 2 * math.pi, 72, endpoint=False)
    ring = np.stack([np.cos(angles), np.sin(angles)], axis=1)
    visible = np.zeros((n, 2))
    box = np.full((n, 4), np.nan)
    starts = np.stack([a for a, *_ in body.links])  # (links, N, 3)
    spans = np.stack([b - a for a, b, *_ in body.links])
    r_links = np.array([r for _, _, r, *_ in body.links])[:, None]  # (links, 1)
    for cam, origin in enumerate((np.zeros(3), np.array([head.baseline_m, 0.0, 0.0]))):
        c = body.centre - origin
        dist = np.linalg.norm(c, axis=1)
        axis = c / dist[:, None]
        e1 = np.cross(axis, [0.0, 1.0, 0.0])
        e1 /= np.linalg.norm(e1, axis=1, keepdims=True)
        e2 = np.cross(axis, e1)
        tan_half = radius / np.sqrt(np.maximum(dist * dist - radius * radius, 1e-12))
        # The tangent cone's rays, unnormalised: axis + tan_half (x e1 + y e2) over the disc and the ring.
        frame = np.stack([e1, e2], axis=1) * tan_half[:, None, None]  # (N, 2, 3)
        rays = axis[:, None] + disc @ frame  # (N, K, 3)
        edge = axis[:, None] + ring @ frame
        ahead = (dist > radius) & (edge[..., 2].min(axis=1) > 0.01)
        if cam == 0:
            with np.errstate(divide="ignore", invalid="ignore"):
                u = head.fx_px * edge[..., 0] / edge[..., 2] + head.cx_px
                v = head.fy_px * edge[..., 1] / edge[..., 2] + head.cy_px
            box = np.where(ahead[:, None], np.stack([u.min(1), u.max(1), v.min(1), v.max(1)], axis=1), np.nan)
        # Where each ray meets the sphere (rays from inside the cone do): the segment camera -> surface.
        rays = np.ascontiguousarray(rays.transpose(2, 0, 1))  # (3, N, K): the components first (_from_camera)
        rr = _dot(rays, rays)
        b = _dot(rays, c.T[:, :, None])
        disc_ = np.maximum(b * b - rr * (dist * dist - radius * radius)[:, None], 0.0)
        hit = rays * ((b - np.sqrt(disc_)) / rr)  # relative to the camera
        # Every point of a ray's segment lies within the sphere's radius of the segment camera -> centre: a link
        # farther than its own radius plus that from this segment hides no ray, and is not tested ray by ray.
        # All links at once (a sees of a few candidates costs its numpy calls, not its arithmetic). Nor are the
        # rays of a sphere shown by neither camera, or (right camera) not enough by the left one.
        shown = ahead & background_behind & (visible[:, 0] >= least_share if cam == 1 else True)
        near = (
            _from_camera(c.T[:, None], (starts - origin).transpose(2, 0, 1), spans.transpose(2, 0, 1))
            < r_links + radius
        ) & shown
        near_cfg, near_link = np.nonzero(near.T)  # by configuration
        clear = np.ones(rr.shape, bool)
        if near_cfg.size:
            start = (starts[near_link, near_cfg] - origin).T[:, :, None]  # (3, pairs, 1)
            span = spans[near_link, near_cfg].T[:, :, None]
            gap = _from_camera(hit[:, near_cfg], start, span)  # (pairs, rays)
            first = np.flatnonzero(np.diff(near_cfg, prepend=-1))  # each configuration's first pair
            clear[near_cfg[first]] = np.logical_and.reduceat(gap >= r_links[near_link], first, axis=0)
        visible[:, cam] = np.where(shown, clear.mean(axis=1), 0.0)
    centre = body.centre
    with np.errstate(divide="ignore", invalid="ignore"):
        centre_px = np.stack(
            [
                head.fx_px * centre[:, 0] / centre[:, 2] + head.cx_px,
                head.fy_px * centre[:, 1] / centre[:, 2] + head.cy_px,
            ],
            axis=1,
        )
    return SphereViews(centre_px, box, visible)


# --- depth from the pair --------------------------------------------------------------------------------------

_BLOCK_PX = 5  # SGBM's block size


def _disparity_search(head: StereoHead) -> tuple[int, int]:
    """SGBM's minDisparity and numDisparities for the _NEAR_M to _FAR_M search (a multiple of 16)."""
    fb = head.fx_px * head.baseline_m
    min_disp = math.floor(fb / _FAR_M)
    return min_disp, 16 * math.ceil((fb / _NEAR_M - min_disp) / 16)


def no_depth_band_px(head: StereoHead) -> int:
    """The columns at the left edge of the left image where `depth_from_pair` gives no depth: the
    largest disparity searched: a left pixel there has no candidate match inside the right image."""
    min_disp, num_disp = _disparity_search(head)
    return min_disp + num_disp


def depth_from_pair(left: np.ndarray, right: np.ndarray, head: StereoHead) -> np.ndarray:
    """Depth (H, W) float32 in m along the left optical axis from semi-global block matching; NaN: no data.

    The disparity search covers _NEAR_M to _FAR_M: the eye's 40-120 cm range and the background behind it,
    so that the background does not match falsely into the range. Tuned for the sphere: 5 x 5 blocks (the
    curved, slanted surface is nearly fronto-parallel inside one), weak smoothness penalties (SGBM's
    smoothing flattens the sphere's disparity bump, pushing its depth outwards) and the prefilter's full
    gradient range (preFilterCap 63) gave the smallest sub-pixel error. The left-right check, the uniqueness
    ratio and the speckle filter turn occlusions, untextured areas and mismatches into holes, as on a real
    head. Like any SGBM head, the first ~128 columns (the largest disparity searched) get no depth: padding
    the images would recover some, but sends what the right camera cannot see to false background matches.
    """
    if left.ndim == 3:
        left = cv2.cvtColor(left, cv2.COLOR_BGR2GRAY)
        right = cv2.cvtColor(right, cv2.COLOR_BGR2GRAY)
    min_disp, num_disp = _disparity_search(head)
    fb = head.fx_px * head.baseline_m
    block = _BLOCK_PX
    sgbm = cv2.StereoSGBM_create(
        minDisparity=min_disp,
        numDisparities=num_disp,
        blockSize=block,
        P1=2 * block * block,
        P2=8 * block * block,
        disp12MaxDiff=1,
        preFilterCap=63,
        uniquenessRatio=10,
        speckleWindowSize=100,
        speckleRange=2,
        mode=cv2.StereoSGBM_MODE_SGBM_3WAY,
    )
    disparity_px = sgbm.compute(left, right).astype(np.float32) / 16.0
    valid = disparity_px >= max(min_disp, 1)  # invalid pixels come back as (min_disp - 1)
    with np.errstate(divide="ignore"):
        return np.where(valid, np.float32(fb) / disparity_px, np.float32(np.nan)).astype(np.float32)
