"""Process jobs for tests: module-level functions a worker process unpickles by reference, so it imports this
module. Light on purpose (the standard library only), like a real job's: importing a test module instead would
cost each new worker seconds (its store, its runner, pytest)."""

from __future__ import annotations

import time
from typing import Any


def sleeper(seconds: float, link: Any) -> str:
    """A worker that never looks at its cancel flag (a hung solver)."""
    time.sleep(seconds)
    return "slept"


def exploder(message: str, link: Any) -> None:
    raise RuntimeError(message)
