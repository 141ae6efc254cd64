"""The README's and the docs' examples run as written: every ```bash and ```python block, in order, in a fresh
folder that has the repository's sample_sessions/ (the examples' paths are relative to a clone's root), with
`calib` the checkout's. Not run: the set-up commands (scripts/run.sh, scripts/test.sh, pip), the benchmarks (they
print figures, in minutes), and `calib serve` itself: the block that starts it has its curl commands sent to
the desk `calib serve` serves, served by this test in its own process (tests/browser.py desk_served: a `calib
serve` costs a second or two of CPU to start), its simulated robots 20 times as fast (the examples wait on its
jobs). The command itself is under test in test_wheel.py, test_faults.py and test_cli.py."""

from __future__ import annotations

import os
import re
import subprocess
import sys
from contextlib import ExitStack
from pathlib import Path

import pytest
from browser import desk_served

ROOT = Path(__file__).resolve().parent.parent
BLOCK = re.compile(r"^```(bash|python)\n(.*?)^```", re.S | re.M)
# Set-up commands (the ROS 2 blocks too: tests/test_ros2.py runs their two processes) and benchmarks.
NOT_RUN = re.compile(r"^(bash scripts/|\.venv/bin/python benchmarks/|\.venv/bin/pip install|python3 -m venv)", re.M)
DROPPED = re.compile(r"^(source \.venv/bin/activate|calib serve)\b.*$", re.M)  # the venv is this one
DOCS = [
    "README.md",
    "docs/bag-import.md",
    "docs/urdf-robots.md",
    "docs/dashboard.md",
    "docs/robots.md",
    "docs/command-line.md",
    "docs/calibration.md",
    "docs/planning.md",
    "docs/profiles.md",
    "docs/handeye.md",
]


def examples(doc: str) -> list[tuple[str, str]]:
    return [(lang, body) for lang, body in BLOCK.findall((ROOT / doc).read_text(encoding="utf-8"))]


@pytest.mark.parametrize("doc", DOCS)
@pytest.mark.subprocess
def test_the_examples_run_as_written(doc: str, tmp_path: Path) -> None:
    work = tmp_path / "clone"
    work.mkdir()
    (work / "sample_sessions").symlink_to(ROOT / "sample_sessions")
    env = {
        **os.environ,
        "PATH": f"{Path(sys.executable).parent}{os.pathsep}{os.environ['PATH']}",
        "PYTHONPATH": str(ROOT),
    }
    ran = 0
    with ExitStack() as stack:
        for lang, body in examples(doc):
            if lang == "bash" and NOT_RUN.search(body):
                continue
            if "localhost:8000" in body:
                server = stack.enter_context(desk_served(tmp_path / "data", sim_speed=20.0))
                body = body.replace("localhost:8000", server.url.removeprefix("http://"))
            body = DROPPED.sub("", body)
            cmd = ["bash", "-euo", "pipefail", "-c", body] if lang == "bash" else [sys.executable, "-c", body]
            done = subprocess.run(cmd, cwd=work, env=env, capture_output=True, text=True, timeout=180)
            assert done.returncode == 0, (
                f"{doc}: this {lang} example failed:\n{body}\n{done.stdout[-2000:]}\n{done.stderr[-3000:]}"
            )
            ran += 1
    assert ran >= 1  # the doc has examples, and the test sees them
