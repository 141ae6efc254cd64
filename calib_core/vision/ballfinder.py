"""BallFinder: the 3-D centre of a sphere of known radius in a depth map (Nickels & Huber, section III-A).

The paper's steps, then ours:

1. Back-project the depth map and keep the points near the kinematic prediction (the seed).
2. Drop connected regions too small to be the sphere; depth steps separate regions.
3. Hough transform: every point votes for the centres one radius behind it, along directions of the
   hemisphere facing away from the camera, into a voxel grid; the best 3 x 3 x 3 box wins. Only the
   directions within a cone around the surface's inward normal vote: with the whole hemisphere (the
   paper's; `normal_cone_deg=90`) a wall fills a slab of the accumulator about as densely as the
   sphere fills its peak once depth noise blurs it, which a seed's gate hides but a search without a
   seed does not.
4. A robust least-squares fit with the radius fixed refines the best cells (`_refine`).
5. Checks against the depth map, so that a poor guess is reported as "not found" with a reason instead
   of returned (`_evaluate`): the fit must stay near its vote and within the gate, cover most of the
   outline that is not hidden, leave no depth seen through the sphere, and the surface inside the
   outline must, fitted on its own, have the radius asked for and be round.

Camera frame: OpenCV (x right, y down, z forward); depth is along the optical axis, 0, NaN or inf where
there is no data. Everything is in metres (`_m`) and pixels (`_px`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import cache

import cv2
import numpy as np

from .sighting import Detail

# Stereo depth noise grows with z^2. The default is a 525 px, 9 cm baseline head with 0.25 px of
# disparity noise: 0.25 / (525 * 0.09) m at 1 m.
DEPTH_SIGMA_1M_M = 0.25 / (525 * 0.09)
_LOCAL_PX = 2  # half-width of the neighbourhood whose mean depth residual must be unbiased (`_refine`)
_OCCLUDER_PX = 4  # pixels dropped around something in front of the sphere (`_refine`)
_MAX_CELLS = 1_000_000  # accumulator size without a seed (the voxel grows to fit the scene)
_MAX_VOTERS = 20_000  # pixels that vote (the stride grows to keep to it)


@dataclass(frozen=True)
class FinderOptions:
    """What to tune for a real depth sensor (the first three) and the detector's own trade-offs."""

    depth_sigma_1m_m: float = DEPTH_SIGMA_1M_M  # depth noise at 1 m (it grows with z^2)
    jump_m: float = 0.03  # smallest depth step between neighbouring pixels that separates objects (or 7 sigma)
    edge_px: int = 2  # pixels dropped on each side of a depth step (>= the matcher's foreground fattening)
    min_region_fraction: float = 0.25  # of the sphere's expected area, for a connected region to vote
    directions: int = 120  # on the hemisphere away from the camera; about 11 fall in a point's normal cone
    normal_cone_deg: float = 25.0  # votes only this close to the local inward normal (90: the paper's)
    voxel_fraction: float = 0.125  # accumulator voxel, in radii
    samples_per_radius: float = 7.0  # voting pixels across the sphere's image radius (sets the stride)
    candidates: int = 3  # accumulator peaks tried, best first, until one passes the checks (4x without a seed)
    min_votes: int = 10  # in the winning box
    min_visible_fraction: float = 0.7  # of the pixels that could show the sphere (`_refine`)
    max_see_through_fraction: float = 0.15  # of the outline's pixels seen behind the sphere's surface
    # The surface's own shape, fitted inside the outline, in units of 1 / radius_m (at 2 standard errors):
    radius_tolerance: float = 0.3  # for its mean curvature
    roundness_tolerance: float = 0.6  # for the difference of its principal curvatures


@dataclass
class SphereDetection:
    """The result: the centre in the camera frame, or None and why not."""

    found: bool
    center_m: np.ndarray | None
    votes: int  # the winning cell's 3 x 3 x 3 box sum (votes weigh z^2, about 1 per voting pixel)
    inliers: int  # depth points on the sphere used in the fit (every stride-th pixel of a near sphere)
    fit_rms_m: float  # NaN when no fit was made
    reason: str  # "ok", or why the sphere was not found

    def to_json(self) -> Detail:
        return {
            "found": self.found,
            "center": None if self.center_m is None else [float(v) for v in self.center_m],
            "votes": int(self.votes),
            "inliers": int(self.inliers),
            "fit_rms": None if math.isnan(self.fit_rms_m) else float(self.fit_rms_m),
            "reason": self.reason,
        }


@dataclass
class _View:
    """The cropped depth map as points: rows v0.., columns u0.."""

    u0: int
    v0: int
    z: np.ndarray  # (h, w) float32, NaN where missing
    x: np.ndarray
    y: np.ndarray
    usable: np.ndarray  # (h, w) bool: valid and not next to a depth step
    xn: np.ndarray  # (w,) (u - cx) / fx
    yn: np.ndarray  # (h,) (v - cy) / fy


@cache
def _hemisphere(n: int) -> np.ndarray:
    """n Fibonacci directions spread evenly over the hemisphere z > 0 (equal-area: z uniform)."""
    k = np.arange(n) + 0.5
    z = k / n
    phi = k * math.pi * (3 - math.sqrt(5))
    s = np.sqrt(1 - z * z)
    return np.stack([s * np.cos(phi), s * np.sin(phi), z], axis=1)


def _rotate_z_to(a: np.ndarray) -> np.ndarray:
    """A rotation taking +z to the unit vector a (a[2] > 0: the camera looks along +z)."""
    v = np.cross([0.0, 0.0, 1.0], a)
    vx = np.array([[0, -v[2], v[1]], [v[2], 0, -v[0]], [-v[1], v[0], 0]])
    return np.eye(3) + vx + vx @ vx / (1 + a[2])


def _box(cam: tuple[float, float, float, float], shape: tuple[int, int], c: np.ndarray, r_m: float) -> tuple:
    """Image rows and columns (v0, v1, u0, u1) that see the ball (c, r_m); all of them if it reaches z < 5 cm."""
    fx, fy, cx, cy = cam
    h, w = shape
    z_lo = c[2] - r_m
    if z_lo < 0.05:
        return 0, h, 0, w
    zs = (z_lo, c[2] + r_m)
    us = [cx + fx * (c[0] + s * r_m) / z for s in (-1, 1) for z in zs]
    vs = [cy + fy * (c[1] + s * r_m) / z for s in (-1, 1) for z in zs]
    v0, v1 = max(0, math.floor(min(vs)) - 1), min(h, math.ceil(max(vs)) + 2)
    u0, u1 = max(0, math.floor(min(us)) - 1), min(w, math.ceil(max(us)) + 2)
    return v0, max(v0, v1), u0, max(u0, u1)


def _view(depth: np.ndarray, cam: tuple, box: tuple, opt: FinderOptions) -> _View:
    """Back-project the box and mark depth steps (both sides, widened to edge_px)."""
    fx, fy, cx, cy = cam
    v0, v1, u0, u1 = box
    z = depth[v0:v1, u0:u1]
    z = np.where(np.isfinite(z) & (z > 0), z, np.float32(np.nan))
    xn = ((np.arange(u0, u1) - cx) / fx).astype(np.float32)
    yn = ((np.arange(v0, v1) - cy) / fy).astype(np.float32)
    k = np.float32(7 * opt.depth_sigma_1m_m)
    step = np.zeros(z.shape, bool)
    for a, b, sa, sb in (
        (z[:, 1:], z[:, :-1], np.s_[:, 1:], np.s_[:, :-1]),
        (z[1:], z[:-1], np.s_[1:], np.s_[:-1]),
    ):
        near = np.fmin(a, b)
        jump = np.abs(a - b) > np.maximum(np.float32(opt.jump_m), k * near * near)
        step[sa] |= jump
        step[sb] |= jump
    if opt.edge_px > 1:
        step = cv2.dilate(step.view(np.uint8), np.ones((2 * opt.edge_px - 1,) * 2, np.uint8)).view(bool)
    usable = ~np.isnan(z) & ~step
    return _View(u0, v0, z, xn[None, :] * z, yn[:, None] * z, usable, xn, yn)


def _regions(view: _View, mask: np.ndarray, f_px: float, r_m: float, opt: FinderOptions) -> np.ndarray:
    """The mask without connected regions smaller than min_region_fraction of the sphere's expected area."""
    n, labels, stats, _ = cv2.connectedComponentsWithStats(mask.view(np.uint8), connectivity=4)
    area = stats[:, cv2.CC_STAT_AREA]
    z_mean = np.bincount(labels[mask], weights=view.z[mask], minlength=n) / np.maximum(area, 1)
    r_px = np.maximum(f_px * r_m / np.maximum(z_mean, 1e-3) - opt.edge_px, 1.0)
    keep = area >= opt.min_region_fraction * math.pi * r_px * r_px
    keep[0] = False
    return keep[labels]


def _normals(view: _View, cam: tuple, rows: np.ndarray, cols: np.ndarray, h_px: int) -> np.ndarray:
    """Unit inward normals (pointing away from the camera) at the given pixels of the view; NaN where unknown.

    From the depth gradient of the depth map smoothed over (2 h_px + 1)^2 usable pixels: for a pinhole
    camera the surface normal is (-fx z_u, -fy z_v, (u - cx) z_u + (v - cy) z_v + z)."""
    fx, fy, cx, cy = cam
    k = (2 * h_px + 1,) * 2
    good = view.usable.astype(np.float32)
    count = cv2.boxFilter(good, -1, k, normalize=False, borderType=cv2.BORDER_CONSTANT)
    total = cv2.boxFilter(np.where(view.usable, view.z, 0), -1, k, normalize=False, borderType=cv2.BORDER_CONSTANT)
    enough = count >= 0.5 * k[0] * k[1]
    zs = np.where(enough, total / np.maximum(count, 1), np.nan)
    h, w = zs.shape
    r0, r1 = np.clip(rows - h_px, 0, h - 1), np.clip(rows + h_px, 0, h - 1)
    c0, c1 = np.clip(cols - h_px, 0, w - 1), np.clip(cols + h_px, 0, w - 1)
    z_u = (zs[rows, c1] - zs[rows, c0]) / np.maximum(c1 - c0, 1)
    z_v = (zs[r1, cols] - zs[r0, cols]) / np.maximum(r1 - r0, 1)
    z = zs[rows, cols]
    n = np.stack(
        [-fx * z_u, -fy * z_v, (cols + view.u0 - cx) * z_u + (rows + view.v0 - cy) * z_v + z],
        axis=1,
    )
    return n / np.linalg.norm(n, axis=1, keepdims=True)


@cache
def _cone_table(m: int, cone_deg: float, cells: int = 48) -> np.ndarray:
    """For inward normals binned by their (x, y) on a cells x cells grid over [-1, 1]^2 (hemisphere
    around +z), the indices of the `_hemisphere(m)` directions within cone_deg of them, padded with m."""
    dirs = _hemisphere(m)
    g = (np.arange(cells) + 0.5) / cells * 2 - 1
    x, y = np.meshgrid(g, g, indexing="ij")
    nz = np.sqrt(np.maximum(1 - x * x - y * y, 0))
    normal = np.stack([x, y, nz], axis=-1) / np.sqrt(x * x + y * y + nz * nz)[..., None]
    within = normal @ dirs.T >= math.cos(math.radians(cone_deg))
    k = max(int(within.sum(axis=-1).max()), 1)
    order = np.argsort(~within, axis=-1, kind="stable")[..., :k]
    return np.where(np.take_along_axis(within, order, axis=-1), order, m)


def _peaks(
    p: np.ndarray,
    normals: np.ndarray | None,
    axis: np.ndarray,
    r_m: float,
    lo: np.ndarray,
    voxel_m: float,
    n: np.ndarray,
    candidates: int,
    opt: FinderOptions,
) -> list[tuple[np.ndarray, int]]:
    """Hough voting into the grid lo + voxel_m * [0, n): the best `candidates` cells (3 x 3 x 3 box sums).

    Each point votes for the centres at r_m along the directions of the hemisphere around `axis` (away
    from the camera) that lie within the normal cone of its inward normal (all of them without normals)."""
    rot = _rotate_z_to(axis)
    # Direction m (the padding) is far outside any grid.
    dirs = np.vstack([_hemisphere(opt.directions) @ rot.T, [0.0, 0.0, -1e6]])
    if normals is None:
        choice = np.broadcast_to(np.arange(opt.directions), (len(p), opt.directions))
    else:
        local = normals @ rot  # NaN normals (unknown) vote nowhere
        ok = local[:, 2] > 0
        p, local = p[ok], local[ok]
        cells = _cone_table(opt.directions, opt.normal_cone_deg)
        ij = np.clip(((local[:, :2] + 1) / 2 * cells.shape[0]).astype(int), 0, cells.shape[0] - 1)
        choice = cells[ij[:, 0], ij[:, 1]]
    base, off = (p - lo) / voxel_m, (r_m / voxel_m) * dirs
    flat = np.zeros(choice.shape, np.int64)
    inside = np.ones(choice.shape, bool)
    for a in range(3):
        i = np.floor(base[:, a : a + 1] + off[choice, a]).astype(np.int64)
        inside &= (i >= 0) & (i < n[a])
        flat = flat * n[a] + i
    # Each vote weighs z^2, the area its pixel covers (normalised to 1 on average), so that the sphere's
    # peak does not depend on its distance and a nearer surface does not outvote it.
    z2 = p[:, 2] * p[:, 2]
    weight = np.broadcast_to((z2 / max(float(np.mean(z2)), 1e-12))[:, None], choice.shape)
    acc = np.bincount(flat[inside], weight[inside], minlength=int(np.prod(n))).reshape(n)
    acc = acc[:-2] + acc[1:-1] + acc[2:]
    acc = acc[:, :-2] + acc[:, 1:-1] + acc[:, 2:]
    acc = acc[:, :, :-2] + acc[:, :, 1:-1] + acc[:, :, 2:]
    out = []
    suppress = max(1, round(r_m / voxel_m))  # peaks closer than one radius are the same sphere
    for _ in range(candidates):
        cell = np.unravel_index(int(np.argmax(acc)), acc.shape)
        votes = int(acc[cell])
        if votes == 0:
            break
        out.append((lo + (np.array(cell) + 1.5) * voxel_m, votes))
        acc[tuple(slice(max(0, c - suppress), c + suppress + 1) for c in cell)] = 0
    return out


def _huber_weights(res: np.ndarray, scale_m: float) -> np.ndarray:
    a = np.abs(res)
    return np.where(a <= scale_m, 1.0, scale_m / np.maximum(a, 1e-12))


def _fit(p: np.ndarray, c: np.ndarray, r_m: float, scale_m: float, shape: bool = False) -> tuple:
    """Gauss-Newton with Huber weights (scale_m: the depth noise) on the depth residuals z - front(c).

    The depth residual, not |p - c| - r, because stereo noise lies along the ray: across it near the
    outline it lengthens |p - c| whatever its sign, which biases the centre towards the camera by
    about sigma^2 / (2 r) (1 mm at 1.2 m). With `shape`, fits the radius too and an astigmatism
    a (x^2 - y^2) + b (2 x y) across the line of sight. Returns the centre, the radius, the difference
    of the principal curvatures (4 |(a, b)|: 0 on a sphere, 1 / r on a cylinder) and the standard
    errors of these two (0 without `shape`); the radius is inf if the fit fails: the points flatter than
    a sphere of 5 r_m, or the sphere off most of their rays."""
    ray = p / p[:, 2:3]
    rr = np.einsum("ij,ij->i", ray, ray)
    x = np.array([*c, r_m, 0.0, 0.0])
    n = 6 if shape else 3
    J = np.zeros((len(p), n))
    for _ in range(8):  # enough: `_refine` calls again from the result
        b = ray @ x[:3]
        disc = b * b - rr * (x[:3] @ x[:3] - x[3] * x[3])
        hit = disc > 0
        sq = np.sqrt(np.where(hit, disc, 1.0))
        res = np.where(hit, p[:, 2] - (b - sq) / rr, 0.0)
        J[:, :3] = -(ray * ((1 - b / sq) / rr)[:, None] + (1 / sq)[:, None] * x[:3])
        if shape:
            u = x[:3] / np.linalg.norm(x[:3])
            h = math.hypot(u[0], u[2])
            e1 = np.array([u[2], 0.0, -u[0]]) / h
            e2 = np.array([-u[0] * u[1], h * h, -u[1] * u[2]]) / h  # u x e1
            d = p - x[:3]
            xp, yp = d @ e1, d @ e2
            J[:, 3] = x[3] / sq
            J[:, 4] = -(xp * xp - yp * yp)
            J[:, 5] = -2 * xp * yp
            res = res + J[:, 4] * x[4] + J[:, 5] * x[5]
        if np.count_nonzero(hit) < len(p) // 2:  # the sphere has left the points
            return x[:3], math.inf, math.inf, math.inf, math.inf
        w = _huber_weights(res, scale_m) * hit
        H = J.T @ (J * w[:, None]) + 1e-12 * np.eye(n)
        step = np.linalg.solve(H, -(J.T @ (w * res)))
        x[:n] += step
        if shape and not 0 < x[3] < 5 * r_m:
            return x[:3], math.inf, math.inf, math.inf, math.inf
        if np.linalg.norm(step[:4]) < 1e-5 and np.linalg.norm(step[4:]) * r_m * r_m < 1e-5:
            break
    if not shape:
        return x[:3], r_m, 0.0, 0.0, 0.0
    cov = np.linalg.inv(H) * float(np.sum(w * res * res) / max(np.count_nonzero(w) - n, 1))
    return x[:3], x[3], math.sqrt(cov[3, 3]), 4 * math.hypot(x[4], x[5]), 4 * math.sqrt(max(cov[4, 4], cov[5, 5]))


def _sub_box(view: _View, cam: tuple, shape: tuple[int, int], c: np.ndarray, r_m: float) -> tuple[slice, slice]:
    v0, v1, u0, u1 = _box(cam, shape, c, r_m)
    h, w = view.z.shape
    rows = slice(min(max(v0 - view.v0, 0), h), min(max(v1 - view.v0, 0), h))
    cols = slice(min(max(u0 - view.u0, 0), w), min(max(u1 - view.u0, 0), w))
    return rows, cols


def _sigma_m(z_m: float, opt: FinderOptions) -> float:
    return opt.depth_sigma_1m_m * z_m * z_m


@dataclass
class _Patch:
    """Every stride-th pixel around a candidate: rays (xn, yn, 1), their squared length, depth (NaN where
    missing), depth of the kept pixels only, and their points."""

    xn: np.ndarray
    yn: np.ndarray
    rr: np.ndarray
    z_all: np.ndarray
    z: np.ndarray
    p: np.ndarray


def _patch(view: _View, kept: np.ndarray, cam: tuple, shape: tuple, c: np.ndarray, r_m: float, stride: int) -> _Patch:
    rows, cols = _sub_box(view, cam, shape, c, r_m)
    rows, cols = slice(rows.start, rows.stop, stride), slice(cols.start, cols.stop, stride)
    xn, yn = np.broadcast_arrays(view.xn[cols][None, :].astype(float), view.yn[rows][:, None].astype(float))
    z_all = view.z[rows, cols].astype(float)
    z = np.where(kept[rows, cols], z_all, np.nan)
    return _Patch(xn, yn, xn * xn + yn * yn + 1, z_all, z, np.stack([xn * z, yn * z, z], axis=-1))


def _front_depth(patch: _Patch, c: np.ndarray, r_m: float, margin_rad: float) -> np.ndarray:
    """Depth of the sphere's front surface along the patch's rays; NaN outside its outline less
    margin_rad (an angle).

    Less a margin because the outline's pixels are kept where the sphere meets another surface and
    dropped where it ends at a depth step, and one-sided they would pull the fit."""
    b = patch.xn * c[0] + patch.yn * c[1] + c[2]
    cc = float(c @ c)
    half_angle = math.asin(min(r_m / math.sqrt(cc), 1.0)) - margin_rad
    inside = b > np.sqrt(patch.rr * cc) * math.cos(max(half_angle, 0.0))
    disc = np.maximum(b * b - patch.rr * (cc - r_m * r_m), 0)
    return np.where(inside, (b - np.sqrt(disc)) / patch.rr, np.nan)


def _refine(
    patch: _Patch,
    c0: np.ndarray,
    r_m: float,
    sigma_m: float,
    margin_rad: float,
    first_tol_m: float,
    *,
    free: bool = False,
    rounds: int = 3,
) -> tuple[tuple, np.ndarray, float, int]:
    """The fit from c0: select the points on the sphere, fit, repeat. Returns `_fit`'s result, the final
    selection (a mask of the patch), the depth noise and how many kept pixels could show the sphere
    (inside its outline, neither in front of it nor near something that is).

    A point is on the sphere if its ray meets the sphere within 3 sigma of its front surface in depth
    (first_tol_m the first time, for the vote's error) and its neighbourhood is not, on average, off
    the sphere or behind something. In depth because stereo noise lies along the ray. Through the
    outline (less margin_rad, `_front_depth`) because a surface touching the sphere, the table under
    it, lies within any tolerance of it in 3-D near the contact but outside its outline in the image.
    On average because where the forearm holding the sphere hides its rim, the forearm's surface is
    within tolerance of the sphere's but always on one side. Sigma is the fit's own (median absolute
    residual), kept between sigma_m and twice that: a noisier depth map than configured still works.
    With `free` the radius and shape are fitted too, still inside the outline of (c0, r_m) where the
    surfaces touching the sphere stay out; a larger round surface the sphere was fitted into shows its
    own radius there."""
    sigma, tol = sigma_m, first_tol_m
    front0 = _front_depth(patch, c0, r_m, margin_rad)
    on = np.abs(patch.z - front0) < tol
    fit = (c0, r_m, 0.0, 0.0, 0.0)
    k = (2 * _LOCAL_PX + 1,) * 2
    could = 0
    for _ in range(rounds):
        if np.count_nonzero(on) < 10:
            break
        fit = _fit(patch.p[on], fit[0], fit[1], sigma, free)
        if not math.isfinite(fit[1]):
            break
        dz = patch.z - _front_depth(patch, fit[0], fit[1], margin_rad)
        res = dz[on][~np.isnan(dz[on])]
        sigma = float(np.clip(1.4826 * np.median(np.abs(res)), sigma_m, 2 * sigma_m)) if res.size else sigma_m
        tol = max(3 * sigma, 0.005)
        near = np.abs(dz) < tol
        if free:
            near &= ~np.isnan(front0)
        valid = ~np.isnan(dz)
        n_on, sum_on, n_valid, sum_valid = (
            cv2.boxFilter(a.astype(np.float32), -1, k, normalize=False, borderType=cv2.BORDER_CONSTANT)
            for a in (near, np.where(near, dz, 0), valid, np.where(valid, dz, 0))
        )
        # Something in front, on average over at least half a window.
        hidden = ((sum_valid < -0.5 * tol * n_valid) & (n_valid >= 0.5 * k[0] * k[1])).astype(np.uint8)
        hidden = cv2.dilate(hidden, np.ones((2 * _OCCLUDER_PX + 1,) * 2, np.uint8)).astype(bool)
        on = near & ~hidden & (np.abs(sum_on) <= 3.5 * sigma * np.sqrt(n_on))
        could = int(np.count_nonzero(valid & ~hidden & (dz >= -tol)))
    return fit, on, sigma, could


def _see_through(patch: _Patch, c: np.ndarray, r_m: float, sigma_m: float, margin_rad: float) -> float:
    """The share of the valid pixels inside the sphere's outline (less margin_rad) that are seen well
    behind its surface, where no sphere can be."""
    front = _front_depth(patch, c, r_m, margin_rad)
    inside = ~np.isnan(front)
    dz = patch.z_all[inside] - front[inside]
    valid = np.count_nonzero(dz >= -max(3 * sigma_m, 0.005))
    return np.count_nonzero(dz > max(4 * sigma_m, r_m / 4)) / max(valid, 1)


def _shape_check(
    patch: _Patch, c: np.ndarray, r_m: float, noise_m: float, margin_rad: float, opt: FinderOptions
) -> str | None:
    """Why the surface inside the outline, fitted on its own (radius and astigmatism free), is not a
    sphere of radius r_m; None if it is. Catches a wrong radius asked for, and planes and cylinders
    (the forearm) that the fixed-radius fit can follow within the depth noise."""
    (_, r_own, r_se, dk, dk_se), *_ = _refine(
        patch, c, r_m, noise_m, margin_rad, max(3 * noise_m, 0.005), free=True, rounds=4
    )
    if not math.isfinite(r_own):
        return "the surface, fitted on its own, is flat or no sphere"
    if not abs(r_m / r_own - 1) + 2 * r_m * r_se / r_own**2 <= opt.radius_tolerance:
        return f"the surface's radius is {r_own * 100:.1f} cm, not {r_m * 100:.1f} cm"
    if not (dk + 2 * dk_se) * r_m <= opt.roundness_tolerance:
        return f"the surface is not round: its curvatures across the line of sight differ by {dk:.0f} /m"
    return None


def _not_found(reason: str, votes: int = 0, inliers: int = 0, rms_m: float = math.nan) -> SphereDetection:
    return SphereDetection(False, None, votes, inliers, rms_m, reason)


def _evaluate(
    view: _View,
    kept: np.ndarray,
    cam: tuple,
    shape: tuple,
    c0: np.ndarray,
    votes: int,
    r_m: float,
    voxel_m: float,
    seed: np.ndarray | None,
    search_m: float,
    opt: FinderOptions,
) -> SphereDetection:
    """Refine the vote c0 and say whether the result is trustworthy."""
    sigma = _sigma_m(float(c0[2]), opt)
    tol = max(6 * sigma, 0.005)  # the noise may be up to twice sigma
    f_px = math.sqrt(cam[0] * cam[1])
    margin = (opt.edge_px + 1) / f_px
    # Wide enough for the outline of any centre accepted (R / 2 from the vote); every stride-th pixel,
    # about 20 across the radius: more add time, not accuracy.
    stride = max(1, round(f_px * r_m / float(c0[2]) / 20))
    patch = _patch(view, kept, cam, shape, c0, 1.5 * r_m + tol, stride)
    (c, r, *_), on, noise, could = _refine(patch, c0, r_m, sigma, margin, tol + 2 * voxel_m)
    inl = patch.p[on]
    if not math.isfinite(r):
        return _not_found("the fit failed", votes)
    if len(inl) < 10:
        return _not_found(f"only {len(inl)} points on the sphere's surface", votes, len(inl))
    rms = float(np.sqrt(np.mean((np.linalg.norm(inl - c, axis=1) - r_m) ** 2)))
    fail = None
    if (moved := float(np.linalg.norm(c - c0))) > r_m / 2:
        fail = f"the fit moved {moved * 100:.1f} cm from the vote"
    elif seed is not None and np.linalg.norm(c - seed) > search_m:
        fail = "the fitted centre is outside the gate"
    elif rms > 2 * noise + 0.001:
        fail = f"fit RMS {rms * 1000:.1f} mm is too large for depth noise {noise * 1000:.1f} mm"
    else:
        behind = _see_through(patch, c, r_m, noise, margin)
        visible = len(inl) / max(could, 1)
        if behind > opt.max_see_through_fraction:
            fail = f"{behind:.0%} of the outline shows depth behind the sphere's surface: no sphere of this radius"
        elif visible < opt.min_visible_fraction:
            fail = f"only {visible:.0%} of the visible outline lies on the sphere's surface"
        else:
            fail = _shape_check(patch, c, r_m, noise, margin, opt)
    if fail:
        return _not_found(fail, votes, len(inl), rms)
    return SphereDetection(True, c, votes, len(inl), rms, "ok")


def find_sphere(
    depth_m: np.ndarray,
    fx: float,
    fy: float,
    cx: float,
    cy: float,
    radius_m: float,
    seed_m: np.ndarray | None = None,
    *,
    gate_m: float | None = None,
    options: FinderOptions | None = None,
) -> SphereDetection:
    """Find the centre of a sphere of radius `radius_m` in `depth_m` (H x W, metres along the optical axis).

    seed_m: the kinematic prediction of the centre. Points farther than gate_m (default radius + 0.2 m)
    from it are ignored and the centre is searched within gate_m - radius of it. Without a seed the
    whole map is searched (slower)."""
    opt = options or FinderOptions()
    depth = np.asarray(depth_m, dtype=np.float32)
    if depth.ndim != 2:
        raise ValueError(f"depth map must be 2-D, got shape {depth.shape}")
    if not (radius_m > 0 and math.isfinite(radius_m)):
        raise ValueError(f"radius must be a positive number of metres, got {radius_m}")
    cam = (float(fx), float(fy), float(cx), float(cy))
    f_px = math.sqrt(cam[0] * cam[1])
    shape = depth.shape
    voxel = radius_m * opt.voxel_fraction
    if seed_m is None:
        seed = None
        view = _view(depth, cam, (0, shape[0], 0, shape[1]), opt)
        mask = view.usable
        if not mask.any():
            return _not_found("no depth data")
        x, y, z = view.x[mask], view.y[mask], view.z[mask]
        lo = np.array([x.min(), y.min(), z.min()]) - radius_m
        hi = np.array([x.max(), y.max(), z.max()]) + radius_m
        voxel = max(voxel, float(np.prod(hi - lo) / _MAX_CELLS) ** (1 / 3))
        n = np.ceil((hi - lo) / voxel).astype(int) + 1
        z_ref = float(np.percentile(z, 25))  # the sphere is rather in front of the background
        axis = np.array([0.0, 0.0, 1.0])
        search = math.inf
    else:
        seed = np.asarray(seed_m, dtype=float).reshape(3)
        if not np.all(np.isfinite(seed)):
            raise ValueError(f"seed must be a finite point, got {seed_m}")
        if seed[2] <= 0:
            return _not_found("the seed is behind the camera")
        gate = radius_m + 0.20 if gate_m is None else float(gate_m)
        search = gate - radius_m
        if search <= 0:
            raise ValueError(f"gate {gate} m must be larger than the radius {radius_m} m")
        view = _view(depth, cam, _box(cam, shape, seed, gate), opt)
        d2 = (view.x - seed[0]) ** 2 + (view.y - seed[1]) ** 2 + (view.z - seed[2]) ** 2
        mask = view.usable & (d2 <= gate * gate)
        if not mask.any():
            return _not_found("no depth data within the gate")
        lo = seed - search - voxel
        n = np.full(3, math.ceil(2 * search / voxel) + 3)
        z_ref = max(float(seed[2]), 0.1)
        axis = seed / np.linalg.norm(seed)
    kept = _regions(view, mask, f_px, radius_m, opt)
    if not kept.any():
        return _not_found("no connected region is large enough for the sphere")
    r_px = f_px * radius_m / z_ref
    stride = max(int(r_px / opt.samples_per_radius), math.ceil(math.sqrt(np.count_nonzero(kept) / _MAX_VOTERS)), 1)
    rows, cols = np.nonzero(kept[::stride, ::stride])
    rows, cols = rows * stride, cols * stride
    p = np.stack([view.x[rows, cols], view.y[rows, cols], view.z[rows, cols]], axis=1).astype(float)
    normals = None
    if opt.normal_cone_deg < 90:
        normals = _normals(view, cam, rows, cols, int(np.clip(round(r_px / 6), 1, 4)))
    peaks = _peaks(p, normals, axis, radius_m, lo, voxel, n, opt.candidates * (1 if seed_m is not None else 4), opt)
    if not peaks or peaks[0][1] < opt.min_votes:
        return _not_found("too few votes for any centre", peaks[0][1] if peaks else 0)
    failed = []
    for c0, votes in peaks:
        if votes < opt.min_votes:
            break
        det = _evaluate(view, kept, cam, shape, c0, votes, radius_m, voxel, seed, search, opt)
        if det.found:
            return det
        failed.append(det)
    return failed[0]  # why the best-voted centre is not the sphere
