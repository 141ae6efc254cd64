"""Review scene: how long selecting a frame takes in the server, for a 1000-frame Robonaut session.

    .venv/bin/python benchmarks/dashboard_scene.py [--frames 1000] [--selects 300] [--robot robonaut-a]

Simulates the session's measurements (no rendering), builds the Review (old = nominal, new = the
simulator's truth), loads it into a ReviewScene on an in-process viser server (port 0, no browser)
and times `select(index)` over many random frames, side by side and in the overlay: the server's
share of "slider moved -> scene updated" (the issue's target: at most 50 ms). Also the build and
load times, which happen once per (session, old, new).
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np
import viser

sys.path.insert(0, str(Path(__file__).resolve().parent.parent / "tests"))
from sim_frames import measured_frames

from app.scene.review import Review
from app.scene.review_scene.scene import ReviewScene
from calib_core import SimulatedRobot, load_profile


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--frames", type=int, default=1000)
    parser.add_argument("--selects", type=int, default=300)
    parser.add_argument("--robot", default="robonaut-a")
    args = parser.parse_args()

    profile = load_profile(args.robot)
    sim = SimulatedRobot.from_profile(profile, seed=0).simulate(args.frames)
    data = sim.data
    frames = measured_frames(data)

    start = time.perf_counter()
    review = Review.build(profile, frames, data, profile.nominal(), sim.true_params)
    build_ms = 1e3 * (time.perf_counter() - start)

    server = viser.ViserServer(host="127.0.0.1", port=0, verbose=False)
    try:
        scene = ReviewScene(server)
        start = time.perf_counter()
        scene.load(review)
        load_ms = 1e3 * (time.perf_counter() - start)
        rng = np.random.default_rng(0)
        indices = rng.choice(review.indices, args.selects)
        print(f"{args.robot}: {len(frames)} frames, {data.n_observations} observations")
        print(f"  Review.build {build_ms:.0f} ms, ReviewScene.load {load_ms:.0f} ms (once per session and pair)")
        for overlay in (False, True):
            scene.set_overlay(overlay)
            times_ms = []
            for index in indices:
                start = time.perf_counter()
                scene.select(int(index))
                times_ms.append(1e3 * (time.perf_counter() - start))
            t = np.array(times_ms)
            label = "overlay     " if overlay else "side by side"
            print(
                f"  select() {label}: median {np.median(t):.1f} ms, p95 {np.percentile(t, 95):.1f} ms, "
                f"max {t.max():.1f} ms over {len(t)} selects"
            )
    finally:
        server.stop()


if __name__ == "__main__":
    main()
