"""The desk's own error: an id it does not know. app/server.py answers it 404 with its sentence.

Repositories, the job runner and the review raise it for unknown ids; nothing catches KeyError or
IndexError on their behalf, so a stray one is a bug (500), not "not found".
"""

from __future__ import annotations


class NotFound(Exception):
    """An unknown id (a session, a frame, a calibration, a job, a robot); the message is the answer's sentence."""

    @classmethod
    def unknown(cls, kind: str, key: object) -> NotFound:
        return cls(f"no {kind} '{key}' on this desk")
