"""Faults, each injected: the robot disconnecting or stalling mid-replay (frames kept, the replay resumed),
`calib serve` killed with SIGKILL mid-capture, mid-calibration and mid-apply (a consistent store after the
restart, and no job Manager or worker process of it left running), a calibration worker killed through the
API, a job failing on a file error (its message names no path of the server), and a data directory that
refuses writes (507, nothing half-written). The store's own killed-writer and sweep tests are in
test_store.py, the worker crash and time-out tests at the job runner's level in test_jobs.py."""

from __future__ import annotations

import errno
import itertools
import os
import secrets
import signal
import subprocess
import sys
import threading
import time
from contextlib import suppress
from pathlib import Path

import cv2
import httpx
import numpy as np
import pytest
from browser import CLIENT, Server, free_port
from desk_jobs import wait_job
from fastapi.testclient import TestClient

from app.jobs.process_jobs import crashed
from app.services.replay import ReplayPlan
from app.store import INTERRUPTED, Store
from calib_core import load_profile, read_dataset

ROOT = Path(__file__).resolve().parent.parent
SAMPLES = ROOT / "sample_sessions"
FINISHED = ("done", "failed", "cancelled")
pytestmark = pytest.mark.slow  # faults injected into running replays, jobs and stores


def served_job(server: Server, job_id: str, timeout_s: float = 60.0) -> dict:
    """Poll a `calib serve`'s GET /api/jobs/{id} until the job has finished (in-process: desk_jobs.wait_job)."""
    deadline = time.monotonic() + timeout_s
    while True:
        job = server.get(f"/api/jobs/{job_id}").json()
        if job["state"] in FINISHED:
            return job
        assert time.monotonic() < deadline, f"job still {job['state']}: {job}"
        time.sleep(0.05)


# --- in-process: one app with the Robonaut day-1 sample --------------------------------------------------
@pytest.fixture(scope="module")
def desk_options(sample_copy) -> dict:
    return {"sample_dir": sample_copy("robonaut-a-day1")}


@pytest.fixture(scope="module")
def data_dir(client: TestClient) -> Path:
    return client.app.state.desk.data_dir


@pytest.fixture(scope="module")
def daily(client: TestClient) -> str:
    """A daily calibration of the day-1 sample (to apply)."""
    r = client.post("/api/sessions/robonaut-a-day1/calibrations", json={"mode": "daily"})
    job = wait_job(client, r.json()["job"])
    assert job["state"] == "done", job
    return job["result"]


def _frames(client: TestClient, session_id: str) -> list[dict]:
    return client.get(f"/api/sessions/{session_id}").json()["frames"]


def _plan_rad(client: TestClient, session_id: str, count: int, seed: int) -> np.ndarray:
    q, _, _ = client.app.state.desk.replay.configurations(session_id, ReplayPlan(count=count, seed=seed))
    return q


def _each_configuration_once(client: TestClient, frames: list[dict], q_plan: np.ndarray) -> bool:
    names = client.app.state.desk.robots.get("nao").profile.joint_names
    q_frames = np.radians([[f["joints"][n] for n in names] for f in frames])
    near = np.all(np.abs(q_plan[:, None, :] - q_frames[None, :, :]) <= np.radians(0.1), axis=2)
    return bool((near.sum(axis=1) == 1).all() and (near.sum(axis=0) == 1).all())


def test_a_disconnect_mid_replay_keeps_the_frames_and_a_resume_finishes_the_plan(client: TestClient) -> None:
    driver = client.app.state.desk.robots.driver("nao")
    sid = client.post("/api/sessions", json={"robot": "nao", "name": "disconnect"}).json()["id"]
    plan = {"count": 4, "seed": 1}
    q_plan = _plan_rad(client, sid, 4, 1)
    driver.inject_fault("drop", after_moves=2)
    job = wait_job(client, client.post(f"/api/sessions/{sid}/replay", json=plan).json()["job"])
    assert job["state"] == "failed"
    assert job["error"] == (
        "replay stopped at configuration 3 of 4: nao disconnected: the link to the robot was lost; the 2 frames "
        "before it are kept (start the replay again with resume to go on)"
    )
    kept = _frames(client, sid)
    assert [f["index"] for f in kept] == [1, 2] and all(f["images"] for f in kept)
    robot = client.get("/api/robot", params={"robot": "nao"}).json()
    assert (robot["connected"], robot["moving"]) == (False, False)
    r = client.post("/api/robot/move", json={"robot": "nao", "joints": {}})
    assert r.status_code == 503 and r.json()["detail"] == "nao disconnected: the link to the robot was lost"

    driver.reconnect()
    dry = client.post(f"/api/sessions/{sid}/replay", json={**plan, "resume": True, "dry_run": True}).json()
    assert wait_job(client, dry["job"])["state"] == "done"
    assert len(client.get(f"/api/jobs/{dry['job']}/dry-run").json()["configurations"]) == 2
    job = wait_job(client, client.post(f"/api/sessions/{sid}/replay", json={**plan, "resume": True}).json()["job"])
    assert job["state"] == "done", job
    frames = _frames(client, sid)
    assert [f["index"] for f in frames] == [1, 2, 3, 4]
    assert frames[:2] == kept  # untouched by the resume
    assert _each_configuration_once(client, frames, q_plan)
    # New configurations are planned in the job (the request returns at once): it fails with nothing to do, and
    # so does the dry run's.
    for dry_run in (False, True):
        ask = {**plan, "resume": True, "dry_run": dry_run}
        job = wait_job(client, client.post(f"/api/sessions/{sid}/replay", json=ask).json()["job"])
        assert job["state"] == "failed" and job["error"].startswith("nothing to resume"), job


def test_a_move_that_never_arrives_times_out_and_fails_the_replay(client: TestClient) -> None:
    driver = client.app.state.desk.robots.driver("nao")
    sid = client.post("/api/sessions", json={"robot": "nao", "name": "stall"}).json()["id"]
    plan = {"count": 2, "seed": 5}
    q_plan = _plan_rad(client, sid, 2, 5)
    driver.move_slack_s = 0.5
    try:
        driver.inject_fault("stall", after_moves=1)
        t0 = time.monotonic()
        job = wait_job(client, client.post(f"/api/sessions/{sid}/replay", json=plan).json()["job"])
        elapsed_s = time.monotonic() - t0
    finally:
        driver.move_slack_s = 5.0
    assert job["state"] == "failed" and elapsed_s < 10
    assert job["error"].startswith("replay stopped at configuration 2 of 2: nao did not arrive within ")
    assert job["error"].endswith(
        "(not responding); the robot was told to stop; the 1 frames before it are kept "
        "(start the replay again with resume to go on)"
    )
    assert [f["index"] for f in _frames(client, sid)] == [1]
    robot = client.get("/api/robot", params={"robot": "nao"}).json()
    assert (robot["connected"], robot["moving"]) == (True, False)
    job = wait_job(client, client.post(f"/api/sessions/{sid}/replay", json={**plan, "resume": True}).json()["job"])
    assert job["state"] == "done", job
    assert _each_configuration_once(client, _frames(client, sid), q_plan)


def test_a_calibration_worker_killed_through_the_api_fails_its_job_and_the_server_stays_up(
    client: TestClient,
) -> None:
    jobs = client.app.state.desk.jobs
    # Twenty-fold cross-validation: 21 solves, seconds of work, so the worker is caught running.
    r = client.post("/api/sessions/robonaut-a-day1/calibrations", json={"mode": "full", "folds": 20})
    job_id = r.json()["job"]
    deadline = time.monotonic() + 30
    snap = jobs.get(job_id)
    while snap.state != "running":  # a process job runs once its worker has said which it is
        assert time.monotonic() < deadline and not snap.state.finished, snap
        snap = jobs.wait_version(job_id, snap.version, deadline - time.monotonic())
    os.kill(jobs.worker_pid(job_id), signal.SIGKILL)
    job = wait_job(client, job_id, timeout_s=15)
    assert (job["state"], job["error"]) == ("failed", crashed("calibration"))
    assert client.get("/api/health").status_code == 200


def test_a_job_that_fails_on_a_file_error_names_the_file_but_no_path_of_the_server(
    client: TestClient, data_dir: Path
) -> None:
    # A file where the calibrations folder belongs: storing the result fails with an OSError that is not a
    # full or read-only disk, whose text holds the full path of the file it tried to write.
    folder = data_dir / "calibrations"
    folder.rename(data_dir / "calibrations.away")
    folder.write_text("not a folder")
    try:
        r = client.post("/api/sessions/robonaut-a-day1/calibrations", json={"mode": "daily"})
        job = wait_job(client, r.json()["job"])
    finally:
        folder.unlink()
        (data_dir / "calibrations.away").rename(folder)
    assert job["state"] == "failed"
    listed = next(j for j in client.get("/api/jobs").json() if j["id"] == job["id"])
    for error in (job["error"], listed["error"]):
        assert error.startswith("internal error: NotADirectoryError: [Errno 20] Not a directory: "), error
        assert ".json" in error and "/" not in error and "Traceback" not in error, error


# --- the data directory refusing writes ---------------------------------------------------------------
def _state(client: TestClient, data_dir: Path) -> dict:
    """The files under the data directory and every row the API shows of sessions, calibrations, applies."""
    files = sorted(
        str(p.relative_to(data_dir))
        for p in data_dir.rglob("*")
        if p.is_file() and not p.name.startswith("store.sqlite")
    )
    sessions = client.get("/api/sessions").json()
    return {
        "files": files,
        "sessions": sessions,
        "frames": {s["id"]: _frames(client, s["id"]) for s in sessions},
        "calibrations": [c["id"] for c in client.get("/api/sessions/robonaut-a-day1/calibrations").json()],
        "history": client.get("/api/robot/history", params={"robot": "robonaut-a"}).json(),
        "driver": client.get("/api/robot", params={"robot": "robonaut-a"}).json()["calibration"],
    }


def _refused(r: httpx.Response, reason: str) -> None:
    assert r.status_code == 507, r.text
    assert r.json() == {"detail": f"the data directory cannot be written ({reason})"}


@pytest.fixture(scope="module")
def capture_session(client: TestClient) -> str:
    return client.post("/api/sessions", json={"robot": "robonaut-a", "name": "disk"}).json()["id"]


def test_a_full_disk_fails_a_capture_and_a_calibration_and_writes_nothing(
    client: TestClient, data_dir: Path, capture_session: str, monkeypatch: pytest.MonkeyPatch
) -> None:
    # Tests may run as root, where a read-only folder still takes writes: the file data is refused where a
    # full disk refuses it, at the flush to the device.
    def fsync(fd: int) -> None:
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))

    before = _state(client, data_dir)
    with monkeypatch.context() as m:
        m.setattr(os, "fsync", fsync)
        _refused(client.post(f"/api/sessions/{capture_session}/capture"), "no space left on device")
        r = client.post("/api/sessions/robonaut-a-day1/calibrations", json={"mode": "daily"})
        job = wait_job(client, r.json()["job"])
    assert (job["state"], job["error"]) == ("failed", "the data directory cannot be written (no space left on device)")
    assert _state(client, data_dir) == before
    # Once the disk takes writes again, so does the store.
    r = client.post(f"/api/sessions/{capture_session}/capture")
    assert r.status_code == 201
    for url in r.json()["frame"]["images"].values():
        assert cv2.imdecode(np.frombuffer(client.get(url).content, np.uint8), cv2.IMREAD_COLOR) is not None


def test_a_read_only_database_fails_import_capture_apply_and_calibration_and_writes_nothing(
    client: TestClient, data_dir: Path, capture_session: str, daily: str
) -> None:
    store = client.app.state.desk.store
    csv = (SAMPLES / "robonaut-a-day1" / "data.csv").read_bytes()
    upload = {"data": ("day1.csv", csv, "text/csv")}
    before = _state(client, data_dir)
    with store.db.lock:  # the store's own connection: every write it tries is refused by SQLite
        store.db._db.execute("PRAGMA query_only = ON")
    try:
        reason = "the database is read-only"
        _refused(client.post("/api/sessions/import", data={"robot": "robonaut-a", "name": "ro"}, files=upload), reason)
        # The images are written first, then the row is refused: the images go again.
        _refused(client.post(f"/api/sessions/{capture_session}/capture"), reason)
        _refused(client.post(f"/api/calibrations/{daily}/apply", json={"confirm": True}), reason)
        job = wait_job(
            client, client.post("/api/sessions/robonaut-a-day1/calibrations", json={"mode": "daily"}).json()["job"]
        )
        assert (job["state"], job["error"]) == ("failed", f"the data directory cannot be written ({reason})")
        assert _state(client, data_dir) == before
    finally:
        with store.db.lock:
            store.db._db.execute("PRAGMA query_only = OFF")
    r = client.post(f"/api/calibrations/{daily}/apply", json={"confirm": True})
    assert (
        r.status_code == 200 and client.get("/api/robot", params={"robot": "robonaut-a"}).json()["calibration"] == daily
    )


def test_a_full_database_fails_an_import_and_keeps_no_part_of_it(client: TestClient, data_dir: Path) -> None:
    store = client.app.state.desk.store
    csv = (SAMPLES / "robonaut-a-day2" / "data.csv").read_bytes()
    upload = {"data": ("day2.csv", csv, "text/csv")}
    before = _state(client, data_dir)
    with store.db.lock:  # the database may not grow by a page: SQLite answers SQLITE_FULL, as on a full disk
        pages = store.db._db.execute("PRAGMA page_count").fetchone()[0]
        limit = store.db._db.execute("PRAGMA max_page_count").fetchone()[0]
        store.db._db.execute(f"PRAGMA max_page_count = {pages}")
    try:
        r = client.post("/api/sessions/import", data={"robot": "robonaut-a", "name": "full"}, files=upload)
        _refused(r, "no space left on device")
        assert _state(client, data_dir) == before
    finally:
        with store.db.lock:
            store.db._db.execute(f"PRAGMA max_page_count = {limit}")
    r = client.post("/api/sessions/import", data={"robot": "robonaut-a", "name": "full"}, files=upload)
    n_csv = read_dataset(load_profile("robonaut-a"), SAMPLES / "robonaut-a-day2" / "data.csv").n_configurations
    assert r.status_code == 201 and client.get(f"/api/sessions/{r.json()['id']}").json()["measured"] == n_csv


# --- SIGKILL: a real `calib serve`, killed at random moments ----------------------------------------------
KILLS = 2


def _serve(data_dir: Path, log: Path, timeout_s: float = 120.0) -> Server:
    """`calib serve` in a process group of its own (so its workers can be cleaned up after a kill)."""
    port, viser_port = free_port(), free_port()
    cmd = [str(Path(sys.executable).parent / "calib"), "serve", "--port", str(port), "--viser-port", str(viser_port)]
    with open(log, "ab") as out:
        proc = subprocess.Popen(
            [*cmd, "--data-dir", str(data_dir), "--sim-speed", "50"],
            cwd=ROOT,
            stdout=out,
            stderr=subprocess.STDOUT,
            env={**os.environ, "PYTHONUNBUFFERED": "1"},
            start_new_session=True,
        )
    server = Server(f"http://127.0.0.1:{port}", proc, data_dir)
    deadline = time.monotonic() + timeout_s
    while True:
        assert proc.poll() is None, f"calib serve exited: {log.read_text()[-2000:]}"
        with suppress(httpx.HTTPError):
            if server.get("/api/health").status_code == 200:
                return server
        assert time.monotonic() < deadline, "calib serve did not answer in time"
        time.sleep(0.1)


def _kill(server: Server) -> None:
    """SIGKILL the server, then whatever it left running (the job Manager, calibration workers)."""
    server.process.kill()
    server.process.wait()
    with suppress(ProcessLookupError):
        os.killpg(server.process.pid, signal.SIGKILL)


class _Applier(threading.Thread):
    """Applies two calibrations in turn, back to back, until the server dies under it."""

    def __init__(self, server: Server, cal_ids: list[str]) -> None:
        super().__init__(daemon=True)
        self.server, self.cal_ids = server, cal_ids
        self.acked: list[str] = []
        self.in_flight: str | None = None
        self.refused: list[str] = []

    def run(self) -> None:
        with httpx.Client(base_url=self.server.url, timeout=30) as http:
            for k in range(100_000):
                self.in_flight = self.cal_ids[k % 2]
                try:
                    r = http.post(f"/api/calibrations/{self.in_flight}/apply", json={"confirm": True})
                except httpx.HTTPError:
                    return
                if r.status_code != 200:
                    self.refused.append(r.text)
                    return
                if r.json()["recorded"]:  # not when it was already active (a new round starts with either)
                    self.acked.append(self.in_flight)
                self.in_flight = None


def _calibrate(server: Server, session_id: str, mode: str) -> str:
    job = served_job(server, server.post(f"/api/sessions/{session_id}/calibrations", json={"mode": mode}).json()["job"])
    assert job["state"] == "done", job
    return job["result"]


PROC = Path("/proc/self/stat").is_file()  # Linux: the process tree is read from /proc


def _descendants(pid: int) -> dict[int, int]:
    """{pid: start time} of every live process below `pid`, read from /proc."""
    children: dict[int, list[tuple[int, int]]] = {}
    for entry in Path("/proc").iterdir():
        if entry.name.isdigit() and (stat := _stat(int(entry.name))) is not None:
            children.setdefault(stat[1], []).append((int(entry.name), stat[2]))
    found: dict[int, int] = {}
    todo = [pid]
    while todo:
        for child, start in children.get(todo.pop(), []):
            found[child] = start
            todo.append(child)
    return found


def _stat(pid: int) -> tuple[str, int, int] | None:
    """(state, parent pid, start time) of a process, None once it is gone."""
    try:
        fields = (Path("/proc") / str(pid) / "stat").read_text().rsplit(")", 1)[1].split()
    except (OSError, IndexError):
        return None
    return fields[0], int(fields[1]), int(fields[19])


def _alive(pid: int, start: int) -> bool:
    """The very process (not a later one with its pid) still runs (a zombie has ended)."""
    stat = _stat(pid)
    return stat is not None and stat[2] == start and stat[0] not in "ZX"


def _kill_leaving_no_children(server: Server) -> float:
    """SIGKILL the server alone: its job Manager and calibration workers (spawned python processes, and the
    resource tracker) must end by themselves within seconds. Returns how long they took."""
    children = _descendants(server.process.pid) if PROC else {}
    assert len(children) >= 2 or not PROC, children  # the Manager and the warmed-up worker at least
    server.process.kill()
    server.process.wait()
    killed = time.monotonic()
    try:
        while left := {pid for pid, start in children.items() if _alive(pid, start)}:
            assert time.monotonic() < killed + 5.0, f"still running 5 s after the server was killed: {left}"
            time.sleep(0.05)
        return time.monotonic() - killed
    finally:
        _kill(server)


@pytest.mark.subprocess
def test_sigkill_mid_replay_calibration_and_apply_leaves_a_consistent_store(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    seed = secrets.randbits(32)
    rng = np.random.default_rng(seed)
    data, log = tmp_path / "data", tmp_path / "serve.log"
    server = _serve(data, log)
    rounds = []
    try:
        cals = [_calibrate(server, "robonaut-a-day1", "daily"), _calibrate(server, "robonaut-a-day1", "full")]
        bodies = {c: server.get(f"/api/calibrations/{c}").json() for c in cals}
        sid = server.post("/api/sessions", json={"robot": "nao", "name": "killed"}).json()["id"]
        n_source = len(server.get("/api/sessions/nao").json()["frames"])
        acked, active = 0, None
        for k in range(KILLS):
            applier = _Applier(server, cals)
            applier.start()
            replay = server.post(f"/api/sessions/{sid}/replay", json={"from_session": "nao", "resume": k > 0})
            replay_job = replay.json()["job"]
            t0 = time.monotonic()
            time.sleep(rng.uniform(0.5, 2.0))
            # Ten-fold cross-validation: seconds of solving, so the kill most likely finds it running.
            cal_job = server.post("/api/sessions/nao/calibrations", json={"mode": "full", "folds": 10}).json()["job"]
            time.sleep(rng.uniform(0.02, 0.4))
            seen = len(server.get(f"/api/sessions/{sid}").json()["frames"])
            children_gone_s = _kill_leaving_no_children(server)
            killed_after_s = time.monotonic() - t0
            applier.join(timeout=30)
            acked += len(applier.acked)
            assert not applier.refused, applier.refused
            last = applier.acked[-1] if applier.acked else active
            server = _serve(data, log)
            where = f"round {k}, seed {seed}"

            assert server.get("/api/health").status_code == 200
            jobs = {j["id"]: j for j in server.get("/api/jobs").json()}
            assert all(j["state"] in FINISHED for j in jobs.values()), where
            assert (jobs[replay_job]["state"], jobs[replay_job]["error"]) == ("failed", INTERRUPTED), where
            cal = jobs[cal_job]
            assert cal["state"] == "done" or (cal["state"], cal["error"]) == ("failed", INTERRUPTED), where
            if cal["state"] == "done":
                assert server.get(f"/api/calibrations/{cal['result']}").status_code == 200, where

            # Frames: numbered without a gap, none the client saw lost, every image readable.
            frames = server.get(f"/api/sessions/{sid}").json()["frames"]
            assert [f["index"] for f in frames] == list(range(1, len(frames) + 1)), where
            assert len(frames) >= seen, where
            for f in frames:
                for url in f["images"].values():
                    img = cv2.imdecode(np.frombuffer(server.get(url).content, np.uint8), cv2.IMREAD_UNCHANGED)
                    assert img is not None and img.size > 0, (where, url)
            # Each source configuration is a frame or still to do: the resume plan is exactly the rest.
            dry = server.post(
                f"/api/sessions/{sid}/replay", json={"from_session": "nao", "resume": True, "dry_run": True}
            )
            assert len(dry.json()["configurations"]) == n_source - len(frames), where

            # Applies: the active calibration is the last acknowledged or the one in flight, whole, and the
            # history is one unbroken chain.
            history = server.get("/api/robot/history", params={"robot": "robonaut-a"}).json()
            active = server.get("/api/robot/calibration", params={"robot": "robonaut-a"}).json()["id"]
            assert active in {last, applier.in_flight} - {None}, where
            assert active == history[0]["calibration"], where
            assert server.get("/api/robot", params={"robot": "robonaut-a"}).json()["calibration"] == active, where
            assert all(h["previous"] == older["calibration"] for h, older in itertools.pairwise(history)), where
            assert history[-1]["previous"] is None and acked <= len(history) <= acked + k + 1, where
            for c in cals:
                assert server.get(f"/api/calibrations/{c}").json() == bodies[c], where
            rounds.append(
                {
                    "killed_after_s": round(killed_after_s, 2),
                    "frames_seen": seen,
                    "frames_after": len(frames),
                    "calibration": cal["state"],
                    "applies_acked": len(applier.acked),
                    "active_was_in_flight": active == applier.in_flight,
                    "children_gone_after_s": round(children_gone_s, 2),
                }
            )
    finally:
        server.process.send_signal(signal.SIGINT)
        try:
            server.process.wait(timeout=20)
        except subprocess.TimeoutExpired:
            _kill(server)
        with suppress(ProcessLookupError):
            os.killpg(server.process.pid, signal.SIGKILL)
    print(f"\nSIGKILL rounds (seed {seed}): {rounds}")

    # After the sweep (leftovers of any age), files and rows match one to one.
    monkeypatch.setattr("app.store.files.SWEEP_AGE_S", 0.0)
    store = Store(data)
    cal_files = {f"calibrations/{p.name}" for p in (data / "calibrations").iterdir()}
    assert cal_files == {store.calibrations.info(c.id).path for c in store.calibrations.list()}
    for c in store.calibrations.list():
        store.calibrations.load(c.id)  # loads whole
    for s in store.sessions.list():
        referenced = {rel for f in store.sessions.frames(s.id) for rel in f.images.values()}
        images = data / "sessions" / s.id / "images"
        on_disk = {f"sessions/{s.id}/images/{p.name}" for p in images.iterdir()} if images.is_dir() else set()
        assert on_disk == referenced, s.id
    assert not [p for p in data.rglob("*") if p.name.endswith(".tmp") or p.name.startswith(".s-")]
    store.close()


@pytest.mark.subprocess
def test_a_stop_ends_the_open_pages_event_streams_instead_of_waiting_for_them(tmp_path: Path) -> None:
    """Ctrl-C with a page open: its robot and job event streams (which never end by themselves) end at once, so
    the stop does not wait out uvicorn's grace period and cancel them (it did: 3 s at every stop)."""
    data, log = tmp_path / "data", tmp_path / "serve.log"
    server = _serve(data, log)
    job = server.post("/api/sessions/nao/calibrations", json={"mode": "full", "folds": 20}).json()["job"]
    opened = {name: threading.Event() for name in ("robot", "job")}
    ended: set[str] = set()

    def follow(name: str, path: str) -> None:
        with CLIENT.stream("GET", f"{server.url}{path}", timeout=60) as events:
            for line in events.iter_lines():
                if line.startswith("data:"):
                    opened[name].set()
            ended.add(name)  # the stream ended as a response does (a cut one raises instead)

    streams = [
        threading.Thread(target=follow, args=("robot", "/api/robot/events?robot=nao")),
        threading.Thread(target=follow, args=("job", f"/api/jobs/{job}/events")),
    ]
    try:
        for t in streams:
            t.start()
        assert all(event.wait(30) for event in opened.values()), "the event streams did not open"
        server.process.send_signal(signal.SIGINT)
        server.process.wait(timeout=30)
        for t in streams:
            t.join(timeout=30)
    finally:
        if server.process.poll() is None:
            _kill(server)
    assert ended == {"robot", "job"}, ended
    assert "graceful shutdown exceeded" not in log.read_text(encoding="utf-8")


@pytest.mark.subprocess
def test_sigterm_stops_calib_serve_promptly_with_jobs_running(tmp_path: Path) -> None:
    """SIGTERM (a service manager's stop) with a calibration solving in its worker and a replay driving the robot:
    the server exits within seconds, leaves no process behind, and the jobs are stored as cancelled."""
    data, log = tmp_path / "data", tmp_path / "serve.log"
    server = _serve(data, log)
    try:
        sid = server.post("/api/sessions", json={"robot": "nao", "name": "stopped"}).json()["id"]
        replay_job = server.post(f"/api/sessions/{sid}/replay", json={"from_session": "nao"}).json()["job"]
        cal_job = server.post("/api/sessions/nao/calibrations", json={"mode": "full", "folds": 20}).json()["job"]
        deadline = time.monotonic() + 60
        while {server.get(f"/api/jobs/{j}").json()["state"] for j in (replay_job, cal_job)} != {"running"}:
            assert time.monotonic() < deadline, "the jobs did not start"
            time.sleep(0.05)
        children = _descendants(server.process.pid) if PROC else {}
        t0 = time.monotonic()
        server.process.send_signal(signal.SIGTERM)
        server.process.wait(timeout=30)
        took = time.monotonic() - t0
        while left := {pid for pid, start in children.items() if _alive(pid, start)}:
            assert time.monotonic() < t0 + 10, f"still running after the server stopped: {left}"
            time.sleep(0.05)
    finally:
        if server.process.poll() is None:
            _kill(server)
    print(f"\nSIGTERM with a calibration and a replay running: calib serve stopped in {took:.2f} s")
    assert took < 8.0, f"calib serve took {took:.1f} s to stop on SIGTERM"
    store = Store(data)
    assert store.jobs.get(replay_job).state == "cancelled" and store.jobs.get(cal_job).state == "cancelled"
