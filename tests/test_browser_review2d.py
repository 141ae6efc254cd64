"""The operator's 2-D review and frame list (issue 25, items 8 to 11), in a real headless Chromium at 1600x1000: the
overlay draws one ring per measurement with each calibration's prediction in its own colour; a session of several
sensors offers the 2-D view of its cameras, its frame list fits its panel, and lengths show in the display unit;
the 2-D zoom stays on the marks when zoomed and stepped; the frame list keeps the selected frame in view.

Set CALIB_SCREENSHOTS=/some/folder to keep a screenshot of each.
"""

from __future__ import annotations

import shutil
from collections.abc import Iterator
from pathlib import Path

import pytest
from browser import Server, calibrated, desk_served, ready_page, shot, split_pixel

pytestmark = [pytest.mark.browser, pytest.mark.subprocess]

# Red pixels of a 2-D view's canvas: the measurements' rings (the NAO's camera image is grey, the predictions and
# their residual lines blue and green).
RED_PIXELS = (
    "id => { const c = document.querySelector(id); const d = c.getContext('2d').getImageData(0, 0, c.width,"
    " c.height).data; let n = 0; for (let i = 0; i < d.length; i += 4) n += d[i] > 180 && d[i] - d[i + 1] > 100"
    " && d[i] - d[i + 2] > 100; return n; }"
)
# The selected row on screen: below the list's sticky header (its cells stick, not its row), inside the list and
# the window.
SELECTED_IN_VIEW = (
    "() => { const row = document.querySelector('#frames tr.selected'); if (!row) return false;"
    " const box = row.closest('.scroll').getBoundingClientRect(); const r = row.getBoundingClientRect();"
    " const head = document.querySelector('#frames th').getBoundingClientRect();"
    " return r.height > 0 && r.top >= head.bottom - 1 && r.bottom <= box.bottom + 1 && r.bottom <= innerHeight; }"
)


@pytest.fixture(scope="module")
def desk(tmp_path_factory: pytest.TempPathFactory, first_start: Path) -> Iterator[tuple[Server, dict[str, str]]]:
    """A desk with the NAO and Motoman samples calibrated (everything, no frame held out): the calibrations' ids."""
    with desk_served(shutil.copytree(first_start, tmp_path_factory.mktemp("desk") / "data")) as server:
        cals = {sid: calibrated(server, sid, mode="full", holdout=0.0) for sid in ("nao", "motoman-left-cube")}
        yield server, cals


def review_page(chromium, server: Server, session: str):
    """A page at 1600x1000 on the session's review (its newest calibration against the robot's active one), its
    first frame's 2-D view drawn."""
    page = ready_page(chromium, server.url, 1600, 1000)
    page.click(f"li[data-session='{session}']")
    page.wait_for_function("document.querySelector('#review-new').value !== ''")
    page.click("#tabs button[data-tab='review']")
    page.wait_for_selector("#frames tr.selected")
    return page


def frame_drawn(page, index: int) -> None:
    page.wait_for_function("i => document.querySelector('#split-new').dataset.frame === String(i)", arg=index)


def rows(page) -> list[int]:
    return page.eval_on_selector_all("#frames tr[data-frame]", "rs => rs.map(r => +r.dataset.frame)")


def test_the_overlay_draws_one_ring_per_measurement_and_each_prediction_in_its_colour(chromium_2d, desk) -> None:
    """NAO's nominal model (34 px) against its calibration (under 1 px), overlaid in 2-D: one image, a red ring per
    measurement, the old prediction a blue dot well outside it and the new one a green dot inside it."""
    server, cals = desk
    page = review_page(chromium_2d, server, "nao")
    first = rows(page)[0]
    frame_drawn(page, first)
    page.uncheck("#indices")  # no point numbers over the marks sampled
    page.check("#overlay")
    page.wait_for_function(
        "() => [...document.querySelectorAll('#split canvas')].filter((c) => c.checkVisibility()).length === 1"
    )
    server.post("/api/review", json={"session": "nao", "new": cals["nao"]})  # the default viewer's, as the page's
    marks = server.get(f"/api/review/marks/{first}").json()
    # A point whose old prediction is far from every measurement (no other ring over its dot).
    far = [
        k
        for k, p in enumerate(marks["old"])
        if marks["measured"][k] and min(abs(p[0] - q[0]) + abs(p[1] - q[1]) for q in marks["measured"] if q) > 20
    ]
    assert far, marks
    k = far[0]
    ring = split_pixel(page, marks, marks["measured"][k], 6)
    old = split_pixel(page, marks, marks["old"][k])
    new = split_pixel(page, marks, marks["new"][k])
    assert ring[0] > 150 and ring[0] > ring[1] + 80, ring
    assert old[2] > 150 and old[0] < 80 and old[1] < 120, old  # blue, away from the ring
    assert new[1] > 140 and new[0] < 80, new  # green, inside the ring
    page.locator("#split").scroll_into_view_if_needed()
    shot(page, "review-8-overlay")


def test_several_sensors_offer_their_cameras_in_2d_and_show_lengths_in_the_display_unit(chromium_2d, desk) -> None:
    """The Motoman sample (a laser tracker and two cameras) opens on the tracker: its errors in mm (the profile is in
    metres) in a frame list that fits its panel, and a choice of the cameras for the 2-D view; a camera chosen, its
    marks are drawn and its errors are in px."""
    server, cals = desk
    page = review_page(chromium_2d, server, "motoman-left-cube")
    answer = server.post("/api/review", json={"session": "motoman-left-cube", "new": cals["motoman-left-cube"]})
    table = {r["index"]: r for r in answer.json()["table"]}
    assert answer.json()["summary"]["unit"] == "m"
    assert page.is_visible("#split-sensor-label") and not page.is_visible("#split-new")
    options = page.eval_on_selector_all("#split-sensor option", "os => os.map(o => o.value)")
    assert options == ["", "camera1", "camera2"], options
    headers = page.eval_on_selector_all("#frames th", "hs => hs.map(h => h.textContent)")
    assert headers[2:] == ["old mm", "new mm ▼", "new−old mm"], headers
    first = rows(page)[0]
    cells = page.eval_on_selector(f"#frames tr[data-frame='{first}']", "r => [...r.children].map(c => c.textContent)")
    assert float(cells[2]) == pytest.approx(1000 * table[first]["err_old"], abs=1e-3), cells
    assert float(cells[4].replace("−", "-")) == pytest.approx(
        1000 * (table[first]["err_new"] - table[first]["err_old"]), abs=1e-3
    ), cells
    fits = page.eval_on_selector(
        "#frames",
        "t => [t.scrollWidth <= t.parentElement.clientWidth,"
        " t.getBoundingClientRect().right <= document.querySelector('aside').getBoundingClientRect().right]",
    )
    assert fits == [True, True], fits
    assert page.text_content("#summary th").startswith("error (mm)")
    assert page.eval_on_selector("#review-new", "s => s.selectedOptions[0].textContent").endswith(" mm")
    shot(page, "review-9-tracker")

    page.select_option("#split-sensor", "camera1")
    page.wait_for_function("document.querySelector('#review-sensor').value === 'camera1'")
    page.wait_for_selector("#split-new", state="visible")
    first = rows(page)[0]
    frame_drawn(page, first)
    assert page.text_content("#frames th[data-sort='err_old']") == "old px"
    server.post(
        "/api/review", json={"session": "motoman-left-cube", "new": cals["motoman-left-cube"], "sensor": "camera1"}
    )
    marks = server.get(f"/api/review/marks/{first}").json()
    assert (marks["width"], marks["height"]) == (6000, 4000)
    measured = [p for p in marks["measured"] if p]
    reds = sum(split_pixel(page, marks, p, 6)[0] > 150 for p in measured)
    assert reds >= 0.5 * len(measured), (reds, len(measured))
    shot(page, "review-9-camera1")


def test_the_2d_zoom_stays_on_the_marks(chromium_2d, desk) -> None:
    """NAO's board sits at the top of its image: + zooms centred on the measurements, so at 4x its rings are in view
    (not the floor); a step to the next frame keeps its rings in view (as many as the whole image shows)."""
    server, _ = desk
    page = review_page(chromium_2d, server, "nao")
    order = rows(page)
    frame_drawn(page, order[0])
    whole = page.evaluate(RED_PIXELS, "#split-new")
    assert whole > 100, whole
    page.click("#zoom-in")
    page.click("#zoom-in")
    page.wait_for_function("document.querySelector('#zoom-level').textContent === 'zoom 4.0x'")
    zoomed = page.evaluate(RED_PIXELS, "#split-new")
    assert zoomed >= 0.8 * whole, (zoomed, whole)
    page.locator("#split").scroll_into_view_if_needed()
    shot(page, "review-10-zoomed")

    page.click("#step-fwd")
    frame_drawn(page, order[1])
    assert page.text_content("#zoom-level") != "zoom 1.0x"
    stepped = page.evaluate(RED_PIXELS, "#split-new")
    shot(page, "review-10-stepped")
    page.click("#zoom-fit")
    page.wait_for_function("document.querySelector('#zoom-level').textContent === 'zoom 1.0x'")
    assert stepped >= 0.8 * page.evaluate(RED_PIXELS, "#split-new"), stepped


def test_the_frame_list_shows_the_selected_frame_after_a_sort_and_a_calibration(chromium_2d, desk) -> None:
    """The frame list scrolled to its end: sorted by frame number, the selected (worst) frame's row is in view; a
    calibration made on the page opens its review on its worst frame, in view."""
    server, _ = desk
    page = review_page(chromium_2d, server, "nao")
    page.wait_for_function(SELECTED_IN_VIEW)  # the tab shown and laid out (polled each frame)
    bottom = "() => { const s = document.querySelector('#frames').parentElement; s.scrollTop = s.scrollHeight; }"
    page.evaluate(bottom)
    assert not page.evaluate(SELECTED_IN_VIEW)
    page.click("#frames th[data-sort='index']")
    page.wait_for_function("document.querySelector('#frames th[data-sort=index]').textContent.endsWith('▼')")
    assert page.evaluate(SELECTED_IN_VIEW)
    shot(page, "review-11-sorted")

    page.evaluate(bottom)
    assert not page.evaluate(SELECTED_IN_VIEW)
    before = page.get_attribute("#apply-what", "data-id")
    page.click("#tabs button[data-tab='calibrate']")
    page.click("#calibrate-start")
    page.wait_for_selector("#tab-review:not([hidden])", timeout=120_000)
    page.wait_for_function("id => document.querySelector('#apply-what').dataset.id !== id", arg=before)
    assert page.get_attribute("#frames tr.selected", "data-frame") == str(rows(page)[0])
    page.wait_for_function(SELECTED_IN_VIEW, timeout=10_000)
    shot(page, "review-11-calibrated")
