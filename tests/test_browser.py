"""End to end in a real headless Chromium: the operator's calibrate-review-apply path on the page.

Set CALIB_SCREENSHOTS=docs/screenshots to keep a screenshot of each workflow step.
"""

from __future__ import annotations

import os
import re
import time
from pathlib import Path

import numpy as np
import pytest
import viser
from browser import PAPER_COLOURS, colour_pixels, desk_served, new_nao_session, split_pixel, wait_for_scene
from test_scene import URDF_DIR, build

from app.scene.review import frame_bounds_m
from app.scene.review_scene.layout import display_rotation
from app.scene.review_scene.scene import ReviewScene
from calib_core import load_profile

pytestmark = [pytest.mark.browser, pytest.mark.subprocess]
SHOTS = os.environ.get("CALIB_SCREENSHOTS")


def shot(page, name: str) -> None:
    if SHOTS:
        Path(SHOTS).mkdir(parents=True, exist_ok=True)
        close_notices(page)
        page.screenshot(path=str(Path(SHOTS) / f"{name}.png"))


def close_notices(page) -> None:
    """Close the notices of the 3-D view's client that show, as an operator would. viser's notice of software
    WebGL (the tests' headless chromium has no GPU) is hidden by the scene's page already (static/viser_notice.js):
    its close button, not visible, cannot be clicked."""
    notices = page.frame_locator("#scene").locator(".mantine-Notification-closeButton:visible")
    for _ in range(notices.count()):
        notices.first.click()
        page.wait_for_timeout(400)  # the notice slides out


def test_calibrate_review_and_apply_in_the_browser(chromium, desk_data: Path) -> None:
    """The operator's path: calibrate, review, apply. The review reads at a glance: rings for measurements with
    the new calibration's green dot visible inside them (3-D and 2-D), new-minus-old per frame with better/worse,
    stepping in the list's order, a scene that keeps its size while the rest loads, a zoomable 2-D view, distinct
    words for the solver's start and the old calibration; after the apply the panel and the header agree and the
    history says what the apply was."""
    with desk_served(desk_data) as server:
        page = chromium.new_page(viewport={"width": 1500, "height": 1000})
        page.goto(server.url)
        page.wait_for_selector("body[data-ready='1']", timeout=60_000)
        wait_for_scene(page)
        scene_height = page.eval_on_selector("#scene-wrap", "e => e.getBoundingClientRect().height")

        # The page opens on step 1; a replay offers the connected robot's own sessions only, newest first.
        assert page.is_visible("#tab-observe") and not page.is_visible("#tab-calibrate")
        robot = server.get("/api/robot").json()["robot"]
        created = {s["id"]: s["created"] for s in server.get("/api/sessions").json() if s["robot"] == robot}
        offered = page.eval_on_selector_all("#replay-from option", "os => os.map(o => o.value)")
        assert set(offered) == set(created) and len(offered) >= 1, (robot, offered)
        assert [created[i] for i in offered] == sorted(created.values(), reverse=True)
        page.click("#tabs button[data-tab='replay']")  # its menu of sessions (long names) stays inside the panel
        right = page.eval_on_selector(
            "#replay-from", "s => [s.getBoundingClientRect().right, s.closest('aside').getBoundingClientRect().right]"
        )
        assert right[0] <= right[1], right
        page.click("#tabs button[data-tab='observe']")

        # No session yet: nothing to calibrate, capture or replay into; Stop is always there. The 2-D view says how
        # to fill it.
        assert page.get_attribute("#split-old", "data-status") == "no frame"
        shot(page, "0-start")
        assert all(page.is_disabled(b) for b in ("#calibrate-start", "#calibrate-cancel", "#capture", "#replay-start"))
        assert page.is_enabled("#stop")

        # Open the first-day sample session and run a full calibration with a held-out share.
        page.click("li[data-session='robonaut-a-day1']")
        page.wait_for_selector("#frames tr[data-frame]", state="attached")
        page.click("#tabs button[data-tab='calibrate']")
        page.select_option("#mode", "full")
        page.fill("#holdout", "0.3")
        shot(page, "3-calibrate")
        before_active = page.get_attribute("#active-cal", "data-id")
        assert page.is_enabled("#calibrate-start") and page.is_disabled("#calibrate-cancel")
        page.click("#calibrate-start")
        page.wait_for_function("document.querySelector('#job-state').textContent.startsWith('done')", timeout=120_000)
        page.wait_for_selector("#calibrate-start:enabled", state="attached")  # the page goes on to the review
        assert page.is_disabled("#calibrate-cancel")  # nothing left to cancel
        page.wait_for_selector("#tab-review:not([hidden])")
        page.wait_for_selector("#parameters tr td", state="attached")

        # The summary shows the new calibration's figures, far below the old ones.
        old = float(page.text_content("#summary tr[data-figure='mean'] td[data-col='old']"))
        new = float(page.text_content("#summary tr[data-figure='mean'] td[data-col='new']"))
        assert new < 0.3 * old, (old, new)
        held = page.text_content("#summary tr[data-figure='mean'] td[data-col='heldout_new']")
        assert float(held) < 0.3 * old

        # The scene kept its size while the warnings and the table loaded below it; no timings for operators.
        page.wait_for_selector("#warnings p", state="attached")
        assert page.eval_on_selector("#scene-wrap", "e => e.getBoundingClientRect().height") == scene_height
        assert page.text_content("#scene-ms") == ""  # timings only with ?debug
        headers = page.eval_on_selector_all("#parameters th", "hs => hs.map(h => h.textContent)")
        assert headers[1:3] == ["start", "calibrated"], headers

        # Per frame: new minus old, better or worse, in the list and in the frame's summary.
        rows = page.eval_on_selector_all(
            "#frames tr[data-frame]", "rs => rs.map(r => [+r.dataset.frame, r.lastChild.dataset.verdict])"
        )
        assert sum(v == "better" for _, v in rows) > 0.8 * len(rows), rows
        first = rows[0][0]
        page.wait_for_function(f"document.querySelector('#frame-summary').dataset.frame === '{first}'")
        assert re.search(r"\(better, band \d+\.\d+ cm\)", page.text_content("#frame-summary"))  # beyond the noise

        # Stepping follows the list's order (worst first), whatever the frame numbers; sorted again, the new order.
        page.click("#step-fwd")
        page.wait_for_function(f"document.querySelector('#split-new').dataset.frame === '{rows[1][0]}'")
        page.click("#frames th[data-sort='index']")  # frame number, descending
        ordered = page.eval_on_selector_all("#frames tr[data-frame]", "rs => rs.map(r => +r.dataset.frame)")
        page.click("#step-fwd")
        after = ordered[ordered.index(rows[1][0]) + 1]
        page.wait_for_function(f"document.querySelector('#split-new').dataset.frame === '{after}'")

        # 2-D: the measured sphere is a hollow red ring with the prediction's dot showing, not a red disc on top.
        page.click(f"#frames tr[data-frame='{first}']")
        page.wait_for_function(f"document.querySelector('#split-new').dataset.frame === '{first}'")
        new_id = page.get_attribute("#apply-what", "data-id")
        server.post("/api/review", json={"session": "robonaut-a-day1", "new": new_id})  # the default viewer's
        marks = server.get(f"/api/review/marks/{first}").json()
        ring = split_pixel(page, marks, marks["measured"][0], 6)
        dot = split_pixel(page, marks, marks["new"][0])
        assert ring[0] > 150 and ring[0] > ring[1] + 80, ring  # anti-aliased red
        assert dot[1] > 140 and dot[0] < 80, dot  # green, not covered by the red measurement

        # 2-D zoom and magnified residuals.
        page.hover("#split-new")
        page.mouse.wheel(0, -300)
        page.wait_for_function("document.querySelector('#zoom-level').textContent !== 'zoom 1.0x'")
        page.select_option("#magnify", "10")

        # 3-D: the paper's colours, the new calibration's green dot visible in the one-frame view (looked at until
        # the scene has drawn them).
        deadline = time.monotonic() + 30
        while True:
            png = page.locator("#scene").screenshot()
            missing = [name for name, rgb in PAPER_COLOURS.items() if colour_pixels(png, rgb) <= 20]
            if not missing:
                break
            assert time.monotonic() < deadline, f"no {', '.join(missing)} marks in the 3-D view"
        shot(page, "4-review")

        # Meanwhile another calibration is applied through the API, so the history gets a row to re-apply.
        job = server.post("/api/sessions/robonaut-a-day1/calibrations", json={"mode": "daily", "base": new_id})
        deadline = time.monotonic() + 120
        while (j := server.get(f"/api/jobs/{job.json()['job']}").json())["state"] in ("queued", "running"):
            assert time.monotonic() < deadline, j
            time.sleep(0.2)
        other = j["result"]
        assert server.post(f"/api/calibrations/{other}/apply", json={"confirm": True}).status_code == 200

        # Apply: the robot's active calibration changes to the new one, here, in the Apply panel and on the server.
        page.click("#tabs button[data-tab='apply']")
        assert re.fullmatch(r"c-[0-9a-f]{8}", new_id), new_id
        page.click("#apply")
        page.wait_for_function(f"document.querySelector('#active-cal').dataset.id === {new_id!r}")
        page.wait_for_function(f"document.querySelector('#apply-active').dataset.id === {new_id!r}")
        assert new_id != before_active
        assert server.get("/api/robot/calibration", params={"robot": "robonaut-a"}).json()["id"] == new_id
        page.wait_for_selector(f"#history tr[data-calibration='{new_id}']", state="attached")
        history = page.text_content(f"#history tr[data-calibration='{new_id}']")
        assert "full" in history and "before" in history and "after" in history, history
        assert "fitted)" in history and "Robonaut" in history, history  # over which frames; the session's name
        shot(page, "5-apply")

        # The history's re-apply button shows whole inside the panel at this width (it was clipped), and works.
        reapply = f"#history tr[data-calibration='{other}'] button"
        page.wait_for_selector(reapply)
        inside = page.eval_on_selector(
            reapply,
            "b => { const a = b.closest('aside'); const r = b.getBoundingClientRect();"
            " const p = a.getBoundingClientRect(); return [r.width > 0, r.left >= p.left,"
            " r.right <= p.left + a.clientWidth, a.scrollWidth <= a.clientWidth, b.scrollWidth <= b.clientWidth]; }",
        )
        assert inside == [True] * 5, inside  # visible; left and right edges inside; no sideways scroll; text fits
        page.click(reapply)
        page.wait_for_function(f"document.querySelector('#active-cal').dataset.id === {other!r}")
        assert server.get("/api/robot/calibration", params={"robot": "robonaut-a"}).json()["id"] == other


def test_a_session_of_several_sensors_and_a_calibration_that_did_not_converge(chromium_2d, desk_data: Path) -> None:
    """The Motoman's three-sensor sample is reviewed one sensor at a time (the tracker in mm, a camera in px); a
    one-sensor session shows no sensor choice. A daily calibration from the nominal model stops at the solver's
    iteration limit: the page says so (job line, toast, warning) and applying it asks the operator first."""
    with desk_served(desk_data) as server:
        page = chromium_2d.new_page(viewport={"width": 1500, "height": 1000})
        page.goto(server.url)
        page.wait_for_selector("body[data-ready='1']", timeout=60_000)

        page.click("li[data-session='motoman-left-cube']")
        page.wait_for_selector("#frames tr[data-frame]", state="attached")
        page.click("#tabs button[data-tab='review']")
        page.wait_for_selector("#review-sensor-label:not([hidden])")
        assert page.eval_on_selector_all("#review-sensor option", "os => os.map(o => o.value)") == [
            "tracker",
            "camera1",
            "camera2",
        ]
        assert page.input_value("#review-sensor") == "tracker"
        assert page.text_content("#summary th") == "error (mm)"  # its metres, shown in mm
        page.select_option("#review-sensor", "camera1")
        page.wait_for_function("document.querySelector('#summary th').textContent === 'error (px)'")
        camera1 = server.post("/api/review", json={"session": "motoman-left-cube", "sensor": "camera1"}).json()
        measured = sum(1 for r in camera1["table"] if r["err_old"] is not None)
        shown = page.eval_on_selector_all("#frames tr[data-frame]", "rows => rows.length")
        assert shown == len(camera1["table"]) and measured > 100
        shot(page, "4b-review-sensor")

        page.click("li[data-session='robonaut-a-day1']")
        page.wait_for_function("document.querySelector('#summary th').textContent === 'error (cm)'")
        assert page.is_hidden("#review-sensor-label")
        page.click("#tabs button[data-tab='calibrate']")
        page.select_option("#mode", "daily")
        page.select_option("#base", "")
        page.fill("#holdout", "0")
        before = len(server.get("/api/sessions/robonaut-a-day1/calibrations").json())
        page.dblclick("#calibrate-start")  # an impatient operator: still one calibration
        page.wait_for_function(
            "document.querySelector('#job-state').textContent.includes('did not converge')", timeout=120_000
        )
        assert len(server.get("/api/sessions/robonaut-a-day1/calibrations").json()) == before + 1
        page.wait_for_function("document.querySelector('#toast').textContent.includes('did not converge')")
        page.wait_for_selector("#warnings [data-code='not-converged']")
        shot(page, "4c-not-converged")

        page.click("#tabs button[data-tab='apply']")
        asked: list[str] = []
        page.once("dialog", lambda d: (asked.append(d.message), d.dismiss()))
        before = server.get("/api/robot/calibration", params={"robot": "robonaut-a"}).json()["id"]
        page.click("#apply")
        deadline = time.monotonic() + 10
        while not asked and time.monotonic() < deadline:
            page.wait_for_timeout(100)
        assert asked and "did not converge" in asked[0], asked
        assert server.get("/api/robot/calibration", params={"robot": "robonaut-a"}).json()["id"] == before


def test_a_frame_whose_detection_failed_shows_as_not_found(chromium_2d, desk_data: Path) -> None:
    """Robonaut day 1's frames 3, 18 and 29 found no sphere (`measured: [null]`): selecting one raises no
    error in the page, both halves of the 2-D split view show that frame and say it was not found."""
    with desk_served(desk_data) as server:
        page = chromium_2d.new_page(viewport={"width": 1500, "height": 1000})
        errors: list[str] = []
        page.on("pageerror", lambda e: errors.append(str(e)))
        page.goto(server.url)
        page.wait_for_selector("body[data-ready='1']", timeout=60_000)
        page.click("li[data-session='robonaut-a-day1']")
        page.wait_for_selector("#frames tr[data-frame]", state="attached")
        page.click("#tabs button[data-tab='review']")
        table = server.post("/api/review", json={"session": "robonaut-a-day1"}).json()["table"]
        failed = [r["index"] for r in table if r["status"] == "not found"]
        assert all(server.get(f"/api/review/marks/{i}").json()["measured"] == [None] for i in failed)
        assert failed[:3] == [3, 18, 29], failed
        for index in (failed[0], 5, failed[1]):
            page.click(f"#frames tr[data-frame='{index}']")
            page.wait_for_function(
                f"['#split-old', '#split-new'].every(s => document.querySelector(s).dataset.frame === '{index}')"
            )
        assert page.get_attribute("#split-old", "data-status") == "not found"
        assert page.get_attribute("#split-new", "data-status") == "not found"
        page.wait_for_function(f"document.querySelector('#frame-summary').dataset.frame === '{failed[1]}'")
        summary = page.text_content("#frame-summary")  # said, not an error of "- cm"
        assert summary == f"Frame {failed[1]} not found: no error to show", summary
        toast = page.locator("#toast")
        assert toast.is_hidden() or "Cannot read" not in toast.text_content()
        assert errors == []
        shot(page, "4d-not-found")


def test_observe_and_replay_in_the_browser(chromium, desk_data: Path) -> None:
    with desk_served(desk_data, sim_speed=10.0) as server:
        # A new capture session; Observe: watch live, capture one frame on a click.
        page, sid = new_nao_session(chromium, server.url, "browser session")
        page.locator("#observe-on").check()
        page.click("#capture")
        page.wait_for_function(
            "sid => document.querySelector(`li[data-session='${sid}']`).textContent.includes('/1 frames')", arg=sid
        )
        page.wait_for_function("document.querySelector('#observe-state').textContent.startsWith('live:')")
        # The camera's latest look beside it: the boards' corners found (red) and predicted (blue).
        page.wait_for_function("document.querySelector('#live-caption').textContent.includes('points found')")
        # The image's look number and its caption agree (read together: a new look may land between two reads).
        page.wait_for_function(
            "() => { const n = Number(document.querySelector('#live-image').dataset.look);"
            " return n >= 1 && document.querySelector('#live-caption').textContent"
            ".startsWith(`look ${n}, lower_camera on `); }"
        )
        shot(page, "1-observe")
        page.locator("#observe-on").uncheck()
        page.wait_for_function("document.querySelector('#live-caption').textContent === ''")  # no stale look

        # Replay: a dry run of six new configurations, then drive through them (enough that the pause below
        # lands before the last frame: a pause that comes after it finds the replay done).
        page.click("#tabs button[data-tab='replay']")
        page.check("input[name=replay-source][value=count]")
        page.fill("#replay-count", "6")
        asked: list[dict] = []
        page.on(
            "request", lambda r: r.method == "POST" and r.url.endswith("/replay") and asked.append(r.post_data_json)
        )
        page.click("#dry-run")
        page.wait_for_function("document.querySelector('#dry-run-result').textContent.includes('6 configurations')")
        assert all(page.is_disabled(f"#replay-{a}") for a in ("pause", "resume", "abort"))  # nothing to pause
        page.click("#replay-start")
        # While it runs: pause (shown as paused, resume offered, no second replay), then resume.
        page.wait_for_selector("#replay-pause:enabled", timeout=30_000)
        assert page.is_disabled("#replay-start") and page.is_disabled("#replay-resume")
        page.click("#replay-pause")
        page.wait_for_function("document.querySelector('#replay-state').textContent.startsWith('paused')")
        assert page.is_enabled("#replay-resume") and page.is_disabled("#replay-pause")
        page.click("#replay-resume")
        # Watch live is off, yet the 3-D robot follows the replay; each frame joins the list as it is captured.
        deadline = time.monotonic() + 10
        while not any(v["live"] for v in server.get("/api/viewers").json() if v["connected"]):
            assert time.monotonic() < deadline, "the replay is not shown live"
            time.sleep(0.05)
        page.wait_for_function(
            "document.querySelectorAll('#frames tr[data-frame]').length >= 2"
            " && !document.querySelector('#replay-state').textContent.startsWith('done')",
            timeout=60_000,
        )
        page.wait_for_function(
            "document.querySelector('#replay-state').textContent.startsWith('done')", timeout=120_000
        )
        deadline = time.monotonic() + 10
        while any(v["live"] for v in server.get("/api/viewers").json()):  # off again, as before the replay
            assert time.monotonic() < deadline, "still shown live after the replay"
            time.sleep(0.05)
        assert all(page.is_disabled(f"#replay-{a}") for a in ("pause", "resume", "abort"))
        assert page.is_enabled("#replay-start")
        shot(page, "2-replay")
        frames = server.get(f"/api/sessions/{sid}").json()["frames"]
        assert [f["index"] for f in frames] == [1, 2, 3, 4, 5, 6, 7]
        assert sum(f["status"] == "measured" for f in frames[1:]) >= 1
        # The dry run checked the poses the replay drove through; the next plan is new poses.
        page.click("#dry-run")
        deadline = time.monotonic() + 10
        while len(asked) < 3 and time.monotonic() < deadline:
            page.wait_for_timeout(100)
        assert [a["dry_run"] for a in asked] == [True, False, True], asked
        assert asked[0]["seed"] == asked[1]["seed"] != asked[2]["seed"], asked

        # Another NAO added to the running desk from the page: listed, connected and drivable at once.
        page.click("#add-robot-toggle")
        page.fill("#add-robot input[name=name]", "nao-2")
        page.fill("#add-robot input[name=profile]", "nao")
        page.select_option("#add-robot select[name=driver]", "simulated")
        page.click("#add-robot button[type=submit]")
        page.wait_for_function("document.querySelector('#robot-select').value === 'nao-2'")
        page.wait_for_function("document.querySelector('#robot-state').textContent.startsWith('nao-2: ')")
        assert page.is_enabled("#new-session button") and page.is_enabled("#observe-on")
        assert page.is_disabled("#capture")  # no session of nao-2 to capture into yet
        added = {r["name"]: r for r in server.get("/api/robots").json()}["nao-2"]
        assert (added["model"], added["drivable"], added["simulated"]) == ("nao", True, True)
        assert server.get("/api/robot").json()["robot"] == "nao-2"


HOLDS = "p => !!window.__viserSceneTree && Object.keys(window.__viserSceneTree.getState()).some(k => k.startsWith(p))"


def _in_client(page, prefix: str) -> bool:
    """Whether the browser's viser scene holds a node under `prefix`."""
    return page.evaluate(HOLDS, prefix)


def _shown_box(scene: ReviewScene) -> np.ndarray:
    """The world box the scene frames the browsers' cameras on, which holds the copies it shows: the robot's frame
    origins at the nominal model and zero joint angles, turned upright and placed where each copy's root is, and
    their labels (kept on-screen); a review's selected frame too (tests/test_scene.py)."""
    state = scene.state()
    profile = load_profile(state["robot"])
    zero = np.zeros((1, len(profile.joints)))
    b = frame_bounds_m(profile, profile.nominal(), zero)
    corners = np.array([[b[i, 0], b[j, 1], b[k, 2]] for i in (0, 1) for j in (0, 1) for k in (0, 1)])
    corners = corners @ display_rotation(profile).T
    roots = [r for r in ("/review/old", "/review/new", "/live") if r in state["nodes"] and state["nodes"][r]["shown"]]
    labels = [np.add(state["nodes"][f"{r}/label"]["position"], state["nodes"][r]["position"])[None] for r in roots]
    points = np.concatenate([corners + state["nodes"][r]["position"] for r in roots] + labels)
    framed = np.array(state["camera"]["framing"]["box_m"])
    assert np.all(framed[0] <= points.min(axis=0) + 1e-9) and np.all(points.max(axis=0) <= framed[1] + 1e-9)
    return framed


def _framed(
    reports: list, since: float, box: np.ndarray, others: frozenset[int] = frozenset(), timeout_s: float = 30.0
) -> tuple:
    """Wait until a browser (not one of `others`) reports, after `since`, a camera framed on the box (_fits);
    return its latest report (time, client id, look_at, position, fov, width, height)."""
    deadline = time.monotonic() + timeout_s
    while True:
        latest = {r[1]: r for r in reports if r[0] > since and r[1] not in others}
        if latest and all(_fits(r, box) for r in latest.values()):
            return next(iter(latest.values()))
        if time.monotonic() > deadline:
            raise AssertionError(f"no browser camera framed on {box.round(3).tolist()} after the switch: {latest}")
        time.sleep(0.1)


def _fits(report: tuple, box: np.ndarray) -> bool:
    """The camera looks at the box's centre from a distance where the box's bounding sphere fits both fields of
    view, without the robot shrunk to a speck (less than 1.5 times the distance that just fits)."""
    _, _, look_at, position, fov, width, height = report
    radius = np.linalg.norm(box[1] - box[0]) / 2
    horizontal = 2 * np.arctan(np.tan(fov / 2) * width / height)
    just_fits = radius / np.sin(min(fov, horizontal) / 2)
    distance = np.linalg.norm(np.asarray(position) - look_at)
    return bool(np.allclose(look_at, box.mean(axis=0), atol=1e-4) and just_fits <= distance <= 1.5 * just_fits)


def _marks_and_labels(scene: ReviewScene) -> np.ndarray:
    """(N, 3) world points: the selected frame's marks on both copies and the copies' labels."""
    state = scene.state()
    R = display_rotation(load_profile(state["robot"]))
    out = []
    for side in ("old", "new"):
        root = np.asarray(state["nodes"][f"/review/{side}"]["position"])
        group = f"/review/{side}/base/frame"
        lift = np.asarray(state["nodes"][group]["position"])
        for part in ("measured", "predicted"):
            out.append((np.asarray(state["nodes"][f"{group}/{part}"]["points"]) + lift) @ R.T + root)
        out.append((np.asarray(state["nodes"][f"/review/{side}/label"]["position"]) + root)[None])
    return np.concatenate(out)


def _aimed(reports: list, since: float, points: np.ndarray, within: float, timeout_s: float = 30.0) -> tuple:
    """Wait until a browser reports, after `since`, a camera nearer than `within` to what it looks at that has
    every point inside its field of view (viser's client glides to a new camera: its reports on the way, the
    first of them from where it was, come first)."""
    deadline = time.monotonic() + timeout_s
    while True:
        latest = {r[1]: r for r in reports if r[0] > since}
        for r in latest.values():
            _, _, look_at, position, fov, width, height = r
            axis = (look_at - position) / np.linalg.norm(look_at - position)
            rays = (points - position) / np.linalg.norm(points - position, axis=1)[:, None]
            half = min(fov, 2 * np.arctan(np.tan(fov / 2) * width / height)) / 2
            if _distance(r) < within and np.all(np.arccos(np.clip(rays @ axis, -1, 1)) < half):
                return r
        if time.monotonic() > deadline:
            raise AssertionError(
                f"no browser camera nearer than {within:.2f} m shows the selected frame's marks: {latest}"
            )
        time.sleep(0.1)


def _distance(report: tuple) -> float:
    return float(np.linalg.norm(np.asarray(report[3]) - report[2]))


def test_the_scene_follows_a_robot_change_in_the_browser(chromium) -> None:
    """A Robonaut review in an open browser, then NAO, then the Motoman: nothing of the previous robot stays in
    the browser's scene, and every browser's camera is framed on the robot now shown (a browser opened later
    too)."""
    server = viser.ViserServer(host="127.0.0.1", port=0, verbose=False)
    reports: list[tuple] = []  # (time, client, look_at, position, fov, width, height) as the browsers send them

    def record(client: viser.ClientHandle) -> None:
        client.camera.on_update(
            lambda c: reports.append(
                (
                    time.time(),
                    client.client_id,
                    c.look_at.copy(),
                    c.position.copy(),
                    c.fov,
                    c.image_width,
                    c.image_height,
                )
            )
        )

    server.on_client_connect(record)
    try:
        scene = ReviewScene(server)
        scene.load(build("robonaut-a", 4))
        robonaut = {slot: c["node"] for slot, c in scene.state()["urdf"].items()}
        page = chromium.new_page(viewport={"width": 480, "height": 360})
        page.goto(f"http://127.0.0.1:{server.get_port()}/")
        page.wait_for_function(HOLDS, arg=f"{robonaut['old']}/visual/", timeout=60_000)
        assert _in_client(page, f"{robonaut['old']}/visual/shoulder_roll/")  # the arm with its sphere
        robonaut_distance = _distance(_framed(reports, 0.0, _shown_box(scene)))

        # "Frame it" turns the camera onto the selected frame's marks and labels (from afar, through a narrow field
        # of view: tests/test_scene.py).
        since = time.time()
        scene.select(3)
        scene.frame_marks()
        _aimed(reports, since, _marks_and_labels(scene), within=np.inf)

        since = time.time()
        scene.load(build("nao", 3, new=False))
        nao = scene.state()["urdf"]["old"]["node"]
        page.wait_for_function(HOLDS, arg=f"{nao}/visual/")
        box = _shown_box(scene)
        nao_distance = _distance(_framed(reports, since, box))
        gone = [node for node in robonaut.values() if _in_client(page, node)]
        assert gone == [], f"Robonaut copies still in the browser: {gone}"

        since = time.time()
        scene.set_robot(URDF_DIR / "motoman.urdf", "motoman")
        box = _shown_box(scene)
        assert box[1, 2] - box[0, 2] > 2.0  # metres tall, not NAO's half metre
        motoman_distance = _distance(_framed(reports, since, box))
        assert not _in_client(page, nao)
        assert motoman_distance > 3 * nao_distance and robonaut_distance > nao_distance

        # A browser that opens now starts framed on the Motoman, in its own (tall) window.
        since, first = time.time(), {r[1] for r in reports}
        second = chromium.new_page(viewport={"width": 300, "height": 480})
        second.goto(f"http://127.0.0.1:{server.get_port()}/")
        assert _framed(reports, since, box, others=frozenset(first))[1] not in first
        assert len(server.get_clients()) == 2
    finally:
        server.stop()


def test_joint_sliders_send_the_whole_configuration_within_the_margin_and_revert_on_a_refusal(
    chromium_2d,
    desk_data: Path,
) -> None:
    """A second slider moved while the first joint still moves: both joints arrive (each slider sends the whole
    configuration the sliders show, not the others' mid-motion readings); the sliders end at the limits less
    the driver's margin; a refused move puts the sliders back to the robot's readings with the server's reason."""
    with desk_served(desk_data) as server:
        page = chromium_2d.new_page(viewport={"width": 1500, "height": 1000})
        page.goto(server.url)
        page.wait_for_selector("body[data-ready='1']", timeout=60_000)
        robot = server.get("/api/robot").json()
        info = {r["name"]: r for r in server.get("/api/robots").json()}[robot["robot"]]
        margin = info["margin_deg"]
        assert margin > 0
        for j in info["joints"]:
            lo, hi = (float(page.get_attribute(f"input[data-joint='{j['name']}']", a)) for a in ("min", "max"))
            m = min(margin, (j["upper_deg"] - j["lower_deg"]) / 2)
            assert (lo, hi) == pytest.approx((j["lower_deg"] + m, j["upper_deg"] - m)), j["name"]
        page.wait_for_function("document.querySelector('#robot-state').textContent.endsWith('still')")
        (a, b) = [j for j in info["joints"] if j["upper_deg"] - j["lower_deg"] > 60][:2]
        start = server.get("/api/robot").json()["joints"]
        goal = {}
        for j in (a, b):  # 25 deg towards the farther limit: a second or so of motion
            up = j["upper_deg"] - start[j["name"]] > start[j["name"]] - j["lower_deg"]
            goal[j["name"]] = round(start[j["name"]] + (25.0 if up else -25.0), 1)
        slide = "([s, v]) => { const e = document.querySelector(`input[data-joint='${s}']`); e.value = v;"
        slide += " e.dispatchEvent(new Event('change')); }"
        page.evaluate(slide, [a["name"], goal[a["name"]]])
        page.wait_for_timeout(150)
        page.evaluate(slide, [b["name"], goal[b["name"]]])
        deadline = time.monotonic() + 20
        while True:
            state = server.get("/api/robot").json()
            if not state["moving"] and all(abs(state["joints"][n] - g) < 0.3 for n, g in goal.items()):
                break
            assert time.monotonic() < deadline, (goal, state["joints"], state["moving"])
            time.sleep(0.1)
        page.wait_for_function(  # the sliders show the configuration reached, from the page's next reading
            "goal => Object.entries(goal).every(([n, g]) =>"
            " Math.abs(+document.querySelector(`input[data-joint='${n}']`).value - g) <= 0.3)",
            arg=goal,
        )
        for n, g in goal.items():
            assert float(page.input_value(f"input[data-joint='{n}']")) == pytest.approx(g, abs=0.3), n

        # A move the server refuses: its reason is shown and the sliders go back to the readings.
        reason = "shoulder_roll 88.0 deg is within the 2.0 deg safety margin of its upper limit (test)"
        page.route(
            "**/api/robot/move",
            lambda route: route.fulfill(status=422, content_type="application/json", body=f'{{"detail": "{reason}"}}'),
        )
        page.evaluate(slide, [a["name"], goal[a["name"]] - 10])
        page.wait_for_function("r => document.querySelector('#toast').textContent.includes(r)", arg=reason)
        page.wait_for_function(
            "([s, v]) => Math.abs(+document.querySelector(`input[data-joint='${s}']`).value - v) < 0.11",
            arg=[a["name"], state["joints"][a["name"]]],
        )
