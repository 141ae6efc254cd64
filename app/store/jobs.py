"""Job snapshots (app/jobs.py's), kept on every state change so that a job outlives its server."""

from __future__ import annotations

import json

from ..errors import NotFound
from .db import Database, jsonable, now

JOB_ACTIVE_STATES = ("queued", "running")
INTERRUPTED = "interrupted by a server restart"


class JobRepository:
    def __init__(self, db: Database) -> None:
        self.db = db

    def save(self, job: dict) -> None:
        """Upsert a job snapshot by its id."""
        snap = json.dumps(jsonable(job))
        with self.db.tx() as db:
            db.execute(
                "INSERT INTO jobs VALUES (?, ?, ?, ?, ?, ?, ?) ON CONFLICT(id) DO UPDATE SET "
                "kind = excluded.kind, state = excluded.state, session_id = excluded.session_id, "
                "updated = excluded.updated, snapshot = excluded.snapshot",
                (job["id"], job["kind"], job["state"], job.get("session"), job["created"], job["updated"], snap),
            )

    def list(self, session_id: str | None = None) -> list[dict]:
        """Newest first."""
        sql, args = "SELECT snapshot FROM jobs", []
        if session_id is not None:
            sql, args = sql + " WHERE session_id = ?", [session_id]
        return [json.loads(r["snapshot"]) for r in self.db.all(sql + " ORDER BY created DESC, rowid DESC", args)]

    def get(self, job_id: str) -> dict:
        row = self.db.one("SELECT snapshot FROM jobs WHERE id = ?", (job_id,))
        if row is None:
            raise NotFound.unknown("job", job_id)
        return json.loads(row["snapshot"])

    def fail_interrupted(self) -> int:
        """Jobs a previous server left queued or running: failed, with the reason. Returns how many."""
        with self.db.tx() as db:
            marks = ",".join("?" * len(JOB_ACTIVE_STATES))
            rows = db.execute(f"SELECT snapshot FROM jobs WHERE state IN ({marks})", JOB_ACTIVE_STATES).fetchall()
            stamp = now()
            for r in rows:
                job = json.loads(r["snapshot"])
                job.update(state="failed", error=INTERRUPTED, updated=stamp, paused=False)
                job["version"] = job.get("version", 0) + 1
                db.execute(
                    "UPDATE jobs SET state = 'failed', updated = ?, snapshot = ? WHERE id = ?",
                    (stamp, json.dumps(job), job["id"]),
                )
        return len(rows)
