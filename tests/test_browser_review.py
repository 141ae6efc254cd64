"""The operator's review without surprises (issue 25's first items), in a real headless Chromium: the review opens
on the session's newest calibration and Apply applies the one on screen; each tab follows its own robot; a reload
mid-replay gives back its controls; pause holds at once; noise is not coloured as change; no stale figures.

Set CALIB_SCREENSHOTS=/some/folder to keep a screenshot of each.
"""

from __future__ import annotations

import os
from pathlib import Path

import pytest
from browser import calibrated, ready_page, served

pytestmark = [pytest.mark.browser, pytest.mark.subprocess]
SHOTS = os.environ.get("CALIB_SCREENSHOTS")


def shot(page, name: str) -> None:
    if SHOTS:
        Path(SHOTS).mkdir(parents=True, exist_ok=True)
        page.screenshot(path=str(Path(SHOTS) / f"{name}.png"))


def test_a_session_opens_on_its_newest_calibration_and_apply_applies_the_one_on_screen(chromium, tmp_path) -> None:
    with served(tmp_path / "data") as server:
        older = calibrated(server, "robonaut-a-day1", mode="full", holdout=0.0)
        newer = calibrated(server, "robonaut-a-day1", mode="full", holdout=0.3)
        listed = [c["id"] for c in server.get("/api/sessions/robonaut-a-day1/calibrations").json()]
        assert listed == [newer, older]  # the API: newest first

        page = ready_page(chromium, server.url)
        page.on("dialog", lambda d: d.accept())
        page.click("li[data-session='robonaut-a-day1']")
        page.wait_for_function("document.querySelector('#review-new').value !== ''")
        assert page.input_value("#review-new") == newer
        assert page.eval_on_selector_all("#calibrations li", "ls => ls.map(l => l.dataset.calibration)") == listed
        page.click("#tabs button[data-tab='apply']")
        shown = page.get_attribute("#apply-what", "data-id")
        assert shown == newer and newer in page.text_content("#apply-what")
        shot(page, "review-1-newest")
        page.click("#apply")
        page.wait_for_function("id => document.querySelector('#active-cal').dataset.id === id", arg=shown)
        assert server.get("/api/robot/calibration", params={"robot": "robonaut-a"}).json()["id"] == shown
