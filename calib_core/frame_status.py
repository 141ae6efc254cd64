"""What became of a frame (one configuration, one look at a target): the status a sighting, a session folder,
the dashboard's store and its API give it. A string enum: each member is the text files and answers hold."""

from __future__ import annotations

from enum import StrEnum

from .errors import InputError


class FrameStatus(StrEnum):
    MEASURED = "measured"  # a sensor measured the target: the frame has observations
    NOT_FOUND = "not found"  # the look found nothing (its reason says why)
    SKIPPED = "skipped"  # not driven to: the dry run predicted the target out of view (its reason says why)
    PENDING = "pending"  # recorded, not looked at yet

    @classmethod
    def parse(cls, text: object, where: str = "status") -> FrameStatus:
        """`text` as a status; InputError naming `where` and the known statuses otherwise."""
        try:
            return cls(text)
        except ValueError:
            raise InputError(f"{where}: unknown frame status {text!r} ({', '.join(cls)})") from None
