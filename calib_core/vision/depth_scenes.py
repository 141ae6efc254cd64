"""Analytic depth maps for testing and benchmarking the BallFinder without the stereo renderer: spheres of a
known radius on forearm-like cylinders, a table under the first, a wall behind, seen by a 640 x 480,
f = 525 px camera, with what a stereo matcher adds: depth noise growing with z^2 (nominal: a 9 cm
baseline and 0.25 px of disparity noise, 5.3 mm at 1 m), the sphere's outline fattened by its own
(foreground) depth, and missing pixels (NaN or 0). Everything in metres, in the camera's OpenCV
frame (x right, y down, z forward); depth is along the optical axis.

`case` draws a random scene with the truth and a seed (the kinematic prediction) up to 15 cm off;
`render` builds one to order; `detect` runs the BallFinder with this camera.
"""

from __future__ import annotations

import math

import cv2
import numpy as np

from .ballfinder import SphereDetection, find_sphere

F_PX = 525.0
CX_PX, CY_PX = 319.5, 239.5
W_PX, H_PX = 640, 480
RADIUS_M = 0.04
NOISE_1M_M = 0.25 / (525 * 0.09)  # sigma of depth at 1 m; grows with z^2
FOREARM_RADIUS_M = 0.03

_u, _v = np.meshgrid(np.arange(W_PX, dtype=float), np.arange(H_PX, dtype=float))
RAYS = np.stack([(_u - CX_PX) / F_PX, (_v - CY_PX) / F_PX, np.ones_like(_u)], axis=-1)  # depth = ray parameter


def _sphere_t(c: np.ndarray, r: float) -> np.ndarray:
    b = RAYS @ c
    rr = np.einsum("...i,...i", RAYS, RAYS)
    disc = b * b - rr * (c @ c - r * r)
    with np.errstate(invalid="ignore"):
        t = (b - np.sqrt(disc)) / rr
    return np.where((disc > 0) & (t > 0), t, np.inf)


def _plane_t(n: np.ndarray, h: float) -> np.ndarray:
    """The plane n.x = h."""
    dn = RAYS @ n
    with np.errstate(divide="ignore", invalid="ignore"):
        t = h / dn
    return np.where(t > 0, t, np.inf)


def _disc_t(centre: np.ndarray, n: np.ndarray, r: float) -> np.ndarray:
    t = _plane_t(n, n @ centre)
    hit = RAYS * np.where(np.isfinite(t), t, 0)[..., None] - centre
    return np.where(np.linalg.norm(hit, axis=-1) < r, t, np.inf)


def _cylinder_t(a: np.ndarray, w: np.ndarray, r: float, length: float) -> np.ndarray:
    """A solid capped cylinder from a to a + length w: the entry of the ray into it."""
    dw = RAYS @ w
    d_perp = RAYS - dw[..., None] * w
    a_perp = a - (a @ w) * w
    qa = np.einsum("...i,...i", d_perp, d_perp)
    qb = -2 * d_perp @ a_perp
    qc = a_perp @ a_perp - r * r
    disc = qb * qb - 4 * qa * qc
    with np.errstate(invalid="ignore", divide="ignore"):
        s = np.sqrt(disc)
        t0, t1 = (-qb - s) / (2 * qa), (-qb + s) / (2 * qa)
        s0, s1 = (a @ w) / dw, (a @ w + length) / dw
    lo = np.maximum(t0, np.minimum(s0, s1))
    hi = np.minimum(t1, np.maximum(s0, s1))
    return np.where((disc > 0) & (lo < hi) & (lo > 0), lo, np.inf)


def render(
    rng: np.random.Generator,
    centres_m: list[np.ndarray],
    *,
    radius_m: float = RADIUS_M,
    noise: float = 1.0,
    fatten_px: int = 2,
    holes: float = 0.03,
    forearm: bool = True,
    occluder: bool = False,
    table_drop_m: float = 0.0,
    wall_gap_m: float | None = 0.15,
    sphere: bool = True,
) -> np.ndarray:
    """Depth (float32, NaN or 0 where missing) of spheres on sticks, a table under the first, and a wall."""
    c0 = centres_m[0]
    t = np.full((H_PX, W_PX), np.inf)
    # The table below the first sphere: the camera looks down at it at 40 deg (its normal points up, -y,
    # and towards the camera, -z).
    n_up = np.array([0.0, -math.cos(0.7), -math.sin(0.7)])
    t = np.minimum(t, _plane_t(n_up, n_up @ c0 - radius_m - table_drop_m))
    if wall_gap_m is not None:
        t = np.minimum(t, _plane_t(np.array([0.0, 0.0, 1.0]), c0[2] + radius_m + wall_gap_m))
    on_sphere = np.zeros((H_PX, W_PX), bool)
    for c in centres_m:
        if forearm:
            w = rng.normal(size=3)
            w[2] = abs(w[2]) * 0.5 - 0.1  # mostly across the view and away from the camera
            w /= np.linalg.norm(w)
            start = math.sqrt(radius_m**2 - (0.8 * FOREARM_RADIUS_M) ** 2)  # touches the sphere
            t = np.minimum(t, _cylinder_t(c + start * w, w, FOREARM_RADIUS_M, 0.35))
        if sphere:
            ts = _sphere_t(c, radius_m)
            on_sphere |= ts < t
            t = np.minimum(t, ts)
    if occluder:  # a plate 10 cm in front of the first sphere hides it
        d = c0 / np.linalg.norm(c0)
        t = np.minimum(t, _disc_t(c0 - 0.1 * d, d, 0.12))
    if fatten_px > 0:  # block matching gives the sphere's outline the sphere's (foreground) depth
        k = np.ones((2 * fatten_px + 1,) * 2, np.uint8)
        ring = cv2.dilate(on_sphere.view(np.uint8), k).astype(bool) & ~on_sphere
        near = cv2.erode(np.where(on_sphere, t, np.inf).astype(np.float32), k)
        t = np.where(ring & (near < t), near, t)
    t = t + rng.normal(size=t.shape) * noise * NOISE_1M_M * np.where(np.isfinite(t), t, 0) ** 2
    depth = np.where(np.isfinite(t), t, np.nan).astype(np.float32)
    depth[rng.random(depth.shape) < holes] = np.nan
    for _ in range(int(holes * 200)):  # blobs without data, some of them 0 instead of NaN
        u, v, r = rng.integers(0, W_PX), rng.integers(0, H_PX), int(rng.integers(2, 8))
        cv2.circle(depth, (int(u), int(v)), r, 0.0 if rng.random() < 0.5 else np.nan, -1)
    return depth


def random_centre(rng: np.random.Generator, z_m: tuple[float, float] = (0.4, 1.2)) -> np.ndarray:
    """A sphere centre at a depth in z_m, anywhere in the image with a margin of twice its radius."""
    z = rng.uniform(*z_m)
    margin = 2 * F_PX * RADIUS_M / z
    u = rng.uniform(margin, W_PX - margin)
    v = rng.uniform(margin, H_PX - margin)
    return np.array([(u - CX_PX) / F_PX * z, (v - CY_PX) / F_PX * z, z])


def seed_near(rng: np.random.Generator, c: np.ndarray, max_m: float = 0.15) -> np.ndarray:
    d = rng.normal(size=3)
    return c + d / np.linalg.norm(d) * rng.uniform(0, max_m)


def case(
    rng: np.random.Generator, noise: float = 1.0, z_m: tuple[float, float] = (0.4, 1.2)
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A random scene: (depth, true centre, seed)."""
    c = random_centre(rng, z_m)
    depth = render(
        rng,
        [c],
        noise=noise,
        fatten_px=int(rng.integers(1, 3)),
        table_drop_m=float(rng.choice([0.0, rng.uniform(0.0, 0.3)])),
        wall_gap_m=float(rng.uniform(0.02, 0.4)),
    )
    return depth, c, seed_near(rng, c)


def detect(depth: np.ndarray, seed: np.ndarray | None, radius_m: float = RADIUS_M, **kw) -> SphereDetection:
    return find_sphere(depth, F_PX, F_PX, CX_PX, CY_PX, radius_m, seed, **kw)
