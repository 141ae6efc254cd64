"""Where the page's files (static/) are, for the server and the scene proxy."""

from __future__ import annotations

from importlib import resources
from pathlib import Path


def _static_dir() -> Path:
    """The page: package data, in a wheel as in a checkout; a checkout run through PYTHONPATH (a git worktree
    beside an editable install of another) serves its own static/, not the installed checkout's."""
    checkout = Path(__file__).resolve().parents[2]
    if (checkout / "pyproject.toml").is_file() and (checkout / "static" / "index.html").is_file():
        return checkout / "static"
    return Path(str(resources.files("app.static")))


STATIC_DIR = _static_dir()
