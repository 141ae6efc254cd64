"""The dashboard's web server: FastAPI (the JSON API and the page) with the viser scene beside it.

One process, one uvicorn worker: the viser server runs its own threads and port, started and
stopped in the app's lifespan; calibrations run in a spawn process pool (app/jobs.py).
"""

from __future__ import annotations

import logging
from collections.abc import AsyncIterator
from contextlib import asynccontextmanager
from pathlib import Path

from fastapi import FastAPI, Request
from fastapi.exceptions import RequestValidationError
from fastapi.responses import JSONResponse
from fastapi.staticfiles import StaticFiles

from calib_core import InputError

from .api import VERSION, router
from .desk import PACKAGE_DIR, SAMPLE_DIR, Desk

STATIC_DIR = PACKAGE_DIR / "static"
log = logging.getLogger("calib.server")


def create_app(
    data_dir: Path,
    *,
    sample_dir: Path | None = SAMPLE_DIR,
    viser_host: str = "127.0.0.1",
    viser_port: int = 0,
    time_scale: float = 1.0,
    workers: int = 1,
) -> FastAPI:
    desk = Desk(
        data_dir,
        sample_dir=sample_dir,
        viser_host=viser_host,
        viser_port=viser_port,
        time_scale=time_scale,
        workers=workers,
    )

    @asynccontextmanager
    async def lifespan(app: FastAPI) -> AsyncIterator[None]:
        desk.start()
        app.state.desk = desk
        try:
            yield
        finally:
            desk.stop()

    app = FastAPI(title="robot-selfcal dashboard", version=VERSION, lifespan=lifespan)
    app.include_router(router)
    _error_handlers(app)
    app.mount("/", StaticFiles(directory=STATIC_DIR, html=True), name="static")
    return app


def _error_handlers(app: FastAPI) -> None:
    """The user's mistakes answer 4xx with one sentence; a bug answers 500 without a traceback."""

    def detail(status: int, text: str) -> JSONResponse:
        return JSONResponse({"detail": text}, status_code=status)

    @app.exception_handler(InputError)  # also a joint limit refused (drivers.LimitError)
    async def input_error(request: Request, exc: InputError) -> JSONResponse:
        return detail(422, str(exc))

    @app.exception_handler(KeyError)
    async def not_found(request: Request, exc: KeyError) -> JSONResponse:
        what = exc.args[0] if exc.args else "it"
        return detail(404, f"{what} not found")

    @app.exception_handler(IndexError)
    async def out_of_range(request: Request, exc: IndexError) -> JSONResponse:
        return detail(404, str(exc) or "index out of range")

    @app.exception_handler(RequestValidationError)
    async def invalid(request: Request, exc: RequestValidationError) -> JSONResponse:
        parts = []
        for err in exc.errors()[:5]:
            where = ".".join(str(x) for x in err.get("loc", ()) if x != "body")
            parts.append(f"{where}: {err.get('msg', 'invalid')}")
        return detail(422, "; ".join(parts) or "invalid request")

    @app.exception_handler(Exception)
    async def internal(request: Request, exc: Exception) -> JSONResponse:
        log.exception("internal error on %s %s", request.method, request.url.path)
        return detail(500, f"internal error ({type(exc).__name__}); the server log has the details")


def serve(host: str, port: int, data_dir: Path, *, viser_port: int, time_scale: float = 1.0) -> None:
    import uvicorn

    app = create_app(data_dir, viser_host=host, viser_port=viser_port, time_scale=time_scale)
    print(f"calib dashboard: open http://{'127.0.0.1' if host in ('0.0.0.0', '::') else host}:{port}/", flush=True)
    uvicorn.run(app, host=host, port=port, workers=1, log_level="warning")
