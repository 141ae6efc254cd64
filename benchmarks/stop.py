"""How long STOP takes to answer with a robot hung in a call (issue 36): a `calib serve --naoqi` desk and a simulated
NAO served over libqi by `calib sim-naoqi`, each in its own process, as an operator runs them. The NAO is driven
through a replay; then its fault harness makes every call hang (CalibSim.fault("hang")), as a NAOqi that is stuck
or a network that drops packets without a reset. Measured, on the wall clock of this process:

- STOP (`POST /api/robot/stop`) with the robot answering, then with it hung: the time to the answer, and what it
  says of nao-3;
- the replay's cancel (`POST /api/jobs/{id}/cancel`) with the robot hung: the time until the job has ended;
- the robot's state once it answers again (the fault cleared).

    .venv/bin/python benchmarks/stop.py [--runs 10]
"""

from __future__ import annotations

import argparse
import socket
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import httpx

ROOT = Path(__file__).resolve().parent.parent
CALIB = str(Path(sys.executable).parent / "calib")


def _port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def _until(ok, what: str, timeout_s: float = 60.0) -> None:
    deadline = time.monotonic() + timeout_s
    while not ok():
        if time.monotonic() > deadline:
            raise SystemExit(f"not within {timeout_s:g} s: {what}")
        time.sleep(0.02)


def _timed_stops(client: httpx.Client, runs: int) -> tuple[list[float], dict]:
    """ms to each STOP's answer, and the last answer's entry for nao-3."""
    times, entry = [], {}
    for _ in range(runs):
        t0 = time.perf_counter()
        answer = client.post("/robot/stop").json()
        times.append((time.perf_counter() - t0) * 1000)
        entry = next(s for s in answer["stops"] if s["robot"] == "nao-3")
        time.sleep(0.1)
    return times, entry


def _figures(times: list[float]) -> str:
    return f"median {statistics.median(times):.0f} ms, max {max(times):.0f} ms over {len(times)}"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--runs", type=int, default=10, help="STOPs timed in each state (default 10)")
    args = parser.parse_args()
    import qi

    folder = Path(tempfile.mkdtemp(prefix="stop-bench-"))
    url, port = f"tcp://127.0.0.1:{_port()}", _port()
    conn = folder / "nao-3.yaml"
    sim = subprocess.Popen(
        [CALIB, "sim-naoqi", "--url", url, "--speed", "8", "--name", "nao-3", "--connection-out", str(conn)],
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
    )
    desk = None
    try:
        _until(conn.exists, "calib sim-naoqi listening")
        serve = [CALIB, "serve", "--port", str(port), "--data-dir", str(folder / "data"), "--naoqi", str(conn)]
        desk = subprocess.Popen(serve, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, cwd=ROOT)
        with httpx.Client(base_url=f"http://127.0.0.1:{port}/api", timeout=120) as client:

            def answers() -> bool:
                try:
                    return client.get("/robot", params={"robot": "nao-3"}).json().get("connected") is True
                except httpx.HTTPError:
                    return False

            _until(answers, "the desk answering with nao-3 connected", 120)
            client.post("/robot/connect", json={"robot": "nao-3"})
            healthy, entry = _timed_stops(client, args.runs)
            print(f"STOP, nao-3 answering: {_figures(healthy)}; nao-3: {entry['message']}")

            sid = client.post("/sessions", json={"robot": "nao-3", "name": "stop benchmark"}).json()["id"]
            job = client.post(f"/sessions/{sid}/replay", json={"count": 20, "planner": "random"}).json()["job"]
            _until(lambda: client.get(f"/jobs/{job}").json()["detail"].get("done", 0) >= 1, "a frame captured")
            session = qi.Session()
            session.connect(url)
            session.service("CalibSim").fault("hang", 0)  # every call hangs from now
            time.sleep(0.3)  # a call is under way and hung by now, within its 2-s deadline and the 1-s readings' limit
            t0 = time.perf_counter()
            client.post(f"/jobs/{job}/cancel")
            _until(lambda: client.get(f"/jobs/{job}").json()["state"] != "running", "the replay ending", 30)
            ended = client.get(f"/jobs/{job}").json()
            frames = len(client.get(f"/sessions/{sid}").json()["frames"])
            print(
                f"cancel of the replay, nao-3 hung in a call: ended {ended['state']} after "
                f"{(time.perf_counter() - t0) * 1000:.0f} ms, {frames} frames kept ({ended['error'] or 'no error'})"
            )
            time.sleep(1.0)  # past the readings' limit
            hung, entry = _timed_stops(client, args.runs)
            print(f"STOP, nao-3 hung in a call: {_figures(hung)}; nao-3: {entry['message']}")
            state = client.get("/robot", params={"robot": "nao-3"}).json()
            print(f"nao-3's state: {state['message']}")

            session.service("CalibSim").fault("", 0)
            session.close()
            _until(answers, "nao-3 answering again", 30)
            back, entry = _timed_stops(client, 3)
            print(f"once it answers again: {_figures(back)}; nao-3: {entry['message']}")
    finally:
        for proc in (desk, sim):
            if proc is not None:
                proc.terminate()
                proc.wait(30)


if __name__ == "__main__":
    main()
