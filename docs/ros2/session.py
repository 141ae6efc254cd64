"""A session on the ROS 2 arm through the desk's API (README "Your ROS 2 robot"): replay, calibrate, apply.

    python docs/ros2/session.py [--url http://127.0.0.1:8000] [--robot arm] [--count 20]

Prints each step's answer and the joint offsets found. Standard library only.
"""

from __future__ import annotations

import argparse
import json
import time
import urllib.request


def call(url: str, path: str, body: dict | None = None) -> dict:
    data = None if body is None else json.dumps(body).encode()
    request = urllib.request.Request(f"{url}/api{path}", data, {"content-type": "application/json"})
    with urllib.request.urlopen(request, timeout=60) as answer:
        return json.loads(answer.read())


def wait(url: str, job: str) -> dict:
    while True:
        snapshot = call(url, f"/jobs/{job}")
        if snapshot["state"] in ("done", "failed", "cancelled"):
            return snapshot
        time.sleep(0.5)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--url", default="http://127.0.0.1:8000")
    ap.add_argument("--robot", default="arm")
    ap.add_argument("--count", type=int, default=20)
    args = ap.parse_args()
    session = call(args.url, "/sessions", {"robot": args.robot, "name": "ROS 2 session"})["id"]
    t0 = time.monotonic()
    replay = wait(args.url, call(args.url, f"/sessions/{session}/replay", {"count": args.count})["job"])
    print(f"replay of {args.count} configurations: {replay['state']} in {time.monotonic() - t0:.1f} s")
    if replay["state"] != "done":
        raise SystemExit(replay.get("error"))
    job = wait(args.url, call(args.url, f"/sessions/{session}/calibrations", {"mode": "offsets"})["job"])
    if job["state"] != "done":
        raise SystemExit(job.get("error"))
    cal = call(args.url, f"/calibrations/{job['result']}")
    print(
        f"calibration {cal['id']}: {cal['figures']['before']['rms']:.3f} -> {cal['figures']['after']['rms']:.3f} "
        f"{cal['figures']['after']['unit']} RMS"
    )
    for p in cal["parameters"]:
        if p["unit"] == "deg" and "." not in p["name"]:
            print(f"  {p['name']}: {p['value']:+.3f} deg")
    print(call(args.url, f"/calibrations/{cal['id']}/apply", {}))


if __name__ == "__main__":
    main()
