"""How long a desk takes to start and to stop (issue 23, the suite's time: the tests start about 40), and a Robonaut
full calibration's time (the Monte Carlo tests run 400 of them).

- start: `calib serve` on a new data directory (the sample sessions imported) or on one a desk has started in
  before, from launching the command to /api/health answering; the CPU of the desk and of its job workers then;
- stop: from SIGINT to the process's end;
- calibrate: a full calibration of 67 simulated Robonaut configurations, in-process (the median of the runs).

    .venv/bin/python benchmarks/desk_start.py [--runs 5]
"""

from __future__ import annotations

import argparse
import resource
import shutil
import signal
import socket
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import httpx
import numpy as np

ROOT = Path(__file__).resolve().parent.parent


def _port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def _children_cpu_s() -> float:
    r = resource.getrusage(resource.RUSAGE_CHILDREN)
    return r.ru_utime + r.ru_stime


def desk(data_dir: Path) -> tuple[float, float, float]:
    """(start s, stop s, CPU s of the desk's whole life) of one `calib serve` on data_dir."""
    port = _port()
    cpu0, t0 = _children_cpu_s(), time.perf_counter()
    proc = subprocess.Popen(
        [str(Path(sys.executable).parent / "calib"), "serve", "--port", str(port), "--data-dir", str(data_dir)],
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
        cwd=ROOT,
    )
    with httpx.Client() as client:
        while True:
            try:
                if client.get(f"http://127.0.0.1:{port}/api/health").status_code == 200:
                    break
            except httpx.HTTPError:
                if proc.poll() is not None:
                    raise SystemExit("calib serve exited") from None
            time.sleep(0.01)
    started = time.perf_counter()
    proc.send_signal(signal.SIGINT)
    proc.wait(timeout=30)
    return started - t0, time.perf_counter() - started, _children_cpu_s() - cpu0


def calibrate_ms(runs: int) -> float:
    from calib_core import SimulatedRobot, calibrate, load_profile

    rn = load_profile("robonaut-a")
    data = [SimulatedRobot.from_profile(rn, seed=10_000 + s).simulate(67).data for s in range(runs)]
    calibrate(rn, data[0], "full")  # its imports
    times = []
    for d in data:
        t0 = time.perf_counter()
        calibrate(rn, d, "full")
        times.append(time.perf_counter() - t0)
    return 1000 * float(np.median(times))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--runs", type=int, default=5)
    args = ap.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        fresh = [desk(Path(tmp) / f"fresh-{k}") for k in range(args.runs)]
        again = []
        for k in range(args.runs):
            shutil.copytree(Path(tmp) / "fresh-0", Path(tmp) / f"again-{k}")
            again.append(desk(Path(tmp) / f"again-{k}"))
    load = Path("/proc/loadavg").read_text().split()[0]
    print(f"calib serve, {args.runs} runs each, load average {load} (medians):")
    for name, runs in (("new data directory", fresh), ("started in before", again)):
        start, stop, cpu = np.median(np.array(runs), axis=0)
        print(f"  {name}: start {start:.2f} s, stop {stop:.2f} s, CPU {cpu:.2f} s")
    print(f"robonaut-a full calibration, 67 configurations: {calibrate_ms(4 * args.runs):.1f} ms")


if __name__ == "__main__":
    main()
