"""The CPU of writing a dataset in its robot's CSV format (calib_core.io `to_csv`: every `calib simulate`, a day of
`calib simulate --days`, a session folder's data.csv), this checkout and, in the same run, an earlier commit.

    .venv/bin/python benchmarks/csv_write.py [--writes 5] [--against COMMIT]

Each checkout, in a process of its own with one BLAS thread, simulates each built-in robot (seed 1, the
configurations `calib simulate` draws by default) and writes its CSV `--writes` times; printed per robot: the mean
CPU of a write in ms, and whether both checkouts wrote the same text (its sha256).
"""

from __future__ import annotations

from checkouts import against_parser, alternating, compared

WRITE = """
import hashlib, json, sys, time
from calib_core import SimulatedRobot, load_profile
from calib_core.io import to_csv
out = {}
for name in ("robonaut-a", "nao", "motoman", "arm-handeye"):
    profile = load_profile(name)
    data = SimulatedRobot.from_profile(profile, seed=1).simulate().data
    start = time.process_time()
    for _ in range(int(sys.argv[1])):
        text = to_csv(profile, data)
    ms = (time.process_time() - start) / int(sys.argv[1]) * 1000
    out[name] = [data.n_observations, ms, hashlib.sha256(text.encode()).hexdigest()]
print(json.dumps(out))
"""


def main() -> None:
    ap = against_parser(__doc__)
    ap.add_argument("--writes", type=int, default=5)
    args = ap.parse_args()
    with compared(args.against) as trees:
        got = {name: runs[0] for name, runs in alternating(trees, 1, WRITE, str(args.writes)).items()}
    for robot, (n, _, digest) in got["this checkout"].items():
        same = all(g[robot][2] == digest for g in got.values())
        print(f"{robot:12s} " + "  ".join(f"{name}: {g[robot][1]:6.1f} ms" for name, g in got.items()),
              f"({n} observations; {'the same text' if same else 'TEXTS DIFFER'})")  # fmt: skip


if __name__ == "__main__":
    main()
