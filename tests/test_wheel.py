"""The project as a user installs it: a wheel built from the tree, installed into a fresh virtual
environment (its dependencies the test's own), `calib serve` started from a folder that has nothing of the
project, the page and the sample sessions served from the installed package data."""

from __future__ import annotations

import os
import subprocess
import sys
import sysconfig
import tomllib
from pathlib import Path

import pytest
from browser import served

ROOT = Path(__file__).resolve().parents[1]
SAMPLES = ("motoman-left-cube", "nao", "robonaut-a-day1", "robonaut-a-day2")


def test_every_package_of_the_tree_is_in_the_wheel() -> None:
    """pyproject lists its packages (two of them are data folders mapped into app); a new subpackage
    that is not listed would be missing from the wheel."""
    tool = tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["setuptools"]
    tree = {
        ".".join(p.parent.relative_to(ROOT).parts)
        for top in ("app", "calib_core")
        for p in (ROOT / top).rglob("__init__.py")
    }
    mapped = {name: ROOT / folder for name, folder in tool["package-dir"].items()}
    # Folders of data whose names Python could import are listed too, or setuptools warns at every install.
    roots = {**{top: ROOT / top for top in ("app", "calib_core")}, **mapped}
    data = {
        ".".join((name, *d.relative_to(folder).parts))
        for name, folder in roots.items()
        for d in folder.rglob("*")
        if d.is_dir()
        and "__pycache__" not in d.parts
        and all(part.isidentifier() for part in d.relative_to(folder).parts)
        and not (d / "__init__.py").exists()
    }
    assert set(tool["packages"]) == tree | set(mapped) | data
    assert all((folder / "__init__.py").is_file() for folder in mapped.values())


@pytest.mark.subprocess
def test_an_installed_wheel_serves_the_page_and_the_samples(tmp_path: Path) -> None:
    wheels, venv, elsewhere = tmp_path / "wheels", tmp_path / "venv", tmp_path / "elsewhere"
    elsewhere.mkdir()
    env = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "VIRTUAL_ENV")}
    run = {"check": True, "capture_output": True, "env": env, "cwd": elsewhere, "timeout": 600}
    subprocess.run([sys.executable, "-m", "pip", "wheel", "-q", "--no-deps", "-w", str(wheels), str(ROOT)], **run)
    (wheel,) = wheels.glob("robot_selfcal-*.whl")
    subprocess.run([sys.executable, "-m", "venv", "--without-pip", str(venv)], **run)
    pip = [sys.executable, "-m", "pip", "--python", str(venv / "bin" / "python"), "install", "-q", "--no-deps"]
    subprocess.run([*pip, str(wheel)], **run)
    # The dependencies (numpy, scipy, opencv, viser, ...) are this environment's, seen through a path line (not
    # its .pth files, so not its editable install of the checkout): the wheel's own files are what is tested,
    # and installing 300 MB of dependencies again would take half a minute of every test run.
    dependencies = sysconfig.get_paths()["purelib"]
    (venv_site,) = (venv / "lib").glob("python3*/site-packages")
    (venv_site / "dependencies.pth").write_text(dependencies + "\n")
    where = subprocess.run(
        [str(venv / "bin" / "python"), "-c", "import app, calib_core; print(app.__file__, calib_core.__file__)"],
        text=True,
        **run,
    ).stdout
    assert str(ROOT) not in where and str(venv) in where  # the installed copy, not the checkout

    with served(tmp_path / "data", 90.0, calib=venv / "bin" / "calib", cwd=elsewhere, env=env) as server:
        page = server.get("/")
        assert page.status_code == 200 and "<title>" in page.text and "app.js" in page.text
        # The page's modules (app.js imports static/js/*.js), each with a type a browser runs a module script of.
        modules = ["app.js", *(f"js/{p.name}" for p in sorted((ROOT / "static" / "js").glob("*.js")))]
        for module in modules:
            got = server.get(f"/{module}")
            assert got.status_code == 200, module
            assert got.headers["content-type"].split(";")[0] in ("text/javascript", "application/javascript"), module
        assert server.get("/vendor/swagger-ui/swagger-ui-bundle.js").status_code == 200  # /docs offline
        sessions = {s["id"]: s for s in server.get("/api/sessions").json()}
        assert set(SAMPLES) <= set(sessions), sessions.keys()
        assert sessions["motoman-left-cube"]["frames"] == 216
        frames = server.get("/api/sessions/robonaut-a-day1").json()["frames"]
        image = next(f["images"]["left"] for f in frames if f["images"])
        assert server.get(image).content[:2] == b"\xff\xd8"  # a sample's JPEG
    examples = subprocess.run(  # the README's sample inputs are package data too
        [str(venv / "bin" / "python"), "-c", "import app.sample_sessions as s; print(*s.__path__)"], text=True, **run
    ).stdout.strip()
    assert (Path(examples) / "bags" / "nao.bag").is_file() and (
        Path(examples) / "depth" / "robonaut-sphere.npy"
    ).is_file()
