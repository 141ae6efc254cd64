"""What a desk costs while nothing happens (issue 38, the suite's time: a desk is open through most of it).

- desk: an in-process desk of the built-in simulated robots, at rest: its share of a core over `--seconds`;
- page (with `--page`, needs Debian's chromium): a `calib serve` with one page open on it, idle: the server's and
  chromium's shares of a core, the page without and with the 3-D view.

    .venv/bin/python benchmarks/idle_desk.py [--seconds 10] [--page]
"""

from __future__ import annotations

import argparse
import os
import shutil
import sys
import tempfile
import time
from collections.abc import Callable
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent.parent / "tests"))

TICK_S = 1 / os.sysconf("SC_CLK_TCK")
SETTLE_S = 5.0  # after a start or a page's load (the 3-D view takes a few seconds), before measuring


def _stat_cpu_s(pid: str) -> float:
    """A process's CPU seconds so far (0 once it has gone)."""
    try:
        fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    except OSError:
        return 0.0
    return (int(fields[11]) + int(fields[12])) * TICK_S


def _chromium_cpu_s() -> float:
    """The CPU seconds so far of every chromium process."""
    pids = []
    for pid in filter(str.isdigit, os.listdir("/proc")):
        try:
            if b"chromium" in Path(f"/proc/{pid}/cmdline").read_bytes():
                pids.append(pid)
        except OSError:
            continue
    return sum(_stat_cpu_s(pid) for pid in pids)


def _shares(meters: dict[str, Callable[[], float]], seconds: float) -> dict[str, float]:
    """The share of a core each meter (CPU seconds so far) grows by over `seconds`."""
    time.sleep(SETTLE_S)
    before = {name: meter() for name, meter in meters.items()}
    time.sleep(seconds)
    return {name: (meter() - before[name]) / seconds for name, meter in meters.items()}


def desk(seconds: float) -> None:
    from fastapi.testclient import TestClient

    from app.web.server import create_app

    folder = Path(tempfile.mkdtemp())
    try:
        with TestClient(create_app(folder / "data")) as client:
            client.get("/api/health")
            share = _shares({"desk": time.process_time}, seconds)["desk"]
        print(f"idle desk (in-process, the built-in robots at rest): {100 * share:.1f}% of a core")
    finally:
        shutil.rmtree(folder, ignore_errors=True)


def page(seconds: float) -> None:
    from browser import launch, served
    from playwright.sync_api import sync_playwright

    folder = Path(tempfile.mkdtemp())
    try:
        with served(folder / "data") as server, sync_playwright() as pw:
            pid = str(server.process.pid)
            meters = {"calib serve": lambda: _stat_cpu_s(pid), "chromium": _chromium_cpu_s}
            browser = launch(pw, webgl=True)
            for view in (False, True):
                tab = browser.new_page(viewport={"width": 1500, "height": 1000})
                if not view:  # the 3-D view's iframe gets an empty page
                    tab.route(
                        "**/scene/**", lambda route: route.fulfill(body="<!doctype html>", content_type="text/html")
                    )
                tab.goto(server.url)
                tab.wait_for_selector("body[data-ready='1']", timeout=60_000)
                shares = _shares(meters, seconds)
                said = ", ".join(f"{name} {100 * share:.1f}%" for name, share in shares.items())
                print(f"idle page {'with' if view else 'without'} the 3-D view: {said} of a core")
                tab.close()
            browser.close()
    finally:
        shutil.rmtree(folder, ignore_errors=True)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--seconds", type=float, default=10.0, help="how long each idle state is measured")
    parser.add_argument("--page", action="store_true", help="also a served desk with a page open (chromium)")
    args = parser.parse_args()
    desk(args.seconds)
    if args.page:
        page(args.seconds)


if __name__ == "__main__":
    main()
