"""/docs works without the internet: Swagger UI comes from the desk itself (static/vendor/swagger-ui/), and
with every request to anywhere but the desk refused, headless Chromium still lists the API's operations."""

from __future__ import annotations

from pathlib import Path
from urllib.parse import urlparse

import pytest
from browser import desk_served

pytestmark = [pytest.mark.browser, pytest.mark.subprocess]


def test_the_openapi_page_renders_offline(chromium_2d, desk_data: Path) -> None:
    with desk_served(desk_data) as server:
        paths = server.get("/openapi.json").json()["paths"]
        operations = sum(len(methods) for methods in paths.values())
        assert server.get("/redoc").status_code == 404  # ReDoc would load a CDN script: off
        refused: list[str] = []

        def offline(route) -> None:
            if urlparse(route.request.url).hostname in ("127.0.0.1", "localhost"):
                route.continue_()
            else:
                refused.append(route.request.url)
                route.abort()

        page = chromium_2d.new_page()
        page.route("**/*", offline)
        page.goto(f"{server.url}/docs")
        page.locator(".opblock").first.wait_for(timeout=30_000)
        assert page.locator(".opblock").count() == operations
        assert page.locator(".opblock-summary-path", has_text="/api/health").count() >= 1
        assert refused == []  # nothing was even asked of the internet
