"""scripts/venv.sh, which run.sh and test.sh source: pip runs on a fresh clone and when pyproject.toml
changed, never when nothing did (a stand-in pip records its calls; the real install is CI's fresh clone)."""

from __future__ import annotations

import shutil
import subprocess
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent


def ensure(repo: Path, *specs: str) -> list[str]:
    """Run `ensure_venv SPECS` in repo; the pip calls it made."""
    log = repo / "pip.log"
    log.unlink(missing_ok=True)
    subprocess.run(["bash", "-c", 'source scripts/venv.sh && ensure_venv "$@"', "ensure", *specs], cwd=repo, check=True)
    return log.read_text().splitlines() if log.exists() else []


@pytest.mark.subprocess
def test_pip_runs_only_when_the_venv_is_new_or_pyproject_changed(tmp_path):
    (tmp_path / "scripts").mkdir()
    shutil.copy(ROOT / "scripts" / "venv.sh", tmp_path / "scripts")
    shutil.copy(ROOT / "pyproject.toml", tmp_path)
    bin_dir = tmp_path / ".venv" / "bin"  # an existing venv whose pip only logs (python3 -m venv is skipped)
    bin_dir.mkdir(parents=True)
    (bin_dir / "python").write_text("#!/bin/sh\n")
    (bin_dir / "pip").write_text(f'#!/bin/sh\necho "$*" >> {tmp_path / "pip.log"}\n')
    for name in ("python", "pip"):
        (bin_dir / name).chmod(0o755)

    assert ensure(tmp_path, ".[test]") == ["install -q --upgrade pip", "install -q -e .[test]"]  # no record yet
    assert ensure(tmp_path, ".[test]") == []  # nothing changed
    assert ensure(tmp_path, ".", ".[test]") == []  # the app is part of the test install
    with (tmp_path / "pyproject.toml").open("a") as f:
        f.write("\n# a new dependency\n")
    assert ensure(tmp_path, ".", ".[test]") == ["install -q --upgrade pip", "install -q -e ."]
    assert ensure(tmp_path, ".", ".[test]") == []
    assert ensure(tmp_path, ".[test]") == ["install -q --upgrade pip", "install -q -e .[test]"]  # needs the extras
