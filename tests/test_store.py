"""The dashboard's store: round trips, the sample sessions equal to their CSV, bad input leaving nothing,
atomic re-measure, the apply history, crash leftovers, concurrent writers and persisted jobs."""

import json
import os
import shutil
import subprocess
import sys
import threading
import time
from pathlib import Path

import cv2
import numpy as np
import pytest

from app.store import INTERRUPTED, SWEEP_AGE_S, FrameInfo, Store
from calib_core import Calibration, InputError, calibrate, load_profile, parse_dataset, read_dataset, to_csv

SAMPLES = Path(__file__).resolve().parent.parent / "sample_sessions"
SAMPLE_NAMES = ["robonaut-a-day1", "robonaut-a-day2", "nao"]


@pytest.fixture(scope="module")
def samples(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A private copy of the sample sessions (another process may rewrite the originals meanwhile)."""
    dst = tmp_path_factory.mktemp("samples")
    for name in SAMPLE_NAMES:
        shutil.copytree(SAMPLES / name, dst / name)
    return dst


@pytest.fixture(scope="module")
def sample_store(tmp_path_factory: pytest.TempPathFactory, samples: Path) -> Store:
    store = Store(tmp_path_factory.mktemp("data"))
    assert sorted(store.ensure_samples(samples)) == sorted(SAMPLE_NAMES)
    return store


def _files(root: Path) -> set[str]:
    return {str(p.relative_to(root)) for p in root.rglob("*") if p.is_file() and p.name != "store.sqlite-shm"}


def _robonaut_frame(store: Store, sid: str, index: int | None, x_cm: float, **images: np.ndarray) -> int:
    return store.add_frame(
        sid,
        index=index,
        joints_rad=np.linspace(-0.5, 0.5, 10),
        target=0,
        status="measured",
        reason="ok",
        measured=np.array([[x_cm, 90.0, 5.0]]),
        points=np.full((1, 3), np.nan),
        vertices=np.array([-1]),
        images=images or None,
        detail={"votes": np.int64(300), "fit_rms": np.float64(0.001), "center": np.array([0.1, 0.2, 0.9])},
    )


def test_a_frame_round_trips_with_its_images_and_detail(tmp_path: Path) -> None:
    store = Store(tmp_path)
    sid = store.create_session("robonaut-a", "bench", source="capture", description="d")
    assert sid.startswith("s-") and len(sid) == 10
    rng = np.random.default_rng(0)
    left = rng.integers(0, 255, (48, 64, 3), dtype=np.uint8)
    left = cv2.GaussianBlur(left, (9, 9), 3)  # smooth, so JPEG q90 keeps it close
    grey = np.full((48, 64), 120, np.uint8)
    assert _robonaut_frame(store, sid, None, 1.5, left=left, right=grey) == 1
    assert store.add_frame(sid, index=None, joints_rad=np.zeros(10), target=0, status="not found", reason="gone") == 2

    f = store.frame(sid, 1)
    assert f.status == "measured" and f.reason == "ok" and f.target == 0
    np.testing.assert_array_equal(f.joints_rad, np.linspace(-0.5, 0.5, 10))
    assert f.detail == {"votes": 300, "fit_rms": 0.001, "center": [0.1, 0.2, 0.9]}
    assert set(f.images) == {"left", "right"}
    back = cv2.imread(str(tmp_path / f.images["left"]), cv2.IMREAD_UNCHANGED)
    assert back.shape == left.shape and np.abs(back.astype(int) - left).mean() < 3
    assert cv2.imread(str(tmp_path / f.images["right"]), cv2.IMREAD_UNCHANGED).shape == grey.shape
    info = store.session(sid)
    assert (info.frames, info.measured, info.source, info.description) == (2, 1, "capture", "d")
    assert [g.index for g in store.frames(sid)] == [1, 2]

    data = store.dataset(sid, load_profile("robonaut-a"))
    assert data.frame_ids.tolist() == [1] and data.measured.tolist() == [[1.5, 90.0, 5.0]]
    with pytest.raises(KeyError):
        store.frame(sid, 3)
    with pytest.raises(KeyError):
        store.session("s-nothere")
    with pytest.raises(InputError, match="robot 'robonaut-a', not 'nao'"):
        store.dataset(sid, load_profile("nao"))


def test_a_bad_frame_is_refused_and_writes_nothing(tmp_path: Path) -> None:
    store = Store(tmp_path)
    sid = store.create_session("robonaut-a", "bench", source="capture")
    before = _files(tmp_path)
    img = {"left": np.zeros((8, 8, 3), np.uint8)}
    bad = [
        ({"joints_rad": np.zeros(9), "status": "not found"}, "10 joint readings"),
        ({"joints_rad": np.zeros(10), "status": "measured"}, "exactly when its status"),
        ({"joints_rad": np.zeros(10), "status": "pending", "measured": np.ones((1, 3))}, "exactly when"),
        ({"joints_rad": np.zeros(10), "status": "measured", "measured": np.ones((1, 2))}, "rows of 3 numbers"),
        ({"joints_rad": np.zeros(10), "status": "wobbly"}, "unknown frame status"),
        ({"joints_rad": np.zeros(10), "status": "pending", "images": {"../x": img["left"]}}, "image role"),
        ({"joints_rad": np.zeros(10), "status": "pending", "images": {"left": np.zeros((8, 8))}}, "uint8"),
    ]
    for kwargs, message in bad:
        with pytest.raises(InputError, match=message):
            store.add_frame(sid, index=None, target=0, **kwargs)
    assert store.frames(sid) == [] and _files(tmp_path) == before
    with pytest.raises(KeyError):
        store.add_frame("s-nothere", index=None, joints_rad=np.zeros(10), target=0, status="pending")
    with pytest.raises(InputError, match="unknown robot"):
        store.create_session("r2d2", "x", source="capture")
    with pytest.raises(InputError, match="session id"):
        store.create_session("nao", "x", source="capture", session_id="../escape")


@pytest.mark.parametrize("name", SAMPLE_NAMES)
def test_a_sample_session_gives_the_dataset_of_its_csv(sample_store: Store, samples: Path, name: str) -> None:
    meta = json.loads((samples / name / "session.json").read_text())
    profile = load_profile(meta["robot"])
    info = sample_store.session(name)
    assert (info.robot, info.name, info.source) == (meta["robot"], meta["name"], "sample")
    assert info.truth == json.loads((samples / name / "truth.json").read_text())
    assert info.frames == len(meta["frames"])
    assert info.measured == sum(f["status"] == "measured" for f in meta["frames"])

    got = sample_store.dataset(name, profile)
    want = read_dataset(profile, samples / name / "data.csv")
    for key in ("frame_ids", "cfg", "target", "vertex"):
        np.testing.assert_array_equal(getattr(got, key), getattr(want, key), err_msg=key)
    for key in ("joints", "measured", "point"):
        a, b = getattr(got, key), getattr(want, key)
        np.testing.assert_array_equal(np.isnan(a), np.isnan(b), err_msg=key)
        np.testing.assert_allclose(np.nan_to_num(a), np.nan_to_num(b), rtol=0, atol=1e-9, err_msg=key)
    # The store's dataset writes the same CSV, and its rows serve per-row predictions.
    assert to_csv(profile, got) == to_csv(profile, want)
    assert got.header == want.header and len(got.rows) == got.n_observations
    again = parse_dataset(profile, to_csv(profile, got))
    np.testing.assert_allclose(again.measured, want.measured, atol=1e-6)

    frames = sample_store.frames(name)
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
    assert store.ensure_samples(only) == ["robonaut-a-day1"]
    store.delete_session("robonaut-a-day1")
    assert not (tmp_path / "data" / "sessions" / "robonaut-a-day1").exists()
    assert Store(tmp_path / "data").ensure_samples(only) == []
    assert store.sessions() == []


def test_a_broken_sample_is_skipped_and_leaves_nothing(tmp_path: Path, samples: Path) -> None:
    only = tmp_path / "samples"
    shutil.copytree(samples / "robonaut-a-day1", only / "broken")
    (only / "broken" / "images" / "0003_left.jpg").unlink()
    store = Store(tmp_path / "data")
    assert store.ensure_samples(only) == []
    assert store.sessions() == [] and _files(tmp_path / "data" / "sessions") == set()
    assert list((tmp_path / "data" / "sessions").iterdir()) == []


def test_an_import_failing_inside_its_transaction_leaves_nothing(
    tmp_path: Path, samples: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    store = Store(tmp_path)

    def fail(*args: object) -> None:
        raise OSError("disk full")

    monkeypatch.setattr(Store, "_insert_observations", staticmethod(fail))
    with pytest.raises(OSError, match="disk full"):
        store.import_session_folder(samples / "robonaut-a-day1")
    with pytest.raises(OSError, match="disk full"):
        store.import_csv("nao", "x", (samples / "nao" / "data.csv").read_text(), "nao.csv")
    assert store.sessions() == [] and list((tmp_path / "sessions").iterdir()) == []


KILLED_WRITER = """
import sys, numpy as np
from pathlib import Path
from app.store import Store
store = Store(Path(sys.argv[1]))
csv_text = Path(sys.argv[2]).read_text()
sid = store.create_session("robonaut-a", "killed", source="capture")
print("ready", flush=True)
for i in range(100000):
    img = np.full((120, 160, 3), i % 256, np.uint8)
    store.add_frame(sid, index=None, joints_rad=np.zeros(10), target=0, status="measured",
                    measured=np.array([[float(i), 1.0, 2.0]]), images={"left": img, "right": img[:, :, 0]})
    if i % 5 == 0:
        store.add_frame(sid, index=1, joints_rad=np.zeros(10), target=0, status="not found", reason=str(i),
                        images={"left": img})
    if i % 10 == 0:
        store.import_csv("robonaut-a", f"csv {i}", csv_text, "day1.csv")
"""


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
    sessions = store.sessions()
    capture = next(s for s in sessions if s.source == "capture")
    assert capture.frames > 5  # it got somewhere before the kill
    for s in sessions:
        if s.source == "import":  # an import is all there or not there at all
            assert (s.frames, s.measured) == (n_csv, n_csv)
    frames = store.frames(capture.id)
    for f in frames:
        for rel in f.images.values():
            assert cv2.imread(str(tmp_path / rel)) is not None, rel
    measured = [f for f in frames if f.status == "measured"]
    data = store.dataset(capture.id, profile)
    assert data.frame_ids.tolist() == [f.index for f in measured]
    assert frames[0].status == "not found" and set(frames[0].images) == {"left"}


def test_import_csv_round_trips(tmp_path: Path, samples: Path) -> None:
    store = Store(tmp_path)
    profile = load_profile("nao")
    text = (samples / "nao" / "data.csv").read_text()
    sid = store.import_csv("nao", "uploaded", text, "nao.csv")
    info = store.session(sid)
    want = parse_dataset(profile, text)
    n = want.n_configurations
    assert (info.source, info.name, info.frames, info.measured) == ("import", "uploaded", n, n)
    got = store.dataset(sid, profile)
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
        store.import_csv("robonaut-a", "bad", text, "bad.csv")
    assert (err.value.file, err.value.line, err.value.column) == ("bad.csv", line, column)
    assert f"line {line}" in str(err.value) and f"column '{column}'" in str(err.value)
    assert store.sessions() == [] and _files(tmp_path) == before


def test_remeasure_replaces_a_frame_whole_or_not_at_all(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    store = Store(tmp_path)
    sid = store.create_session("robonaut-a", "bench", source="capture")
    dark, bright = np.full((16, 16), 20, np.uint8), np.full((16, 16), 230, np.uint8)
    _robonaut_frame(store, sid, 5, 1.0, left=dark)
    first = store.frame(sid, 5)
    assert first.images == {"left": f"sessions/{sid}/images/0005_left.jpg"}

    _robonaut_frame(store, sid, 5, 2.0, left=bright)
    second = store.frame(sid, 5)
    assert [f.index for f in store.frames(sid)] == [5]
    assert second.images["left"] != first.images["left"] and not (tmp_path / first.images["left"]).exists()
    assert cv2.imread(str(tmp_path / second.images["left"]), cv2.IMREAD_GRAYSCALE).mean() > 200
    assert store.dataset(sid, load_profile("robonaut-a")).measured.tolist() == [[2.0, 90.0, 5.0]]

    # A failure inside the transaction (after the new image was written) keeps the old frame whole.
    def fail(*args: object) -> None:
        raise OSError("disk full")

    monkeypatch.setattr(Store, "_insert_observations", staticmethod(fail))
    files = _files(tmp_path)
    with pytest.raises(OSError, match="disk full"):
        _robonaut_frame(store, sid, 5, 3.0, left=dark)
    monkeypatch.undo()
    assert _same_frame(store.frame(sid, 5), second)
    assert store.dataset(sid, load_profile("robonaut-a")).measured.tolist() == [[2.0, 90.0, 5.0]]
    assert _files(tmp_path) == files


def _same_frame(a: FrameInfo, b: FrameInfo) -> bool:
    return all(
        np.array_equal(x, y) if isinstance(x, np.ndarray) else x == y
        for x, y in zip(vars(a).values(), vars(b).values(), strict=True)
    )


def test_a_restart_sweeps_what_a_crash_left(tmp_path: Path) -> None:
    store = Store(tmp_path)
    sid = store.create_session("robonaut-a", "bench", source="capture")
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
    assert [f.index for f in again.frames(sid)] == [1]


def _calibration(samples: Path, name: str, mode: str) -> Calibration:
    profile = load_profile("robonaut-a")
    return calibrate(profile, read_dataset(profile, samples / name / "data.csv"), mode)


def test_calibrations_and_the_apply_history(tmp_path: Path, samples: Path) -> None:
    store = Store(tmp_path)
    sid = store.import_session_folder(samples / "robonaut-a-day1")
    full = _calibration(samples, "robonaut-a-day1", "full")
    a = store.add_calibration(full, session_id=sid, base_id=None, holdout=0.0)
    b = store.add_calibration(full, session_id=sid, base_id=a, holdout=0.2)
    assert a.startswith("c-") and (tmp_path / "calibrations" / f"{a}.json").is_file()
    assert store.calibration(a).values() == full.values()
    info = store.calibration_info(b)
    assert (info.session_id, info.base_id, info.holdout, info.mode, info.robot) == (sid, a, 0.2, "full", "robonaut-a")
    assert info.figures["after"]["rms"] == pytest.approx(full.figures["after"].rms)
    assert [c.id for c in store.calibrations(session_id=sid)] == [b, a]
    assert store.calibrations(robot="nao") == []

    assert store.active("robonaut-a") is None
    assert store.apply("robonaut-a", a, "first") == (a, None)
    assert store.apply("robonaut-a", b) == (b, a)
    assert store.apply("robonaut-a", a, "rollback") == (a, b)
    assert store.active("robonaut-a") == a and store.active("nao") is None
    history = store.history("robonaut-a")
    assert [(h["calibration"], h["previous"], h["note"]) for h in history] == [
        (a, b, "rollback"),
        (b, a, ""),
        (a, None, "first"),
    ]
    assert history[0]["seq"] > history[1]["seq"] and history[0]["session"] == sid and history[0]["mode"] == "full"
    assert history[0]["figures"]["after"]["rms"] == pytest.approx(full.figures["after"].rms)

    with pytest.raises(InputError, match="is for robot 'robonaut-a', not 'nao'"):
        store.apply("nao", a)
    with pytest.raises(KeyError):
        store.apply("robonaut-a", "c-nothere")
    with pytest.raises(KeyError):
        store.add_calibration(full, session_id="s-nothere", base_id=None, holdout=0.0)
    assert len(list((tmp_path / "calibrations").iterdir())) == 2  # the refused one left no file
    assert store.active("robonaut-a") == a and len(store.history("robonaut-a")) == 3

    # The history survives a restart, and a deleted session leaves its calibrations (without a session).
    store.delete_session(sid)
    again = Store(tmp_path)
    assert again.active("robonaut-a") == a and again.calibration_info(a).session_id is None
    assert not (tmp_path / "sessions" / sid).exists()


def test_concurrent_writers_and_readers(tmp_path: Path) -> None:
    store = Store(tmp_path)
    sid = store.create_session("robonaut-a", "bench", source="capture")
    errors: list[BaseException] = []
    n_threads, per_thread = 8, 15

    def write(k: int) -> None:
        try:
            for i in range(per_thread):
                img = np.full((8, 8), k * 10 + i, np.uint8) if i % 3 == 0 else None
                _robonaut_frame(store, sid, None, float(k * 100 + i), **({"left": img} if img is not None else {}))
                if i % 5 == 0:
                    store.create_session("nao", f"t{k}-{i}", source="capture")
        except BaseException as exc:
            errors.append(exc)

    def read() -> None:
        try:
            for _ in range(30):
                store.sessions()
                store.dataset(sid, load_profile("robonaut-a"))
        except BaseException as exc:
            errors.append(exc)

    threads = [threading.Thread(target=write, args=(k,)) for k in range(n_threads)]
    threads += [threading.Thread(target=read) for _ in range(2)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert errors == []
    frames = store.frames(sid)
    assert [f.index for f in frames] == list(range(1, n_threads * per_thread + 1))
    xs = sorted(store.dataset(sid, load_profile("robonaut-a")).measured[:, 0])
    assert xs == sorted(float(k * 100 + i) for k in range(n_threads) for i in range(per_thread))
    assert sum(len(f.images) for f in frames) == n_threads * 5
    assert len(store.sessions()) == 1 + n_threads * 3


def test_jobs_persist_and_a_restart_fails_the_interrupted(tmp_path: Path) -> None:
    store = Store(tmp_path)
    base = {"progress": 0.5, "result": None, "error": None, "session": None, "detail": {}, "cost": [1.0]}
    for i, state in enumerate(["done", "running", "queued", "cancelled"]):
        t = f"2026-01-01T00:00:0{i}.000+00:00"
        store.save_job({**base, "id": f"j-{i}", "kind": "replay", "state": state, "created": t, "updated": t})
    store.save_job({**base, "id": "j-0", "kind": "replay", "state": "done", "created": "x", "updated": "y"})
    again = Store(tmp_path)
    assert again.fail_interrupted_jobs() == 2
    jobs = {j["id"]: j for j in again.jobs()}
    assert [j["id"] for j in again.jobs()][:3] == ["j-3", "j-2", "j-1"]
    assert {k: (j["state"], j["error"]) for k, j in jobs.items()} == {
        "j-0": ("done", None),
        "j-1": ("failed", INTERRUPTED),
        "j-2": ("failed", INTERRUPTED),
        "j-3": ("cancelled", None),
    }
    assert again.fail_interrupted_jobs() == 0
    assert again.job("j-1")["cost"] == [1.0]
