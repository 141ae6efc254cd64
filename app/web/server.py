"""The dashboard's web server: FastAPI (the JSON API, the page and the 3-D scene) on one port.

One process, one uvicorn worker: the viser server runs its own threads on a loopback port, started and
stopped in the app's lifespan, and browsers reach it through this app (app/web/scene_proxy.py: its client page
and its websocket under /scene, behind the same guard as the API); calibrations run in a spawn process pool
(app/jobs/runner.py).
"""

from __future__ import annotations

import errno
import gc
import logging
import socket
import threading
from collections.abc import AsyncIterator, Callable, Iterable
from contextlib import asynccontextmanager
from pathlib import Path
from types import FrameType

from fastapi import FastAPI, Request
from fastapi.exceptions import RequestValidationError
from fastapi.responses import JSONResponse
from fastapi.staticfiles import StaticFiles

from calib_core import InputError

from ..clock import SYSTEM_CLOCK, Clock
from ..drivers import RobotFault
from ..errors import NotAllowed, NotFound, TooLarge
from ..robots.desk_config import DeskConfig
from ..scene.viewers import TooManyViewers
from ..services.safety import ConfirmationRequired
from ..store import StoreWriteError
from . import scene_proxy, security
from .api_docs import add_docs, keep_schema_names
from .desk import SAMPLE_DIR, Desk
from .limits import Limits
from .routers import api
from .routers.robots import VERSION
from .static_dir import STATIC_DIR

SHUTDOWN_WAIT_S = 3
log = logging.getLogger("calib.server")


def create_app(
    data_dir: Path,
    *,
    config: DeskConfig | None = None,
    sample_dir: Path | None = SAMPLE_DIR,
    host: str = "127.0.0.1",
    viser_port: int = 0,
    time_scale: float = 1.0,
    clock: Clock = SYSTEM_CLOCK,
    workers: int = 1,
    trusted_hosts: Iterable[str] | None = None,
    new_token: bool = False,
    limits: Limits | None = None,
) -> FastAPI:
    """`config`: the robots (None: the built-in ones). `host`: the address the server is bound to; off loopback
    every /api request but /api/health, and the scene under /scene, need the access token (app/web/security.py);
    `app.state.new_token` is the token made at this start (shown once), None when one was stored before;
    `app.state.closing` is set once the server is asked to stop (`serve`): the pages' event streams end then.
    `viser_port`: the viser server's port, on 127.0.0.1 whatever `host` is (0: any free one). `trusted_hosts`:
    the Host names answered (None: any). `limits`: the size of an upload and the rows of an import or a
    calibration (None: app/web/limits.py's defaults). `clock`: the drivers' (app/clock.py; a test's ManualClock)."""
    limits = limits or Limits()
    tokens = None
    token = None
    if not security.is_loopback(host):
        tokens = security.TokenFile(data_dir)
        token = tokens.renew() if new_token else tokens.ensure()
    desk = Desk(data_dir, loopback=security.is_loopback(host), limits=limits)

    @asynccontextmanager
    async def lifespan(app: FastAPI) -> AsyncIterator[None]:
        desk.start(
            config=config,
            sample_dir=sample_dir,
            viser_port=viser_port,
            time_scale=time_scale,
            clock=clock,
            workers=workers,
        )
        app.state.desk = desk
        try:
            yield
        finally:
            desk.stop()

    app = FastAPI(title="robot-selfcal dashboard", version=VERSION, lifespan=lifespan, docs_url=None, redoc_url=None)
    app.state.new_token = token
    app.state.closing = threading.Event()
    add_docs(app)
    keep_schema_names(app)
    app.include_router(api)
    app.include_router(scene_proxy.router)
    _error_handlers(app, desk.scrub)
    app.add_middleware(security.Guard, tokens=tokens, trusted_hosts=trusted_hosts, limits=limits)
    app.mount("/", StaticFiles(directory=STATIC_DIR, html=True), name="static")
    return app


def _error_handlers(app: FastAPI, scrub: Callable[[str], str]) -> None:
    """The user's mistakes answer 4xx with one sentence; a bug answers 500 without a traceback; no
    sentence names a path of the server (a file under the data directory is named by its file name)."""

    def detail(status: int, text: str) -> JSONResponse:
        return JSONResponse({"detail": scrub(text)}, status_code=status)

    @app.exception_handler(ConfirmationRequired)
    async def needs_confirmation(request: Request, exc: ConfirmationRequired) -> JSONResponse:
        return JSONResponse({"detail": scrub(exc.detail), "reasons": [scrub(r) for r in exc.reasons]}, status_code=409)

    @app.exception_handler(StoreWriteError)  # the disk is full or read-only: nothing was half-written
    async def cannot_write(request: Request, exc: StoreWriteError) -> JSONResponse:
        return detail(507, str(exc))

    @app.exception_handler(RobotFault)  # the robot is disconnected or not responding
    async def robot_fault(request: Request, exc: RobotFault) -> JSONResponse:
        return detail(503, str(exc))

    @app.exception_handler(TooLarge)  # an InputError beyond the desk's limits
    async def too_large(request: Request, exc: TooLarge) -> JSONResponse:
        return detail(413, str(exc))

    @app.exception_handler(NotAllowed)
    async def not_allowed(request: Request, exc: NotAllowed) -> JSONResponse:
        return detail(403, str(exc))

    @app.exception_handler(InputError)  # also a joint limit refused (drivers.LimitError)
    async def input_error(request: Request, exc: InputError) -> JSONResponse:
        return detail(422, str(exc))

    @app.exception_handler(TooManyViewers)
    async def too_many_viewers(request: Request, exc: TooManyViewers) -> JSONResponse:
        return detail(429, str(exc))

    @app.exception_handler(NotFound)
    async def not_found(request: Request, exc: NotFound) -> JSONResponse:
        return detail(404, str(exc))

    @app.exception_handler(RequestValidationError)
    async def invalid(request: Request, exc: RequestValidationError) -> JSONResponse:
        parts = []
        for err in exc.errors()[:5]:
            where = ".".join(str(x) for x in err.get("loc", ()) if x != "body") or "request body"
            parts.append(f"{where}: {err.get('msg', 'invalid')}")
        return detail(422, "; ".join(parts) or "invalid request")

    @app.exception_handler(Exception)
    async def internal(request: Request, exc: Exception) -> JSONResponse:
        log.exception("internal error on %s %s", request.method, request.url.path)
        return detail(500, f"internal error ({type(exc).__name__}); the server log has the details")


def serve(
    host: str,
    port: int,
    data_dir: Path,
    *,
    viser_port: int,
    config: DeskConfig | None = None,
    time_scale: float = 1.0,
    new_token: bool = False,
    limits: Limits | None = None,
) -> None:
    import uvicorn

    sock = listen(host, port)  # before anything starts or is announced: a port taken is said as such
    loopback = security.is_loopback(host)
    app = create_app(
        data_dir,
        config=config,
        host=host,
        viser_port=viser_port,
        time_scale=time_scale,
        trusted_hosts=security.LOOPBACK_NAMES if loopback else None,
        new_token=new_token,
        limits=limits,
    )
    url = f"http://{'127.0.0.1' if host in ('0.0.0.0', '::') else host}:{port}/"
    token = app.state.new_token
    if token is not None:
        print(f"calib dashboard: open {url}?token={token}", flush=True)
        print(
            f"access token (shown this once; stored hashed in {Path(data_dir) / security.TOKEN_FILE}; "
            f"calib serve --new-token makes a new one): {token}",
            flush=True,
        )
    else:
        print(f"calib dashboard: open {url}", flush=True)
        if not loopback:
            print("every API request needs the access token printed at the first start", flush=True)
    # The scene's websocket relays viser's messages uncompressed, as viser sends them: compressing meshes and
    # point clouds costs more time than it saves on a local network. An open page's event streams end when the
    # server is asked to stop (`closing`), before uvicorn waits for the requests under way: a stop waits for
    # them at most SHUTDOWN_WAIT_S (the scene's websockets close at once, 1012).

    class Server(uvicorn.Server):
        def handle_exit(self, sig: int, frame: FrameType | None) -> None:
            app.state.closing.set()
            super().handle_exit(sig, frame)

    config = uvicorn.Config(
        app,
        workers=1,
        log_level="warning",
        ws_per_message_deflate=False,
        timeout_graceful_shutdown=SHUTDOWN_WAIT_S,
    )
    try:
        Server(config).run(sockets=[sock])
    finally:
        # Stopped (uvicorn raises the signal that stopped it again), everything closed: the process ends. Its
        # objects need no more collecting: the interpreter's collections at exit over the web stack's took 0.35
        # of the 0.6 s from SIGINT to the process's end.
        gc.freeze()


def listen(host: str, port: int) -> socket.socket:
    """The server's listening socket; InputError when the address cannot be had (a port another program
    holds: say so, and how to choose another)."""
    try:
        family = socket.getaddrinfo(host, port, type=socket.SOCK_STREAM)[0][0]
        sock = socket.create_server((host, port), family=family, backlog=2048)
        # Its protocol said (create_server leaves it 0): asyncio sets TCP_NODELAY only on the connections of a
        # socket that says it is TCP. Without it each answer on a kept-alive connection waited 40 ms for the
        # browser's delayed ACK (uvicorn writes an answer's head and body apart: Nagle held the body back).
        return socket.socket(family, socket.SOCK_STREAM, socket.IPPROTO_TCP, fileno=sock.detach())
    except socket.gaierror:
        raise InputError(f"--host {host} is not an address of this machine") from None
    except OSError as exc:
        if exc.errno == errno.EADDRINUSE:
            raise InputError(
                f"port {port} on {host} is taken (another calib serve, or another program): stop it, or choose "
                f"another port with --port (scripts/run.sh --port {port + 1})"
            ) from None
        raise InputError(f"cannot listen on {host}:{port} ({exc.strerror})") from None
