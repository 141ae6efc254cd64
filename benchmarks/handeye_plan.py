"""A hand-eye set-up's workspace-wide plan: the time and memory of `plan` once the poses are fitted on measured frames.

    .venv/bin/python benchmarks/handeye_plan.py --configurations 12 --seeds 3

The sample arm (a wrist camera, a ChArUco board on the table, both poses unknown to the profile): a first day of
`--frames` configurations simulated and measured, the poses fitted on them in closed form (`register`, what the
desk does before a first calibration), then `--configurations` planned over the whole workspace for the
`handeye` mode, per seed. Printed per seed: wall and CPU seconds, the candidates found, the planner's predicted
error; at the end the process's peak memory. Uniform draws see the board in about 1 of 400 configurations here.
"""

from __future__ import annotations

import argparse
import resource
import time

from calib_core import SimulatedRobot, load_profile
from calib_core.estimation import plan, register


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--configurations", type=int, default=12)
    parser.add_argument("--frames", type=int, default=8, help="measured frames the poses are fitted on")
    parser.add_argument("--seeds", type=int, default=3)
    args = parser.parse_args()
    profile = load_profile("arm-handeye")
    robot = SimulatedRobot.from_profile(profile, seed=3)
    q, targets = robot.configurations(args.frames)
    p = register(profile, robot.measure(q, targets).data, profile.nominal())
    print(f"arm-handeye, poses fitted on {args.frames} frames, {args.configurations} configurations planned (handeye)")
    print("seed  wall s  cpu s  candidates  predicted")
    for seed in range(args.seeds):
        wall, cpu = time.perf_counter(), time.process_time()
        made = plan(profile, "handeye", args.configurations, p, seed=seed)
        wall, cpu = time.perf_counter() - wall, time.process_time() - cpu
        predicted = f"{made.predicted.mean:.4f} {made.predicted.unit}"
        print(f"{seed:4d}  {wall:6.2f}  {cpu:5.2f}  {made.candidates:10d}  {predicted}")
    peak_mb = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    print(f"peak memory {peak_mb:.0f} MB")


if __name__ == "__main__":
    main()
