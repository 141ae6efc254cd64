"""Replay planning: how long planning N new NAO configurations takes, and how long the replay request waits.

    .venv/bin/python benchmarks/replay_plan.py [--counts 1 10 50 200] [--robot nao]

In-process (FastAPI's TestClient, the simulated robots at 50x speed): `Desk.replay_plan` alone (the
simulator's stance sampling, each stance aimed at the board, with the active calibration), the dry run
(which plans and checks, and answers with every configuration), and the POST that starts a replay (its
job is cancelled at once).
"""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

from fastapi.testclient import TestClient

from app.server import create_app
from app.services.replay import ReplayPlan


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--counts", type=int, nargs="+", default=[1, 10, 50, 200])
    parser.add_argument("--robot", default="nao")
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as tmp, TestClient(create_app(Path(tmp), time_scale=50.0)) as client:
        desk = client.app.state.desk
        sid = client.post("/api/sessions", json={"robot": args.robot, "name": "plan"}).json()["id"]
        url = f"/api/sessions/{sid}/replay"
        desk.replay.configurations(sid, ReplayPlan(count=1))  # warm-up
        print(f"{args.robot}: planning N new configurations (ms; per configuration in brackets)")
        for count in args.counts:
            t0 = time.perf_counter()
            q, _, _ = desk.replay.configurations(sid, ReplayPlan(count=count, seed=count))
            plan_ms = 1e3 * (time.perf_counter() - t0)
            t0 = time.perf_counter()
            r = client.post(url, json={"count": count, "seed": count, "dry_run": True})
            dry_ms = 1e3 * (time.perf_counter() - t0)
            assert r.status_code == 200, r.text
            t0 = time.perf_counter()
            r = client.post(url, json={"count": count, "seed": count})
            start_ms = 1e3 * (time.perf_counter() - t0)
            assert r.status_code == 202, r.text
            client.post(f"/api/jobs/{r.json()['job']}/cancel")
            print(
                f"  N={count:4d}: replay_plan {plan_ms:7.0f} ({plan_ms / len(q):5.1f})  dry run {dry_ms:7.0f}  "
                f"start replay (request) {start_ms:7.1f}"
            )


if __name__ == "__main__":
    main()
