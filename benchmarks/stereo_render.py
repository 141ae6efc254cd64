"""Render the Robonaut head's stereo pair and measure depth with SGBM on simulated configurations.

    .venv/bin/python benchmarks/stereo_render.py               # 60 configurations
    .venv/bin/python benchmarks/stereo_render.py --n 20 --seed 3

Prints the render and SGBM time per 640 x 480 frame, and the SGBM depth error against the ray caster's
depth on the sphere's interior (pixels more than 3 px inside its visible silhouette) by distance bin:
median and 90th percentile of the absolute error (mm), the median signed error (bias) and the fraction of
interior pixels with a valid depth; also on the sphere's rim (its outer 3 px). And how often the arm hides
the sphere or it reaches into the left band of columns where SGBM gives no depth: the simulator picks
configurations that avoid both (SimulatedRobot.visible), so both counts should be 0.
"""

from __future__ import annotations

import argparse
import statistics
import time

import cv2
import numpy as np

from calib_core import SimulatedRobot, load_profile
from calib_core.vision.stereo import SPHERE, StereoHead, depth_from_pair, no_depth_band_px, render_pair

BINS_M = ((0.4, 0.6), (0.6, 0.8), (0.8, 1.0), (1.0, 1.2))
INNER_PX = 3.0


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--n", type=int, default=60, help="configurations")
    parser.add_argument("--seed", type=int, default=1)
    args = parser.parse_args()

    profile = load_profile("robonaut-a")
    robot = SimulatedRobot.from_profile(profile, seed=args.seed)
    q, _ = robot.configurations(args.n)
    head = StereoHead.from_profile(profile, robot.true_params)
    band_px = no_depth_band_px(head)  # SGBM's largest disparity: the left image's columns without depth
    rng = np.random.default_rng(args.seed)
    render_pair(profile, robot.true_params, q[0], head, rng)  # warm up (texture tables)

    render_s, sgbm_s = [], []
    inner: dict[int, list[np.ndarray]] = {i: [] for i in range(len(BINS_M))}
    inner_count = dict.fromkeys(inner, 0)
    rim: list[np.ndarray] = []
    rim_count = 0
    hidden = in_band = 0
    for row in q:
        t0 = time.perf_counter()
        images = render_pair(profile, robot.true_params, row, head, rng)
        t1 = time.perf_counter()
        depth_m = depth_from_pair(images.left, images.right, head)
        t2 = time.perf_counter()
        render_s.append(t1 - t0)
        sgbm_s.append(t2 - t1)
        sphere = images.object_id == SPHERE
        if sphere.sum() < 50:
            hidden += 1
            continue
        in_band += bool(sphere[:, :band_px].any())
        inside = cv2.distanceTransform(sphere.astype(np.uint8), cv2.DIST_L2, 3) > INNER_PX
        error_m = depth_m - images.depth_true
        z_m = float(np.median(images.depth_true[sphere]))
        b = next((i for i, (lo, hi) in enumerate(BINS_M) if lo <= z_m < hi), None)
        if b is not None:
            inner[b].append(error_m[inside])
            inner_count[b] += 1
        rim.append(error_m[sphere & ~inside])
        rim_count += 1

    print(f"robonaut-a stereo head, {len(q)} configurations (seed {args.seed}), 640 x 480")
    print(
        f"  render {1e3 * statistics.median(render_s):.0f} ms, SGBM {1e3 * statistics.median(sgbm_s):.0f} ms "
        f"per frame (median); render + SGBM {1e3 * statistics.median(np.add(render_s, sgbm_s)):.0f} ms"
    )
    print(f"  sphere hidden (< 50 px visible: the arm in front): {hidden} of {len(q)} configurations")
    print(f"  sphere partly in the leftmost {band_px} columns (no SGBM depth there): {in_band}")
    print("  SGBM depth error on the sphere interior (> 3 px inside the silhouette), mm:")
    print("    distance     frames   median |e|   p90 |e|   bias   valid")
    for b, (lo, hi) in enumerate(BINS_M):
        print(f"    {100 * lo:3.0f}-{100 * hi:3.0f} cm  " + _row(inner[b], inner_count[b]))
    print("    all          " + _row([e for es in inner.values() for e in es], sum(inner_count.values())))
    print("    rim (outer 3 px) " + _row(rim, rim_count)[4:])


def _row(errors: list[np.ndarray], frames: int) -> str:
    if not errors:
        return f"{frames:6d}        -          -        -       -"
    e = np.concatenate(errors)
    ok = e[np.isfinite(e)]
    if not len(ok):
        return f"{frames:6d}        -          -        -    0.00"
    mm = 1e3 * ok
    return (
        f"{frames:6d}   {np.median(np.abs(mm)):8.2f}   {np.percentile(np.abs(mm), 90):7.2f}  "
        f"{np.median(mm):+6.2f}   {len(ok) / len(e):5.2f}"
    )


if __name__ == "__main__":
    main()
