"""The CPU of drawing configurations in view (calib_core.vision: `Sampler.configurations`, what the simulated robots,
`calib simulate`, a random replay and a desk's start ask for), this checkout and, in the same run, an earlier commit.

    .venv/bin/python benchmarks/visibility.py [--seeds 20] [--runs 3] [--against COMMIT]

Per built-in robot: `--seeds` draws each of 1, 8 and 30 configurations (seeds 0, 1, ...; the robot's true model for
odd seeds, its nominal one for even ones), in a process of its own with one BLAS thread, `--runs` times, one
checkout after the other, alternating. Printed: the median of the runs' CPU seconds, and whether both checkouts
drew the same configurations and left the random stream in the same state (a digest of the draws, of the refusals'
messages and of the stream's next numbers).
"""

from __future__ import annotations

import statistics

from checkouts import against_parser, alternating, compared

DRAW = """
import hashlib, json, sys, time
import numpy as np
from calib_core import load_profile
from calib_core.errors import InputError
from calib_core.sim import SimulatedRobot
from calib_core.vision import Visibility
from calib_core.vision.sampling import Sampler
profile = load_profile(sys.argv[1])
truth = SimulatedRobot.from_profile(profile, seed=0).true_params
digest, cpu = hashlib.sha256(), 0.0
for seed in range(int(sys.argv[2])):
    for n in (1, 8, 30):
        rng = np.random.default_rng(seed)
        view = Visibility(profile, truth if seed % 2 else profile.nominal())
        start = time.process_time()
        try:
            q, targets = Sampler(view, rng).configurations(n)
        except InputError as exc:
            digest.update(str(exc).encode())
        else:
            digest.update(q.tobytes() + targets.tobytes())
        cpu += time.process_time() - start
        digest.update(rng.random(3).tobytes())
print(json.dumps({"cpu": cpu, "digest": digest.hexdigest()[:16]}))
"""


def main() -> None:
    ap = against_parser(__doc__)
    ap.add_argument("--seeds", type=int, default=20)
    ap.add_argument("--runs", type=int, default=3)
    args = ap.parse_args()
    with compared(args.against) as trees:
        for robot in ("robonaut-a", "nao", "motoman", "arm-handeye"):
            got = alternating(trees, args.runs, DRAW, robot, str(args.seeds))
            for name, runs in got.items():
                cpu = statistics.median(r["cpu"] for r in runs)
                print(f"{robot:12s} {name:14s} {cpu:6.2f} s CPU, draws {runs[0]['digest']}", flush=True)
            if len(got) == 2:
                a, b = (runs[0]["digest"] for runs in got.values())
                print(f"{robot:12s} the same draws and stream: {a == b}", flush=True)


if __name__ == "__main__":
    main()
