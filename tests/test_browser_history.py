"""Step 6, History, in a real headless Chromium, as an operator reads it: a team of five NAOs on the desk
(`calib serve --desk`), ten simulated days of nao-1 whose left knee drifts 0.05 deg a day, one day of each other
NAO, nao-4's board mounted 2 mm off; each day imported with the date it was measured, calibrated and applied
through the API.

Set CALIB_SCREENSHOTS=/tmp/shots-history to keep a screenshot of each step.
"""

from __future__ import annotations

import json
import re
from pathlib import Path

import pytest
from browser import calibrated, desk_served, ready_page, shot

from app.cli import main as calib

pytestmark = [pytest.mark.browser, pytest.mark.subprocess]

DESK = """robots:
  - {name: nao-1, profile: nao, driver: simulated}
  - {name: nao-2, profile: nao}
  - {name: nao-3, profile: nao}
  - {name: nao-4, profile: nao}
  - {name: nao-5, profile: nao}
connected: nao-1
"""


def _applied(server, robot: str, csv: Path, measured: str) -> str:
    r = server.post(
        "/api/sessions/import",
        data={"robot": robot, "name": csv.stem, "measured": measured},
        files={"data": (csv.name, csv.read_bytes())},
    )
    assert r.status_code == 201, r.text
    cal = calibrated(server, r.json()["id"], mode="full")
    assert server.post(f"/api/calibrations/{cal}/apply", json={"confirm": True}).status_code == 200
    return cal


def test_the_history_names_the_drifting_knee_and_the_odd_nao(chromium_2d, tmp_path: Path) -> None:
    days = tmp_path / "days"
    assert calib(["simulate", "--robot", "nao", "--days", "10", "--drift", "LKneePitch:0.05", "--seed", "7",
                  "--start", "2026-11-10T09:00:00Z", "--out", str(days)]) == 0  # fmt: skip
    for i in (2, 3, 4, 5):
        shift = ["--shift", "LTransX:2"] if i == 4 else []
        assert calib(["simulate", "--robot", "nao", "--seed", str(30 + i), "--out", str(tmp_path / f"nao-{i}.csv"),
                      *shift]) == 0  # fmt: skip
    (tmp_path / "desk.yaml").write_text(DESK)
    with desk_served(tmp_path / "data", desk=tmp_path / "desk.yaml") as server:
        for d in json.loads((days / "days.json").read_text())["days"]:
            _applied(server, "nao-1", days / d["data"], d["measured"])
        for i in (2, 3, 4):  # nao-5 runs its nominal model
            _applied(server, f"nao-{i}", tmp_path / f"nao-{i}.csv", "2026-11-19T09:00:00Z")

        page = ready_page(chromium_2d, server.url, height=1400)
        page.click("#tabs button[data-tab='history']")
        page.wait_for_selector("#drift-summary .trend")
        trend = page.inner_text("#drift-summary .trend")
        assert "LKneePitch: +0.0" in trend and "deg a day over 9 days" in trend, trend
        rate = float(re.search(r"LKneePitch: \+([0-9.]+) deg a day", trend).group(1))
        assert abs(rate - 0.05) < 0.2 * 0.05
        assert page.locator("#drift-summary .flag").count() == 0  # nothing else flagged
        plots = page.locator("#drift-plots svg.drift-plot")
        assert plots.count() == 1 and plots.first.get_attribute("data-parameter") == "LKneePitch"
        assert page.locator("#drift-plots svg.drift-plot circle").count() == 10
        assert page.locator("#drift-plots svg.drift-plot line[stroke='#c00']").count() == 1  # the trend's line
        assert page.get_attribute("#drift-csv", "href") == "/api/robot/drift.csv?robot=nao-1"
        # The team: five NAOs, nao-4 named with its board, nao-5 on its nominal model.
        rows = page.locator("#team tr[data-robot]")
        assert rows.count() == 5
        assert page.locator("#team tr.odd").get_attribute("data-robot") == "nao-4"
        assert "nao-4: LTransX" in page.inner_text("#team-odd")
        assert "nominal model" in page.inner_text("#team tr[data-robot='nao-5']")
        first = page.locator("#team-parameters tr[data-parameter]").first  # each parameter across robots
        assert first.get_attribute("data-parameter") == "LTransX"
        assert first.locator("td.odd").count() == 1 and page.locator("#team-parameters th").count() == 5
        shot(page, "history-nao-1")
        page.check("#drift-all")
        page.wait_for_function("document.querySelectorAll('#drift-plots svg.drift-plot').length === 21")
        assert page.locator("#drift-plots svg.drift-plot").first.get_attribute("data-parameter") == "LKneePitch"
        # Another robot: its own history (one calibration: nothing to compare yet), the same team.
        page.select_option("#robot-select", "nao-3")
        page.wait_for_function("document.querySelector('#tab-history').dataset.robot === 'nao-3'")
        assert "One calibration applied to nao-3" in page.inner_text("#drift-summary")
        assert page.locator("#drift-plots svg").count() == 0
        assert page.locator("#team tr.me").get_attribute("data-robot") == "nao-3"
        page.select_option("#robot-select", "nao-5")
        page.wait_for_function("document.querySelector('#tab-history').dataset.robot === 'nao-5'")
        assert "No calibration applied to nao-5 yet" in page.inner_text("#drift-summary")
        shot(page, "history-nao-5")
        page.close()
