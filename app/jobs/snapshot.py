"""A job as everyone reads it: the runner hands out copies, the store keeps it, the API answers it as it is."""

from __future__ import annotations

from dataclasses import asdict, dataclass, field, replace
from enum import StrEnum
from typing import Any


class JobState(StrEnum):
    """Where a job is. A paused job is running (its `paused` flag is set): pausing is not a state of its own."""

    QUEUED = "queued"
    RUNNING = "running"
    DONE = "done"
    FAILED = "failed"
    CANCELLED = "cancelled"

    @property
    def finished(self) -> bool:
        return self in (JobState.DONE, JobState.FAILED, JobState.CANCELLED)


@dataclass
class JobSnapshot:
    """One job now. `version` grows with every change (a stream of them sends each once)."""

    id: str
    kind: str  # "calibration" | "replay" | "dry_run" | "capture"
    state: JobState
    progress: float  # 0..1
    result: str | None  # a calibration job's calibration id, a replay's or a dry run's session id
    error: str | None  # why it failed, one sentence
    session: str | None
    created: str
    updated: str
    detail: dict[str, object] = field(default_factory=dict)  # what the job reports as it runs (phase, iterations, ...)
    cost: list[float | None] = field(default_factory=list)  # an iterative solve's cost per iteration
    version: int = 0
    paused: bool = False  # a running job held at its next checkpoint

    def copy(self) -> JobSnapshot:
        return replace(self, detail=dict(self.detail), cost=list(self.cost))

    def to_dict(self) -> dict[str, Any]:
        """The snapshot as plain data (what the store writes as JSON)."""
        return {**asdict(self), "state": self.state.value}

    @classmethod
    def from_dict(cls, raw: dict[str, Any]) -> JobSnapshot:
        """A stored snapshot; one of the first dashboard's (which kept no progress, detail, cost, version or
        pause) gets their defaults."""
        return cls(
            id=raw["id"],
            kind=raw["kind"],
            state=JobState(raw["state"]),
            progress=float(raw.get("progress", 0.0)),
            result=raw.get("result"),
            error=raw.get("error"),
            session=raw.get("session"),
            created=raw["created"],
            updated=raw["updated"],
            detail=dict(raw.get("detail", {})),
            cost=list(raw.get("cost", [])),
            version=int(raw.get("version", 0)),
            paused=bool(raw.get("paused", False)),
        )
