"""Replay planning: how long planning N new configurations takes, and how long the requests wait.

    .venv/bin/python benchmarks/replay_plan.py [--counts 1 10 50 200] [--robot nao]
    .venv/bin/python benchmarks/replay_plan.py --robot robonaut-a --counts 300

In-process (FastAPI's TestClient, the simulated robots at 50x speed): `ReplayService.configurations` alone
(the plan), the dry run of the same count with another seed (its request, which answers 202 with a job, and
the job, which plans, checks and predicts), a cancel of such a dry run once it has chosen its first
configuration (until its job has ended), and the POST that starts a replay (its job is cancelled at once).
"""

from __future__ import annotations

import argparse
import tempfile
import time
from collections.abc import Callable
from pathlib import Path

from fastapi.testclient import TestClient

from app.jobs.snapshot import JobSnapshot
from app.services.replay import ReplayPlan
from app.web.server import create_app


def wait(client: TestClient, job: str, ok: Callable[[JobSnapshot], bool]) -> JobSnapshot:
    """The job's snapshot once `ok` holds or it has ended, woken by each change of the job."""
    jobs = client.app.state.desk.jobs
    snap = jobs.get(job)
    while not ok(snap) and not snap.state.finished:
        snap = jobs.wait_version(job, snap.version, 60.0)
    return snap


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
        print(f"{args.robot}: N new configurations (ms; per configuration in brackets)")
        for count in args.counts:
            t0 = time.perf_counter()
            q, _, _ = desk.replay.configurations(sid, ReplayPlan(count=count, seed=count))
            plan_ms = 1e3 * (time.perf_counter() - t0)
            t0 = time.perf_counter()
            r = client.post(url, json={"count": count, "seed": count + 1, "dry_run": True})
            dry_ms = 1e3 * (time.perf_counter() - t0)
            assert r.status_code == 202, r.text
            job = wait(client, r.json()["job"], lambda j: False)
            assert job.state == "done", job
            job_ms = 1e3 * (time.perf_counter() - t0)
            r = client.post(url, json={"count": count, "seed": count + 2, "dry_run": True})
            wait(client, r.json()["job"], lambda j: j.detail.get("stage") == "choosing")
            t0 = time.perf_counter()
            client.post(f"/api/jobs/{r.json()['job']}/cancel")
            job = wait(client, r.json()["job"], lambda j: False)
            cancel_ms = 1e3 * (time.perf_counter() - t0)
            assert job.state in ("cancelled", "done"), job
            t0 = time.perf_counter()
            r = client.post(url, json={"count": count, "seed": count})
            start_ms = 1e3 * (time.perf_counter() - t0)
            assert r.status_code == 202, r.text
            client.post(f"/api/jobs/{r.json()['job']}/cancel")
            print(
                f"  N={count:4d}: plan {plan_ms:7.0f} ({plan_ms / len(q):5.1f})  dry run: request {dry_ms:5.1f}, "
                f"job {job_ms:7.0f}, cancel {cancel_ms:5.1f} ({job['state']})  start replay (request) {start_ms:5.1f}"
            )


if __name__ == "__main__":
    main()
