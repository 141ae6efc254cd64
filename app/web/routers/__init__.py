"""The JSON API under /api, one router per resource (specs/api.md is the pinned part; the rest serves the page).

Handlers are thin: they take what they need through FastAPI's `Depends` (routers/deps.py) and answer
Pydantic models, so /openapi.json is the truth. Bad input answers 4xx with {"detail": "..."} (app/web/server.py):
unknown ids 404 (NotFound), the user's mistakes 422 (a CSV's line and column, a joint and its limit),
never a 500 or a traceback. Handlers that touch viser or the store are plain `def` (FastAPI runs them in its
thread pool), so the event loop never waits on them.
"""

from __future__ import annotations

from fastapi import APIRouter

from . import calibrations, history, jobs, review, robot, robots, sessions

# Every 4xx answer is one sentence naming what is wrong (app/web/server.py's handlers), also for the event streams
# (JSON, not an event), so the schema is given with its media type.
PROBLEM = {
    "description": 'Bad input: {"detail": one sentence naming the problem}',
    "content": {
        "application/json": {
            "schema": {"type": "object", "properties": {"detail": {"type": "string"}}, "required": ["detail"]}
        }
    },
}
api = APIRouter(prefix="/api", responses={"4XX": PROBLEM})
for module in (robots, sessions, jobs, calibrations, robot, history, review):
    api.include_router(module.router)
