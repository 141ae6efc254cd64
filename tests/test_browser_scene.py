"""The Review's 3-D view as an instrument, in a real headless Chromium showing an in-process viser server's scene
with the script the desk's scene page inlines (static/viser_marks.js, app/web/scene_proxy.py; tests/test_viewers.py
checks it is there): the marks are drawn over the bodies (seen from behind the hand's sphere, its rings still
show), "frame it" shows both copies from nearly the same direction, and in the overlay it never puts the camera
inside the translucent copy."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import pytest
import viser
from browser import calibrated, colour_pixels, desk_served
from test_browser_viewers import open_page, open_session, scene_frame, step
from test_scene import _marks_world, build

from app.scene.framing import FRONT
from app.scene.review_scene.scene import ReviewScene
from app.scene.theme import configure
from app.web.static_dir import STATIC_DIR

pytestmark = pytest.mark.browser

RED, GREEN = (255, 0, 0), (0, 200, 0)
MIDDLE = {"x": 300, "y": 150, "width": 200, "height": 200}  # of the 800 x 500 page: away from viser's panels
SHOTS = Path(os.environ.get("CALIB_SCREENSHOTS", "/tmp/calib-screenshots"))

# The browser's camera (three.js, in viser's client) in the server's world (viser turns its three.js world: the root
# node's transform), and whether it has reached a position (viser glides there).
AT = """([p, tol]) => { const m = window.__viserMutable; const root = m && m.nodeRefFromName[''];
  if (!m || !m.camera || !root) return false; root.updateWorldMatrix(true, false);
  const c = m.camera.position.clone().applyMatrix4(root.matrixWorld.clone().invert());
  return Math.hypot(c.x - p[0], c.y - p[1], c.z - p[2]) < tol; }"""
# The marks' materials as the page's script left them (drawn over the bodies).
OVER = """() => { const n = window.__viserMutable && window.__viserMutable.nodeRefFromName;
  const o = n && n['/review/old/base/frame/measured']; if (!o) return false; let over = true, seen = 0;
  o.traverse(x => { if (x.material) { seen++; over = over && x.material.depthTest === false; } });
  return seen > 0 && over; }"""
# The translucent copy's visuals whose bounding box (the browser's own geometry) holds the camera, of how many.
INSIDE_GHOST = """() => { const m = window.__viserMutable; const n = m.nodeRefFromName; let boxes = 0;
  const inside = [];
  const ghost = Object.keys(n).filter(k => k.startsWith('/review/old/base/ghost/') && k.includes('/visual/'));
  for (const k of ghost) { n[k].updateWorldMatrix(true, true); n[k].traverse(o => { if (!o.geometry) return;
    o.geometry.computeBoundingBox(); const b = o.geometry.boundingBox.clone().applyMatrix4(o.matrixWorld);
    boxes++; if (b.containsPoint(m.camera.position)) inside.push(k); }); }
  return [boxes, inside]; }"""


def _settle(page, client: viser.ClientHandle) -> None:
    """Until the browser's camera stands where the server put it."""
    target = [float(v) for v in client.camera.position]
    page.wait_for_function(AT, arg=[target, 1e-3 * max(1.0, float(np.linalg.norm(target)))], timeout=30_000)


def test_marks_over_bodies_frame_it_and_the_overlay(chromium, viser_server: viser.ViserServer) -> None:
    configure(viser_server)  # as the desk's: the control panel out of the way
    scene = ReviewScene(viser_server)
    scene.load(build("robonaut-a", 6))
    scene.select(4)
    page = chromium.new_page(viewport={"width": 800, "height": 500})
    page.add_init_script(path=STATIC_DIR / "viser_marks.js")  # as the desk's scene page has it inlined
    page.goto(f"http://127.0.0.1:{viser_server.get_port()}/")
    page.wait_for_function(OVER, timeout=60_000)
    (client,) = viser_server.get_clients().values()
    SHOTS.mkdir(parents=True, exist_ok=True)

    # (c) The new copy's marks from the front, then from behind the hand's sphere at the same distance: its
    # prediction's dot (lifted onto the sphere's front) shows as much (the sphere would hide it).
    marks = _marks_world(scene, "new").mean(axis=0)
    dot = {}
    for name, direction in (("front", FRONT), ("behind", -FRONT)):
        client.camera.position = marks + 0.6 * direction  # moves the look-at point along
        client.camera.look_at = marks
        _settle(page, client)
        page.screenshot(path=SHOTS / f"scene-marks-{name}.png")
        dot[name] = colour_pixels(page.screenshot(clip=MIDDLE), GREEN, tol=40)  # the marks, where the camera looks
    assert dot["front"] > 50 and dot["behind"] > 0.7 * dot["front"], dot

    # (a) Frame it, side by side, the residuals x10: both copies' marks in view, from directions within 5 degrees.
    scene.set_magnify(10)
    scene.frame_marks()
    _settle(page, client)
    page.screenshot(path=SHOTS / "scene-frame-it.png")
    old, new = _marks_world(scene, "old"), _marks_world(scene, "new")
    to_old, to_new = client.camera.position - old.mean(axis=0), client.camera.position - new.mean(axis=0)
    assert np.degrees(np.arccos(to_old @ to_new / np.linalg.norm(to_old) / np.linalg.norm(to_new))) <= 5.0
    assert colour_pixels(page.screenshot(), RED, tol=40) > 50

    # (d) Frame it in the overlay: the camera outside every body of the translucent copy, as the browser draws it.
    scene.set_overlay(True)
    scene.frame_marks()
    _settle(page, client)
    page.screenshot(path=SHOTS / "scene-frame-it-overlay.png")
    boxes, inside = page.evaluate(INSIDE_GHOST)
    assert boxes > 3 and inside == [], inside


# The iframe's camera (three.js: its own world), and whether it stood still between two polls.
CAMERA = "() => { const c = window.__viserMutable.camera; return [...c.position.toArray(), c.fov]; }"
STILL = """() => { const c = window.__viserMutable && window.__viserMutable.camera; if (!c) return false;
  const now = [...c.position.toArray(), c.fov].join(); const still = now === window.__calibCamera;
  window.__calibCamera = now; return still; }"""
# The new copy's selected frame: its label and its residual lines' lengths.
NEW_FRAME = """() => { const s = window.__viserSceneTree.getState(); const p = s['/review/new/base/frame/lines'];
  const q = Array.from(p.message.props.points); const lengths = [];
  for (let i = 0; i + 5 < q.length; i += 6)
    lengths.push(Math.hypot(q[i + 3] - q[i], q[i + 4] - q[i + 1], q[i + 5] - q[i + 2]));
  return { label: s['/review/new/label'].message.props.text, lengths }; }"""


def _still(scene) -> list[float]:
    """The iframe's camera once it stands still (viser glides to a camera it is sent)."""
    scene.wait_for_function(STILL, polling=250, timeout=30_000)
    return scene.evaluate(CAMERA)


@pytest.mark.subprocess
def test_the_page_keeps_the_camera_frames_it_and_magnifies(chromium, desk_data: Path) -> None:
    """On the desk's page, a Robonaut session and its calibration: stepping frames leaves the 3-D camera where it
    was; "3-D residuals x10" draws the residual lines ten times as long and says so over the view and on the
    copies' labels; "Frame it" moves the camera onto the marks with a narrowed field of view; the marks are
    drawn over the bodies (the scene page's own script)."""
    with desk_served(desk_data) as server:
        calibrated(server, "robonaut-a-day1", mode="full", holdout=0.0)
        page = open_page(chromium, server.url, viewport={"width": 1500, "height": 1000})
        open_session(page, "robonaut-a-day1")
        scene = scene_frame(page)
        scene.wait_for_function("() => !!window.__viserSceneTree.getState()['/review/new/base/frame/lines']")
        scene.wait_for_function(OVER, timeout=30_000)
        # Drawn in software here: viser's notice of it is hidden in the view, the page says it in a line.
        page.wait_for_selector("#scene-software:not([hidden])")
        notice = "[...document.querySelectorAll('[class*=Notification-title]')].filter(t => t.offsetParent !== null)"
        assert scene.evaluate(f"() => {notice}.map(t => t.textContent)") == []
        before = _still(scene)
        step(page)
        step(page)
        assert _still(scene) == pytest.approx(before, abs=1e-9)  # as the operator left it

        shown = scene.evaluate(NEW_FRAME)
        assert page.is_hidden("#scene-magnify")
        page.select_option("#scene-magnify-select", "10")
        scene.wait_for_function(f"() => ({NEW_FRAME})().label.endsWith('residuals x10')", timeout=30_000)
        magnified = scene.evaluate(NEW_FRAME)
        assert magnified["lengths"] == pytest.approx([10 * x for x in shown["lengths"]], rel=1e-4)
        assert 0 < max(shown["lengths"]) < 0.01  # millimetres: invisible at x1
        assert page.text_content("#scene-magnify") == "residuals x10" and page.is_visible("#scene-magnify")

        page.click("#frame-marks")
        scene.wait_for_function("() => window.__viserMutable.camera.fov < 30", timeout=30_000)
        framed = _still(scene)
        assert framed[:3] != pytest.approx(before[:3], abs=1e-3)
        SHOTS.mkdir(parents=True, exist_ok=True)
        page.screenshot(path=SHOTS / "page-frame-it-x10.png")
