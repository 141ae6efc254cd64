"""Fixtures shared by the test modules, and the markers' effects.

Profiles (`rn`, `nao`, `motoman`), a store and a desk are the module's: a module's tests may share what one of
them changed (a desk's sessions, say), another module starts from a fresh one. `client` is an in-process desk
(create_app in a TestClient); a module that needs it otherwise (no samples, another clock) overrides
`desk_options`. `desk_data` is a data directory for a `calib serve`, as a desk's first start leaves it.
`sample_copy` copies sample sessions where a test may change or break them.

`chromium` is a headless chromium the browser tests of a test process share (its first `new_page` a tab of one
context the process keeps, `Tabs`); `chromium_2d` another for the tests that look at the rest of the page: its pages
load the desk without the 3-D view's client (chromium draws WebGL in software, about a third of such a test's time)
and it has no GPU process (compositing a page through Mesa's GL cost a second of CPU a test), but it is `chromium` when
CALIB_SCREENSHOTS asks for screenshots.

Markers (pyproject.toml): `browser` (drives a headless chromium: skipped where Debian's chromium is missing),
`subprocess` (starts `calib`, `calib serve` or another program, beyond a desk's own job workers) and `slow`;
`scripts/test.sh --fast` runs the tests that have none of them.
"""

from __future__ import annotations

import asyncio
import os
import shutil
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import pytest
import viser
from browser import kept_context, launch
from fastapi.testclient import TestClient
from hypothesis import Phase, settings

from app.store import Store
from app.web.server import create_app
from calib_core import Profile, load_profile

if TYPE_CHECKING:
    from playwright.sync_api import Browser, BrowserContext, Page, ViewportSize

# The fuzz tests report a failing example as found, unshrunk: shrinking one (a damaged image) took Hypothesis five
# minutes in a CI run, a third of CI's limit; the example and its seed still reproduce it.
settings.register_profile("unshrunk", phases=(Phase.explicit, Phase.reuse, Phase.generate, Phase.target))
settings.load_profile("unshrunk")

SAMPLES = Path(__file__).resolve().parent.parent / "sample_sessions"


# The mean seconds of a test of each marker in a full run on two workers (2026-11-27, pytest's junit durations:
# 29 browser tests 10.5 s, 103 other subprocess tests 2.5 s, 203 other slow tests 2.0 s, 701 unmarked 0.16 s).
MARKER_SECONDS = {"browser": 10.5, "subprocess": 2.5, "slow": 2.0}
UNMARKED_SECONDS = 0.16


def _expected_s(item: pytest.Item) -> float:
    return max((s for m, s in MARKER_SECONDS.items() if item.get_closest_marker(m)), default=UNMARKED_SECONDS)


def pytest_collection_modifyitems(config: pytest.Config, items: list[pytest.Item]) -> None:
    """Chromium's tests skipped where it is missing; the modules in the order of their expected time, longest
    first (scripts/test.sh has xdist hand out whole modules in this order, --no-loadscope-reorder): the short ones
    then fill both workers to the end, instead of one long module running alone while the other worker waits."""
    if shutil.which("chromium") is None:
        skip = pytest.mark.skip(reason="Debian's chromium is not installed")
        for item in items:
            if item.get_closest_marker("browser"):
                item.add_marker(skip)
    module_s: dict[str, float] = {}
    for item in items:
        module_s[item.nodeid.split("::")[0]] = module_s.get(item.nodeid.split("::")[0], 0.0) + _expected_s(item)
    items.sort(key=lambda item: -module_s[item.nodeid.split("::")[0]])  # stable: a module's own order kept


# --- the built-in robots ------------------------------------------------------------------------------------
@pytest.fixture(scope="module")
def rn() -> Profile:
    return load_profile("robonaut-a")


@pytest.fixture(scope="module")
def nao() -> Profile:
    return load_profile("nao")


@pytest.fixture(scope="module")
def motoman() -> Profile:
    return load_profile("motoman")


# --- stores and desks ---------------------------------------------------------------------------------------
@pytest.fixture(scope="module")
def sample_copy(tmp_path_factory: pytest.TempPathFactory) -> Callable[..., Path]:
    """`sample_copy(*names)`: a new folder holding a copy of those sample sessions (a desk's `sample_dir`)."""

    def copy(*names: str) -> Path:
        folder = tmp_path_factory.mktemp("samples")
        for name in names:
            shutil.copytree(SAMPLES / name, folder / name)
        return folder

    return copy


@pytest.fixture(scope="module")
def store(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Store]:
    """An empty store of the module's."""
    s = Store(tmp_path_factory.mktemp("store"))
    yield s
    s.close()


@pytest.fixture(scope="module")
def desk_options() -> dict[str, Any]:
    """create_app's options for the module's desk beyond the defaults of `client`: a module overrides this."""
    return {}


@pytest.fixture(scope="session")
def first_start(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A data directory as a desk's first start leaves it (the built-in robots recorded, the sample sessions
    imported), made once per test process: `desk_data` and `client` start from copies (importing the samples took
    each desk 0.6 s of CPU). The tests of that import start from an empty one."""
    folder = tmp_path_factory.mktemp("first-start") / "data"
    app = create_app(folder)
    with TestClient(app):
        pass
    app.state.desk.store.close()
    return folder


@pytest.fixture
def desk_data(tmp_path: Path, first_start: Path) -> Path:
    """The test's data directory for a desk (`calib serve --data-dir`): a copy of `first_start`."""
    return Path(shutil.copytree(first_start, tmp_path / "data"))


@pytest.fixture(scope="module")
def client(
    tmp_path_factory: pytest.TempPathFactory, first_start: Path, desk_options: dict[str, Any]
) -> Iterator[TestClient]:
    """The module's in-process desk: the sample sessions and simulated robots at 50 times their speed, unless
    `desk_options` says otherwise; started once for the module's tests, stopped after them."""
    data_dir = tmp_path_factory.mktemp("desk") / "data"
    if not {"sample_dir", "config"} & set(desk_options):  # the built-in robots and their samples, as first started
        shutil.copytree(first_start, data_dir)
    app = create_app(data_dir, **{"time_scale": 50.0, **desk_options})
    with TestClient(app) as c:
        yield c


@pytest.fixture
def viser_server() -> Iterator[viser.ViserServer]:
    """A viser server of the test's own, on loopback and a free port."""
    server = viser.ViserServer(host="127.0.0.1", port=0, verbose=False)
    yield server
    server.stop()


class _Playwright:
    """Playwright's sync API for the whole session (each start of its driver and of a chromium costs about a second
    of CPU; the browser tests are in a dozen modules). Between its calls the API marks its event loop as running in
    this thread (playwright/_impl/_greenlets.py), where a later test's asyncio.run would then refuse to start: the
    mark is there while a test uses a browser (`use`), and taken off after it (`leave`)."""

    def __init__(self, api: Any) -> None:
        self.api = api
        self.loop = asyncio.get_running_loop()  # the mark, as the API left it

    def use(self) -> Any:
        asyncio._set_running_loop(self.loop)
        return self.api

    def leave(self) -> None:
        asyncio._set_running_loop(None)


@pytest.fixture(scope="session")
def _playwright() -> Iterator[_Playwright]:
    sync_api = pytest.importorskip("playwright.sync_api")  # imported by the browser tests only
    with sync_api.sync_playwright() as api:
        pw = _Playwright(api)
        pw.leave()
        yield pw
        pw.use()


# A test's first page opens in one context the test process keeps (tests/browser.py kept_context): chromium keeps
# 127.0.0.1's renderer process for it, where a page of a context of its own started one.
@dataclass
class _Chromium:
    browser: Browser
    kept: BrowserContext  # where a test opens its first page; its own first page the keeper


def _launched(playwright: _Playwright, *, webgl: bool) -> Iterator[_Chromium]:
    browser = launch(playwright.use(), webgl=webgl)
    kept = kept_context(browser)
    playwright.leave()
    yield _Chromium(browser, kept)
    playwright.use()
    browser.close()
    playwright.leave()


@pytest.fixture(scope="session")
def _chromium_process(_playwright: _Playwright) -> Iterator[_Chromium]:
    yield from _launched(_playwright, webgl=True)


@pytest.fixture(scope="session")
def _chromium_2d_process(_playwright: _Playwright) -> Iterator[_Chromium]:
    yield from _launched(_playwright, webgl=False)


class Tabs:
    """The browser of one test: `new_page` opens a page (the first a tab of the kept context, tests/browser.py
    kept_context; the others each a context of its own, a window of its own as the Browser's new_page gives it: a tab
    behind another gets no animation frames, and its clicks waited for them), `new_context` a context of the test's
    own. `scene=False`: the pages get an empty page in the 3-D view's iframe (the desk's /scene/ paths): the page's API
    calls, 2-D view and controls work as ever, the scene's viewer simply has no browser."""

    def __init__(self, chromium: _Chromium, *, scene: bool = True) -> None:
        self.browser, self.kept, self.scene = chromium.browser, chromium.kept, scene

    def new_page(self, *, viewport: ViewportSize | None = None) -> Page:
        if len(self.kept.pages) == 1:  # the keeper alone
            page = self.kept.new_page()
            if viewport is not None:
                page.set_viewport_size(viewport)
        else:
            page = self.browser.new_page(**({} if viewport is None else {"viewport": viewport}))
        if not self.scene:
            page.route(
                "**/scene/**",
                lambda route: route.fulfill(body="<!doctype html><title>no 3-D view</title>", content_type="text/html"),
            )
        return page

    def new_context(self, **options: Any) -> BrowserContext:
        assert self.scene, "the pages of a test without the 3-D view are opened by new_page"
        return self.browser.new_context(**options)


@contextmanager
def _in_use(playwright: _Playwright, chromium: _Chromium, *, scene: bool = True) -> Iterator[Tabs]:
    """The browser for one test: the contexts and tabs it opened are closed after it and the kept context's cookies
    cleared (off loopback a desk sets its read cookie, which a desk on another port of 127.0.0.1 would be sent)."""
    playwright.use()
    try:
        yield Tabs(chromium, scene=scene)
        for context in chromium.browser.contexts:
            if context is not chromium.kept:
                context.close()
        for page in chromium.kept.pages[1:]:
            page.close()
        chromium.kept.clear_cookies()
    finally:
        playwright.leave()


@pytest.fixture
def chromium(_playwright: _Playwright, _chromium_process: _Chromium) -> Iterator[Tabs]:
    """Headless chromium, one per test process (a start costs a second or two)."""
    with _in_use(_playwright, _chromium_process) as tabs:
        yield tabs


@pytest.fixture
def chromium_2d(request: pytest.FixtureRequest) -> Iterator[Tabs]:
    screenshots = bool(os.environ.get("CALIB_SCREENSHOTS"))
    # Without screenshots, a chromium of its own without a GPU process: its pages draw no 3-D view.
    chromium = request.getfixturevalue("_chromium_process" if screenshots else "_chromium_2d_process")
    with _in_use(request.getfixturevalue("_playwright"), chromium, scene=screenshots) as tabs:
        yield tabs
