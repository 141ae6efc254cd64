"""The desk's own errors, each answered by app/web/server.py with its sentence: an id it does not know (404), a
request it does not take from where it comes (403), and one beyond its limits (413).

Repositories, the job runner and the review raise NotFound for unknown ids; nothing catches KeyError or
IndexError on their behalf, so a stray one is a bug (500), not "not found".
"""

from __future__ import annotations

from calib_core.errors import InputError


class NotFound(Exception):
    """An unknown id (a session, a frame, a calibration, a job, a robot); the message is the answer's sentence."""

    @classmethod
    def unknown(cls, kind: str, key: object) -> NotFound:
        return cls(f"no {kind} '{key}' on this desk")


class NotAllowed(Exception):
    """What this desk does not do for a request from where it comes (a file on the server named by a browser
    elsewhere); the message says what to do instead."""


class TooLarge(InputError):
    """Bad input beyond one of the desk's limits (app/web/limits.py): the message names the limit."""
