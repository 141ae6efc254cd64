"""A big import and its calibration, end to end through `calib serve` (issue 13, bounded work): how long
the import and the start of a calibration take, how long the calibration job runs, and the peak memory of
the server with its worker processes.

    .venv/bin/python benchmarks/big_session.py                  # 96,000 simulated Robonaut frames
    .venv/bin/python benchmarks/big_session.py --rows 5000 --timeout 120
    .venv/bin/python benchmarks/big_session.py --cancel-after 20   # how soon a cancel ends the job

Samples the resident memory of the server and every process under it every 0.1 s. Stops (and says so) when
the calibration has not ended after --timeout seconds or the processes pass --max-gb together.
"""

from __future__ import annotations

import argparse
import io
import sys
import tempfile
import threading
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent.parent / "tests"))
import httpx
from browser import served

from calib_core import SimulatedRobot, load_profile, to_csv


def tree_rss_mb(pid: int) -> float:
    """Resident memory of a process and all its descendants, MB."""
    parents: dict[int, int] = {}
    rss: dict[int, float] = {}
    for proc in Path("/proc").iterdir():
        if not proc.name.isdigit():
            continue
        try:
            fields = (proc / "stat").read_text().rsplit(")", 1)[1].split()
            status = (proc / "status").read_text()
        except OSError:
            continue
        parents[int(proc.name)] = int(fields[1])
        for line in status.splitlines():
            if line.startswith("VmRSS:"):
                rss[int(proc.name)] = int(line.split()[1]) / 1024
    total, todo = 0.0, [pid]
    while todo:
        p = todo.pop()
        total += rss.get(p, 0.0)
        todo.extend(c for c, parent in parents.items() if parent == p)
    return total


class PeakMemory:
    """The peak of tree_rss_mb(pid), sampled on a thread; `over` is set once it passes `limit_mb`."""

    def __init__(self, pid: int, limit_mb: float) -> None:
        self.pid, self.limit_mb = pid, limit_mb
        self.peak_mb = 0.0
        self.over = threading.Event()
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._thread.start()

    def reset(self) -> None:
        self.peak_mb = tree_rss_mb(self.pid)

    def _run(self) -> None:
        while not self._stop.wait(0.1):
            now = tree_rss_mb(self.pid)
            self.peak_mb = max(self.peak_mb, now)
            if now > self.limit_mb:
                self.over.set()

    def stop(self) -> None:
        self._stop.set()
        self._thread.join()


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--rows", type=int, default=96_000, help="simulated Robonaut frames (one CSV row each)")
    ap.add_argument("--mode", default="full")
    ap.add_argument("--holdout", type=float, default=0.2)
    ap.add_argument("--timeout", type=float, default=300.0, help="give up on the calibration after this, s")
    ap.add_argument("--max-gb", type=float, default=8.0, help="give up when the processes pass this, GB")
    ap.add_argument("--cancel-after", type=float, help="cancel the calibration this long after it started, s")
    args = ap.parse_args()

    profile = load_profile("robonaut-a")
    sim = SimulatedRobot.from_profile(profile, seed=5).simulate(args.rows)
    csv = to_csv(profile, sim.data).encode()
    print(f"{args.rows} frames of robonaut-a: CSV of {len(csv) / 1e6:.1f} MB")
    with tempfile.TemporaryDirectory() as tmp, served(Path(tmp) / "data", timeout_s=180) as server:
        pid = server.process.pid
        time.sleep(2.0)  # the worker process warms up
        memory = PeakMemory(pid, args.max_gb * 1024)
        print(f"server started: {tree_rss_mb(pid):.0f} MB (server and workers)")
        try:
            memory.reset()
            t0 = time.perf_counter()
            r = server.post(
                "/api/sessions/import",
                data={"robot": "robonaut-a", "name": f"{args.rows} frames"},
                files={"data": ("big.csv", io.BytesIO(csv), "text/csv")},
            )
            took = time.perf_counter() - t0
            print(f"import: {r.status_code} in {took:.2f} s, peak {memory.peak_mb:.0f} MB; {r.text[:200]}")
            if r.status_code != 201:
                return
            sid = r.json()["id"]

            memory.reset()
            t0 = time.perf_counter()
            body = {"mode": args.mode, "holdout": args.holdout}
            try:
                r = httpx.post(f"{server.url}/api/sessions/{sid}/calibrations", json=body, timeout=args.timeout)
            except Exception as exc:  # the request itself may never come back
                print(f"start of the calibration: no answer after {time.perf_counter() - t0:.1f} s ({exc!r})")
                print(f"  peak {memory.peak_mb:.0f} MB")
                return
            print(
                f"start of the calibration: {r.status_code} in {time.perf_counter() - t0:.2f} s, "
                f"peak {memory.peak_mb:.0f} MB; {r.text[:200]}"
            )
            if r.status_code != 202:
                return
            job = r.json()["job"]
            cancelled_at = None
            while True:
                if (
                    args.cancel_after is not None
                    and cancelled_at is None
                    and time.perf_counter() - t0 > args.cancel_after
                ):
                    cancelled_at = time.perf_counter()
                    server.post(f"/api/jobs/{job}/cancel")
                snap = server.get(f"/api/jobs/{job}").json()
                if snap["state"] not in ("queued", "running"):
                    break
                if memory.over.is_set() or time.perf_counter() - t0 > args.timeout:
                    why = "memory limit" if memory.over.is_set() else "time limit"
                    server.post(f"/api/jobs/{job}/cancel")
                    print(f"calibration stopped by the benchmark ({why}) after {time.perf_counter() - t0:.1f} s")
                    break
                time.sleep(0.2)
            snap = server.get(f"/api/jobs/{job}").json()
            if cancelled_at is not None:
                print(
                    f"cancelled {args.cancel_after:g} s after the start: "
                    f"ended {time.perf_counter() - cancelled_at:.2f} s later"
                )
            print(
                f"calibration job: {snap['state']} after {time.perf_counter() - t0:.1f} s, "
                f"peak {memory.peak_mb:.0f} MB (server and workers); error: {snap['error']}; "
                f"iterations {snap['detail'].get('iterations')}"
            )
        finally:
            memory.stop()


if __name__ == "__main__":
    main()
