"""What a browser test's page of the desk costs chromium (issue 38, the suite's time; needs Debian's chromium).

The desk's page, opened `--pages` times in a chromium without a GPU process (the browser tests' `chromium_2d`), each
time until it says it is ready, then closed: each page in a context of its own (the Browser's new_page), or as a tab
of one context where a page of the same site (127.0.0.1, any port) stays open (tests/browser.py `kept_context`,
as tests/conftest.py `Tabs` opens a test's first page): chromium's CPU seconds a page, both ways, alternating.

    .venv/bin/python benchmarks/browser_pages.py [--pages 5] [--rounds 2]
"""

from __future__ import annotations

import argparse
import sys
import tempfile
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent.parent / "tests"))

from idle_desk import _chromium_cpu_s  # benchmarks/ is this script's folder


def _ready(page, url: str):
    """The desk's page at `url`, in a window of the browser tests' size, once it says it is ready."""
    page.set_viewport_size({"width": 1500, "height": 1000})
    page.goto(url)
    page.wait_for_selector("body[data-ready='1']", timeout=60_000)
    return page


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--pages", type=int, default=5)
    parser.add_argument("--rounds", type=int, default=2)
    args = parser.parse_args()
    from browser import desk_served, kept_context, launch
    from playwright.sync_api import sync_playwright

    with tempfile.TemporaryDirectory() as folder, desk_served(Path(folder) / "data") as server, sync_playwright() as pw:
        browser = launch(pw, webgl=False)
        kept = kept_context(browser)
        _ready(browser.new_page(), server.url).context.close()  # the server's and chromium's first, not counted
        for _ in range(args.rounds):
            for way, own in (("a context of its own", True), ("a tab of the kept context", False)):
                before = _chromium_cpu_s()
                for _ in range(args.pages):
                    page = _ready(browser.new_page() if own else kept.new_page(), server.url)
                    page.context.close() if own else page.close()
                cpu_s = (_chromium_cpu_s() - before) / args.pages
                print(f"the desk's page in {way}: chromium {cpu_s:.2f} s of CPU a page")
        browser.close()


if __name__ == "__main__":
    main()
