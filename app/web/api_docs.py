"""The OpenAPI page (/docs) from Swagger UI files the desk serves itself (static/vendor/swagger-ui/), not
from a CDN, so it works on a robot's network without the internet. ReDoc (a CDN script too) is off.

The document keeps its schemas' names: pydantic tells two answers of one class name apart by their modules
(app.web.routers.robot.Applied is `app__web__routers__robot__Applied`), and those names are the ones the document
gave them before the routers moved under app/web/ (KEPT_PREFIXES), which clients generated from it use."""

from __future__ import annotations

from typing import Any

from fastapi import FastAPI
from fastapi.openapi.docs import get_swagger_ui_html
from fastapi.responses import HTMLResponse

ASSETS = "/vendor/swagger-ui"
SCHEMAS = "#/components/schemas/"
KEPT_PREFIXES = {"app__web__routers__": "app__routers__"}  # a schema's name now -> the name the document keeps


def add_docs(app: FastAPI) -> None:
    """GET /docs: Swagger UI on the app's OpenAPI document (the app is made with docs_url=None)."""

    @app.get("/docs", include_in_schema=False)
    def docs() -> HTMLResponse:
        return get_swagger_ui_html(
            openapi_url=app.openapi_url or "/openapi.json",
            title=f"{app.title}: API",
            swagger_js_url=f"{ASSETS}/swagger-ui-bundle.js",
            swagger_css_url=f"{ASSETS}/swagger-ui.css",
            swagger_favicon_url=f"{ASSETS}/favicon-32x32.png",
            swagger_ui_parameters={"validatorUrl": None},  # the online validator's badge is an outside request
        )


def keep_schema_names(app: FastAPI) -> None:
    """The app's OpenAPI document with its schemas named as before (KEPT_PREFIXES), made once as FastAPI makes it."""
    made = app.openapi

    def openapi() -> dict[str, Any]:
        if app.openapi_schema is None:
            document = made()
            schemas = document.get("components", {}).get("schemas", {})
            document["components"]["schemas"] = {_kept(name): schema for name, schema in schemas.items()}
            app.openapi_schema = _refs_kept(document)
        return app.openapi_schema

    app.openapi = openapi  # type: ignore[method-assign]  # FastAPI's way to change its document


def _kept(name: str) -> str:
    for now, kept in KEPT_PREFIXES.items():
        if name.startswith(now):
            return kept + name.removeprefix(now)
    return name


def _refs_kept(node: Any) -> Any:
    """`node` with every reference to a schema naming it as the document keeps it."""
    if isinstance(node, dict):
        return {
            key: SCHEMAS + _kept(value.removeprefix(SCHEMAS))
            if key == "$ref" and isinstance(value, str) and value.startswith(SCHEMAS)
            else _refs_kept(value)
            for key, value in node.items()
        }
    if isinstance(node, list):
        return [_refs_kept(value) for value in node]
    return node
