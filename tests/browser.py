"""Shared by the browser test and the dashboard benchmark: a `calib serve` subprocess on free ports (`served`), the
same desk served in this process (`desk_served`: for tests of the page rather than of the command), and a headless
Debian chromium driven by Playwright (never `playwright install`)."""

from __future__ import annotations

import http.cookiejar
import ipaddress
import os
import signal
import socket
import subprocess
import sys
import time
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path

import httpx
import numpy as np

CHROMIUM = "/usr/bin/chromium"
CHROMIUM_ARGS = [
    "--no-sandbox",
    "--disable-background-networking",
    "--disable-component-update",
    "--disable-sync",
    "--no-first-run",
]
# WebGL without a GPU: Mesa's llvmpipe through EGL where Debian's Mesa is installed (scripts/test.sh installs it),
# else chromium's own SwiftShader. Opening a review's scene cost SwiftShader 5-6 s of CPU (compiling the
# scene's shaders), llvmpipe 2 s; the browser tests' time fell by a sixth. With llvmpipe the page is composited
# in software (the 3-D view's canvas still drawn by the GPU process): llvmpipe compositing each page cost more than it
# saves (benchmarks/scene_open.py --gpu-compositing; over the WebGL browser tests, a throwaway sampler's
# figures: chromium 93-95 -> 75-77 s of CPU).
MESA_EGL = Path("/usr/share/glvnd/egl_vendor.d/50_mesa.json")
SOFTWARE_COMPOSITING = "--disable-gpu-compositing"
WEBGL_ARGS = (
    ["--use-gl=angle", "--use-angle=gl-egl", "--ignore-gpu-blocklist", SOFTWARE_COMPOSITING]
    if MESA_EGL.exists()
    else ["--enable-unsafe-swiftshader", "--use-angle=swiftshader"]
)
PAPER_COLOURS = {"red": (255, 0, 0), "blue": (0, 0, 255), "green": (0, 200, 0)}


def listening(port: int) -> set[str]:
    """The addresses a TCP port is listened on (from /proc/net/tcp and tcp6): e.g. {"127.0.0.1"}."""
    found = set()
    for table, size in (("/proc/net/tcp", 4), ("/proc/net/tcp6", 16)):
        for line in Path(table).read_text().splitlines()[1:]:
            local, state = line.split()[1], line.split()[3]
            address, hex_port = local.split(":")
            if state == "0A" and int(hex_port, 16) == port:  # LISTEN
                raw = bytes.fromhex(address)
                # the kernel writes each 32-bit word in host (little-endian) order
                words = b"".join(raw[i : i + 4][::-1] for i in range(0, size, 4))
                found.add(str(ipaddress.ip_address(words)))
    return found


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


class _NoCookies(http.cookiejar.DefaultCookiePolicy):
    """Keeps no cookie: each request is sent as a fresh client would send it (the desk's token cookie too)."""

    def set_ok(self, cookie: http.cookiejar.Cookie, request: object) -> bool:
        return False


# One client for every request the tests send a desk: httpx.get and httpx.post make a client each, and each client
# loads the certificate store for an SSL context (about 30 ms of CPU; 40 s over a run of the suite). A connection
# per request (no keep-alive: none can be closed by the desk while it is reused) and no cookies kept, as before.
CLIENT = httpx.Client(
    timeout=30, cookies=http.cookiejar.CookieJar(policy=_NoCookies()), limits=httpx.Limits(max_keepalive_connections=0)
)


@dataclass
class Server:
    url: str
    process: subprocess.Popen | None  # None: the desk runs in this process (`desk_served`)
    data_dir: Path
    token: str | None = None  # the access token printed at the first start off loopback

    def get(self, path: str, **kw) -> httpx.Response:
        return CLIENT.get(f"{self.url}{path}", **kw)

    def post(self, path: str, **kw) -> httpx.Response:
        return CLIENT.post(f"{self.url}{path}", **kw)


@contextmanager
def served(
    data_dir: Path,
    timeout_s: float = 60.0,
    sim_speed: float = 1.0,
    *,
    host: str = "127.0.0.1",
    port: int = 0,
    calib: Path | None = None,
    cwd: Path | None = None,
    env: dict[str, str] | None = None,
    command: list[str] | None = None,
    extra: tuple[str, ...] = (),
) -> Iterator[Server]:
    """`calib serve` as a user starts it (bound to `host`, on `port` or a free one), until the block ends.
    `calib`: another installation's command (default: this environment's), run in `cwd` (default: the
    checkout) with `env` (default: this process's); `command`: the whole command instead (a checkout's
    `python -m app.cli`); `extra`: more options (`--ros2 FILE`)."""
    port = port or free_port()
    calib = calib or Path(sys.executable).parent / "calib"
    cmd = [*(command or [str(calib)]), "serve", "--host", host, "--port", str(port)]
    proc = subprocess.Popen(
        [*cmd, "--data-dir", str(data_dir), "--sim-speed", str(sim_speed), *extra],
        cwd=cwd or Path(__file__).resolve().parent.parent,
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        env={**(os.environ if env is None else env), "PYTHONUNBUFFERED": "1"},
    )
    server = Server(f"http://127.0.0.1:{port}", proc, data_dir)
    deadline = time.monotonic() + timeout_s
    try:
        while True:
            if proc.poll() is not None:
                raise RuntimeError(f"calib serve exited: {proc.stdout.read().decode()[-2000:]}")  # type: ignore[union-attr]
            try:
                if server.get("/api/health").status_code == 200:
                    break
            except httpx.HTTPError:
                pass
            if time.monotonic() > deadline:
                raise RuntimeError("calib serve did not answer /api/health in time")
            time.sleep(0.05)
        if host != "127.0.0.1":  # printed before the server started: the first lines
            for _ in range(20):
                line = proc.stdout.readline().decode()  # type: ignore[union-attr]
                if "?token=" in line:
                    server.token = line.rsplit("?token=", 1)[1].strip()
                    break
        yield server
    finally:
        proc.send_signal(signal.SIGINT)
        try:
            proc.wait(timeout=20)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()


@contextmanager
def desk_served(data_dir: Path, sim_speed: float = 1.0, desk: Path | None = None) -> Iterator[Server]:
    """The desk `calib serve --host 127.0.0.1 [--desk FILE]` makes (app.web.server.serve's application, on
    loopback, on a free port), served by uvicorn in a thread of this process until the block ends, stopped as
    SIGINT stops `calib serve`: for the browser tests, which test the page, not the command (tests/test_faults.py,
    test_wheel.py, test_browser_viewers.py and the examples start `calib serve` itself). A `calib serve` on a
    data directory started in before costs 1.5 s of CPU to start and stop (benchmarks/desk_start.py), most of it
    importing the web stack this process has imported already."""
    import threading

    import uvicorn

    from app.robots.desk_config import load_desk_config
    from app.web import security
    from app.web.server import SHUTDOWN_WAIT_S, create_app, listen

    sock = listen("127.0.0.1", 0)
    port = sock.getsockname()[1]
    app = create_app(
        data_dir,
        config=None if desk is None else load_desk_config(desk),
        host="127.0.0.1",
        viser_port=0,
        time_scale=sim_speed,
        trusted_hosts=security.LOOPBACK_NAMES,
    )
    config = uvicorn.Config(
        app, log_level="warning", ws_per_message_deflate=False, timeout_graceful_shutdown=SHUTDOWN_WAIT_S
    )
    server = uvicorn.Server(config)
    thread = threading.Thread(target=server.run, kwargs={"sockets": [sock]}, name="desk-served", daemon=True)
    thread.start()
    try:
        deadline = time.monotonic() + 60
        while not server.started:
            if not thread.is_alive() or time.monotonic() > deadline:
                raise RuntimeError("the in-process desk did not start")
            time.sleep(0.02)
        yield Server(f"http://127.0.0.1:{port}", None, data_dir)
    finally:
        app.state.closing.set()  # the pages' event streams end, as at a SIGINT
        server.should_exit = True
        thread.join(timeout=30)
        sock.close()
        if thread.is_alive():  # it would serve on into the next test
            raise RuntimeError("the in-process desk did not stop within 30 s")


def launch(playwright, *, webgl: bool = True):
    """Debian's chromium; `webgl=False` for pages that draw no 3-D view: without a GPU process (Mesa's GL composited
    every page, a second of a 2-D test's CPU)."""
    return playwright.chromium.launch(
        executable_path=CHROMIUM, args=[*CHROMIUM_ARGS, *(WEBGL_ARGS if webgl else ["--disable-gpu"])]
    )


# A page of a context of its own starts a renderer process; a page of a context where a page of the same site stays
# open does not (the site of http://127.0.0.1:<any port>/ is 127.0.0.1, where every desk of the tests is served): the
# desk's page 0.47-0.64 s of chromium's CPU the one way, 0.20-0.29 s the other (benchmarks/browser_pages.py).
KEEPER_URL = "http://127.0.0.1:9/"


def kept_context(browser):
    """A context of `browser` with a page kept open at KEEPER_URL (answered by the page's own route: nothing listens
    there), so that chromium keeps 127.0.0.1's renderer process for the context's next pages."""
    context = browser.new_context()
    keeper = context.new_page()
    keeper.route(
        KEEPER_URL, lambda route: route.fulfill(body="<!doctype html><title>kept</title>", content_type="text/html")
    )
    keeper.goto(KEEPER_URL)
    return context


def ready_page(browser, url: str, width: int = 1500, height: int = 1000):
    """A page of the desk at `url` in a window of `width` x `height` px, once it says it is ready."""
    page = browser.new_page(viewport={"width": width, "height": height})
    page.goto(url)
    page.wait_for_selector("body[data-ready='1']", timeout=60_000)
    return page


def new_nao_session(browser, url: str, name: str) -> tuple:
    """A page at the desk with the simulated NAO connected and a new capture session of that name selected
    (the page on step 1, Observe); the page and the session's id."""
    return new_session(browser, url, "nao", name)


def new_session(browser, url: str, robot: str, name: str) -> tuple:
    """A page at the desk with the simulated `robot` connected and a new capture session of that name selected
    (the page on step 1, Observe); the page and the session's id."""
    page = ready_page(browser, url)
    page.select_option("#robot-select", robot)
    page.wait_for_function(
        "r => document.querySelector('#robot-state').textContent.startsWith(r)", arg=robot, timeout=60_000
    )
    page.click("#new-session-toggle")
    page.fill("#new-session input[name=name]", name)
    page.click("#new-session button[type=submit]")
    page.wait_for_selector("#sessions li.selected")
    # Its review (an empty frame list's header) is the last thing the page loads for a new session, in the same
    # task as its last step, showing step 1: a tab clicked before then would be switched back to Observe.
    page.wait_for_selector("#frames th", state="attached")  # in step 4, hidden
    page.wait_for_selector("#tab-observe:not([hidden])")
    return page, page.get_attribute("#sessions li.selected", "data-session")


def nao_replay_tab(browser, url: str, name: str) -> tuple:
    """A new NAO capture session's page (`new_nao_session`) on its Replay tab, waiting up to 60 s for what it asks."""
    page, sid = new_nao_session(browser, url, name)
    page.set_default_timeout(60_000)
    page.click("#tabs button[data-tab='replay']")
    return page, sid


def colour_pixels(png: bytes, rgb: tuple[int, int, int], tol: int = 70) -> int:
    """How many pixels of a screenshot are within `tol` of a colour (per channel)."""
    import cv2

    img = cv2.imdecode(np.frombuffer(png, np.uint8), cv2.IMREAD_COLOR)[:, :, ::-1].astype(int)
    return int((np.abs(img - np.array(rgb)).max(axis=2) <= tol).sum())


# A pixel of a split-view canvas (CSS px from its top-left): [r, g, b].
PIXEL = (
    "([id, x, y]) => { const c = document.querySelector(id); const k = c.width / c.clientWidth;"
    " const d = c.getContext('2d').getImageData(Math.round(x * k), Math.round(y * k), 1, 1).data;"
    " return Array.from(d.slice(0, 3)); }"
)


def split_pixel(page, marks: dict, p: list[float], dx: float = 0.0) -> list[int]:
    """The colour [r, g, b] of the new side's 2-D view (#split-new, unzoomed) at image point p of a frame's
    marks (GET /api/review/marks/{frame}), `dx` CSS px to the right."""
    width, height = page.eval_on_selector("#split-new", "c => [c.clientWidth, c.clientHeight]")
    s = min(width / marks["width"], height / marks["height"])
    x = width / 2 + (p[0] - marks["width"] / 2) * s + dx
    return page.evaluate(PIXEL, ["#split-new", x, height / 2 + (p[1] - marks["height"] / 2) * s])


def wait_for_scene(page, timeout_ms: int = 60_000) -> None:
    """Until the viser client in the page's iframe has drawn triangles."""
    frame = page.frame_locator("#scene")
    frame.locator("body").wait_for(timeout=timeout_ms)
    viser_frame = next(f for f in page.frames if f != page.main_frame)
    viser_frame.wait_for_function(
        "() => window.__viserTestpoints && window.__viserTestpoints.rendererInfo"
        " && window.__viserTestpoints.rendererInfo.render.triangles > 0",
        timeout=timeout_ms,
    )


def job_ended(server: Server, job: str, timeout_s: float = 120.0) -> dict:
    """The job's last snapshot, read from its server-sent events (woken by each change, no polling)."""
    import json

    with CLIENT.stream("GET", f"{server.url}/api/jobs/{job}/events", timeout=timeout_s) as events:
        for line in events.iter_lines():
            if line.startswith("data:"):
                snap = json.loads(line[5:])
                if snap["state"] not in ("queued", "running"):
                    return snap
    raise AssertionError(f"job {job}'s events ended before it did")


def calibrated(server: Server, session: str, **request) -> str:
    """A calibration of the session made through the API (`request`: mode, base, holdout); its id."""
    job = server.post(f"/api/sessions/{session}/calibrations", json=request).json()["job"]
    snap = job_ended(server, job)
    assert snap["state"] == "done", snap
    return snap["result"]


def shot(page, name: str) -> None:
    """The page's screenshot as `name`.png in the folder CALIB_SCREENSHOTS names (none without it)."""
    folder = os.environ.get("CALIB_SCREENSHOTS")
    if folder:
        Path(folder).mkdir(parents=True, exist_ok=True)
        page.screenshot(path=str(Path(folder) / f"{name}.png"))
