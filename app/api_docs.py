"""The OpenAPI page (/docs) from Swagger UI files the desk serves itself (static/vendor/swagger-ui/), not
from a CDN, so it works on a robot's network without the internet. ReDoc (a CDN script too) is off."""

from __future__ import annotations

from fastapi import FastAPI
from fastapi.openapi.docs import get_swagger_ui_html
from fastapi.responses import HTMLResponse

ASSETS = "/vendor/swagger-ui"


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
