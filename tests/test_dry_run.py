"""The dry run of new configurations runs as a job (the request used to plan them itself: 300 Robonaut
configurations took 44.7 s, 2,000 did not answer in 400 s and went on after the client left). The request
answers at once with the job; the job reports each configuration it chooses, a cancel (the jobs API, STOP)
ends it within a step, its result is what the synchronous dry run answers, and the replay after it drives the
plan it checked. The API in-process, and the page's Replay step in a real browser."""

from __future__ import annotations

import json
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest
from desk_jobs import wait_for
from fastapi.testclient import TestClient

from app.jobs.snapshot import JobSnapshot
from app.services.replay import ReplayPlan, ReplayService


def events(client: TestClient, job: str) -> list[dict]:
    """The job's server-sent events, until the stream ends with the job."""
    with client.stream("GET", f"/api/jobs/{job}/events") as stream:
        return [json.loads(line[5:]) for line in stream.iter_lines() if line.startswith("data:")]


def choosing(at_least: int) -> Callable[[JobSnapshot], bool]:
    return lambda j: j.detail.get("stage") == "choosing" and j.detail["step"] >= at_least


@pytest.mark.slow
def test_a_dry_run_of_a_large_plan_answers_at_once_and_a_cancel_ends_it(client: TestClient) -> None:
    sid = client.post("/api/sessions", json={"robot": "robonaut-a", "name": "large plan"}).json()["id"]
    ask = {"count": 300, "seed": 11, "dry_run": True}
    r = client.post(f"/api/sessions/{sid}/replay", json=ask)
    assert r.status_code == 202, r.text
    job = r.json()["job"]
    assert not client.app.state.desk.jobs.get(job).state.finished  # answered before the plan was made
    # The same request again (a double click, a second tab) is that job; another dry run of the robot waits.
    again = client.post(f"/api/sessions/{sid}/replay", json=ask)
    assert again.status_code == 202 and again.json()["job"] == job
    other = client.post(f"/api/sessions/{sid}/replay", json={**ask, "count": 20})
    assert other.status_code == 422
    assert (
        other.json()["detail"]
        == f"a dry run (job {job}) is planning for robonaut-a: wait for it to end, or cancel it first"
    )
    bad = client.post(f"/api/sessions/{sid}/replay", json={**ask, "mode": "weekly"})  # still answered at once
    assert bad.status_code == 422 and "unknown mode 'weekly'" in bad.json()["detail"]

    # It reports each configuration it chooses; there is no result yet, and nothing to pause.
    snap = wait_for(client, job, choosing(3))
    assert (snap.kind, snap.state, snap.detail["steps"]) == ("dry_run", "running", 300)
    assert 0 < snap.progress < 0.5
    early = client.get(f"/api/jobs/{job}/dry-run")
    assert early.status_code == 422 and early.json()["detail"].startswith(f"the dry run (job {job}) is still running")
    assert client.post(f"/api/jobs/{job}/pause").status_code == 422

    assert client.post(f"/api/jobs/{job}/cancel").status_code == 200
    last = events(client, job)[-1]
    assert last["state"] == "cancelled" and last["detail"]["step"] < 300, last  # stopped while choosing
    gone = client.get(f"/api/jobs/{job}/dry-run")
    assert (
        gone.status_code == 422
        and gone.json()["detail"] == f"the dry run (job {job}) ended cancelled; it has no result"
    )

    # STOP (the desk's button, Esc) cancels a dry run as it cancels a replay.
    job = client.post(f"/api/sessions/{sid}/replay", json=ask).json()["job"]
    wait_for(client, job, choosing(1))
    client.post("/api/robot/stop")
    last = events(client, job)[-1]
    assert last["state"] == "cancelled" and last["detail"]["step"] < 300, last
    # A job that is not a dry run has no dry run result.
    assert client.get("/api/jobs/j-00000000/dry-run").status_code == 404


@pytest.mark.slow
def test_a_dry_run_jobs_result_is_the_dry_run_and_the_replay_after_it_drives_that_plan(
    client: TestClient, monkeypatch: pytest.MonkeyPatch
) -> None:
    desk = client.app.state.desk
    sid = client.post("/api/sessions", json={"robot": "nao", "name": "small plan"}).json()["id"]
    plan = {"count": 6, "seed": 7}
    # What the dry run answered in its request before (the same service, planning afresh).
    before = ReplayService(desk.store, desk.robots, desk.jobs).dry_run(sid, ReplayPlan(**plan))

    r = client.post(f"/api/sessions/{sid}/replay", json={**plan, "dry_run": True})
    assert r.status_code == 202, r.text
    job = r.json()["job"]
    seen = events(client, job)
    assert (seen[-1]["state"], seen[-1]["result"]) == ("done", sid), seen[-1]
    assert [e["progress"] for e in seen] == sorted(e["progress"] for e in seen)
    phases = [e["detail"].get("phase") for e in seen]
    assert phases.index("planning") < phases.index("predicting")
    result = client.get(f"/api/jobs/{job}/dry-run").json()
    assert result == before
    assert len(result["configurations"]) == 6 and result["predicted"]["n"] == 6

    # The replay after it drives the plan it checked, planning nothing more.
    def planned_again(*args, **kw):
        raise AssertionError("the replay planned its configurations again")

    monkeypatch.setattr("app.services.replay.plan_configurations", planned_again)
    q_plan = desk.replay.configurations(sid, ReplayPlan(**plan))[0]
    job = client.post(f"/api/sessions/{sid}/replay", json=plan).json()["job"]
    assert events(client, job)[-1]["state"] == "done"
    frames = client.get(f"/api/sessions/{sid}").json()["frames"]
    names = desk.robots.get("nao").profile.joint_names
    q_frames = np.radians([[f["joints"][n] for n in names] for f in frames])
    near = np.all(np.abs(q_plan[:, None, :] - q_frames[None, :, :]) <= np.radians(0.1), axis=2)
    assert (near.sum(axis=1) == 1).all() and (near.sum(axis=0) == 1).all()  # each planned configuration once

    # A dry run of frames has nothing to plan: it answers in its request.
    r = client.post(f"/api/sessions/{sid}/replay", json={"remeasure": True, "dry_run": True})
    assert r.status_code == 200 and len(r.json()["configurations"]) == 6


@pytest.mark.browser
@pytest.mark.subprocess
def test_a_dry_run_in_the_browser_shows_its_progress_then_its_result(chromium_2d, desk_data: Path) -> None:
    from browser import desk_served, nao_replay_tab

    with desk_served(desk_data, sim_speed=20.0) as server:
        page, _ = nao_replay_tab(chromium_2d, server.url, "dry run in the browser")
        page.check("input[name=replay-source][value=count]")
        asked: list[dict] = []
        page.on("request", lambda r: r.method == "POST" and r.url.endswith("/replay") and asked.append(r.url))
        # Every text the Replay step's state line shows.
        page.evaluate(
            "window.__states = []; new MutationObserver(() => window.__states.push("
            "document.querySelector('#replay-state').textContent)).observe(document.querySelector('#replay-state'),"
            " {childList: true, characterData: true, subtree: true})"
        )

        # A double click: one dry run, its progress, then its result.
        page.fill("#replay-count", "150")
        page.dblclick("#dry-run")
        page.wait_for_function("document.querySelector('#dry-run-result').textContent.includes('150 configurations')")
        states = page.evaluate("window.__states")
        assert any(
            s.startswith("dry run running · planning the configurations: ") and " of 150 chosen" in s for s in states
        ), states
        # (the checking phase is short: the page's coalesced events may skip straight from planning to done)
        assert states[-1] == "dry run done", states
        # For the mode of step 3, `auto` as the page opens (the API lists it first).
        assert page.input_value("#mode") == "auto"
        assert "Predicted after an auto calibration from the 150 configurations" in page.text_content(
            "#replay-predicted"
        )
        assert len(asked) == 1, asked
        assert page.is_enabled("#dry-run") and page.is_enabled("#replay-start")

        # Abort, then Esc, cancel a dry run while it plans (drawing 6000 candidate stances for 2000 configurations
        # takes seconds; it used to wait for the choosing after them).
        page.fill("#replay-count", "2000")
        for how in ("abort", "escape"):
            page.click("#dry-run")
            page.wait_for_function(
                "document.querySelector('#replay-state').textContent.includes('planning the configurations')"
            )
            assert page.is_disabled("#dry-run") and page.is_disabled("#replay-start")
            assert page.is_disabled("#replay-pause") and page.is_enabled("#replay-abort")  # nothing to pause
            if how == "abort":
                page.click("#replay-abort")
            else:
                page.keyboard.press("Escape")
            page.wait_for_function(
                "document.querySelector('#replay-state').textContent === 'dry run cancelled'", timeout=10_000
            )
            assert page.text_content("#dry-run-result") == ""
            assert page.is_enabled("#dry-run") and page.is_disabled("#replay-abort")
