"""Dashboard figures (issues 4, 13 and 25): page ready time, the Motoman sample's first and second open, a frame step in
the page until both the 2-D view and the 3-D scene show the new frame (with other viewers open), frame-scrub latency
on a 1000-frame session, and the server's memory with the three sample sessions open. Starts `calib serve` as a user
would, drives it over HTTP and, for the page, through a headless Debian chromium.

    .venv/bin/python benchmarks/dashboard.py [--frames 1000] [--selects 200] [--viewers 10] [--steps 40] [--loads 7]
        [--quick]

--quick: page ready, the Motoman's open and the frame step only (no memory figures, no 1000-frame session).
"""

from __future__ import annotations

import argparse
import io
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent / "tests"))
from browser import launch, served, wait_for_scene

from calib_core import SimulatedRobot, load_profile, to_csv


def rss_mb(pid: int) -> float:
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith("VmRSS:"):
            return int(line.split()[1]) / 1024
    return float("nan")


def children_rss_mb(pid: int) -> float:
    """The spawn pool's worker processes (calibrations run there, not in the server)."""
    total = 0.0
    for proc in Path("/proc").iterdir():
        if proc.name.isdigit():
            try:
                fields = (proc / "stat").read_text().rsplit(")", 1)[1].split()
            except OSError:
                continue
            if int(fields[1]) == pid:
                total += rss_mb(int(proc.name)) + children_rss_mb(int(proc.name))
    return total


def wait(server, job: str) -> dict:
    while True:
        j = server.get(f"/api/jobs/{job}").json()
        if j["state"] not in ("queued", "running"):
            return j
        time.sleep(0.2)


def figures(ms: list[float]) -> str:
    a = np.asarray(ms, float)
    missing = int(np.count_nonzero(~np.isfinite(a)))
    a = a[np.isfinite(a)]
    if not len(a):
        return f"none measured (n={missing})"
    more = f", {missing} not measured" if missing else ""
    return f"median {np.median(a):.1f} ms, p95 {np.percentile(a, 95):.1f} ms, max {a.max():.1f} ms (n={len(a)}{more})"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--frames", type=int, default=1000)
    ap.add_argument("--selects", type=int, default=200)
    ap.add_argument(
        "--viewers", type=int, default=10, help="tabs open on the desk while stepping (the stepping one too)"
    )
    ap.add_argument("--steps", type=int, default=40)
    ap.add_argument("--loads", type=int, default=7, help="page loads timed")
    ap.add_argument("--quick", action="store_true", help="page ready, the Motoman's open and the frame step only")
    args = ap.parse_args()
    with tempfile.TemporaryDirectory() as tmp, served(Path(tmp) / "data") as server:
        pid = server.process.pid
        print(f"server started: RSS {rss_mb(pid):.0f} MB")

        # Page ready: from navigation to the page's data-ready flag (the controls work, with the robots, the
        # sessions and the active calibration shown), to a first click answered right after it (the Calibrate
        # step shown: a main thread still busy, with the 3-D client's script for one, shows here), and to the
        # 3-D view drawn.
        from playwright.sync_api import sync_playwright

        print(f"machine load average (1 min) at the start: {Path('/proc/loadavg').read_text().split()[0]}")
        pw = sync_playwright().start()
        browser = launch(pw)
        ready, clicked, drawn = [], [], []
        for _ in range(args.loads):
            page = browser.new_page(viewport={"width": 1500, "height": 1000})
            t0 = time.perf_counter()
            page.goto(server.url)
            page.wait_for_selector("body[data-ready='1']", timeout=180_000)
            ready.append((time.perf_counter() - t0) * 1e3)
            page.click("#tabs button[data-tab='calibrate']", timeout=180_000)
            page.wait_for_selector("#tab-calibrate:not([hidden])", timeout=180_000)
            clicked.append((time.perf_counter() - t0) * 1e3)
            wait_for_scene(page)
            drawn.append((time.perf_counter() - t0) * 1e3)
            page.close()
        print(f"page ready (controls usable): {figures(ready)}")
        print(f"page ready and a first click answered: {figures(clicked)}")
        print(f"page ready with the 3-D view drawn: {figures(drawn)}")
        first_open(server, browser)
        step(server, browser, args.viewers, args.steps)
        if args.quick:
            browser.close()
            pw.stop()
            return

        # A tab left open: the reviews and selects below are its viewer's, drawn into its connected scene
        # (a request without X-Viewer addresses the default viewer, which no browser shows).
        known = {v["id"] for v in server.get("/api/viewers").json()}
        tab = browser.new_page(viewport={"width": 1500, "height": 1000})
        tab.goto(server.url)
        tab.wait_for_selector("body[data-ready='1']", timeout=180_000)
        wait_for_scene(tab)
        (opened,) = [v["id"] for v in server.get("/api/viewers").json() if v["connected"] and v["id"] not in known]
        viewer = {"X-Viewer": opened}

        # Memory with the three sample sessions open in review, after a calibration of each.
        for sid, mode in (("robonaut-a-day1", "full"), ("robonaut-a-day2", "daily"), ("nao", "full")):
            job = wait(server, server.post(f"/api/sessions/{sid}/calibrations", json={"mode": mode}).json()["job"])
            r = server.post("/api/review", json={"session": sid, "old": None, "new": job["result"]}, headers=viewer)
            for row in r.json()["table"][:20]:
                server.post("/api/review/frame", json={"index": row["index"]}, headers=viewer)
        print(f"server RSS with the three sample sessions reviewed: {rss_mb(pid):.0f} MB")
        print(f"  (+ calibration worker processes: {children_rss_mb(pid):.0f} MB)")

        # A 1000-frame session: import, calibrate, review, then scrub.
        profile = load_profile("robonaut-a")
        sim = SimulatedRobot.from_profile(profile, seed=5).simulate(args.frames)
        csv = to_csv(profile, sim.data).encode()
        t0 = time.perf_counter()
        sid = server.post(
            "/api/sessions/import",
            data={"robot": "robonaut-a", "name": f"{args.frames} frames"},
            files={"data": ("big.csv", io.BytesIO(csv), "text/csv")},
        ).json()["id"]
        print(f"import of {args.frames} frames: {(time.perf_counter() - t0) * 1e3:.0f} ms")
        t0 = time.perf_counter()
        job = wait(server, server.post(f"/api/sessions/{sid}/calibrations", json={"mode": "full"}).json()["job"])
        print(f"full calibration job on {args.frames} frames: {(time.perf_counter() - t0):.2f} s end to end")
        t0 = time.perf_counter()
        server.post("/api/review", json={"session": sid, "old": None, "new": job["result"]}, headers=viewer)
        print(f"review load ({args.frames} frames, old and new): {(time.perf_counter() - t0) * 1e3:.0f} ms")
        rng = np.random.default_rng(0)
        server_ms, round_ms = [], []
        for mode in ({"all": False, "overlay": False}, {"all": False, "overlay": True}):
            for index in rng.integers(1, args.frames + 1, args.selects):
                t0 = time.perf_counter()
                r = server.post("/api/review/frame", json={"index": int(index), **mode}, headers=viewer).json()
                round_ms.append((time.perf_counter() - t0) * 1e3)
                server_ms.append(r["server_ms"])
        print(f"frame select on {args.frames} frames, in the server: {figures(server_ms)}")
        print(f"frame select round trip over HTTP: {figures(round_ms)}")
        print(f"server RSS at the end: {rss_mb(pid):.0f} MB")
        print(f"machine load average (1 min) at the end: {Path('/proc/loadavg').read_text().split()[0]}")
        browser.close()
        pw.stop()


def first_open(server, browser, session: str = "motoman-left-cube") -> None:
    """The Motoman's three-sensor sample (216 frames of 30 markers) opened in a fresh page, the first time since
    the server started (its robot connected, its review's predictions computed) and again in another page: from
    the click (the page's click event) to its review summary shown, the page's 3-D view drawn before the click.
    Playwright's click itself waits for the element to be stable over animation frames, which software rendering
    delays, so the time from asking Playwright to click is printed beside it."""
    for when in ("first", "second"):
        page = browser.new_page(viewport={"width": 1500, "height": 1000})
        page.goto(server.url)
        page.wait_for_selector("body[data-ready='1']", timeout=180_000)
        wait_for_scene(page)
        page.evaluate(OPENED)
        t0 = time.perf_counter()
        page.click(f"li[data-session='{session}']")
        page.wait_for_function("window.__opened.summary", timeout=180_000)
        wall = (time.perf_counter() - t0) * 1e3
        shown = page.evaluate("window.__opened.summary - window.__opened.click")
        print(
            f"{session} opened in the page, the {when} time: {shown:.0f} ms from the click ({wall:.0f} ms from asking)"
        )
        page.close()


# The times of the next click and of the review summary shown after it (performance.now(), ms).
OPENED = """() => {
  window.__opened = {};
  document.addEventListener('click', () => { window.__opened.click ??= performance.now(); }, true);
  new MutationObserver(() => {
    const th = document.querySelector('#summary th');
    if (window.__opened.click && !window.__opened.summary && th && th.textContent.startsWith('error'))
      window.__opened.summary = performance.now();
  }).observe(document.body, { subtree: true, childList: true, characterData: true });
}"""


# In the page: click "next frame", then until the 2-D view (its canvas' frame) and the 3-D scene (the iframe's
# viser client: the new copy's prediction node got new points) both show the next frame; ms for each, for the
# server's answer to the frame select (its scene update done and sent: the page's fetch resolved; the page
# asks for the scene and draws the 2-D view at once), and the server's own time for the scene update (the page
# shows it with ?debug=1, once the server has answered).
STEP = """async (node) => {
  if (!window.__frameAnswers) {
    window.__frameAnswers = [];
    const fetched = window.fetch;
    window.fetch = async (...args) => {
      const res = await fetched(...args);
      if (String(args[0]).endsWith('/review/frame')) window.__frameAnswers.push(performance.now());
      return res;
    };
  }
  const tree = document.querySelector('#scene').contentWindow.__viserSceneTree;
  const points = () => { const n = tree.getState()[node]; return n && n.message.props.points; };
  const before = [document.querySelector('#split-new').dataset.frame, points()];
  const answered = window.__frameAnswers.length;
  const t0 = performance.now();
  document.querySelector('#step-fwd').click();
  let t2d = null, t3d = null, tServer = null;
  await new Promise((done) => {
    const tick = () => {
      const now = performance.now();
      if (t2d === null && document.querySelector('#split-new').dataset.frame !== before[0]) t2d = now;
      if (t3d === null && points() !== before[1]) t3d = now;
      if (tServer === null && window.__frameAnswers.length > answered) tServer = window.__frameAnswers[answered];
      if ((t2d !== null && t3d !== null && tServer !== null) || now - t0 > 10000) done(); else setTimeout(tick, 0);
    };
    tick();
  });
  // The answer's arrival as the browser's network stack saw it (the fetch resolves later when the page's main
  // thread is busy: the 3-D client in the iframe shares it).
  const entry = performance.getEntriesByType('resource')
    .filter((e) => e.name.endsWith('/review/frame') && e.startTime >= t0).pop();
  const server = document.querySelector('#scene-ms').textContent.match(/scene ([0-9.]+) ms/);
  const timing = entry
    ? [entry.responseEnd - t0, entry.requestStart - t0, entry.responseStart - entry.requestStart]
    : [NaN, NaN, NaN];
  return [t2d - t0, t3d - t0, tServer - t0, server ? +server[1] : NaN, ...timing];
}"""


def step(server, browser, viewers: int, steps: int) -> None:
    """NAO's sample session with a calibration, reviewed in `viewers` tabs (each its own viewer and scene); one
    of them steps through the frames: the time until its 2-D view and its 3-D scene show each next frame."""
    job = wait(server, server.post("/api/sessions/nao/calibrations", json={"mode": "full"}).json()["job"])
    assert job["state"] == "done", job
    # The other tabs: small (still drawing), each a browser context of its own, as tabs of separate browsers are
    # (one context's tabs share chromium's six connections per host, which their event streams hold).
    contexts = [browser.new_context(viewport={"width": 240, "height": 180}) for _ in range(viewers - 1)]
    others = []
    for context in contexts:
        page = context.new_page()
        page.set_default_timeout(180_000)
        page.goto(server.url)
        page.wait_for_selector("body[data-ready='1']", timeout=180_000)
        page.click("li[data-session='nao']")
        others.append(page)
    for page in others:
        page.wait_for_selector("#frames tr[data-frame]", state="attached", timeout=180_000)
    page = browser.new_page(viewport={"width": 1500, "height": 1000})
    page.goto(f"{server.url}/?debug=1")
    page.wait_for_selector("body[data-ready='1']", timeout=180_000)
    wait_for_scene(page)
    page.click("li[data-session='nao']")
    page.wait_for_selector("#split-new[data-frame]", state="attached", timeout=180_000)
    page.wait_for_timeout(1000)
    connected = sum(v["connected"] for v in server.get("/api/viewers").json())
    two_d, three_d, answered, in_server, arrived, sent, waited = [], [], [], [], [], [], []
    page.evaluate("performance.setResourceTimingBufferSize(100000)")
    for _ in range(steps):
        a, b, c, d, e, f, g = page.evaluate(STEP, "/review/new/base/frame/predicted")
        two_d.append(a)
        three_d.append(b)
        answered.append(c)
        in_server.append(d)
        arrived.append(e)
        sent.append(f)
        waited.append(g)
        page.wait_for_timeout(50)
    print(f"frame step in the page, NAO, {connected} viewers connected:")
    print(f"  scene update in the server: {figures(in_server)}")
    print(f"  the server's answer arrived (scene updated and sent; the browser's network timing): {figures(arrived)}")
    print(f"    of which the request sent (from the click): {figures(sent)}")
    print(f"    of which from the request sent to the answer's first byte: {figures(waited)}")
    print(f"  the server's answer handled by the page's script (its fetch resolved): {figures(answered)}")
    print(f"  2-D view drawn: {figures(two_d)}")
    both = np.maximum(two_d, arrived).tolist()
    print(f"  server + 2-D, both done (the later of the answer's arrival and the 2-D view drawn): {figures(both)}")
    summed = np.add(two_d, in_server).tolist()
    print(f"  server + 2-D, their sum per step (as if one waited for the other): {figures(summed)}")
    print(f"  3-D scene updated in the browser: {figures(three_d)}")
    print(f"  all three (2-D, server, 3-D): {figures(np.maximum.reduce([two_d, answered, three_d]).tolist())}")
    page.close()
    for context in contexts:
        context.close()


if __name__ == "__main__":
    main()
