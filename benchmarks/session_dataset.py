"""The CPU of reading a stored session as a calib_core Dataset (`SessionRepository.dataset`: every calibration, review,
apply and replay of a session reads it), this checkout and, in the same run, an earlier commit.

    .venv/bin/python benchmarks/session_dataset.py [--reads 5] [--against COMMIT]

Each checkout, in a process of its own with one BLAS thread, imports the sample sessions into a new store and reads
each one `--reads` times; printed per session: its observations and the mean CPU of a read, in ms.
"""

from __future__ import annotations

from checkouts import against_parser, alternating, compared

READ = """
import json, sys, tempfile, time
from pathlib import Path
from calib_core import load_profile
from app.store import Store
from app.store.importers import ensure_samples
store = Store(Path(tempfile.mkdtemp()))
out = {}
for name in sorted(ensure_samples(store, Path(sys.argv[1]) / "sample_sessions")):
    profile = load_profile(store.sessions.get(name).robot)
    start = time.process_time()
    for _ in range(int(sys.argv[2])):
        data = store.sessions.dataset(name, profile)
    out[name] = [data.n_observations, (time.process_time() - start) / int(sys.argv[2]) * 1000]
print(json.dumps(out))
"""


def main() -> None:
    ap = against_parser(__doc__)
    ap.add_argument("--reads", type=int, default=5)
    args = ap.parse_args()
    with compared(args.against) as trees:
        got = {name: runs[0] for name, runs in alternating(trees, 1, READ, "{tree}", str(args.reads)).items()}
    for session in next(iter(got.values())):
        print(f"{session:20s} " + "  ".join(f"{name}: {g[session][1]:6.1f} ms" for name, g in got.items()),
              f"({got['this checkout'][session][0]} observations)")  # fmt: skip


if __name__ == "__main__":
    main()
