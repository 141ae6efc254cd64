"""A child process of the server (a calibration worker, the jobs' Manager) ends as soon as the server is gone.

A server killed with SIGKILL cleans nothing up, and neither child would notice by itself (a worker waits on a
task queue whose write end it holds too; the Manager waits for clients). A thread polls the parent pid rather
than PR_SET_PDEATHSIG, which fires when the *thread* that started the child ends (the pool starts workers from
whichever thread submits).

A spawned child re-imports the server's main module, then the initializer's module, before the initializer
runs: both must be light, or a child spawned just before the kill lives on for the seconds its imports take
(numpy, SciPy, OpenCV on a loaded machine). So this module imports nothing of the project, and `light_main`
names it as the main module the children import.
"""

from __future__ import annotations

import importlib.util
import os
import sys
import threading
import time

PARENT_POLL_S = 0.2  # how often a child looks whether the server still runs


def watch_parent(parent_pid: int) -> None:
    """Runs first in every child: ends this process once `parent_pid` is no longer its parent."""

    def watch() -> None:
        while os.getppid() == parent_pid:
            time.sleep(PARENT_POLL_S)
        os._exit(1)

    threading.Thread(target=watch, name="watch-server", daemon=True).start()


def light_main() -> None:
    """Have spawned children import this module as their main one, not the server's own script (the `calib`
    console script imports the whole command line). multiprocessing's spawn imports the parent's main module
    by its spec's name when it has one, by its file otherwise; a main module run by name (`python -m ...`)
    keeps its own."""
    main = sys.modules.get("__main__")
    if main is not None and getattr(main, "__spec__", None) is None and getattr(main, "__file__", None):
        main.__spec__ = importlib.util.find_spec(__name__)
