"""The dashboard's store: round trips, the sample sessions equal to their CSV, bad input leaving nothing,
atomic re-measure, the apply history, crash leftovers, concurrent writers and persisted jobs."""

import errno
import json
import os
import shutil
import subprocess
import sys
import threading
import time
from dataclasses import replace
from pathlib import Path

import cv2
import numpy as np
import pytest

from app.errors import NotFound
from app.jobs.snapshot import JobSnapshot, JobState
from app.store import INTERRUPTED, FrameInfo, Observations, Store
from app.store.files import SWEEP_AGE_S
from app.store.importers import ensure_samples, import_csv, import_session_folder
from calib_core import Calibration, InputError, calibrate, load_profile, parse_dataset, read_dataset, to_csv

SAMPLE_NAMES = ["robonaut-a-day1", "robonaut-a-day2", "nao"]
ROBONAUT = load_profile("robonaut-a")


@pytest.fixture(scope="module")
def samples(sample_copy) -> Path:
    """A private copy of the sample sessions (another process may rewrite the originals meanwhile)."""
    return sample_copy(*SAMPLE_NAMES)


@pytest.fixture(scope="module")
def sample_store(tmp_path_factory: pytest.TempPathFactory, samples: Path) -> Store:
    store = Store(tmp_path_factory.mktemp("data"))
    assert sorted(ensure_samples(store, samples)) == sorted(SAMPLE_NAMES)
    return store


def _one(measured: np.ndarray) -> Observations:
    """Robonaut's eye measuring its fixture: checked as a frame's observations."""
    return Observations.of(ROBONAUT, 0, measured)


def _files(root: Path) -> set[str]:
    return {str(p.relative_to(root)) for p in root.rglob("*") if p.is_file() and p.name != "store.sqlite-shm"}


def _robonaut_frame(store: Store, sid: str, index: int | None, x_cm: float, **images: np.ndarray) -> int:
    measured = np.array([[x_cm, 90.0, 5.0]])
    return store.sessions.add_frame(
        sid,
        index=index,
        joints_rad=np.linspace(-0.5, 0.5, 10),
        target=0,
        status="measured",
        reason="ok",
        observations=Observations.of(ROBONAUT, 0, measured, np.full((1, 3), np.nan), np.array([-1])),
        images=images or None,
        detail={"votes": np.int64(300), "fit_rms": np.float64(0.001), "center": np.array([0.1, 0.2, 0.9])},
    )


def test_a_frame_round_trips_with_its_images_and_detail(tmp_path: Path) -> None:
    store = Store(tmp_path)
    sid = store.sessions.create("robonaut-a", "bench", source="capture", description="d")
    assert sid.startswith("s-") and len(sid) == 10
    rng = np.random.default_rng(0)
    left = rng.integers(0, 255, (48, 64, 3), dtype=np.uint8)
    left = cv2.GaussianBlur(left, (9, 9), 3)  # smooth, so JPEG q90 keeps it close
    grey = np.full((48, 64), 120, np.uint8)
    assert _robonaut_frame(store, sid, None, 1.5, left=left, right=grey) == 1
    assert (
        store.sessions.add_frame(sid, index=None, joints_rad=np.zeros(10), target=0, status="not found", reason="gone")
        == 2
    )

    f = store.sessions.frame(sid, 1)
    assert f.status == "measured" and f.reason == "ok" and f.target == 0
    np.testing.assert_array_equal(f.joints_rad, np.linspace(-0.5, 0.5, 10))
    assert f.detail == {"votes": 300, "fit_rms": 0.001, "center": [0.1, 0.2, 0.9]}
    assert set(f.images) == {"left", "right"}
    back = cv2.imread(str(tmp_path / f.images["left"]), cv2.IMREAD_UNCHANGED)
    assert back.shape == left.shape and np.abs(back.astype(int) - left).mean() < 3
    assert cv2.imread(str(tmp_path / f.images["right"]), cv2.IMREAD_UNCHANGED).shape == grey.shape
    info = store.sessions.get(sid)
    assert (info.frames, info.measured, info.source, info.description) == (2, 1, "capture", "d")
    assert [g.index for g in store.sessions.frames(sid)] == [1, 2]

    data = store.sessions.dataset(sid, load_profile("robonaut-a"))
    assert data.frame_ids.tolist() == [1] and data.measured.tolist() == [[1.5, 90.0, 5.0]]
    with pytest.raises(NotFound):
        store.sessions.frame(sid, 3)
    with pytest.raises(NotFound):
        store.sessions.get("s-nothere")
    with pytest.raises(InputError, match="robot 'robonaut-a', not 'nao'"):
        store.sessions.dataset(sid, load_profile("nao"))


def test_a_bad_frame_is_refused_and_writes_nothing(tmp_path: Path) -> None:
    store = Store(tmp_path)
    sid = store.sessions.create("robonaut-a", "bench", source="capture")
    before = _files(tmp_path)
    img = {"left": np.zeros((8, 8, 3), np.uint8)}
    bad = [
        ({"joints_rad": np.zeros(9), "status": "not found"}, "10 joint readings"),
        ({"joints_rad": np.zeros(10), "status": "measured"}, "exactly when its status"),
        ({"joints_rad": np.zeros(10), "status": "pending", "observations": _one(np.ones((1, 3)))}, "exactly when"),
        ({"joints_rad": np.zeros(10), "status": "wobbly"}, "unknown frame status"),
        ({"joints_rad": np.zeros(10), "status": "pending", "images": {"../x": img["left"]}}, "image role"),
        ({"joints_rad": np.zeros(10), "status": "pending", "images": {"left": np.zeros((8, 8))}}, "uint8"),
    ]
    for kwargs, message in bad:
        with pytest.raises(InputError, match=message):
            store.sessions.add_frame(sid, index=None, target=0, **kwargs)
    for measured, message in ((np.ones((1, 2)), "rows of 3 numbers"), (np.full((1, 3), np.inf), "finite")):
        with pytest.raises(InputError, match=message):
            _one(measured)
    assert store.sessions.frames(sid) == [] and _files(tmp_path) == before
    with pytest.raises(NotFound):
        store.sessions.add_frame("s-nothere", index=None, joints_rad=np.zeros(10), target=0, status="pending")
    with pytest.raises(InputError, match="unknown robot"):
        store.sessions.create("r2d2", "x", source="capture")
    with pytest.raises(InputError, match="session id"):
        store.sessions.create("nao", "x", source="capture", session_id="../escape")


@pytest.mark.parametrize("name", SAMPLE_NAMES)
def test_a_sample_session_gives_the_dataset_of_its_csv(sample_store: Store, samples: Path, name: str) -> None:
    meta = json.loads((samples / name / "session.json").read_text())
    profile = load_profile(meta["robot"])
    info = sample_store.sessions.get(name)
    assert (info.robot, info.name, info.source) == (meta["robot"], meta["name"], "sample")
    assert info.truth == json.loads((samples / name / "truth.json").read_text())
    assert info.frames == len(meta["frames"])
    assert info.measured == sum(f["status"] == "measured" for f in meta["frames"])

    got = sample_store.sessions.dataset(name, profile)
    want = read_dataset(profile, samples / name / "data.csv")
    for key in ("frame_ids", "cfg", "target", "vertex"):
        np.testing.assert_array_equal(getattr(got, key), getattr(want, key), err_msg=key)
    for key in ("joints", "measured", "point"):
        a, b = getattr(got, key), getattr(want, key)
        np.testing.assert_array_equal(np.isnan(a), np.isnan(b), err_msg=key)
        np.testing.assert_allclose(np.nan_to_num(a), np.nan_to_num(b), rtol=0, atol=1e-9, err_msg=key)
    # The store's dataset writes the same CSV.
    assert to_csv(profile, got) == to_csv(profile, want)
    again = parse_dataset(profile, to_csv(profile, got))
    np.testing.assert_allclose(again.measured, want.measured, atol=1e-6)

    frames = sample_store.sessions.frames(name)
    for record, frame in zip(meta["frames"], frames, strict=True):
        assert (frame.index, frame.status, frame.reason) == (record["frame"], record["status"], record["reason"])
        assert set(frame.images) == set(record["images"])
        for role, rel in frame.images.items():
            assert (sample_store.data_dir / rel).read_bytes() == (samples / name / record["images"][role]).read_bytes()
    if profile.name == "nao":
        # Frames the detector missed take the foot of the stance they belong to (frames 1-72 left, 73-144 right).
        assert [f.target for f in frames] == [0] * 72 + [1] * 72


def test_samples_come_only_into_a_fresh_store(tmp_path: Path, samples: Path) -> None:
    only = tmp_path / "samples"
    shutil.copytree(samples / "robonaut-a-day1", only / "robonaut-a-day1")
    (only / "not-a-session").mkdir()
    store = Store(tmp_path / "data")
    assert ensure_samples(store, only) == ["robonaut-a-day1"]
    store.sessions.delete("robonaut-a-day1")
    assert not (tmp_path / "data" / "sessions" / "robonaut-a-day1").exists()
    assert ensure_samples(Store(tmp_path / "data"), only) == []
    assert store.sessions.list() == []


def test_samples_the_disk_had_no_room_for_come_at_the_next_start(
    tmp_path: Path, samples: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """A full disk at the first start refused the samples, and they never came back (the samples were marked
    done). Now only a start that imported or skipped every one for good marks them."""
    only = tmp_path / "samples"
    shutil.copytree(samples / "robonaut-a-day1", only / "robonaut-a-day1")
    store = Store(tmp_path / "data")

    def full(fd: int) -> None:
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))

    with monkeypatch.context() as m:
        m.setattr(os, "fsync", full)
        assert ensure_samples(store, only) == []
    assert store.sessions.list() == [] and list((tmp_path / "data" / "sessions").iterdir()) == []
    assert ensure_samples(Store(tmp_path / "data"), only) == ["robonaut-a-day1"]  # room again: the next start
    assert ensure_samples(Store(tmp_path / "data"), only) == []  # and once only


def test_a_broken_sample_is_skipped_and_leaves_nothing(tmp_path: Path, samples: Path) -> None:
    only = tmp_path / "samples"
    shutil.copytree(samples / "robonaut-a-day1", only / "broken")
    (only / "broken" / "images" / "0003_left.jpg").unlink()
    store = Store(tmp_path / "data")
    assert ensure_samples(store, only) == []
    assert store.sessions.list() == [] and _files(tmp_path / "data" / "sessions") == set()
    assert list((tmp_path / "data" / "sessions").iterdir()) == []


def test_an_import_failing_inside_its_transaction_leaves_nothing(
    tmp_path: Path, samples: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    store = Store(tmp_path)

    def fail(*args: object) -> None:
        raise OSError("disk full")

    monkeypatch.setattr("app.store.sessions._insert_observations", fail)
    with pytest.raises(OSError, match="disk full"):
        import_session_folder(store, samples / "robonaut-a-day1")
    with pytest.raises(OSError, match="disk full"):
        import_csv(store, "nao", "x", (samples / "nao" / "data.csv").read_text(), "nao.csv")
    assert store.sessions.list() == [] and list((tmp_path / "sessions").iterdir()) == []


KILLED_WRITER = """
import sys, numpy as np
from pathlib import Path
from app.store.importers import import_csv
from app.store import Observations, Store
store = Store(Path(sys.argv[1]))
profile = store.sessions.profile("robonaut-a")
csv_text = Path(sys.argv[2]).read_text()
sid = store.sessions.create("robonaut-a", "killed", source="capture")
print("ready", flush=True)
for i in range(100000):
    img = np.full((120, 160, 3), i % 256, np.uint8)
    obs = Observations.of(profile, 0, np.array([[float(i), 1.0, 2.0]]))
    store.sessions.add_frame(sid, index=None, joints_rad=np.zeros(10), target=0, status="measured",
                    observations=obs, images={"left": img, "right": img[:, :, 0]})
    if i % 5 == 0:
        store.sessions.add_frame(sid, index=1, joints_rad=np.zeros(10), target=0, status="not found", reason=str(i),
                        images={"left": img})
    if i % 10 == 0:
        import_csv(store, "robonaut-a", f"csv {i}", csv_text, "day1.csv")
"""


@pytest.mark.subprocess
def test_a_killed_writer_leaves_a_consistent_store(tmp_path: Path, samples: Path) -> None:
    csv_path = samples / "robonaut-a-day1" / "data.csv"
    proc = subprocess.Popen(
        [sys.executable, "-c", KILLED_WRITER, str(tmp_path), str(csv_path)],
        stdout=subprocess.PIPE,
        cwd=Path(__file__).resolve().parent.parent,
    )
    assert proc.stdout is not None and proc.stdout.readline().strip() == b"ready"
    time.sleep(0.6)
    proc.kill()
    proc.wait()
    store = Store(tmp_path)
    profile = load_profile("robonaut-a")
    n_csv = read_dataset(profile, csv_path).n_configurations
    sessions = store.sessions.list()
    capture = next(s for s in sessions if s.source == "capture")
    assert capture.frames > 5  # it got somewhere before the kill
    for s in sessions:
        if s.source == "import":  # an import is all there or not there at all
            assert (s.frames, s.measured) == (n_csv, n_csv)
    frames = store.sessions.frames(capture.id)
    for f in frames:
        for rel in f.images.values():
            assert cv2.imread(str(tmp_path / rel)) is not None, rel
    measured = [f for f in frames if f.status == "measured"]
    data = store.sessions.dataset(capture.id, profile)
    assert data.frame_ids.tolist() == [f.index for f in measured]
    assert frames[0].status == "not found" and set(frames[0].images) == {"left"}


def test_import_csv_round_trips(tmp_path: Path, samples: Path) -> None:
    store = Store(tmp_path)
    profile = load_profile("nao")
    text = (samples / "nao" / "data.csv").read_text()
    sid, notes = import_csv(store, "nao", "uploaded", text, "nao.csv")
    assert notes == []
    info = store.sessions.get(sid)
    want = parse_dataset(profile, text)
    n = want.n_configurations
    assert (info.source, info.name, info.frames, info.measured) == ("import", "uploaded", n, n)
    got = store.sessions.dataset(sid, profile)
    assert to_csv(profile, got) == to_csv(profile, want)
    np.testing.assert_array_equal(np.isnan(got.joints), np.isnan(want.joints))


@pytest.mark.parametrize(
    ("text", "line", "column"),
    [
        ("frame,x,y\n1,2,3\n", 1, "z"),
        (
            "frame,x,y,z,shoulder_roll,shoulder_pitch,elbow_roll,elbow_pitch,wrist_roll,wrist_pitch,wrist_yaw,"
            "neck_yaw,neck_pitch,neck_roll\n1,1,2,3,0,0,0,0,0,0,0,0,0,0\n2,1,2,abc,0,0,0,0,0,0,0,0,0,0\n",
            3,
            "z",
        ),
    ],
)
def test_a_bad_csv_names_line_and_column_and_leaves_no_session(
    tmp_path: Path, text: str, line: int, column: str
) -> None:
    store = Store(tmp_path)
    before = _files(tmp_path)
    with pytest.raises(InputError) as err:
        import_csv(store, "robonaut-a", "bad", text, "bad.csv")
    assert (err.value.file, err.value.line, err.value.column) == ("bad.csv", line, column)
    assert f"line {line}" in str(err.value) and f"column '{column}'" in str(err.value)
    assert store.sessions.list() == [] and _files(tmp_path) == before


def test_remeasure_replaces_a_frame_whole_or_not_at_all(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    store = Store(tmp_path)
    sid = store.sessions.create("robonaut-a", "bench", source="capture")
    dark, bright = np.full((16, 16), 20, np.uint8), np.full((16, 16), 230, np.uint8)
    _robonaut_frame(store, sid, 5, 1.0, left=dark)
    first = store.sessions.frame(sid, 5)
    assert first.images == {"left": f"sessions/{sid}/images/0005_left.jpg"}

    _robonaut_frame(store, sid, 5, 2.0, left=bright)
    second = store.sessions.frame(sid, 5)
    assert [f.index for f in store.sessions.frames(sid)] == [5]
    assert second.images["left"] != first.images["left"] and not (tmp_path / first.images["left"]).exists()
    assert cv2.imread(str(tmp_path / second.images["left"]), cv2.IMREAD_GRAYSCALE).mean() > 200
    assert store.sessions.dataset(sid, load_profile("robonaut-a")).measured.tolist() == [[2.0, 90.0, 5.0]]

    # A failure inside the transaction (after the new image was written) keeps the old frame whole.
    def fail(*args: object) -> None:
        raise OSError("disk full")

    monkeypatch.setattr("app.store.sessions._insert_observations", fail)
    files = _files(tmp_path)
    with pytest.raises(OSError, match="disk full"):
        _robonaut_frame(store, sid, 5, 3.0, left=dark)
    monkeypatch.undo()
    assert _same_frame(store.sessions.frame(sid, 5), second)
    assert store.sessions.dataset(sid, load_profile("robonaut-a")).measured.tolist() == [[2.0, 90.0, 5.0]]
    assert _files(tmp_path) == files


def _same_frame(a: FrameInfo, b: FrameInfo) -> bool:
    return all(
        np.array_equal(x, y) if isinstance(x, np.ndarray) else x == y
        for x, y in zip(vars(a).values(), vars(b).values(), strict=True)
    )


def test_a_restart_sweeps_what_a_crash_left(tmp_path: Path) -> None:
    store = Store(tmp_path)
    sid = store.sessions.create("robonaut-a", "bench", source="capture")
    _robonaut_frame(store, sid, 1, 1.0, left=np.zeros((8, 8), np.uint8))
    kept = _files(tmp_path)
    # What a kill between a file write and its row leaves: temporary files, unreferenced files and folders.
    (tmp_path / "sessions" / sid / "images" / ".0002_left.jpg.abc.tmp").write_bytes(b"x")
    (tmp_path / "sessions" / sid / "images" / "0002_left.jpg").write_bytes(b"x")
    (tmp_path / "sessions" / ".s-00000000.xyz" / "images").mkdir(parents=True)
    (tmp_path / "calibrations" / "c-00000000.json").write_text("{}")
    young = tmp_path / "calibrations" / ".c-00000001.json.tmp"  # perhaps a write in flight: it stays
    young.write_text("{")
    for p in [*(tmp_path / "sessions").rglob("*"), *(tmp_path / "calibrations").iterdir()]:
        if p != young:
            os.utime(p, (time.time() - 2 * SWEEP_AGE_S,) * 2)
    store.close()
    again = Store(tmp_path)
    assert _files(tmp_path) == kept | {"calibrations/.c-00000001.json.tmp"}
    assert [f.index for f in again.sessions.frames(sid)] == [1]


def _calibration(samples: Path, name: str, mode: str) -> Calibration:
    profile = load_profile("robonaut-a")
    return calibrate(profile, read_dataset(profile, samples / name / "data.csv"), mode)


def test_calibrations_and_the_apply_history(tmp_path: Path, samples: Path) -> None:
    store = Store(tmp_path)
    sid = import_session_folder(store, samples / "robonaut-a-day1")
    full = _calibration(samples, "robonaut-a-day1", "full")
    a = store.calibrations.add(full, session_id=sid, base_id=None, holdout=0.0)
    b = store.calibrations.add(full, session_id=sid, base_id=a, holdout=0.2)
    assert a.startswith("c-") and (tmp_path / "calibrations" / f"{a}.json").is_file()
    assert store.calibrations.load(a).values() == full.values()
    info = store.calibrations.info(b)
    assert (info.session_id, info.base_id, info.holdout, info.mode, info.robot) == (sid, a, 0.2, "full", "robonaut-a")
    assert info.figures["after"]["rms"] == pytest.approx(full.figures["after"].rms)
    assert [c.id for c in store.calibrations.list(session_id=sid)] == [b, a]
    assert store.calibrations.list(robot="nao") == []

    assert store.calibrations.active("robonaut-a") is None
    assert store.calibrations.apply("robonaut-a", a, "first") == (a, None)
    assert store.calibrations.apply("robonaut-a", b) == (b, a)
    assert store.calibrations.apply("robonaut-a", a, "rollback") == (a, b)
    assert store.calibrations.active("robonaut-a") == a and store.calibrations.active("nao") is None
    history = store.calibrations.history("robonaut-a")
    assert [(h["calibration"], h["previous"], h["note"]) for h in history] == [
        (a, b, "rollback"),
        (b, a, ""),
        (a, None, "first"),
    ]
    assert history[0]["seq"] > history[1]["seq"] and history[0]["session"] == sid and history[0]["mode"] == "full"
    assert history[0]["figures"]["after"]["rms"] == pytest.approx(full.figures["after"].rms)

    with pytest.raises(InputError, match="is for robot 'robonaut-a', not 'nao'"):
        store.calibrations.apply("nao", a)
    with pytest.raises(NotFound):
        store.calibrations.apply("robonaut-a", "c-nothere")
    with pytest.raises(NotFound):
        store.calibrations.add(full, session_id="s-nothere", base_id=None, holdout=0.0)
    assert len(list((tmp_path / "calibrations").iterdir())) == 2  # the refused one left no file
    assert store.calibrations.active("robonaut-a") == a and len(store.calibrations.history("robonaut-a")) == 3

    # The history survives a restart, and a deleted session leaves its calibrations (without a session).
    store.sessions.delete(sid)
    again = Store(tmp_path)
    assert again.calibrations.active("robonaut-a") == a and again.calibrations.info(a).session_id is None
    assert not (tmp_path / "sessions" / sid).exists()


def test_concurrent_writers_and_readers(tmp_path: Path) -> None:
    store = Store(tmp_path)
    sid = store.sessions.create("robonaut-a", "bench", source="capture")
    errors: list[BaseException] = []
    n_threads, per_thread = 8, 15

    def write(k: int) -> None:
        try:
            for i in range(per_thread):
                img = np.full((8, 8), k * 10 + i, np.uint8) if i % 3 == 0 else None
                _robonaut_frame(store, sid, None, float(k * 100 + i), **({"left": img} if img is not None else {}))
                if i % 5 == 0:
                    store.sessions.create("nao", f"t{k}-{i}", source="capture")
        except BaseException as exc:
            errors.append(exc)

    def read() -> None:
        try:
            for _ in range(30):
                store.sessions.list()
                store.sessions.dataset(sid, load_profile("robonaut-a"))
        except BaseException as exc:
            errors.append(exc)

    threads = [threading.Thread(target=write, args=(k,)) for k in range(n_threads)]
    threads += [threading.Thread(target=read) for _ in range(2)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert errors == []
    frames = store.sessions.frames(sid)
    assert [f.index for f in frames] == list(range(1, n_threads * per_thread + 1))
    xs = sorted(store.sessions.dataset(sid, load_profile("robonaut-a")).measured[:, 0])
    assert xs == sorted(float(k * 100 + i) for k in range(n_threads) for i in range(per_thread))
    assert sum(len(f.images) for f in frames) == n_threads * 5
    assert len(store.sessions.list()) == 1 + n_threads * 3


def test_jobs_persist_and_a_restart_fails_the_interrupted(tmp_path: Path) -> None:
    store = Store(tmp_path)

    def job(i: int, state: JobState, t: str) -> JobSnapshot:
        return JobSnapshot(f"j-{i}", "replay", state, 0.5, None, None, None, t, t, cost=[1.0], paused=True)

    for i, state in enumerate([JobState.DONE, JobState.RUNNING, JobState.QUEUED, JobState.CANCELLED]):
        store.jobs.save(job(i, state, f"2026-01-01T00:00:0{i}.000+00:00"))
    store.jobs.save(replace(job(0, JobState.DONE, "x"), updated="y"))
    again = Store(tmp_path)
    assert again.jobs.fail_interrupted() == 2
    jobs = {j.id: j for j in again.jobs.list()}
    assert [j.id for j in again.jobs.list()][:3] == ["j-3", "j-2", "j-1"]
    assert {k: (j.state, j.error) for k, j in jobs.items()} == {
        "j-0": ("done", None),
        "j-1": ("failed", INTERRUPTED),
        "j-2": ("failed", INTERRUPTED),
        "j-3": ("cancelled", None),
    }
    assert again.jobs.fail_interrupted() == 0
    assert again.jobs.get("j-1").cost == [1.0] and not again.jobs.get("j-1").paused
    assert (again.jobs.get("j-1").version, again.jobs.get("j-0").version) == (1, 0)


# The schema of the first dashboard (version 1, no version recorded), as it was written to disk.
SCHEMA_V1 = """
CREATE TABLE meta (key TEXT PRIMARY KEY, value TEXT NOT NULL);
CREATE TABLE sessions (
    id TEXT PRIMARY KEY, robot TEXT NOT NULL, name TEXT NOT NULL, description TEXT NOT NULL,
    created TEXT NOT NULL, source TEXT NOT NULL, truth TEXT);
CREATE TABLE frames (
    session_id TEXT NOT NULL REFERENCES sessions(id) ON DELETE CASCADE,
    idx INTEGER NOT NULL, joints_rad TEXT NOT NULL, target INTEGER NOT NULL, status TEXT NOT NULL,
    reason TEXT NOT NULL, images TEXT NOT NULL, detail TEXT NOT NULL, captured TEXT NOT NULL,
    PRIMARY KEY (session_id, idx));
CREATE TABLE observations (
    session_id TEXT NOT NULL, idx INTEGER NOT NULL, seq INTEGER NOT NULL, target INTEGER NOT NULL,
    vertex INTEGER NOT NULL, px REAL, py REAL, pz REAL, m0 REAL NOT NULL, m1 REAL NOT NULL, m2 REAL,
    PRIMARY KEY (session_id, idx, seq),
    FOREIGN KEY (session_id, idx) REFERENCES frames(session_id, idx) ON DELETE CASCADE);
CREATE TABLE calibrations (
    id TEXT PRIMARY KEY, session_id TEXT REFERENCES sessions(id) ON DELETE SET NULL,
    robot TEXT NOT NULL, mode TEXT NOT NULL, created TEXT NOT NULL,
    base_id TEXT REFERENCES calibrations(id), holdout REAL NOT NULL, path TEXT NOT NULL, figures TEXT NOT NULL);
CREATE TABLE applies (
    seq INTEGER PRIMARY KEY AUTOINCREMENT, robot TEXT NOT NULL, time TEXT NOT NULL,
    calibration_id TEXT NOT NULL REFERENCES calibrations(id), previous_id TEXT, note TEXT NOT NULL);
CREATE INDEX applies_robot ON applies (robot, seq);
CREATE TABLE jobs (
    id TEXT PRIMARY KEY, kind TEXT NOT NULL, state TEXT NOT NULL, session_id TEXT,
    created TEXT NOT NULL, updated TEXT NOT NULL, snapshot TEXT NOT NULL);
"""


def test_a_store_made_with_the_first_schema_opens_and_keeps_its_data(tmp_path: Path, samples: Path) -> None:
    """A data directory of the first dashboard, written with its own SQL: opened by today's Store, every row is
    there, the robots table is added in place and the schema version recorded; the store then works."""
    import sqlite3

    full = calibrate(load_profile("nao"), read_dataset(load_profile("nao"), samples / "nao" / "data.csv"), "full")
    (tmp_path / "calibrations").mkdir()
    full.save(tmp_path / "calibrations" / "c-0ld00001.json")
    db = sqlite3.connect(tmp_path / "store.sqlite")
    db.executescript(SCHEMA_V1)
    t = "2026-01-02T03:04:05.000+00:00"
    db.execute("INSERT INTO meta VALUES ('samples', ?)", (t,))
    db.execute("INSERT INTO sessions VALUES ('s-0ld', 'nao', 'old', '', ?, 'capture', NULL)", (t,))
    q = json.dumps([0.0] * len(load_profile("nao").joints))
    db.execute("INSERT INTO frames VALUES ('s-0ld', 1, ?, 0, 'measured', '', '{}', '{}', ?)", (q, t))
    db.execute("INSERT INTO observations VALUES ('s-0ld', 1, 0, 0, 3, NULL, NULL, NULL, 320.5, 240.25, NULL)")
    db.execute(
        "INSERT INTO calibrations VALUES ('c-0ld00001', 's-0ld', 'nao', 'full', ?, NULL, 0.0, "
        "'calibrations/c-0ld00001.json', '{}')",
        (t,),
    )
    db.execute(
        "INSERT INTO applies (robot, time, calibration_id, previous_id, note) "
        "VALUES ('nao', ?, 'c-0ld00001', NULL, 'kept')",
        (t,),
    )
    snap = {"id": "j-0ld", "kind": "calibration", "state": "done", "created": t, "updated": t}
    db.execute("INSERT INTO jobs VALUES ('j-0ld', 'calibration', 'done', 's-0ld', ?, ?, ?)", (t, t, json.dumps(snap)))
    db.commit()
    db.close()

    store = Store(tmp_path)
    assert store.db.version == 4 and store.db.meta("schema") == "4"
    assert [(s.id, s.robot, s.frames, s.measured) for s in store.sessions.list()] == [("s-0ld", "nao", 1, 1)]
    data = store.sessions.dataset("s-0ld", load_profile("nao"))
    assert data.measured.tolist() == [[320.5, 240.25]] and data.vertex.tolist() == [3]
    assert data.sensor.tolist() == [load_profile("nao").data.sensor]  # rows of before: the data sensor's
    assert store.calibrations.load("c-0ld00001").values() == full.values()
    assert store.calibrations.active("nao") == "c-0ld00001"
    assert [h["note"] for h in store.calibrations.history("nao")] == ["kept"]
    old = store.jobs.get("j-0ld")  # the first dashboard kept no progress, detail, cost, version or pause
    assert (old.state, old.session, old.progress, old.detail, old.cost, old.version) == ("done", None, 0.0, {}, [], 0)
    assert ensure_samples(store, samples) == []  # the samples were imported by the old store already
    # The new table is there and empty: a robot of the old store is its built-in profile's instance.
    assert store.robots.list() == [] and store.robots.profile("nao").name == "nao"
    assert store.robots.names_with_data() == ["nao"]
    store.close()
    again = Store(tmp_path)  # migrated once: opening again changes nothing
    assert again.db.version == 4 and len(again.sessions.list()) == 1
    again.close()
