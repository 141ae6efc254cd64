"""BallFinder on synthetic depth maps: centre error by distance and depth noise, detection rate, time.

    .venv/bin/python benchmarks/ballfinder.py              # 40 scenes per distance bin and noise level
    .venv/bin/python benchmarks/ballfinder.py --scenes 10  # quicker

The scenes are calib_core.depth_scenes' (also the tests'): a 4 cm sphere on a forearm, a table under it
(touching it in half the scenes) and a wall behind, seen by a 640 x 480, f = 525 px camera, with
depth noise growing with z^2 ("nominal": 5.3 mm at 1 m, a 9 cm baseline and 0.25 px of disparity
noise; the finder is always configured for nominal), the sphere's outline fattened by 1-2 px with its
own depth and 3% of the pixels missing. The seed (the kinematic prediction) is up to 15 cm off. A
gross miss is a centre more than 1 cm off. Times are the median of one call (wall clock, one thread of
this 2-core machine), without rendering. Then the same with the paper's voting (the whole hemisphere,
no normals), without a seed, and how often something is found where it must not be.
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from calib_core.vision.ballfinder import FinderOptions
from calib_core.vision.depth_scenes import RADIUS_M, case, detect, random_centre, render, seed_near

BINS_M = ((0.4, 0.6), (0.6, 0.8), (0.8, 1.0), (1.0, 1.2))
NOISE = {"none": 0.0, "nominal": 1.0, "2x": 2.0}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--scenes", type=int, default=40, help="scenes per distance bin and noise level")
    args = ap.parse_args()
    rng = np.random.default_rng(2024)
    print(f"{'distance':>10} {'noise':>8} {'found':>7} {'median':>7} {'p90':>7} {'max':>7} {'gross':>6} {'time':>6}")
    print(f"{'cm':>10} {'':>8} {'':>7} {'mm':>7} {'mm':>7} {'mm':>7} {'>1cm':>6} {'ms':>6}")
    seeded_ms = []
    for noise_name, noise in NOISE.items():
        for lo, hi in BINS_M:
            errors, n, ms = _run(rng, args.scenes, noise, (lo, hi), seeded=True)
            seeded_ms += ms
            print(_row(f"{lo * 100:.0f}-{hi * 100:.0f}", noise_name, errors, n, ms))
    print(f"all seeded: median {np.median(seeded_ms):.1f} ms, 90th percentile {np.percentile(seeded_ms, 90):.1f} ms")
    paper = FinderOptions(normal_cone_deg=90, directions=48)
    print(_row("40-120", "paper", *_run(rng, 4 * args.scenes, 1.0, (0.4, 1.2), seeded=True, options=paper)))
    print(_row("40-120", "no seed", *_run(rng, args.scenes, 1.0, (0.4, 1.2), seeded=False)))
    print("found where it must not be (nominal noise, 40-120 cm, with a seed 15 cm off / without a seed):")
    for name, kw, radius in (
        ("no sphere (forearm, table, wall)", {"sphere": False}, RADIUS_M),
        ("sphere behind a plate", {"occluder": True}, RADIUS_M),
        ("radius asked 1.5x too large", {}, 1.5 * RADIUS_M),
        ("radius asked 2x too small", {}, 0.5 * RADIUS_M),
    ):
        found = [0, 0]
        for _ in range(args.scenes):
            c = random_centre(rng)
            depth = render(rng, [c], table_drop_m=float(rng.choice([0.0, 0.1])), **kw)
            found[0] += detect(depth, seed_near(rng, c), radius).found
            found[1] += detect(depth, None, radius).found
        print(f"  {name:<34} {found[0]:>3}/{args.scenes} {found[1]:>3}/{args.scenes}")


def _run(
    rng: np.random.Generator,
    n: int,
    noise: float,
    z_m: tuple[float, float],
    *,
    seeded: bool,
    options: FinderOptions | None = None,
) -> tuple[list[float], int, list[float]]:
    errors, ms = [], []
    for _ in range(n):
        depth, centre, seed = case(rng, noise=noise, z_m=z_m)
        t0 = time.perf_counter()
        det = detect(depth, seed if seeded else None, options=options)
        ms.append((time.perf_counter() - t0) * 1000)
        if det.found:
            errors.append(float(np.linalg.norm(det.center_m - centre)) * 1000)
    return errors, n, ms


def _row(distance: str, noise: str, errors: list[float], n: int, ms: list[float]) -> str:
    e = np.array(errors) if errors else np.array([np.nan])
    return (
        f"{distance:>10} {noise:>8} {len(errors):>3}/{n:<3} {np.median(e):>7.2f} {np.percentile(e, 90):>7.2f} "
        f"{e.max():>7.2f} {int(np.sum(e > 10)):>6} {np.median(ms):>6.1f}"
    )


if __name__ == "__main__":
    main()
