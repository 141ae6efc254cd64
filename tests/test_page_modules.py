"""The page's modules import one way (docs/page.md): a panel imports foundation modules only (never another
panel), foundation modules import foundation modules only, and no import closes a circle; panels talk through
the store's events (static/js/state.js: `on`, `emit`), each event emitted somewhere is heard somewhere and the
other way round, and docs/page.md names every one. Read from the files' text: no browser, no Node."""

from __future__ import annotations

import re
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
STATIC = ROOT / "static"
# What is not a panel: the page's shared tools, which any panel may import. Every other module of static/js is a
# panel (a new module too, until it is named here).
FOUNDATION = {"api", "charts", "controls", "dom", "state", "tabs", "token"}
# `import ... from "./x.js"`, `import "./x.js"`, `export ... from "./x.js"` (comments dropped first).
IMPORT = re.compile(r"""^\s*(?:import|export)\b[^;'"]*?(?:\bfrom\s*)?["']([^"']+)["']""", re.M)
COMMENT = re.compile(r"/\*.*?\*/|(?<![:\"'\\])//[^\n]*", re.S)
EVENT = re.compile(r"""\b(on|emit)\(\s*["']([^"']+)["']""")


def modules() -> dict[str, Path]:
    """The page's modules by name ("app" for the composition root)."""
    return {"app": STATIC / "app.js", **{p.stem: p for p in sorted((STATIC / "js").glob("*.js"))}}


def source(path: Path) -> str:
    return COMMENT.sub("", path.read_text(encoding="utf-8"))


def imports() -> dict[str, set[str]]:
    """Module name -> the names of the page's modules it imports."""
    names = {p.resolve(): name for name, p in modules().items()}
    graph = {}
    for name, path in modules().items():
        targets = {(path.parent / spec).resolve() for spec in IMPORT.findall(source(path)) if spec.startswith(".")}
        unknown = [str(t) for t in targets if t not in names]
        assert unknown == [], f"{name}.js imports a file that is not a page module: {unknown}"
        graph[name] = {names[t] for t in targets}
    return graph


def test_the_import_parser_sees_the_imports() -> None:
    graph = imports()
    assert {"api", "dom", "state"} <= graph["history"]
    assert {"api", "state", "apply", "robots", "sessions"} <= graph["app"]
    assert graph["token"] == set()


def test_no_import_circle() -> None:
    graph = imports()
    circles = []
    done: set[str] = set()

    def visit(node: str, path: list[str]) -> None:
        if node in path:
            circles.append(" -> ".join([*path[path.index(node) :], node]))
            return
        if node in done:
            return
        for nxt in sorted(graph[node]):
            visit(nxt, [*path, node])
        done.add(node)

    for node in sorted(graph):
        visit(node, [])
    assert circles == []


def test_a_panel_imports_no_other_panel() -> None:
    """Nor does a foundation module import a panel (a ring through it would be a ring still)."""
    graph = imports()
    assert set(graph) >= FOUNDATION, "a foundation module named here no longer exists"
    wrong = sorted(
        f"{name}.js imports {other}.js"
        for name, targets in graph.items()
        if name != "app"
        for other in targets - FOUNDATION
    )
    assert wrong == []
    assert all("app" not in targets for targets in graph.values()), "app.js is the root: nothing imports it"


def events() -> tuple[dict[str, set[str]], dict[str, set[str]]]:
    """Event name -> the modules that emit it; event name -> the modules that listen to it."""
    emitted: dict[str, set[str]] = {}
    heard: dict[str, set[str]] = {}
    for name, path in modules().items():
        for verb, event in EVENT.findall(source(path)):
            (emitted if verb == "emit" else heard).setdefault(event, set()).add(name)
    return emitted, heard


def test_every_event_is_emitted_and_heard() -> None:
    emitted, heard = events()
    assert sorted(set(emitted) - set(heard)) == [], "emitted, heard by no module"
    assert sorted(set(heard) - set(emitted)) == [], "heard, emitted by no module"


def test_docs_name_every_event() -> None:
    emitted, heard = events()
    page = (ROOT / "docs" / "page.md").read_text(encoding="utf-8")
    assert sorted(e for e in set(emitted) | set(heard) if f"`{e}`" not in page) == []
