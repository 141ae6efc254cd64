"""The whole HTTP API fuzzed from its own OpenAPI document (schemathesis), in-process, on a small budget.

Every operation gets a few dozen generated requests, valid and invalid by the schema: the answer is
never a 500, never later than a timeout, always of a documented content type and shape, and every
4xx is JSON with a one-sentence string `detail`. The robot's event stream (`GET /api/robot/events`,
endless by design) is read up to a few events; the job event stream ends since its jobs never exist.
Moves run on the simulated robots at a high time scale, so no operation keeps the robot busy for long.
Not checked: that every schema-violating request is refused (pydantic's lax mode takes 0 for false
and "3" for 3, on purpose). Findings are fixed at their root and pinned by the regression tests at the end of this file.
"""

from __future__ import annotations

import time
from pathlib import Path

import pytest
import schemathesis
from fastapi import FastAPI
from fastapi.testclient import TestClient
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from schemathesis.checks import not_a_server_error
from schemathesis.specs.openapi.checks import content_type_conformance, response_schema_conformance

from app.web.server import create_app
from calib_core import InputError, SimulatedRobot, load_profile

REQUEST_TIMEOUT_S = 15.0
MAX_EXAMPLES = 10  # per operation and test: 32 + 15 operations, under 500 requests in all

# The document does not depend on the data directory: a throwaway app gives it without starting.
schema = schemathesis.openapi.from_dict(create_app(Path("unused")).openapi())
pytestmark = pytest.mark.slow  # hundreds of generated requests
schema.config.max_stream_events = 3  # the robot's stream sends one every 0.1 s, forever


class LifespanOwned:
    """The app as schemathesis reaches it, while the fixture owns its lifespan: schemathesis' plugin
    ends the lifespans it starts after every test, which would restart the desk once per operation."""

    def __init__(self, app: FastAPI) -> None:
        self.app = app

    async def __call__(self, scope, receive, send) -> None:
        if scope["type"] != "lifespan":
            await self.app(scope, receive, send)
            return
        while True:
            message = await receive()
            if message["type"] == "lifespan.startup":
                await send({"type": "lifespan.startup.complete"})
            else:
                await send({"type": "lifespan.shutdown.complete"})
                return


@pytest.fixture(scope="module")
def app(client: TestClient) -> LifespanOwned:
    return LifespanOwned(client.app)


def problem_detail(ctx, response, case) -> bool | None:
    """A 4xx answers JSON {"detail": "<one sentence>"}: no list of validator records, no traceback."""
    if 400 <= response.status_code < 500:
        body = response.json()
        assert isinstance(body, dict) and isinstance(body.get("detail"), str), f"4xx body {body!r}"
        assert body["detail"].strip(), "empty detail"
        assert "Traceback" not in body["detail"]
    return None


@schema.parametrize()
@settings(max_examples=MAX_EXAMPLES, deadline=None, suppress_health_check=list(HealthCheck))
def test_api(case, app: LifespanOwned) -> None:
    response = case.call(app=app, timeout=REQUEST_TIMEOUT_S)
    case.validate_response(
        response,
        checks=[
            not_a_server_error,
            content_type_conformance,
            response_schema_conformance,
            problem_detail,
        ],
    )


# --- the same, with ids that exist -------------------------------------------------------------------
# Random ids only ever meet "not found"; these reach the handlers' real work: frames by index, images
# by name, a real calibration and job, a loaded review. DELETE is left out (it would empty the samples).

FRAME_INDEX = st.one_of(st.integers(-2, 160), st.sampled_from([2**31, 2**63, -(2**63), 10**30]))


def known_values(client: TestClient, cal_id: str, job_id: str) -> dict[str, st.SearchStrategy]:
    sessions = [s["id"] for s in client.get("/api/sessions").json()]
    return {
        "session_id": st.sampled_from([*sessions, "NAO", "nao ", "..", "c-00000000"]),
        # a NAO replay's dry run of frames checks them in the request, and NAO's checks per configuration cost more
        "robonaut_session": st.sampled_from([s for s in sessions if s.startswith("robonaut")]),
        "index": FRAME_INDEX,
        "name": st.sampled_from(["0001_image.jpg", "0001_left.jpg", "0002_right.jpg", "9999_image.jpg", "x.jpg"]),
        "cal_id": st.sampled_from([cal_id, cal_id.upper(), "c-00000000"]),
        "job_id": st.sampled_from([job_id, "j-00000000"]),
        "action": st.sampled_from(["cancel", "pause", "resume"]),
    }


@pytest.fixture(scope="module")
def known(client: TestClient) -> dict[str, st.SearchStrategy]:
    r = client.post("/api/sessions/robonaut-a-day1/calibrations", json={"mode": "daily", "holdout": 0.2})
    assert r.status_code == 202, r.text
    job_id = r.json()["job"]
    deadline = time.monotonic() + 120
    while (job := client.get(f"/api/jobs/{job_id}").json())["state"] in ("queued", "running"):
        assert time.monotonic() < deadline, job
        time.sleep(0.1)
    assert job["state"] == "done", job
    assert (
        client.post("/api/review", json={"session": "robonaut-a-day1", "old": None, "new": job["result"]}).status_code
        == 200
    )
    yield known_values(client, job["result"], job_id)
    client.post("/api/robot/stop")
    client.post("/api/sessions/nao/observe", json={"on": False})


WITH_IDS = [
    (op.method.upper(), op.path)
    for op in (result.ok() for result in schema.get_all_operations())
    if "{" in op.path and op.method.upper() != "DELETE"
]


@pytest.mark.parametrize(("method", "path"), WITH_IDS, ids=[f"{m} {p}" for m, p in WITH_IDS])
@settings(max_examples=MAX_EXAMPLES, deadline=None, suppress_health_check=list(HealthCheck))
@given(data=st.data())
def test_api_with_known_ids(method: str, path: str, data, app: LifespanOwned, client: TestClient, known: dict) -> None:
    operation = schema[path][method]
    strategies = {**known, "session_id": known["robonaut_session"]} if path.endswith("/replay") else known
    params = {p.name: data.draw(strategies[p.name], label=p.name) for p in operation.path_parameters}
    case = data.draw(operation.as_strategy(path_parameters=params))
    response = case.call(app=app, timeout=REQUEST_TIMEOUT_S)
    case.validate_response(
        response, checks=[not_a_server_error, content_type_conformance, response_schema_conformance, problem_detail]
    )
    if path.endswith("/replay") and response.status_code == 202:
        # A replay or a dry run of any count (up to the schema's 2,000) answers at once and plans in its job, about
        # 0.1 s a configuration on Robonaut: cancelled here (it stops within a step), so that no such plan goes on
        # loading the machine while the other operations are fuzzed.
        assert client.post(f"/api/jobs/{response.json()['job']}/cancel").status_code == 200


# --- what the fuzzer found, pinned -------------------------------------------------------------------


def test_event_streams_refuse_unknown_ids_before_streaming(client: TestClient) -> None:
    """Found: an unknown job or robot raised inside the stream, after the 200 had started (a broken
    stream, an unhandled ExceptionGroup in the server). Now checked before the first event."""
    r = client.get("/api/jobs/j-00000000/events")
    assert r.status_code == 404 and r.headers["content-type"] == "application/json"
    assert "j-00000000" in r.json()["detail"]
    r = client.get("/api/robot/events", params={"robot": "robonaut-x"})
    assert r.status_code == 422 and "robonaut-x" in r.json()["detail"]


def test_connecting_a_robot_needs_its_exact_name(client: TestClient) -> None:
    """Found: {"robot": ""} was taken (driver("") means the connected one) and set the connected robot
    to "", which broke every later call that used it."""
    before = client.get("/api/robot").json()["robot"]
    r = client.post("/api/robot/connect", json={"robot": ""})
    assert r.status_code == 422 and "robonaut-a" in r.json()["detail"]
    assert client.get("/api/robot").json()["robot"] == before


@pytest.mark.parametrize("index", [2**63, -(2**63) - 1, 10**30])
def test_frame_numbers_beyond_int64_are_bad_input(client: TestClient, index: int) -> None:
    """Found: a frame number beyond SQLite's INTEGER overflowed inside the store (a 500)."""
    for method, path in [("POST", f"/api/sessions/nao/frames/{index}/goto"), ("GET", f"/api/review/marks/{index}")]:
        r = client.request(method, path)
        assert r.status_code == 422, r.text
        assert r.json()["detail"].startswith("path.index"), r.text
    assert client.post("/api/sessions/nao/frames/9223372036854775807/goto").status_code == 404
    assert client.post("/api/review/frame", json={"index": index}).status_code == 422


def test_a_missing_body_is_named(client: TestClient) -> None:
    """Found: a request without its JSON body answered ": Field required"."""
    r = client.post("/api/sessions")
    assert r.status_code == 422
    assert r.json()["detail"] == "request body: Field required"


def test_the_openapi_document_tells_the_error_shape_and_the_file_types() -> None:
    """Found: the document promised FastAPI's list of validation records for 422 while every 4xx is
    {"detail": "<sentence>"}, and did not list JPEG images or the YAML and URDF exports."""
    doc = create_app(Path("unused")).openapi()
    assert "HTTPValidationError" not in doc.get("components", {}).get("schemas", {})
    for path, item in doc["paths"].items():
        for method, op in item.items():
            problem = op["responses"]["4XX"]["content"]["application/json"]["schema"]
            assert problem["properties"]["detail"]["type"] == "string", (method, path)
    assert (
        "image/jpeg"
        in doc["paths"]["/api/files/sessions/{session_id}/images/{name}"]["get"]["responses"]["200"]["content"]
    )
    export = doc["paths"]["/api/calibrations/{cal_id}/export"]["get"]["responses"]["200"]["content"]
    assert {"application/json", "application/yaml", "application/xml"} <= set(export)


def test_a_negative_replay_seed_is_bad_input(client: TestClient) -> None:
    """Found: a negative seed reached numpy's generator (ValueError: a 500)."""
    r = client.post("/api/sessions/robonaut-a-day1/replay", json={"count": 1, "seed": -1, "dry_run": True})
    assert r.status_code == 422 and r.json()["detail"].startswith("seed"), r.text


def test_a_plan_without_enough_visible_configurations_is_bad_input() -> None:
    """Found: a replay plan the simulator could not fill raised RuntimeError (a 500; in `calib simulate`
    an internal error). Now InputError asking for fewer."""
    profile = load_profile("robonaut-a")
    blind = profile.nominal()
    blind[profile.param("fixture.z")] += 1e4  # the fixture far out of every view
    with pytest.raises(InputError, match="found only 0 visible configurations of the 3 asked"):
        SimulatedRobot.from_profile(profile, seed=0, truth=blind).configurations(3)
