"""Viewers (browser tabs) against `calib serve`, in headless Debian chromium:

- frame select to scene: from the request that selects a frame to the page's iframe showing it (viser's
  client store holding the frame's points), through the API's port and its websocket proxy;
- memory: the server's resident memory before, with N tabs open (each reviewing a sample session, one frame
  stepped), and after they are closed and their viewers dropped; twice, so growth from the first round to the
  second shows a leak. Each tab in a browser context of its own: one context allows 6 connections to a host,
  and every page holds one for the robot's event stream.

    .venv/bin/python benchmarks/viewers.py [--tabs 20] [--selects 100] [--rounds 2]

A page whose iframe is not at /scene/<viewer>/ (a desk before viewers: one scene for all) is measured too,
without a viewer header, so the same script gives the figure before and after.
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path
from urllib.parse import urlsplit

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent / "tests"))
from browser import launch, served, wait_for_scene

SESSIONS = ("robonaut-a-day1", "nao", "robonaut-a-day2")
PREDICTED = "/review/old/base/frame/predicted"
# The selected frame as the page's scene holds it: its predictions and measurements.
FRAME = f"""() => {{
  const s = window.__viserSceneTree && window.__viserSceneTree.getState();
  const p = k => s && s[k] ? Array.from(s[k].message.props.points).join(',') : '';
  return p('{PREDICTED}') + '|' + p('/review/old/base/frame/measured');
}}"""


def rss_mb(pid: int) -> float:
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith("VmRSS:"):
            return int(line.split()[1]) / 1024
    raise RuntimeError(f"no VmRSS for process {pid}")


def figures(ms: list[float]) -> str:
    a = np.array(ms)
    return f"median {np.median(a):.1f} ms, p95 {np.percentile(a, 95):.1f} ms, max {a.max():.1f} ms (n={len(a)})"


def scene_of(page):
    return next(f for f in page.frames if f != page.main_frame)


def open_tab(context, url: str, session: str):
    page = context.new_page()
    page.goto(url)
    page.wait_for_selector("body[data-ready='1']", timeout=60_000)
    wait_for_scene(page)
    page.click(f"li[data-session='{session}']")
    page.click("#tabs button[data-tab='review']")
    page.wait_for_selector("#frames tr.selected", state="attached")
    return page


def headers_of(page) -> dict[str, str]:
    """The page's viewer header (none for a desk with one scene for all)."""
    path = urlsplit(page.get_attribute("#scene", "src")).path
    return {"X-Viewer": path.split("/")[2]} if path.startswith("/scene/") else {}


def select_latency(page, server, selects: int) -> list[float]:
    """Select frames in turn (as the page does), each until the page's scene shows it."""
    headers = headers_of(page)
    rows = [int(r.get_attribute("data-frame")) for r in page.locator("#frames tr[data-frame]").all()]
    frame = scene_of(page)
    out = []
    for index in (rows * (selects // len(rows) + 1))[1 : selects + 1]:
        before = frame.evaluate(FRAME)
        t0 = time.perf_counter()
        r = server.post("/api/review/frame", json={"index": index}, headers=headers)
        r.raise_for_status()
        frame.wait_for_function(f"b => ({FRAME})() !== b", arg=before, polling=5, timeout=30_000)
        out.append((time.perf_counter() - t0) * 1e3)
    return out


def viewer_count(server) -> int | None:
    """How many viewers the desk has (None: a desk before viewers)."""
    r = server.get("/api/viewers")
    return len(r.json()) if r.status_code == 200 else None


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--tabs", type=int, default=20)
    ap.add_argument("--selects", type=int, default=100)
    ap.add_argument("--rounds", type=int, default=2)
    args = ap.parse_args()
    from playwright.sync_api import sync_playwright

    with tempfile.TemporaryDirectory() as tmp, served(Path(tmp) / "data") as server, sync_playwright() as pw:
        pid = server.process.pid
        browser = launch(pw)
        context = browser.new_context(viewport={"width": 1300, "height": 900})
        page = open_tab(context, server.url, "robonaut-a-day1")
        print(f"frame select to scene, through the API's port: {figures(select_latency(page, server, args.selects))}")
        page.close()

        time.sleep(8)
        print(f"server RSS before: {rss_mb(pid):.0f} MB")
        for round_ in range(1, args.rounds + 1):
            pages = []
            for k in range(args.tabs):
                tab_context = browser.new_context(viewport={"width": 1000, "height": 700})
                pages.append(open_tab(tab_context, server.url, SESSIONS[k % len(SESSIONS)]))
                pages[-1].click("#step-fwd")
            time.sleep(2)
            viewers = viewer_count(server)
            open_mb = rss_mb(pid)
            for p in pages:
                p.context.close()
            deadline = time.monotonic() + 60
            while viewer_count(server) not in (None, 1) and time.monotonic() < deadline:
                time.sleep(0.5)
            left = viewer_count(server)
            time.sleep(2)
            print(
                f"round {round_}: {args.tabs} tabs open ({viewers} viewers): {open_mb:.0f} MB; closed: "
                f"{left} viewer(s) left, {rss_mb(pid):.0f} MB"
            )
        browser.close()
        print(f"machine load average (1 min) at the end: {Path('/proc/loadavg').read_text().split()[0]}")


if __name__ == "__main__":
    main()
