"""A URDF robot's own look in the review scene: reading its meshes, and what they cost the scene.

    .venv/bin/python benchmarks/robot_look.py [URDF ...] [--frames 40] [--selects 50]

Without URDFs: the meshed arm of tests/test_robot_look.py (an STL, an OBJ, three primitives; a few KB) and
the same arm with a 327,680-triangle sphere as its upper arm (a 16 MB STL), which is thinned to
app.scene.robot_look.MAX_FACES. Any URDF can be given (pybullet's kuka_iiwa/model.urdf, franka_panda/panda.urdf):
each is loaded as a profile with a tracker and a reflector on the last link of its first chain
(benchmarks/urdf_sweep.py). For each: reading the look (time, triangles read and kept, the arrays kept, the
peak of Python allocations while reading, from tracemalloc), then a review of simulated frames on an
in-process viser server (no browser): loading it (both copies, the meshes sent once each) and selecting a
frame (the link frames moved, no mesh sent again), in ms.
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
import tracemalloc
from pathlib import Path

import numpy as np
import trimesh
import viser

HERE = Path(__file__).resolve().parent
sys.path[:0] = [str(HERE), str(HERE.parent / "tests")]
from sim_frames import measured_frames  # noqa: E402
from test_robot_look import meshed_arm  # noqa: E402
from urdf_sweep import chains, load  # noqa: E402

from app.scene import robot_look as looks  # noqa: E402
from app.scene.review import Review  # noqa: E402
from app.scene.review_scene.scene import ReviewScene  # noqa: E402
from calib_core import SimulatedRobot  # noqa: E402
from calib_core.model.urdf_import import read_urdf  # noqa: E402


def measure(urdf: Path, folder: Path, server: viser.ViserServer, frames: int, selects: int) -> None:
    robot = read_urdf(urdf)
    profile = load(urdf, robot, chains(robot)[0][-1], folder)
    looks._looks.clear()  # read anew, as a fresh desk would
    tracemalloc.start()
    t0 = time.perf_counter()
    look = looks.robot_look(profile)
    read_s = time.perf_counter() - t0
    peak_mb = tracemalloc.get_traced_memory()[1] / 2**20
    tracemalloc.stop()
    print(f"{urdf}:")
    if look is None:
        print("  no visuals: simple shapes")
        return
    kept_mb = sum(v.vertices.nbytes + v.faces.nbytes for v in look.visuals) / 2**20
    print(
        f"  read {read_s * 1e3:.0f} ms: {len(look.visuals)} visuals, {look.faces_read:,} triangles read, "
        f"{look.faces:,} kept ({kept_mb:.1f} MB of arrays), Python allocations peaked at {peak_mb:.1f} MB"
    )
    if look.warning:
        print(f"  warning: {look.warning}")
    sim = SimulatedRobot.from_profile(profile, seed=0).simulate(frames)
    review = Review.build(profile, measured_frames(sim.data), sim.data, profile.nominal(), sim.true_params)
    scene = ReviewScene(server)
    t0 = time.perf_counter()
    scene.load(review)
    load_ms = (time.perf_counter() - t0) * 1e3
    rng = np.random.default_rng(0)
    times = []
    for index in rng.choice(review.indices, selects):
        t0 = time.perf_counter()
        scene.select(int(index), aim=False)
        times.append((time.perf_counter() - t0) * 1e3)
    print(
        f"  review of {len(review.indices)} frames loaded in {load_ms:.0f} ms (both copies); select: median "
        f"{np.median(times):.1f} ms, p95 {np.percentile(times, 95):.1f} ms over {selects}"
    )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("urdf", nargs="*", type=Path)
    parser.add_argument("--frames", type=int, default=40)
    parser.add_argument("--selects", type=int, default=50)
    args = parser.parse_args()
    server = viser.ViserServer(host="127.0.0.1", port=0, verbose=False)
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp)
        urdfs = list(args.urdf)
        if not urdfs:
            small = meshed_arm(folder / "small").parent / "urdf" / "arm.urdf"
            big = meshed_arm(folder / "big").parent
            sphere = trimesh.creation.icosphere(subdivisions=7, radius=0.05)
            sphere.export(big / "meshes" / "upper.stl")
            mb = (big / "meshes" / "upper.stl").stat().st_size / 2**20
            print(f"(the big arm's upper arm: {len(sphere.faces):,} triangles, a {mb:.0f} MB STL)")
            urdfs = [small, big / "urdf" / "arm.urdf"]
        for urdf in urdfs:
            measure(urdf, folder, server, args.frames, args.selects)
    server.stop()


if __name__ == "__main__":
    main()
