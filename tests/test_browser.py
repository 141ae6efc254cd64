"""End to end in a real headless Chromium: the operator's calibrate-review-apply path on the page.

Set CALIB_SCREENSHOTS=docs/screenshots to keep a screenshot of each workflow step.
"""

from __future__ import annotations

import os
import re
import shutil
from pathlib import Path

import pytest
from browser import PAPER_COLOURS, colour_pixels, launch, served, wait_for_scene

playwright_api = pytest.importorskip("playwright.sync_api")
pytestmark = pytest.mark.skipif(shutil.which("chromium") is None, reason="Debian's chromium is not installed")
SHOTS = os.environ.get("CALIB_SCREENSHOTS")


def shot(page, name: str) -> None:
    if SHOTS:
        Path(SHOTS).mkdir(parents=True, exist_ok=True)
        page.screenshot(path=str(Path(SHOTS) / f"{name}.png"))


def test_calibrate_review_and_apply_in_the_browser(tmp_path: Path) -> None:
    with served(tmp_path / "data") as server, playwright_api.sync_playwright() as pw:
        browser = launch(pw)
        page = browser.new_page(viewport={"width": 1500, "height": 1000})
        page.goto(server.url)
        page.wait_for_selector("body[data-ready='1']", timeout=60_000)
        wait_for_scene(page)

        # Open the first-day sample session and run a full calibration with a held-out share.
        page.click("li[data-session='robonaut-a-day1']")
        page.wait_for_selector("#frames tr[data-frame]", state="attached")
        page.click("#tabs button[data-tab='calibrate']")
        page.select_option("#mode", "full")
        page.fill("#holdout", "0.3")
        shot(page, "3-calibrate")
        before_active = page.get_attribute("#active-cal", "data-id")
        page.click("#calibrate-start")
        page.wait_for_function("document.querySelector('#job-state').textContent.startsWith('done')", timeout=120_000)
        page.wait_for_selector("#tab-review:not([hidden])")
        page.wait_for_selector("#parameters tr td", state="attached")

        # The summary shows the new calibration's figures, far below the old ones.
        old = float(page.text_content("#summary tr[data-figure='mean'] td[data-col='old']"))
        new = float(page.text_content("#summary tr[data-figure='mean'] td[data-col='new']"))
        assert new < 0.3 * old, (old, new)
        held = page.text_content("#summary tr[data-figure='mean'] td[data-col='heldout_new']")
        assert float(held) < 0.3 * old

        # Scrub to another frame: the label, the slider and the scene follow.
        first_label = page.text_content("#frame-label")
        page.click("#step-fwd")
        page.wait_for_function(f"document.querySelector('#frame-label').textContent !== {first_label!r}")
        page.wait_for_function("document.querySelector('#scene-ms').textContent.includes('ms')")
        page.locator("#all-frames").check()
        page.wait_for_timeout(1500)

        # The 3-D view really draws the papers' colours.
        png = page.locator("#scene").screenshot()
        for name, rgb in PAPER_COLOURS.items():
            assert colour_pixels(png, rgb) > 20, f"no {name} marks in the 3-D view"
        shot(page, "4-review")

        # Apply: the robot's active calibration changes to the new one, here and on the server.
        page.click("#tabs button[data-tab='apply']")
        new_id = page.text_content("#apply-what").strip()
        assert re.fullmatch(r"c-[0-9a-f]{8}", new_id), new_id
        page.click("#apply")
        page.wait_for_function(f"document.querySelector('#active-cal').dataset.id === {new_id!r}")
        assert new_id != before_active
        assert server.get("/api/robot/calibration", params={"robot": "robonaut-a"}).json()["id"] == new_id
        page.wait_for_selector("#history tr td", state="attached")
        shot(page, "5-apply")
        browser.close()


def test_observe_and_replay_in_the_browser(tmp_path: Path) -> None:
    with served(tmp_path / "data", sim_speed=10.0) as server, playwright_api.sync_playwright() as pw:
        browser = launch(pw)
        page = browser.new_page(viewport={"width": 1500, "height": 1000})
        page.goto(server.url)
        page.wait_for_selector("body[data-ready='1']", timeout=60_000)
        page.select_option("#robot-select", "nao")
        page.wait_for_function("document.querySelector('#robot-state').textContent.startsWith('nao')")

        # A new capture session; Observe: watch live, capture one frame on a click.
        page.click("#new-session-toggle")
        page.fill("#new-session input[name=name]", "browser session")
        page.click("#new-session button[type=submit]")
        page.wait_for_selector("#tab-observe:not([hidden])")
        sid = page.get_attribute("#sessions li.selected", "data-session")
        page.locator("#observe-on").check()
        page.click("#capture")
        page.wait_for_function(
            "sid => document.querySelector(`li[data-session='${sid}']`).textContent.includes('/1 frames')", arg=sid
        )
        page.wait_for_function("document.querySelector('#observe-state').textContent.startsWith('live:')")
        shot(page, "1-observe")
        page.locator("#observe-on").uncheck()

        # Replay: a dry run of three new configurations, then drive through them.
        page.click("#tabs button[data-tab='replay']")
        page.check("input[name=replay-source][value=count]")
        page.fill("#replay-count", "3")
        page.click("#dry-run")
        page.wait_for_function("document.querySelector('#dry-run-result').textContent.includes('3 configurations')")
        page.click("#replay-start")
        page.wait_for_function(
            "document.querySelector('#replay-state').textContent.startsWith('done')", timeout=120_000
        )
        shot(page, "2-replay")
        frames = server.get(f"/api/sessions/{sid}").json()["frames"]
        assert [f["index"] for f in frames] == [1, 2, 3, 4]
        assert sum(f["status"] == "measured" for f in frames[1:]) >= 1
        browser.close()
