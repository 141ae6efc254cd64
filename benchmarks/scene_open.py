"""Opening a review's 3-D scene in a browser without a GPU: the CPU of headless chromium's processes (the GPU
process draws WebGL with Mesa's llvmpipe, as on an operator's machine without a GPU, and in the browser tests).

    .venv/bin/python benchmarks/scene_open.py [--robot robonaut-a] [--runs 3] [--environment-map] [--gpu-compositing]

A review of 6 simulated frames on an in-process viser server configured as the desk's (app/scene/theme.py
`configure`), opened in a new page of one chromium per run and left 4 s to load and draw; `--environment-map` adds
viser's environment map ("warehouse"), which the desk drew before it lit its scenes with a hemisphere light;
`--gpu-compositing` composites the page in the GPU process too (llvmpipe), as the browser tests' chromium did before.
Needs Debian's chromium (scripts/test.sh installs it).
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path

import numpy as np
import viser

sys.path.insert(0, str(Path(__file__).resolve().parent.parent / "tests"))
import browser
from sim_frames import measured_frames

from app.scene.review import Review
from app.scene.review_scene.scene import ReviewScene
from app.scene.theme import configure
from calib_core import SimulatedRobot, load_profile

TICKS = os.sysconf("SC_CLK_TCK")


def chromium_cpu_s() -> dict[str, float]:
    """CPU seconds so far of the running chromium processes, by kind (GPU process, renderers, the rest)."""
    out: dict[str, float] = {}
    for pid in filter(str.isdigit, os.listdir("/proc")):
        try:
            cmd = Path(f"/proc/{pid}/cmdline").read_bytes().decode(errors="replace")
            fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
        except OSError:
            continue
        if "chrom" not in cmd:
            continue
        kind = "gpu" if "--type=gpu-process" in cmd else "renderer" if "--type=renderer" in cmd else "other"
        out[kind] = out.get(kind, 0.0) + (int(fields[11]) + int(fields[12])) / TICKS
    return out


def main() -> None:
    from playwright.sync_api import sync_playwright

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--robot", default="robonaut-a")
    parser.add_argument("--runs", type=int, default=3)
    parser.add_argument("--environment-map", action="store_true")
    parser.add_argument("--gpu-compositing", action="store_true")
    args = parser.parse_args()
    if args.gpu_compositing:
        browser.WEBGL_ARGS = [a for a in browser.WEBGL_ARGS if a != browser.SOFTWARE_COMPOSITING]

    profile = load_profile(args.robot)
    sim = SimulatedRobot.from_profile(profile, seed=2).simulate(6)
    review = Review.build(profile, measured_frames(sim.data), sim.data, profile.nominal(), sim.true_params)
    server = viser.ViserServer(host="127.0.0.1", port=0, verbose=False)
    configure(server)
    if args.environment_map:
        server.scene.configure_environment_map("warehouse")
    scene = ReviewScene(server)
    scene.load(review)
    scene.select(review.indices[-1])
    totals = []
    try:
        with sync_playwright() as pw:
            for _ in range(args.runs):
                chromium = browser.launch(pw)
                before = chromium_cpu_s()
                page = chromium.new_page(viewport={"width": 1500, "height": 1000})
                page.goto(f"http://127.0.0.1:{server.get_port()}/")
                time.sleep(4.0)
                after = chromium_cpu_s()
                chromium.close()
                totals.append({kind: after[kind] - before.get(kind, 0.0) for kind in after})
    finally:
        server.stop()
    lit = "viser's environment map" if args.environment_map else "the desk's lights"
    lit += ", composited by the GPU process" if args.gpu_compositing else ""
    print(f"{args.robot}, {lit}: chromium's CPU to open the scene (median of {args.runs} runs)")
    for kind in ("gpu", "renderer", "other"):
        print(f"  {kind:8s} {np.median([t.get(kind, 0.0) for t in totals]):5.2f} s")


if __name__ == "__main__":
    main()
