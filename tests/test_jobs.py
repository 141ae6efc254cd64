"""Background jobs: a calibration in a spawned worker recovers the sample's truth; validation before a
job exists; cancel, failures, a killed or overrunning worker; thread jobs with pause and resume; a
restart shows interrupted jobs as failed. One JobRunner (one spawned worker) on a manual clock serves the
module: its time limits pass when a test advances the clock, never on wall time."""

import json
import math
import os
import subprocess
import sys
import threading
import time
from collections.abc import Iterator
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import numpy as np
import pytest
from manual_jobs import HOUR_S, manual_clock, manual_runner, wait
from worker_functions import exploder, sleeper

from app.clock import ManualClock
from app.errors import NotFound
from app.importers import ensure_samples
from app.jobs.runner import JobContext, JobRunner, crashed
from app.jobs.snapshot import JobSnapshot, JobState
from app.services.calibration import CalibrationService, solve
from app.store import INTERRUPTED, Observations, Store
from calib_core import InputError
from calib_core.errors import Cancelled


@pytest.fixture(scope="module")
def sample_store(store: Store, sample_copy) -> Store:
    """The module's store with Robonaut's first day and NAO among its sessions."""
    ensure_samples(store, sample_copy("robonaut-a-day1", "nao"))
    return store


@pytest.fixture(scope="module")
def jobs(sample_store: Store) -> Iterator[JobRunner]:
    with manual_runner(sample_store) as runner:
        yield runner


@pytest.fixture(scope="module")
def clock(jobs: JobRunner) -> ManualClock:
    return manual_clock(jobs)


@pytest.fixture(scope="module")
def calibrations(sample_store: Store, jobs: JobRunner) -> CalibrationService:
    return CalibrationService(sample_store, jobs)


def wait_running(jobs: JobRunner, job_id: str) -> int:
    """The worker's pid once the job runs in it (a process job runs once its worker has said which it is)."""
    wait(jobs, job_id, lambda s: s.state == JobState.RUNNING)
    pid = jobs.worker_pid(job_id)
    assert pid is not None
    return pid


def alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    return True


def slow_job(calibrations: CalibrationService) -> str:
    """Nelder-Mead on the NAO sample's 21 parameters: seconds of work that checks its cancel flag."""
    return calibrations.submit("nao", "full", None, 0.0, method="nelder-mead")


@pytest.mark.slow
def test_a_calibration_job_recovers_the_samples_truth(
    jobs: JobRunner, calibrations: CalibrationService, sample_store: Store
) -> None:
    job_id = calibrations.submit("robonaut-a-day1", "full", None, 0.3)
    seen = []
    snap = jobs.get(job_id)
    while not snap.state.finished:
        seen.append((snap.state, snap.progress))
        snap = jobs.wait_version(job_id, snap.version, HOUR_S)
    assert snap.state == JobState.DONE, snap.error
    assert snap.progress == 1.0 and snap.error is None and snap.session == "robonaut-a-day1"
    assert any(state == "running" for state, _ in seen)
    assert all(p <= 0.95 for _, p in seen)
    assert len(snap.cost) > 2 and snap.cost[-1] < snap.cost[0] / 100

    cal = sample_store.calibrations.load(snap.result)
    info = sample_store.calibrations.info(snap.result)
    assert (info.session_id, info.holdout, info.mode, cal.source) == ("robonaut-a-day1", 0.3, "full", "robonaut-a-day1")
    measured = [f.index for f in sample_store.sessions.frames("robonaut-a-day1") if f.status == "measured"]
    train, held = cal.frames["train"], cal.frames["holdout"]
    assert sorted(train + held) == measured and not set(train) & set(held) and len(held) == round(0.3 * len(measured))
    after, before = cal.figures["after"].rms, cal.figures["before"].rms
    assert after < before / 50 and cal.figures["holdout_after"].rms < cal.figures["holdout_before"].rms / 20
    assert snap.detail["after_rms"] == pytest.approx(after)

    truth = sample_store.sessions.get("robonaut-a-day1").truth
    offsets = [p for p in cal.parameters if p.name.endswith(".theta") and p.estimated and p.note is None]
    assert len(offsets) >= 8
    for p in offsets:
        assert abs(p.value - truth[p.name]) < 4 * p.std + 0.05, p.name
    # ... where the nominal model was far off: the job really estimated them.
    assert sum(abs(p.nominal - truth[p.name]) > 10 * p.std for p in offsets) >= len(offsets) // 2
    assert sample_store.jobs.get(job_id) == snap


def test_a_base_calibration_is_the_starting_point(
    jobs: JobRunner, calibrations: CalibrationService, sample_store: Store
) -> None:
    full = wait(jobs, calibrations.submit("robonaut-a-day1", "full", None, 0.0))
    daily = wait(jobs, calibrations.submit("robonaut-a-day1", "daily", full.result, 0.0))
    assert daily.state == JobState.DONE, daily.error
    cal = sample_store.calibrations.load(daily.result)
    assert sample_store.calibrations.info(daily.result).base_id == full.result
    # Starting from the full calibration, a daily one starts (and stays) near its after-error.
    assert cal.figures["before"].rms < 2 * sample_store.calibrations.load(full.result).figures["after"].rms


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
def test_a_bad_request_is_refused_before_a_job_exists(
    jobs: JobRunner, calibrations: CalibrationService, args: tuple, message: str
) -> None:
    before = len(jobs.list())
    positional, kwargs = (args[:4], args[4]) if len(args) > 4 else (args, {})
    with pytest.raises(InputError, match=message):
        calibrations.submit(*positional, **kwargs)
    assert len(jobs.list()) == before


def test_unknown_sessions_and_bases_foreign_bases_and_too_few_frames(
    jobs: JobRunner, calibrations: CalibrationService, sample_store: Store
) -> None:
    before = len(jobs.list())
    with pytest.raises(NotFound):
        calibrations.submit("s-nothere", "full", None, 0.0)
    with pytest.raises(NotFound, match="no base calibration 'c-nothere' on this desk"):
        calibrations.submit("robonaut-a-day1", "full", "c-nothere", 0.0)
    assert len(jobs.list()) == before
    nao_cal = wait(jobs, calibrations.submit("nao", "full", None, 0.0)).result
    with pytest.raises(InputError, match="is for robot 'nao', not 'robonaut-a'"):
        calibrations.submit("robonaut-a-day1", "full", nao_cal, 0.0)
    sid = sample_store.sessions.create("robonaut-a", "three frames", source="capture")
    with pytest.raises(InputError, match="no measured frames"):
        calibrations.submit(sid, "full", None, 0.0)
    for k in range(3):
        obs = Observations.of(sample_store.sessions.profile("robonaut-a"), 0, np.ones((1, 3)))
        sample_store.sessions.add_frame(
            sid, index=None, joints_rad=np.full(10, 0.1 * k), target=0, status="measured", observations=obs
        )
    with pytest.raises(
        InputError, match=r"3 observations \(9 rows\) cannot calibrate mode 'full': they would fix 9 of"
    ):
        calibrations.submit(sid, "full", None, 0.0)


def test_a_mode_of_more_parameters_than_rows_runs_when_the_rows_exceed_what_they_determine(
    jobs: JobRunner, calibrations: CalibrationService, sample_store: Store
) -> None:
    """Robonaut's `full` frees 23 parameters, of which no data of one sphere determine more than 19: seven of
    the sample's frames (21 rows) are calibrated, the rest held by name (the request was refused before, 21 <
    23); six (18 rows, no more than what they determine) are refused before a job exists."""
    profile = sample_store.sessions.profile("robonaut-a")
    sample = sample_store.sessions.dataset("robonaut-a-day1", profile)
    for n in (6, 7):
        sid = sample_store.sessions.create("robonaut-a", f"{n} frames", source="capture")
        for c in range(n):
            obs = sample.cfg == c
            sample_store.sessions.add_frame(
                sid,
                index=None,
                joints_rad=sample.joints[c],
                target=int(sample.target[obs][0]),
                status="measured",
                observations=Observations.of(profile, int(sample.target[obs][0]), sample.measured[obs, :3]),
            )
        if n == 6:
            before = len(jobs.list())
            with pytest.raises(InputError, match=r"6 observations \(18 rows\) cannot calibrate mode 'full'"):
                calibrations.submit(sid, "full", None, 0.0)
            assert len(jobs.list()) == before
    snap = wait(jobs, calibrations.submit(sid, "full", None, 0.0))
    assert snap.state == JobState.DONE, snap.error
    cal = sample_store.calibrations.load(snap.result)
    assert len(cal.identifiability.free) == 19 and len(cal.identifiability.held_fixed) == 4
    assert cal.figures["after"].rms < cal.figures["before"].rms / 10


def test_a_calibration_request_answers_before_its_data_are_read_and_cancels_while_they_are(
    jobs: JobRunner, calibrations: CalibrationService, sample_store: Store, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Reading the session, the held-out split and the solve grow with the data: they run in the job, so the
    request answers at once (a 96,000-frame session held it for minutes) and the job can be cancelled while
    the data are still being read."""
    release = threading.Event()
    read = sample_store.sessions.dataset

    def slow_read(*args, **kwargs):
        release.wait(60)
        return read(*args, **kwargs)

    monkeypatch.setattr(sample_store.sessions, "dataset", slow_read)
    t0 = time.monotonic()
    loading = calibrations.submit("robonaut-a-day1", "daily", None, 0.5)
    after = calibrations.submit("robonaut-a-day1", "daily", None, 0.25)
    assert time.monotonic() - t0 < 2.0
    snap = jobs.get(loading)
    assert (snap.state, snap.detail["phase"], snap.detail["frames"]) == ("queued", "loading", 64)
    jobs.cancel(loading)
    assert jobs.get(loading).state == JobState.CANCELLED  # at once, not when the read ends
    release.set()
    done = wait(jobs, after)
    assert done.state == JobState.DONE and done.detail["phase"] == "solving", done.error
    assert jobs.get(loading).state == JobState.CANCELLED and jobs.get(loading).detail["phase"] == "loading"


def test_cancel_a_running_and_a_queued_job(
    jobs: JobRunner, calibrations: CalibrationService, sample_store: Store
) -> None:
    n_cals = len(sample_store.calibrations.list())
    running = slow_job(calibrations)
    queued = calibrations.submit("robonaut-a-day1", "full", None, 0.0)
    pid = wait_running(jobs, running)
    assert jobs.get(queued).state == JobState.QUEUED
    jobs.cancel(queued)
    assert jobs.get(queued).state == JobState.CANCELLED
    jobs.cancel(running)
    snap = wait(jobs, running)
    assert snap.state == JobState.CANCELLED and snap.result is None
    # The manual clock stood still, so its cancel grace never passed: the solver saw the flag, its worker lives.
    assert alive(pid)
    assert len(sample_store.calibrations.list()) == n_cals
    assert (
        sample_store.jobs.get(running).state == JobState.CANCELLED
        and sample_store.jobs.get(queued).state == JobState.CANCELLED
    )
    jobs.cancel(running)  # a finished job: nothing to do
    with pytest.raises(InputError, match="a calibration job runs in a worker process and cannot be paused"):
        jobs.pause(running)
    with pytest.raises(NotFound):
        jobs.cancel("j-nothere")


def test_the_same_calibration_asked_twice_while_it_runs_is_one_job(
    jobs: JobRunner, calibrations: CalibrationService, sample_store: Store
) -> None:
    """A double click on Calibrate, or two tabs asking at once: one job, one calibration; another request
    (another held-out share) is another job, and once the first is done the same request runs again."""
    n_cals = len(sample_store.calibrations.list())
    running = slow_job(calibrations)
    ask = ("robonaut-a-day1", "full", None, 0.3)
    with ThreadPoolExecutor(4) as pool:
        ids = set(pool.map(lambda _: calibrations.submit(*ask), range(4)))
    assert len(ids) == 1
    other = calibrations.submit("robonaut-a-day1", "full", None, 0.2)
    assert other not in ids
    jobs.cancel(running)
    (first,) = ids
    assert wait(jobs, first).state == JobState.DONE and wait(jobs, other).state == JobState.DONE
    assert len(sample_store.calibrations.list()) == n_cals + 2
    assert calibrations.submit(*ask) != first


def test_a_failing_worker_fails_its_job_with_one_line(jobs: JobRunner, calibrations: CalibrationService) -> None:
    # Bad input that slipped past validation: the solver's InputError text is the message.
    payload = calibrations.payload("robonaut-a-day1", "full", None, 0.0)
    job_id = jobs.submit_process("calibration", solve, lambda ctx: {**payload, "mode": "bogus"}, session_id=None)
    snap = wait(jobs, job_id)
    assert snap.state == JobState.FAILED
    assert snap.error == "unknown mode 'bogus' for robot 'robonaut-a' (known: daily, full, auto)"
    # A bug: the exception's type and message on one line, no traceback.
    job_id = jobs.submit_process("test", exploder, lambda ctx: "boom\n  at line 2", session_id=None)
    snap = wait(jobs, job_id)
    assert (snap.state, snap.error) == ("failed", "internal error: RuntimeError: boom at line 2")
    # A payload that cannot be built: the job fails with the reason, and no worker sees it.
    job_id = jobs.submit_process(
        "calibration", solve, lambda ctx: calibrations.payload("s-nothere", "full", None, 0.0), session_id=None
    )
    assert (wait(jobs, job_id).state, jobs.get(job_id).error) == ("failed", "no session 's-nothere' on this desk")


@pytest.mark.slow
def test_a_killed_worker_fails_its_job_and_the_next_job_runs(jobs: JobRunner, calibrations: CalibrationService) -> None:
    job_id = slow_job(calibrations)
    os.kill(wait_running(jobs, job_id), 9)
    snap = wait(jobs, job_id)
    assert (snap.state, snap.error) == ("failed", crashed("calibration"))
    assert (
        snap.error
        == "the calibration worker process stopped unexpectedly (crashed or killed); the worker was restarted"
    )
    after_id = calibrations.submit("robonaut-a-day1", "full", None, 0.0)
    after = wait(jobs, after_id)
    assert after.state == JobState.DONE, after.error
    # A worker that dies while idle (the OOM killer) is replaced for the next job, even one submitted at once.
    os.kill(jobs.worker_pid(after_id), 9)
    again = wait(jobs, calibrations.submit("robonaut-a-day1", "daily", None, 0.0))
    assert again.state == JobState.DONE, again.error


def test_a_worker_that_ignores_cancel_or_overruns_is_stopped(jobs: JobRunner, clock: ManualClock) -> None:
    """The limits pass on the runner's clock: a hung worker lives until they do, and is killed the moment they
    do (the timer runs as the test advances the clock), in no wall time."""
    hung = jobs.submit_process("test", sleeper, lambda ctx: HOUR_S, session_id=None)
    pid = wait_running(jobs, hung)
    jobs.cancel(hung)
    clock.advance(jobs.cancel_grace_s - 0.5)  # halves: sums of them are exact
    assert alive(pid) and jobs.get(hung).state == JobState.RUNNING
    clock.advance(0.5)  # the grace has passed: killed
    assert wait(jobs, hung).state == JobState.CANCELLED

    late = jobs.submit_process("test", sleeper, lambda ctx: HOUR_S, session_id=None)
    pid = wait_running(jobs, late)
    clock.advance(jobs.timeout_s - 0.5)
    assert alive(pid) and jobs.get(late).state == JobState.RUNNING
    clock.advance(0.5)
    snap = wait(jobs, late)
    assert (snap.state, snap.error) == ("failed", "the test took longer than its limit of 1800 s and was stopped")
    assert wait(jobs, jobs.submit_process("test", sleeper, lambda ctx: 0.0, session_id=None)).result == "slept"


def test_a_thread_job_reports_pauses_resumes_and_cancels(jobs: JobRunner, clock: ManualClock) -> None:
    steps = []
    go = threading.Event()

    def work(ctx: JobContext) -> None:
        while True:  # until cancelled
            ctx.checkpoint()
            steps.append(len(steps))
            ctx.progress(len(steps) / 1000, done=np.int64(len(steps)), q=np.array([0.5, math.nan]))
            go.wait()

    job_id = jobs.submit_thread("replay", work, session_id="nao")
    snap = wait(jobs, job_id, lambda s: "done" in s.detail)
    assert snap.state == JobState.RUNNING and snap.detail["done"] == 1 and snap.progress == pytest.approx(0.001)
    assert type(snap.detail["done"]) is int and snap.detail["q"] == [0.5, None]  # ready for JSON
    jobs.pause(job_id)
    assert jobs.get(job_id).paused is True and jobs.store.jobs.get(job_id).paused is True
    go.set()
    clock.until_thread_waits(f"job-{job_id}")  # held at its checkpoint
    assert len(steps) == 1 and jobs.get(job_id).state == JobState.RUNNING  # paused is a flag of a running job

    # Nothing changes while it is held: a wait for a change ends at its timeout, on the runner's clock.
    version = jobs.get(job_id).version
    seen = []
    reader = threading.Thread(target=lambda: seen.append(jobs.wait_version(job_id, version, 30.0)), name="reader")
    reader.start()
    clock.until_thread_waits("reader")
    clock.advance(30.0)
    reader.join()
    assert seen[0].version == version and len(steps) == 1

    jobs.resume(job_id)
    wait(jobs, job_id, lambda s: s.detail["done"] >= 20)
    jobs.cancel(job_id)
    snap = wait(jobs, job_id)
    assert snap.state == JobState.CANCELLED and snap.paused is False and snap.result is None
    assert any(j.id == job_id for j in jobs.list(session_id="nao"))
    assert all(j.session == "nao" for j in jobs.list(session_id="nao"))


def test_a_step_unless_paused_is_not_run_once_a_pause_is_answered(jobs: JobRunner, clock: ManualClock) -> None:
    """What a job keeps through unless_paused (a replay's frame) never comes after a pause was answered; resumed,
    the next step runs."""
    go = threading.Event()
    got: list[str | None] = []

    def work(ctx: JobContext) -> None:
        go.wait()
        got.append(ctx.unless_paused(lambda: "kept while paused"))
        ctx.checkpoint()
        got.append(ctx.unless_paused(lambda: "kept after the resume"))

    job_id = jobs.submit_thread("replay", work, session_id=None)
    jobs.pause(job_id)
    go.set()
    clock.until_thread_waits(f"job-{job_id}")  # held at its checkpoint
    assert got == [None]
    jobs.resume(job_id)
    assert wait(jobs, job_id).state == JobState.DONE
    assert got == [None, "kept after the resume"]


def test_thread_job_results_and_failures(jobs: JobRunner) -> None:
    def bad_input(ctx: JobContext) -> None:
        raise InputError("shoulder_pitch 101.0 deg is beyond its upper limit 95.0 deg")

    def bug(ctx: JobContext) -> None:
        return {}["nope"]

    def stopped(ctx: JobContext) -> None:
        raise Cancelled("the robot was stopped")

    done = wait(jobs, jobs.submit_thread("capture", lambda ctx: "s-1234", session_id=None))
    assert (done.state, done.result, done.progress) == ("done", "s-1234", 1.0)
    failed = wait(jobs, jobs.submit_thread("replay", bad_input, session_id=None))
    assert (failed.state, failed.error) == ("failed", "shoulder_pitch 101.0 deg is beyond its upper limit 95.0 deg")
    assert wait(jobs, jobs.submit_thread("replay", bug, session_id=None)).error == "internal error: KeyError: 'nope'"
    assert wait(jobs, jobs.submit_thread("replay", stopped, session_id=None)).state == JobState.CANCELLED
    with pytest.raises(NotFound):
        jobs.get("j-nothere")
    with pytest.raises(InputError, match="a dry run job cannot be paused; cancel it"):
        jobs.pause(jobs.submit_thread("dry_run", lambda ctx: None, session_id=None, pausable=False))


def test_a_restart_shows_interrupted_jobs_as_failed(jobs: JobRunner, sample_store: Store) -> None:
    release = threading.Event()

    def capture(ctx: JobContext) -> None:
        release.wait(60)

    running = jobs.submit_thread("replay", capture, session_id="nao")
    wait(jobs, running, lambda s: s.state == JobState.RUNNING)
    try:
        restarted = Store(sample_store.data_dir)  # what a new server process sees after a kill
        assert restarted.jobs.fail_interrupted() >= 1
        snap = restarted.jobs.get(running)
        assert (snap.state, snap.error, snap.paused) == ("failed", INTERRUPTED, False)
        assert JobSnapshot.from_dict(json.loads(json.dumps(snap.to_dict()))) == snap
        done = [j for j in restarted.jobs.list() if j.state == JobState.DONE]
        assert done and all(j.error is None for j in done)
    finally:
        release.set()
        wait(jobs, running)


@pytest.mark.subprocess
def test_a_worker_imports_none_of_the_servers_modules() -> None:
    """What a calibration's worker process imports (its main module, the worker's side, the job's function) holds
    no module of the server: not the store, the runner, the routers, viser or FastAPI."""
    root = Path(__file__).resolve().parent.parent
    code = (
        "import sys, app.parent_watch, app.jobs.worker, app.services.calibration; "
        "print(' '.join(sorted(m for m in sys.modules if m.split('.')[0] in ('app', 'fastapi', 'viser', 'sqlite3'))))"
    )
    proc = subprocess.run([sys.executable, "-c", code], cwd=root, capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0, proc.stderr[-2000:]
    assert proc.stdout.split() == [
        "app",
        "app.errors",
        "app.jobs",
        "app.jobs.snapshot",
        "app.jobs.worker",
        "app.limits",
        "app.parent_watch",
        "app.services",
        "app.services.calibration",
    ]


SERVER_LIKE = """\
import sys
with open(sys.argv[1], "a") as log:  # stands for the `calib` script's imports (numpy, OpenCV: seconds)
    log.write("imported\\n")
if __name__ == "__main__":
    from app.jobs.runner import JobRunner
    from app.store import Store

    runner = JobRunner(Store(__import__("pathlib").Path(sys.argv[2])), workers=1)
    runner.shutdown()  # after the Manager and the warmed-up worker have started
"""


@pytest.mark.subprocess
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
