"""The code's layers: calib_core's public surface (what each package hands on, loaded lazily) and no import cycle
in it, and who in app may import whom (its packages on floors: web -> services -> robots -> scene -> drivers -> store;
routers -> services -> store; no import cycle), with no level of app holding more than a handful of entries."""

from __future__ import annotations

import ast
import importlib
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
PACKAGES = ["calib_core", *(f"calib_core.{p}" for p in ("model", "sensors", "estimation", "vision", "sim", "io"))]


def _type_checking_names(package: str) -> set[str]:
    """The names a package's `if TYPE_CHECKING:` block imports (empty when it imports its modules eagerly)."""
    tree = ast.parse((ROOT / package.replace(".", "/") / "__init__.py").read_text(encoding="utf-8"))
    blocks = [n for n in tree.body if isinstance(n, ast.If) and getattr(n.test, "id", None) == "TYPE_CHECKING"]
    return {a.asname or a.name for b in blocks for n in b.body if isinstance(n, ast.ImportFrom) for a in n.names}


@pytest.mark.parametrize("package", PACKAGES)
def test_every_public_name_of_a_package_resolves_and_type_checkers_see_the_same_names(package: str) -> None:
    module = importlib.import_module(package)
    assert module.__all__ and len(set(module.__all__)) == len(module.__all__)
    for name in module.__all__:
        assert getattr(module, name) is not None
    seen = _type_checking_names(package)
    assert not seen or seen == set(module.__all__)
    with pytest.raises(AttributeError, match="no attribute 'nothing_here'"):
        _ = module.nothing_here


@pytest.mark.subprocess
def test_importing_calib_core_or_a_subpackage_loads_neither_scipy_nor_opencv() -> None:
    """A script that only needs a profile or a CSV does not wait for SciPy and OpenCV (seconds on a cold disk)."""
    code = (
        f"import sys, {', '.join(PACKAGES)}; "
        "print(' '.join(m for m in ('scipy', 'cv2', 'rosbags', 'yourdfpy') if m in sys.modules))"
    )
    proc = subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0, proc.stderr[-2000:]
    assert proc.stdout.split() == []


@pytest.mark.subprocess
def test_a_small_calib_solve_loads_neither_scipy_nor_lxml(tmp_path: Path) -> None:
    """`calib solve` of a daily calibration on a sample session starts in about 0.25 s: SciPy (0.3 s) and lxml
    load only where a solve needs them (a pivoted QR, a rotation's closed form, a profile built on a URDF)."""
    data = ROOT / "sample_sessions" / "robonaut-a-day1" / "data.csv"
    argv = ["calib", "solve", "--robot", "robonaut-a", "--mode", "daily", "--data", str(data)]
    code = (
        f"import sys; sys.argv = {[*argv, '--out', str(tmp_path / 'cal.json')]!r}; from app.cli import main\n"
        "try:\n    main()\nexcept SystemExit as e:\n    assert not e.code, e.code\n"
        "print(' '.join(m for m in ('scipy', 'cv2', 'lxml', 'yourdfpy') if m in sys.modules))"
    )
    proc = subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0, proc.stderr[-2000:]
    assert proc.stdout.splitlines()[-1].split() == []
    assert (tmp_path / "cal.json").exists()


def _imports(path: Path, *, typed: bool = False) -> list[str]:
    """The modules a file imports at run time (and, `typed`, in `if TYPE_CHECKING:` too), relative ones made
    absolute."""
    package = ".".join(path.relative_to(ROOT).with_suffix("").parts).removesuffix(".__init__")
    if path.name != "__init__.py":
        package = package.rpartition(".")[0]
    tree = ast.parse(path.read_text(encoding="utf-8"))
    hinted = {
        id(n)
        for b in ast.walk(tree)
        if isinstance(b, ast.If) and getattr(b.test, "id", None) == "TYPE_CHECKING"
        for n in ast.walk(b)
    }
    out = []
    for node in ast.walk(tree):
        if id(node) in hinted and not typed:
            continue
        if isinstance(node, ast.Import):
            out += [a.name for a in node.names]
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                parts = package.split(".")
                base = ".".join(parts[: len(parts) - node.level + 1] + ([base] if base else []))
            out += [f"{base}.{a.name}" if f"{base}.{a.name}" in _KNOWN else base for a in node.names]
    return out


def _files(package: str) -> dict[str, Path]:
    """A package's modules by dotted name (a package by its own name, not its __init__)."""
    return {
        ".".join(p.relative_to(ROOT).with_suffix("").parts).removesuffix(".__init__"): p
        for p in ROOT.glob(f"{package}/**/*.py")
    }


_FILES = _files("app")
_MODULES = set(_FILES)
_CORE = _files("calib_core")
_KNOWN = _MODULES | set(_CORE)


def test_app_imports_calib_core_through_its_packages_only() -> None:
    """calib_core's modules below a subpackage are its own business: app takes what a package hands on."""
    deep = [
        f"{name} imports {m}"
        for name, path in sorted(_FILES.items())
        for m in _imports(path)
        if m.startswith("calib_core.") and m.count(".") >= 2
    ]
    assert deep == []


def _app_imports(name: str) -> set[str]:
    return {m for m in _imports(_FILES[name]) if m in _MODULES and m != name}


def test_the_store_imports_nothing_above_it() -> None:
    """The store is the bottom of the desk: below it only the errors and the job snapshot it keeps."""
    below = {"app", "app.errors", "app.jobs", "app.jobs.snapshot"}
    upward = {
        f"{name} imports {m}"
        for name in _MODULES
        if name.startswith("app.store")
        for m in _app_imports(name)
        if not m.startswith("app.store") and m not in below
    }
    assert upward == set()


def test_routers_reach_the_desk_only_through_their_dependencies() -> None:
    desk = {name for name in _MODULES if "app.web.desk" in _app_imports(name)}
    assert {n for n in desk if n.startswith("app.web.routers")} <= {"app.web.routers.deps"}


# app's packages from the ground up: a module imports its own package's modules and those of lower floors only. The
# store and the jobs share a floor (the store keeps the job snapshot, the runner keeps its jobs in the store).
FLOORS = [
    ("app.clock", "app.errors"),
    ("app.store", "app.jobs"),
    ("app.drivers",),
    ("app.scene",),
    ("app.robots",),
    ("app.services",),
    ("app.web",),
    ("app.cli",),
]


def _floor(name: str) -> int:
    top = ".".join(name.split(".")[:2])
    return next(k for k, floor in enumerate(FLOORS) if top in floor)


def test_every_package_of_app_has_a_floor_and_imports_nothing_above_it() -> None:
    """What the browser sees (scene) never reaches for the services or the web, the services never import the
    web application (its routers, the desk it composes), the drivers never the robots on the desk."""
    assert {".".join(name.split(".")[:2]) for name in _MODULES if name != "app"} == {p for f in FLOORS for p in f}
    upward = {
        f"{name} imports {m}"
        for name in _MODULES
        if name != "app"
        for m in _app_imports(name)
        if m != "app" and _floor(m) > _floor(name)
    }
    assert upward == set()


MAX_ENTRIES = 10


def test_no_level_of_app_holds_more_than_ten_entries() -> None:
    """A reader finds a module among a handful: every package of app holds at most MAX_ENTRIES files and folders
    (its __init__.py and caches not counted)."""
    crowded = {}
    for folder in [ROOT / "app", *(p.parent for p in (ROOT / "app").rglob("*/__init__.py"))]:
        entries = [e for e in folder.iterdir() if e.name not in ("__init__.py", "__pycache__", ".DS_Store")]
        if len(entries) > MAX_ENTRIES:
            crowded[str(folder.relative_to(ROOT))] = sorted(e.name for e in entries)
    assert crowded == {}


def _first_cycle(graph: dict[str, set[str]]) -> list[str]:
    """An import cycle of a graph (module -> the modules it imports) as the path round it, or [] if none."""
    done: set[str] = set()
    path: list[str] = []

    def visit(name: str) -> list[str]:
        if name in path:
            return [*path[path.index(name) :], name]
        if name in done:
            return []
        path.append(name)
        for m in sorted(graph[name]):
            if cycle := visit(m):
                return cycle
        path.pop()
        done.add(name)
        return []

    for name in sorted(graph):
        if cycle := visit(name):
            return cycle
    return []


def test_app_has_no_import_cycle_not_even_through_a_type_hint() -> None:
    """As calib_core's: a driver's `stop() -> Halt` once named core's Halt from the package core imports."""
    graph = {
        name: {m for m in _imports(path, typed=True) if m in _MODULES and m != name} for name, path in _FILES.items()
    }
    cycle = _first_cycle(graph)
    assert not cycle, "import cycle: " + " -> ".join(cycle)


def test_calib_core_has_no_import_cycle_not_even_through_a_type_hint() -> None:
    """The library's layers go one way (sensors < model < vision < estimation, sim < io): a module that names
    another's type in a hint stands above it too, whether Python imports it at run time or a type checker only."""
    graph = {name: {m for m in _imports(path, typed=True) if m in _CORE and m != name} for name, path in _CORE.items()}
    cycle = _first_cycle(graph)
    assert not cycle, "import cycle: " + " -> ".join(cycle)
