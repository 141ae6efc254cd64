"""The dashboard under load on loopback: people scrubbing frames while the page polls the API.

    .venv/bin/python benchmarks/load.py                # one minute
    .venv/bin/python benchmarks/load.py --seconds 15   # a smoke check

Starts `calib serve` as a user would (tests/browser.py's `served`: free ports, a fresh data dir with the
sample sessions), then for --seconds runs at once:
  - --clients browser-like clients, each loading the review of a sample session once and then scrubbing
    at --rate steps/s: POST /api/review/frame at a random frame, GET /api/review/marks/{frame}, GET that
    frame's camera image. Each client is a viewer of its own (its X-Viewer header), as a browser tab is; no
    browser draws their scenes.
  - a background of --background API requests/s, open loop (sent on schedule, whatever the answers'
    latency): session list, a session's detail, jobs, robot, active calibration, in turn.
Reports errors (any non-2xx or transport failure), p50/p99 latency per kind, requests/s achieved, and
the server's resident memory before the load, after a warm-up (the first fifth) and at the end.
"""

from __future__ import annotations

import argparse
import asyncio
import random
import sys
import tempfile
import time
from collections import defaultdict
from pathlib import Path

import httpx
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent / "tests"))
from browser import served

BACKGROUND = [
    ("sessions", "/api/sessions"),
    ("session detail", "/api/sessions/robonaut-a-day1"),
    ("jobs", "/api/jobs"),
    ("robot", "/api/robot"),
    ("robot calibration", "/api/robot/calibration"),
]
REQUEST_TIMEOUT_S = 30.0


def rss_mb(pid: int) -> float:
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith("VmRSS:"):
            return int(line.split()[1]) / 1024
    raise RuntimeError(f"no VmRSS for process {pid}")


class Tally:
    def __init__(self) -> None:
        self.latency_ms: dict[str, list[float]] = defaultdict(list)
        self.errors: dict[str, int] = defaultdict(int)
        self.examples: list[str] = []

    async def request(self, http: httpx.AsyncClient, kind: str, method: str, url: str, **kw) -> httpx.Response | None:
        t0 = time.perf_counter()
        try:
            r = await http.request(method, url, **kw)
        except httpx.HTTPError as exc:
            self._error(kind, f"{kind}: {type(exc).__name__}: {exc}")
            return None
        self.latency_ms[kind].append((time.perf_counter() - t0) * 1e3)
        if not r.is_success:
            self._error(kind, f"{kind}: {method} {url} -> {r.status_code} {r.text[:200]}")
            return None
        return r

    def _error(self, kind: str, text: str) -> None:
        self.errors[kind] += 1
        if len(self.examples) < 5:
            self.examples.append(text)


async def scrubber(
    http: httpx.AsyncClient, tally: Tally, viewer: str, session: str, rate_hz: float, until: float
) -> None:
    headers = {"X-Viewer": viewer}
    r = await tally.request(http, "review load", "POST", "/api/review", json={"session": session}, headers=headers)
    if r is None:
        return
    frames = [row["index"] for row in r.json()["table"]]
    rng = random.Random()
    next_step = time.monotonic()
    while time.monotonic() < until:
        index = rng.choice(frames)
        await tally.request(http, "frame select", "POST", "/api/review/frame", json={"index": index}, headers=headers)
        marks = await tally.request(http, "marks", "GET", f"/api/review/marks/{index}", headers=headers)
        image = marks.json().get("image") if marks is not None else None
        if image:
            await tally.request(http, "image", "GET", image)
        next_step += 1.0 / rate_hz
        await asyncio.sleep(max(0.0, next_step - time.monotonic()))
        next_step = max(next_step, time.monotonic())  # behind schedule: go on, never burst to catch up


async def background(http: httpx.AsyncClient, tally: Tally, rate_hz: float, until: float) -> int:
    tasks: set[asyncio.Task] = set()
    sent = 0
    start = time.monotonic()
    while (now := time.monotonic()) < until:
        kind, url = BACKGROUND[sent % len(BACKGROUND)]
        task = asyncio.create_task(tally.request(http, kind, "GET", url))
        tasks.add(task)
        task.add_done_callback(tasks.discard)
        sent += 1
        await asyncio.sleep(max(0.0, start + sent / rate_hz - now))
    if tasks:
        await asyncio.gather(*tasks)
    return sent


async def run(url: str, pid: int, args: argparse.Namespace) -> dict:
    limits = httpx.Limits(max_connections=args.clients + 64, max_keepalive_connections=args.clients + 64)
    async with httpx.AsyncClient(base_url=url, timeout=REQUEST_TIMEOUT_S, limits=limits) as http:
        memory = {"before": rss_mb(pid)}
        tally = Tally()
        t0 = time.monotonic()
        until = t0 + args.seconds

        async def warm_up_mark() -> None:
            await asyncio.sleep(args.seconds / 5)
            memory["after warm-up"] = rss_mb(pid)

        results = await asyncio.gather(
            background(http, tally, args.background, until),
            warm_up_mark(),
            *(scrubber(http, tally, f"load-{k}", args.session, args.rate, until) for k in range(args.clients)),
        )
        elapsed = time.monotonic() - t0
        memory["end"] = rss_mb(pid)
    return {"tally": tally, "elapsed_s": elapsed, "memory_mb": memory, "background_sent": results[0]}


def report(result: dict, args: argparse.Namespace) -> int:
    tally: Tally = result["tally"]
    elapsed = result["elapsed_s"]
    total = sum(len(v) for v in tally.latency_ms.values()) + sum(tally.errors.values())
    errors = sum(tally.errors.values())
    print(
        f"{args.clients} scrubbing clients at {args.rate:g} steps/s + {args.background:g} background req/s "
        f"for {elapsed:.1f} s on {args.session}"
    )
    print(f"{'kind':<20}{'requests':>9}{'errors':>8}{'req/s':>8}{'p50 ms':>9}{'p99 ms':>9}{'max ms':>9}")
    for kind in sorted(set(tally.latency_ms) | set(tally.errors)):
        lat = np.array(tally.latency_ms.get(kind, [float("nan")]))
        n = len(tally.latency_ms.get(kind, [])) + tally.errors.get(kind, 0)
        print(
            f"{kind:<20}{n:>9}{tally.errors.get(kind, 0):>8}{n / elapsed:>8.1f}"
            f"{np.percentile(lat, 50):>9.1f}{np.percentile(lat, 99):>9.1f}{lat.max():>9.1f}"
        )
    steps = len(tally.latency_ms.get("frame select", []))
    print(
        f"all: {total} requests, {errors} errors, {total / elapsed:.1f} req/s; "
        f"scrub steps {steps / elapsed:.1f}/s (asked {args.clients * args.rate:g}/s); "
        f"background {result['background_sent'] / elapsed:.1f}/s (asked {args.background:g}/s)"
    )
    m = result["memory_mb"]
    print(
        f"server RSS: before {m['before']:.0f} MB, after warm-up {m['after warm-up']:.0f} MB, end {m['end']:.0f} MB "
        f"(growth after warm-up {m['end'] - m['after warm-up']:+.0f} MB)"
    )
    for text in tally.examples:
        print(f"  error: {text}")
    return 1 if errors else 0


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seconds", type=float, default=60.0, help="how long the load runs (default 60)")
    ap.add_argument("--clients", type=int, default=10, help="scrubbing clients (default 10)")
    ap.add_argument("--rate", type=float, default=10.0, help="scrub steps per second per client (default 10)")
    ap.add_argument("--background", type=float, default=50.0, help="background API requests per second (default 50)")
    ap.add_argument("--session", default="robonaut-a-day2", help="the sample session reviewed")
    args = ap.parse_args()
    with tempfile.TemporaryDirectory(prefix="calib-load-") as tmp, served(Path(tmp) / "data") as server:
        result = asyncio.run(run(server.url, server.process.pid, args))
    return report(result, args)


if __name__ == "__main__":
    sys.exit(main())
