"""Background jobs: a calibration in a spawned worker recovers the sample's truth; validation before a
job exists; cancel, failures, a killed or overrunning worker; thread jobs with pause and resume; a
restart shows interrupted jobs as failed. One JobManager (one spawned worker) serves the module."""

import json
import math
import os
import shutil
import subprocess
import sys
import threading
import time
from collections.abc import Iterator
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import numpy as np
import pytest

from app.errors import NotFound
from app.importers import ensure_samples
from app.jobs import CRASHED, FINISHED, JobContext, JobManager, WorkerLink, calibration_worker
from app.store import INTERRUPTED, Store
from calib_core import InputError
from calib_core.estimation.solver import Cancelled

SAMPLES = Path(__file__).resolve().parent.parent / "sample_sessions"


def sleeper(seconds: float, link: WorkerLink) -> str:
    """A worker that never looks at its cancel flag (a hung solver)."""
    time.sleep(seconds)
    return "slept"


def exploder(message: str, link: WorkerLink) -> None:
    raise RuntimeError(message)


@pytest.fixture(scope="module")
def store(tmp_path_factory: pytest.TempPathFactory) -> Store:
    samples = tmp_path_factory.mktemp("samples")
    for name in ("robonaut-a-day1", "nao"):
        shutil.copytree(SAMPLES / name, samples / name)
    store = Store(tmp_path_factory.mktemp("data"))
    ensure_samples(store, samples)
    return store


@pytest.fixture(scope="module")
def jobs(store: Store) -> Iterator[JobManager]:
    manager = JobManager(store, workers=1, cancel_grace_s=0.5)
    yield manager
    manager.shutdown()


def wait(jobs: JobManager, job_id: str, until: tuple[str, ...] = FINISHED, timeout_s: float = 30.0) -> dict:
    deadline = time.monotonic() + timeout_s
    snap = jobs.get(job_id)
    while snap["state"] not in until:
        assert time.monotonic() < deadline, f"job still {snap['state']}"
        snap = jobs.wait_version(job_id, snap["version"], 0.5)
    return snap


def wait_running(jobs: JobManager, job_id: str) -> int:
    """The worker's pid once the job runs in it."""
    wait(jobs, job_id, ("running",))
    while jobs.worker_pid(job_id) is None:
        time.sleep(0.01)
    return jobs.worker_pid(job_id)


def slow_job(jobs: JobManager) -> str:
    """Nelder-Mead on the NAO sample's 21 parameters: seconds of work that checks its cancel flag."""
    return jobs.submit_calibration("nao", "full", None, 0.0, method="nelder-mead")


def test_a_calibration_job_recovers_the_samples_truth(jobs: JobManager, store: Store) -> None:
    job_id = jobs.submit_calibration("robonaut-a-day1", "full", None, 0.3)
    seen = []
    snap = jobs.get(job_id)
    while snap["state"] not in FINISHED:
        seen.append((snap["state"], snap["progress"]))
        snap = jobs.wait_version(job_id, snap["version"], 5.0)
    assert snap["state"] == "done", snap["error"]
    assert snap["progress"] == 1.0 and snap["error"] is None and snap["session"] == "robonaut-a-day1"
    assert any(state == "running" for state, _ in seen)
    assert all(p <= 0.95 for _, p in seen)
    assert len(snap["cost"]) > 2 and snap["cost"][-1] < snap["cost"][0] / 100

    cal = store.calibrations.load(snap["result"])
    info = store.calibrations.info(snap["result"])
    assert (info.session_id, info.holdout, info.mode, cal.source) == ("robonaut-a-day1", 0.3, "full", "robonaut-a-day1")
    measured = [f.index for f in store.sessions.frames("robonaut-a-day1") if f.status == "measured"]
    train, held = cal.frames["train"], cal.frames["holdout"]
    assert sorted(train + held) == measured and not set(train) & set(held) and len(held) == round(0.3 * len(measured))
    after, before = cal.figures["after"].rms, cal.figures["before"].rms
    assert after < before / 50 and cal.figures["holdout_after"].rms < cal.figures["holdout_before"].rms / 20
    assert snap["detail"]["after_rms"] == pytest.approx(after)

    truth = store.sessions.get("robonaut-a-day1").truth
    offsets = [p for p in cal.parameters if p.name.endswith(".theta") and p.estimated and p.note is None]
    assert len(offsets) >= 8
    for p in offsets:
        assert abs(p.value - truth[p.name]) < 4 * p.std + 0.05, p.name
    # ... where the nominal model was far off: the job really estimated them.
    assert sum(abs(p.nominal - truth[p.name]) > 10 * p.std for p in offsets) >= len(offsets) // 2
    assert store.jobs.get(job_id)["state"] == "done" and store.jobs.get(job_id)["result"] == snap["result"]


def test_a_base_calibration_is_the_starting_point(jobs: JobManager, store: Store) -> None:
    full = wait(jobs, jobs.submit_calibration("robonaut-a-day1", "full", None, 0.0))
    daily = wait(jobs, jobs.submit_calibration("robonaut-a-day1", "daily", full["result"], 0.0))
    assert daily["state"] == "done", daily["error"]
    cal = store.calibrations.load(daily["result"])
    assert store.calibrations.info(daily["result"]).base_id == full["result"]
    # Starting from the full calibration, a daily one starts (and stays) near its after-error.
    assert cal.figures["before"].rms < 2 * store.calibrations.load(full["result"]).figures["after"].rms


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (("robonaut-a-day1", "weekly", None, 0.0), "unknown mode 'weekly'"),
        (("robonaut-a-day1", "full", None, 0.95), "between 0 and 0.9"),
        (("robonaut-a-day1", "full", None, -0.1), "between 0 and 0.9"),
        (("robonaut-a-day1", "full", None, math.nan), "not a number"),
        (("robonaut-a-day1", "full", None, 0.0, {"method": "newton"}), "unknown method 'newton'"),
        (("robonaut-a-day1", "full", None, 0.0, {"folds": 1}), "folds 1"),
    ],
)
def test_a_bad_request_is_refused_before_a_job_exists(jobs: JobManager, args: tuple, message: str) -> None:
    before = len(jobs.list())
    positional, kwargs = (args[:4], args[4]) if len(args) > 4 else (args, {})
    with pytest.raises(InputError, match=message):
        jobs.submit_calibration(*positional, **kwargs)
    assert len(jobs.list()) == before


def test_unknown_sessions_and_bases_foreign_bases_and_too_few_frames(jobs: JobManager, store: Store) -> None:
    before = len(jobs.list())
    with pytest.raises(NotFound):
        jobs.submit_calibration("s-nothere", "full", None, 0.0)
    with pytest.raises(NotFound, match="no base calibration 'c-nothere' on this desk"):
        jobs.submit_calibration("robonaut-a-day1", "full", "c-nothere", 0.0)
    assert len(jobs.list()) == before
    nao_cal = wait(jobs, jobs.submit_calibration("nao", "full", None, 0.0))["result"]
    with pytest.raises(InputError, match="is for robot 'nao', not 'robonaut-a'"):
        jobs.submit_calibration("robonaut-a-day1", "full", nao_cal, 0.0)
    sid = store.sessions.create("robonaut-a", "three frames", source="capture")
    with pytest.raises(InputError, match="no measured frames"):
        jobs.submit_calibration(sid, "full", None, 0.0)
    for k in range(3):
        store.sessions.add_frame(
            sid, index=None, joints_rad=np.full(10, 0.1 * k), target=0, status="measured", measured=np.ones((1, 3))
        )
    with pytest.raises(
        InputError, match=r"3 observations \(9 rows\) cannot calibrate mode 'full': they would fix 9 of"
    ):
        jobs.submit_calibration(sid, "full", None, 0.0)


def test_a_mode_of_more_parameters_than_rows_runs_when_the_rows_exceed_what_they_determine(
    jobs: JobManager, store: Store
) -> None:
    """Robonaut's `full` frees 23 parameters, of which no data of one sphere determine more than 19: seven of
    the sample's frames (21 rows) are calibrated, the rest held by name (the request was refused before, 21 <
    23); six (18 rows, no more than what they determine) are refused before a job exists."""
    profile = store.sessions.profile("robonaut-a")
    sample = store.sessions.dataset("robonaut-a-day1", profile)
    for n in (6, 7):
        sid = store.sessions.create("robonaut-a", f"{n} frames", source="capture")
        for c in range(n):
            obs = sample.cfg == c
            store.sessions.add_frame(
                sid,
                index=None,
                joints_rad=sample.joints[c],
                target=int(sample.target[obs][0]),
                status="measured",
                measured=sample.measured[obs, :3],
            )
        if n == 6:
            before = len(jobs.list())
            with pytest.raises(InputError, match=r"6 observations \(18 rows\) cannot calibrate mode 'full'"):
                jobs.submit_calibration(sid, "full", None, 0.0)
            assert len(jobs.list()) == before
    snap = wait(jobs, jobs.submit_calibration(sid, "full", None, 0.0))
    assert snap["state"] == "done", snap["error"]
    cal = store.calibrations.load(snap["result"])
    assert len(cal.identifiability.free) == 19 and len(cal.identifiability.held_fixed) == 4
    assert cal.figures["after"].rms < cal.figures["before"].rms / 10


def test_a_calibration_request_answers_before_its_data_are_read_and_cancels_while_they_are(
    jobs: JobManager, store: Store, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Reading the session, the held-out split and the solve grow with the data: they run in the job, so the
    request answers at once (a 96,000-frame session held it for minutes) and the job can be cancelled while
    the data are still being read."""
    release = threading.Event()
    read = store.sessions.dataset

    def slow_read(*args, **kwargs):
        release.wait(10)
        return read(*args, **kwargs)

    monkeypatch.setattr(store.sessions, "dataset", slow_read)
    t0 = time.monotonic()
    loading = jobs.submit_calibration("robonaut-a-day1", "daily", None, 0.5)
    after = jobs.submit_calibration("robonaut-a-day1", "daily", None, 0.25)
    assert time.monotonic() - t0 < 2.0
    snap = jobs.get(loading)
    assert (snap["state"], snap["detail"]["phase"], snap["detail"]["frames"]) == ("queued", "loading", 64)
    jobs.cancel(loading)
    assert jobs.get(loading)["state"] == "cancelled"  # at once, not when the read ends
    release.set()
    done = wait(jobs, after)
    assert done["state"] == "done" and done["detail"]["phase"] == "solving", done["error"]
    assert jobs.get(loading)["state"] == "cancelled"


def test_cancel_a_running_and_a_queued_job(jobs: JobManager, store: Store) -> None:
    n_cals = len(store.calibrations.list())
    running = slow_job(jobs)
    queued = jobs.submit_calibration("robonaut-a-day1", "full", None, 0.0)
    wait_running(jobs, running)
    assert jobs.get(queued)["state"] == "queued"
    jobs.cancel(queued)
    assert jobs.get(queued)["state"] == "cancelled"
    start = time.monotonic()
    jobs.cancel(running)
    snap = wait(jobs, running, timeout_s=10)
    assert snap["state"] == "cancelled" and snap["result"] is None
    assert time.monotonic() - start < 0.5  # the solver saw the flag; no kill was needed
    assert len(store.calibrations.list()) == n_cals
    assert store.jobs.get(running)["state"] == "cancelled" and store.jobs.get(queued)["state"] == "cancelled"
    jobs.cancel(running)  # a finished job: nothing to do
    with pytest.raises(InputError, match="cannot be paused"):
        jobs.pause(running)
    with pytest.raises(NotFound):
        jobs.cancel("j-nothere")


def test_the_same_calibration_asked_twice_while_it_runs_is_one_job(jobs: JobManager, store: Store) -> None:
    """A double click on Calibrate, or two tabs asking at once: one job, one calibration; another request
    (another held-out share) is another job, and once the first is done the same request runs again."""
    n_cals = len(store.calibrations.list())
    running = slow_job(jobs)
    ask = ("robonaut-a-day1", "full", None, 0.3)
    with ThreadPoolExecutor(4) as pool:
        ids = set(pool.map(lambda _: jobs.submit_calibration(*ask), range(4)))
    assert len(ids) == 1
    other = jobs.submit_calibration("robonaut-a-day1", "full", None, 0.2)
    assert other not in ids
    jobs.cancel(running)
    (first,) = ids
    assert wait(jobs, first)["state"] == "done" and wait(jobs, other)["state"] == "done"
    assert len(store.calibrations.list()) == n_cals + 2
    assert jobs.submit_calibration(*ask) != first


def test_a_failing_worker_fails_its_job_with_one_line(jobs: JobManager) -> None:
    # Bad input that slipped past validation: the solver's InputError text is the message.
    payload = jobs.calibration_payload("robonaut-a-day1", "full", None, 0.0)
    job_id = jobs.submit_process("calibration", calibration_worker, {**payload, "mode": "bogus"}, session_id=None)
    snap = wait(jobs, job_id)
    assert snap["state"] == "failed"
    assert snap["error"] == "unknown mode 'bogus' for robot 'robonaut-a' (known: daily, full)"
    # A bug: the exception's type and message on one line, no traceback.
    job_id = jobs.submit_process("test", exploder, "boom\n  at line 2", session_id=None)
    snap = wait(jobs, job_id)
    assert (snap["state"], snap["error"]) == ("failed", "internal error: RuntimeError: boom at line 2")


def test_a_killed_worker_fails_its_job_and_the_next_job_runs(jobs: JobManager) -> None:
    job_id = slow_job(jobs)
    os.kill(wait_running(jobs, job_id), 9)
    snap = wait(jobs, job_id, timeout_s=10)
    assert (snap["state"], snap["error"]) == ("failed", CRASHED)
    after_id = jobs.submit_calibration("robonaut-a-day1", "full", None, 0.0)
    after = wait(jobs, after_id)
    assert after["state"] == "done", after["error"]
    # A worker that dies while idle (the OOM killer) is replaced for the next job, even one submitted at once.
    os.kill(jobs.worker_pid(after_id), 9)
    again = wait(jobs, jobs.submit_calibration("robonaut-a-day1", "daily", None, 0.0))
    assert again["state"] == "done", again["error"]


def test_a_worker_that_ignores_cancel_or_overruns_is_stopped(jobs: JobManager) -> None:
    hung = jobs.submit_process("test", sleeper, 60.0, session_id=None)
    wait_running(jobs, hung)
    jobs.cancel(hung)
    assert wait(jobs, hung, timeout_s=10)["state"] == "cancelled"  # killed after cancel_grace_s
    jobs.timeout_s = 0.5
    try:
        late = jobs.submit_process("test", sleeper, 60.0, session_id=None)
        snap = wait(jobs, late, timeout_s=15)
    finally:
        jobs.timeout_s = 1800.0
    assert snap["state"] == "failed" and "longer than its limit of 0.5 s" in snap["error"]
    assert wait(jobs, jobs.submit_process("test", sleeper, 0.0, session_id=None))["result"] == "slept"


def test_a_thread_job_reports_pauses_resumes_and_cancels(jobs: JobManager) -> None:
    steps = []
    go = threading.Event()

    def work(ctx: JobContext) -> None:
        while True:  # until cancelled
            ctx.checkpoint()
            steps.append(len(steps))
            ctx.progress(len(steps) / 1000, done=np.int64(len(steps)), q=np.array([0.5, math.nan]))
            go.wait()
            time.sleep(0.002)

    job_id = jobs.submit_thread("replay", work, session_id="nao")
    snap = wait(jobs, job_id, ("running",))
    while not steps:
        time.sleep(0.01)
    snap = jobs.get(job_id)
    assert snap["detail"]["done"] == 1 and snap["progress"] == pytest.approx(0.001)
    assert type(snap["detail"]["done"]) is int and snap["detail"]["q"] == [0.5, None]  # ready for JSON
    jobs.pause(job_id)
    assert jobs.get(job_id)["paused"] is True and store_state(jobs, job_id)["paused"] is True
    go.set()
    time.sleep(0.2)
    held = len(steps)
    time.sleep(0.2)
    assert len(steps) == held <= 2  # blocked in checkpoint
    version = jobs.get(job_id)["version"]
    start = time.monotonic()
    assert jobs.wait_version(job_id, version, 0.3)["version"] == version  # nothing changed: a timeout
    assert time.monotonic() - start >= 0.25
    jobs.resume(job_id)
    while len(steps) < held + 20:
        time.sleep(0.01)
    jobs.cancel(job_id)
    snap = wait(jobs, job_id)
    assert snap["state"] == "cancelled" and snap["paused"] is False and snap["result"] is None
    assert any(j["id"] == job_id for j in jobs.list(session_id="nao"))
    assert all(j["session"] == "nao" for j in jobs.list(session_id="nao"))


def store_state(jobs: JobManager, job_id: str) -> dict:
    return jobs.store.jobs.get(job_id)


def test_thread_job_results_and_failures(jobs: JobManager) -> None:
    def bad_input(ctx: JobContext) -> None:
        raise InputError("shoulder_pitch 101.0 deg is beyond its upper limit 95.0 deg")

    def bug(ctx: JobContext) -> None:
        return {}["nope"]

    def stopped(ctx: JobContext) -> None:
        raise Cancelled("the robot was stopped")

    done = wait(jobs, jobs.submit_thread("capture", lambda ctx: "s-1234", session_id=None))
    assert (done["state"], done["result"], done["progress"]) == ("done", "s-1234", 1.0)
    failed = wait(jobs, jobs.submit_thread("replay", bad_input, session_id=None))
    assert (failed["state"], failed["error"]) == (
        "failed",
        "shoulder_pitch 101.0 deg is beyond its upper limit 95.0 deg",
    )
    assert wait(jobs, jobs.submit_thread("replay", bug, session_id=None))["error"] == "internal error: KeyError: 'nope'"
    assert wait(jobs, jobs.submit_thread("replay", stopped, session_id=None))["state"] == "cancelled"
    with pytest.raises(NotFound):
        jobs.get("j-nothere")


def test_a_restart_shows_interrupted_jobs_as_failed(jobs: JobManager, store: Store) -> None:
    release = threading.Event()

    def capture(ctx: JobContext) -> None:
        while not release.wait(0.01):
            ctx.checkpoint()

    running = jobs.submit_thread("replay", capture, session_id="nao")
    wait(jobs, running, ("running",))
    try:
        restarted = Store(store.data_dir)  # what a new server process sees after a kill
        assert restarted.jobs.fail_interrupted() >= 1
        snap = restarted.jobs.get(running)
        assert (snap["state"], snap["error"]) == ("failed", INTERRUPTED)
        assert json.loads(json.dumps(snap)) == snap
        done = [j for j in restarted.jobs.list() if j["state"] == "done"]
        assert done and all(j["error"] is None for j in done)
    finally:
        release.set()
        wait(jobs, running)


SERVER_LIKE = """\
import sys
with open(sys.argv[1], "a") as log:  # stands for the `calib` script's imports (numpy, OpenCV: seconds)
    log.write("imported\\n")
if __name__ == "__main__":
    from app.jobs import JobManager
    from app.store import Store

    manager = JobManager(Store(__import__("pathlib").Path(sys.argv[2])), workers=1)
    manager.shutdown()  # after the Manager and the warmed-up worker have started
"""


def test_spawned_children_do_not_import_the_servers_script(tmp_path: Path) -> None:
    """A spawned child imports the parent's main script before its initializer (the server watch) runs: with the
    `calib` console script that is the whole command line, seconds on a loaded machine, during which a SIGKILLed
    server's child lived on. The jobs' children import app/parent_watch.py as their main module instead."""
    script, log = tmp_path / "server_like.py", tmp_path / "imports.log"
    script.write_text(SERVER_LIKE)
    root = Path(__file__).resolve().parent.parent
    env = {**os.environ, "PYTHONPATH": str(root)}
    proc = subprocess.run(
        [sys.executable, str(script), str(log), str(tmp_path / "data")], env=env, capture_output=True, timeout=120
    )
    assert proc.returncode == 0, proc.stderr.decode()[-2000:]
    assert log.read_text() == "imported\n"  # by the server alone: not by its Manager nor its worker
