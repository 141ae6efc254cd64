"""Job snapshots (app/jobs/snapshot.py's), kept on every state change so that a job outlives its server."""

from __future__ import annotations

import json
from dataclasses import replace

from ..errors import NotFound
from ..jobs.snapshot import JobSnapshot, JobState
from .db import Database, jsonable, now

LIVE_STATES = tuple(s.value for s in JobState if not s.finished)
INTERRUPTED = "interrupted by a server restart"


class JobRepository:
    def __init__(self, db: Database) -> None:
        self.db = db

    def save(self, job: JobSnapshot) -> None:
        """Upsert a job snapshot by its id."""
        snap = json.dumps(jsonable(job.to_dict()))
        with self.db.tx() as db:
            db.execute(
                "INSERT INTO jobs VALUES (?, ?, ?, ?, ?, ?, ?) ON CONFLICT(id) DO UPDATE SET "
                "kind = excluded.kind, state = excluded.state, session_id = excluded.session_id, "
                "updated = excluded.updated, snapshot = excluded.snapshot",
                (job.id, job.kind, job.state.value, job.session, job.created, job.updated, snap),
            )

    def list(self, session_id: str | None = None) -> list[JobSnapshot]:
        """Newest first."""
        sql, args = "SELECT snapshot FROM jobs", []
        if session_id is not None:
            sql, args = sql + " WHERE session_id = ?", [session_id]
        rows = self.db.all(sql + " ORDER BY created DESC, rowid DESC", args)
        return [JobSnapshot.from_dict(json.loads(r["snapshot"])) for r in rows]

    def get(self, job_id: str) -> JobSnapshot:
        row = self.db.one("SELECT snapshot FROM jobs WHERE id = ?", (job_id,))
        if row is None:
            raise NotFound.unknown("job", job_id)
        return JobSnapshot.from_dict(json.loads(row["snapshot"]))

    def fail_interrupted(self) -> int:
        """Jobs a previous server left queued or running: failed, with the reason. Returns how many."""
        with self.db.tx() as db:
            marks = ",".join("?" * len(LIVE_STATES))
            rows = db.execute(f"SELECT snapshot FROM jobs WHERE state IN ({marks})", LIVE_STATES).fetchall()
            stamp = now()
            for r in rows:
                job = JobSnapshot.from_dict(json.loads(r["snapshot"]))
                job = replace(
                    job, state=JobState.FAILED, error=INTERRUPTED, updated=stamp, paused=False, version=job.version + 1
                )
                db.execute(
                    "UPDATE jobs SET state = 'failed', updated = ?, snapshot = ? WHERE id = ?",
                    (stamp, json.dumps(jsonable(job.to_dict())), job.id),
                )
        return len(rows)
