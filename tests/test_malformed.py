"""Malformed input of every kind, property-based: a clear error naming the problem, never a traceback,
never a partial session.

Each input meets the surface a user hands it to: CSVs the dashboard's import endpoint (HTTP 422 with
the line), images and depth maps `calib detect-board` / `calib detect-sphere` (exit 2 with the file),
robot profiles `load_profile`, calibration files `Calibration.load`, session folders `read_session`
and `app.store.importers.import_session_folder` (InputError naming session.json). The CSV parser itself is fuzzed
in test_dataset.py; here the same mutations travel through HTTP and the store.
"""

from __future__ import annotations

import copy
import json
import math
import re
import shutil
from pathlib import Path

import cv2
import numpy as np
import pytest
import yaml
from fastapi.testclient import TestClient
from hypothesis import HealthCheck, example, given, settings
from hypothesis import strategies as st
from test_dataset import mutate, mutation, small_csv

from app.cli import main as calib
from app.store import Store
from app.store.importers import import_session_folder
from calib_core import Calibration, InputError, calibrate, load_profile, read_dataset
from calib_core.io.session import read_session
from calib_core.model.loader import BUILTIN_PROFILES

ROOT = Path(__file__).resolve().parent.parent
SAMPLES = ROOT / "sample_sessions"
PROFILE_YAML = ROOT / "calib_core" / "model" / "profiles" / "robonaut-a.yaml"
FUZZ = settings(max_examples=40, deadline=None, suppress_health_check=list(HealthCheck))


def files(root: Path) -> set[str]:
    return {str(p.relative_to(root)) for p in root.rglob("*") if p.is_file() and p.name != "store.sqlite-shm"}


# --- tree mutations shared by the YAML and JSON documents ---------------------------------------------

BAD_VALUES = st.sampled_from(
    [None, "", "x", "nan", float("nan"), float("inf"), -1e308, 0, -1, 2**70, True, [], [1, 2], {}, {"a": 1}]
)
tree_edit = st.tuples(st.sampled_from(["delete", "replace", "nan"]), st.integers(0, 1 << 16), BAD_VALUES)


def _paths(node, prefix=()) -> list[tuple]:
    out = [prefix]
    if isinstance(node, dict):
        for k, v in node.items():
            out += _paths(v, (*prefix, k))
    elif isinstance(node, list):
        for i, v in enumerate(node):
            out += _paths(v, (*prefix, i))
    return out


def edit_tree(doc, edits: list[tuple[str, int, object]]):
    """Deleted keys, wrong types, NaN: each edit at a path picked among the document's current paths."""
    doc = copy.deepcopy(doc)
    for kind, pick, value in edits:
        paths = [p for p in _paths(doc) if p]
        if not paths:
            break
        path = paths[pick % len(paths)]
        parent = doc
        for key in path[:-1]:
            parent = parent[key]
        if kind == "delete":
            del parent[path[-1]]
        else:
            # a copy: a list or dict among the values is one object for every example, never to be edited in place
            parent[path[-1]] = float("nan") if kind == "nan" else copy.deepcopy(value)
    return doc


# --- CSVs through the import endpoint -----------------------------------------------------------------


@pytest.fixture(scope="module")
def desk_options() -> dict:
    return {"sample_dir": None}


@pytest.mark.slow
@pytest.mark.parametrize("robot", BUILTIN_PROFILES)
@FUZZ
@given(ops=st.lists(mutation, min_size=1, max_size=5))
@example(ops=[(False, "truncate", 0, 0, "")])
@example(ops=[(True, "replace_field", 2, 0, "1e400")])
def test_a_mutated_csv_imports_whole_or_answers_422_naming_the_line(client: TestClient, robot: str, ops) -> None:
    text = mutate(small_csv(robot), ops)
    data_dir = client.app.state.desk.data_dir
    before_sessions, before_files = client.get("/api/sessions").json(), files(data_dir)
    r = client.post(
        "/api/sessions/import",
        data={"robot": robot, "name": "fuzz"},
        files={"data": ("fuzz.csv", text.encode("utf-8", "surrogatepass"), "text/csv")},
    )
    assert r.status_code in (201, 422), r.text
    if r.status_code == 422:
        detail = r.json()["detail"]
        assert detail.startswith("fuzz.csv") and "Traceback" not in detail, detail
        assert client.get("/api/sessions").json() == before_sessions
        assert files(data_dir) == before_files
    else:
        sid = r.json()["id"]
        frames = client.get(f"/api/sessions/{sid}").json()["frames"]
        assert frames and all(f["status"] == "measured" for f in frames)
        assert client.delete(f"/api/sessions/{sid}").status_code == 200


@pytest.mark.slow
@FUZZ
@given(raw=st.binary(max_size=64))
@example(raw=b"\xff\xfe\x00\x00")
@example(raw=b"frame,x\n\xc3\x28\n")
def test_csv_bytes_that_are_not_utf8_text_answer_422(client: TestClient, raw: bytes) -> None:
    r = client.post(
        "/api/sessions/import",
        data={"robot": "robonaut-a", "name": "fuzz"},
        files={"data": ("bytes.csv", raw, "text/csv")},
    )
    assert r.status_code == 422, r.text
    assert r.json()["detail"].startswith("bytes.csv")


# --- images and depth maps through the CLI --------------------------------------------------------------


def run_cli(capsys: pytest.CaptureFixture, *argv: str) -> tuple[int, str, str]:
    """`calib ...` in-process (the same main() the console script runs): exit code, stdout, stderr."""
    code = calib(list(argv))
    out, err = capsys.readouterr()
    assert "Traceback" not in err and "internal error" not in err, err
    if code == 2:
        assert len(err.strip().splitlines()) == 1, err
    else:  # what still reads as input is answered in JSON (found or not)
        assert code == 0, err
        assert isinstance(json.loads(out)["found"], bool), out
    return code, out, err


def _board_png() -> bytes:
    image = np.full((120, 160), 255, np.uint8)
    for r in range(5):
        for c in range(7):
            if (r + c) % 2:
                image[10 + r * 20 : 30 + r * 20, 10 + c * 20 : 30 + c * 20] = 0
    return cv2.imencode(".png", image)[1].tobytes()


BOARD_PNG = _board_png()
BOARD_JPEG = cv2.imencode(".jpg", cv2.imdecode(np.frombuffer(BOARD_PNG, np.uint8), cv2.IMREAD_GRAYSCALE))[1].tobytes()

image_bytes = st.one_of(
    st.builds(lambda n: BOARD_PNG[:n], st.integers(0, len(BOARD_PNG))),
    st.builds(lambda n: BOARD_JPEG[:n], st.integers(0, len(BOARD_JPEG))),
    st.builds(lambda i, b: BOARD_JPEG[:i] + b + BOARD_JPEG[i + len(b) :], st.integers(0, len(BOARD_JPEG)), st.binary()),
    st.binary(max_size=256),
)


@pytest.mark.slow
@FUZZ
@given(raw=image_bytes, suffix=st.sampled_from([".png", ".jpg", ".bmp", ""]))
@example(raw=b"", suffix=".png")
@example(raw=BOARD_PNG[:40], suffix=".png")
def test_detect_board_on_a_damaged_image_exits_2_naming_it(
    tmp_path_factory: pytest.TempPathFactory, capsys: pytest.CaptureFixture, raw: bytes, suffix: str
) -> None:
    path = tmp_path_factory.mktemp("img") / f"damaged{suffix}"
    path.write_bytes(raw)
    code, _, err = run_cli(capsys, "detect-board", "--image", str(path), "--cols", "6", "--rows", "4", "--json")
    if code == 2:
        assert err.startswith(f"calib detect-board: error: {path}"), err


def _png_header_only(width: int, height: int) -> bytes:
    """A PNG's signature and header (grey, 8 bits) with no image data: what a damaged file may claim."""
    import struct
    import zlib

    def chunk(kind: bytes, data: bytes) -> bytes:
        return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data))

    return (
        b"\x89PNG\r\n\x1a\n"
        + chunk(b"IHDR", struct.pack(">IIBBBBB", width, height, 8, 0, 0, 0, 0))
        + chunk(b"IEND", b"")
    )


def test_an_image_claiming_more_pixels_than_opencv_reads_is_refused_naming_it(tmp_path, capsys) -> None:
    """OpenCV raises (not returns None) on a header of 100,000 x 100,000 px: `calib detect-board` says the file
    is no image it can read, and a bag's compressed image of those bytes is one that does not decode."""
    from calib_core.io.camera_images import grey_compressed

    raw = _png_header_only(100_000, 100_000)
    path = tmp_path / "huge.png"
    path.write_bytes(raw)
    code, _, err = run_cli(capsys, "detect-board", "--image", str(path), "--cols", "6", "--rows", "4")
    assert code == 2 and err.startswith(f"calib detect-board: error: {path}: is not an image OpenCV can read"), err
    assert grey_compressed(np.frombuffer(raw, np.uint8)) is None


def test_a_damaged_jpeg_claiming_8000_x_6000_px_is_refused_not_searched(tmp_path, capsys) -> None:
    """The board's JPEG with its frame header saying 8000 x 6000 px: OpenCV decodes it (the rest grey) and its
    board detectors searched the 48 MP for 19 s (this suite's fuzz test found such a file); now a sentence naming
    the file and its size, exit 2. The library's detector says the same as "not found"."""
    import struct

    from calib_core.vision import detect_board

    raw = bytearray(BOARD_JPEG)
    sof = raw.find(b"\xff\xc0")
    raw[sof + 5 : sof + 9] = struct.pack(">HH", 6000, 8000)  # height, width
    path = tmp_path / "damaged.jpg"
    path.write_bytes(bytes(raw))
    code, _, err = run_cli(capsys, "detect-board", "--image", str(path), "--cols", "6", "--rows", "4")
    assert code == 2 and err.strip() == (
        f"calib detect-board: error: {path}: an image of 8000 x 6000 px (48 MP) is more than the board detector "
        "searches (25 MP): a damaged file, or a camera's image to scale down"
    ), err
    found = detect_board(np.zeros((6000, 8000), np.uint8), 6, 4)
    assert not found.found and found.detail.startswith("an image of 8000 x 6000 px (48 MP) is more than")


def _npy(array: np.ndarray) -> bytes:
    import io

    out = io.BytesIO()
    np.save(out, array, allow_pickle=False)
    return out.getvalue()


GOOD_DEPTH = np.full((24, 32), 0.8, np.float32)

depth_bytes = st.one_of(
    st.builds(
        lambda dtype, shape: _npy(np.zeros(shape, dtype)),
        st.sampled_from([np.int16, np.uint8, np.bool_, np.complex64, np.float16, np.float64, np.int64]),
        st.sampled_from([(24, 32), (5,), (2, 3, 4), (0, 0), (1, 1), ()]),
    ),
    st.builds(
        lambda fill: _npy(np.full((24, 32), fill, np.float32)), st.sampled_from([np.nan, np.inf, -1.0, 0.0, 1e30])
    ),
    st.builds(lambda n: _npy(GOOD_DEPTH)[:n], st.integers(0, len(_npy(GOOD_DEPTH)))),
    st.binary(max_size=200),
    st.just(_npy(np.zeros(3, dtype=[("a", "f4"), ("b", "i4")]))),
)


@pytest.mark.slow
@FUZZ
@given(raw=depth_bytes)
@example(raw=_npy(np.full((24, 32), np.nan, np.float32)))
@example(raw=_npy(np.zeros((24, 32), np.int32)))
@example(raw=b"")  # found: an empty file ended in EOFError, an internal error (exit 1)
@example(raw=_npy(GOOD_DEPTH)[:200])  # found: a cut-off array, the same
@example(raw=_npy(np.zeros((0, 0), np.float32)))  # found: an empty map failed inside OpenCV (exit 1)
@example(raw=_npy(np.zeros((0, 32), np.float32)))
def test_detect_sphere_on_a_damaged_depth_map_exits_2_naming_it(
    tmp_path_factory: pytest.TempPathFactory, capsys: pytest.CaptureFixture, raw: bytes
) -> None:
    path = tmp_path_factory.mktemp("depth") / "depth.npy"
    path.write_bytes(raw)
    args = ["--fx", "40", "--fy", "40", "--cx", "16", "--cy", "12", "--radius", "0.05", "--json"]
    code, _, err = run_cli(capsys, "detect-sphere", "--depth", str(path), *args)
    if code == 2:
        assert err.startswith(f"calib detect-sphere: error: {path}"), err


# --- robot profiles ------------------------------------------------------------------------------------

PROFILE_DOC = yaml.safe_load(PROFILE_YAML.read_text(encoding="utf-8"))


@pytest.mark.slow
@settings(max_examples=60, deadline=None, suppress_health_check=list(HealthCheck))
@given(edits=st.lists(tree_edit, min_size=1, max_size=4))
def test_a_mutated_profile_loads_or_raises_input_error_naming_the_file(tmp_path_factory, edits) -> None:
    path = tmp_path_factory.mktemp("profile") / "robot.yaml"
    path.write_text(yaml.safe_dump(edit_tree(PROFILE_DOC, edits)), encoding="utf-8")
    try:
        profile = load_profile(path)
    except InputError as exc:
        assert exc.file == str(path) and exc.message, exc
        return
    assert len(profile.joint_names) >= 1 and np.all(np.isfinite(profile.nominal()))


# --- calibration files -----------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def calibration_doc() -> dict:
    profile = load_profile("robonaut-a")
    cal = calibrate(profile, read_dataset(profile, SAMPLES / "robonaut-a-day1" / "data.csv"), "daily")
    return cal.to_dict()


@pytest.mark.slow
@settings(max_examples=60, deadline=None, suppress_health_check=list(HealthCheck))
@given(edits=st.lists(tree_edit, min_size=1, max_size=4), as_text=st.sampled_from(["json", "truncated"]))
def test_a_mutated_calibration_file_loads_or_raises_input_error(
    tmp_path_factory, calibration_doc: dict, edits, as_text: str
) -> None:
    text = json.dumps(edit_tree(calibration_doc, edits))
    if as_text == "truncated":
        text = text[: len(text) * 2 // 3]
    path = tmp_path_factory.mktemp("cal") / "cal.json"
    path.write_text(text, encoding="utf-8")
    try:
        cal = Calibration.load(path)
    except InputError as exc:
        assert exc.file == str(path) and exc.message, exc
        return
    try:  # a file that reads may still not fit the robot: named parameter or robot, never a TypeError
        params = cal.params(load_profile("robonaut-a"))
    except InputError as exc:
        assert re.search(r"unknown parameter|is for robot", str(exc)), exc
        return
    assert np.all(np.isfinite(params))


# --- session folders ---------------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def small_session(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The NAO sample cut to its first four frames: small enough to copy for every example."""
    src = SAMPLES / "nao"
    folder = tmp_path_factory.mktemp("session") / "nao-small"
    (folder / "images").mkdir(parents=True)
    meta = json.loads((src / "session.json").read_text(encoding="utf-8"))
    meta["frames"] = meta["frames"][:4]
    keep = {f["frame"] for f in meta["frames"]}
    for f in meta["frames"]:
        for rel in f["images"].values():
            shutil.copy(src / rel, folder / rel)
    lines = (src / "data.csv").read_text(encoding="utf-8").splitlines()
    frame_col = lines[0].split(",").index("frame")
    rows = [ln for ln in lines[1:] if int(ln.split(",")[frame_col]) in keep]
    (folder / "data.csv").write_text("\n".join([lines[0], *rows]) + "\n", encoding="utf-8")
    if meta.get("truth"):
        shutil.copy(src / meta["truth"], folder / meta["truth"])
    (folder / "session.json").write_text(json.dumps(meta), encoding="utf-8")
    read_session(folder)  # the cut is itself a valid session
    return folder


SESSION_VALUES = st.one_of(
    BAD_VALUES,
    st.sampled_from(["../../session.json", "/etc/passwd", "images/../data.csv", "measured", "not found", "nao"]),
)
session_edit = st.tuples(st.sampled_from(["delete", "replace", "nan"]), st.integers(0, 1 << 16), SESSION_VALUES)


@pytest.mark.slow
@settings(max_examples=50, deadline=None, suppress_health_check=list(HealthCheck))
@given(edits=st.lists(session_edit, min_size=1, max_size=3))
def test_a_mutated_session_folder_imports_whole_or_leaves_nothing(
    tmp_path_factory, small_session: Path, store: Store, edits
) -> None:
    folder = tmp_path_factory.mktemp("mutated") / "session"
    shutil.copytree(small_session, folder)
    meta = json.loads((folder / "session.json").read_text(encoding="utf-8"))
    (folder / "session.json").write_text(json.dumps(edit_tree(meta, edits)), encoding="utf-8")
    before_sessions, before_files = store.sessions.list(), files(store.data_dir)
    try:
        sid = import_session_folder(store, folder)
    except InputError as exc:
        assert "session" in str(exc) or str(folder) in str(exc), exc
        assert store.sessions.list() == before_sessions
        assert files(store.data_dir) == before_files, "a failed import left files behind"
        return
    frames = store.sessions.frames(sid)
    assert frames and all(np.all(np.isfinite(f.joints_rad)) for f in frames)
    assert all(math.isfinite(v) for v in frames[0].joints_rad)
    store.sessions.delete(sid)


# --- what the fuzzing found, pinned --------------------------------------------------------------------


def test_a_calibration_parameter_name_must_be_text(tmp_path: Path, calibration_doc: dict) -> None:
    """Found: a list as a parameter's name loaded, then failed in params() with TypeError."""
    doc = copy.deepcopy(calibration_doc)
    doc["parameters"][3]["name"] = [1, 2]
    (tmp_path / "cal.json").write_text(json.dumps(doc), encoding="utf-8")
    with pytest.raises(InputError, match=r"parameters\[3\]\.name: expected a string") as exc:
        Calibration.load(tmp_path / "cal.json")
    assert exc.value.file == str(tmp_path / "cal.json")


SESSION_REGRESSIONS = {
    # found: each of these ended in a TypeError, ValueError, AttributeError or sqlite3.IntegrityError
    "nan-joint": (lambda m: m["frames"][1]["joints_deg"].update(HeadYaw=float("nan")), r"frames\[1\]\.joints_deg"),
    "empty-joint": (lambda m: m["frames"][0]["joints_deg"].update(HeadYaw=""), r"frames\[0\]\.joints_deg"),
    "null-joints": (lambda m: m["frames"][2].update(joints_deg=None), r"frames\[2\]\.joints_deg"),
    "null-images": (lambda m: m["frames"][0].update(images=None), r"frames\[0\]\.images"),
    "null-reason": (lambda m: m["frames"][3].update(reason=None), r"frames\[3\]\.reason"),
    "null-data": (lambda m: m.update(data=None), r"data: expected a file name"),
    # found: the robot field was read as a profile path (any file on the machine)
    "robot-path": (lambda m: m.update(robot="/etc/passwd"), r"robot: unknown robot '/etc/passwd'"),
}


@pytest.mark.parametrize("case", SESSION_REGRESSIONS, ids=list(SESSION_REGRESSIONS))
def test_session_json_regressions(tmp_path: Path, small_session: Path, store: Store, case: str) -> None:
    edit, message = SESSION_REGRESSIONS[case]
    folder = tmp_path / "session"
    shutil.copytree(small_session, folder)
    meta = json.loads((folder / "session.json").read_text(encoding="utf-8"))
    edit(meta)
    (folder / "session.json").write_text(json.dumps(meta), encoding="utf-8")
    with pytest.raises(InputError, match=message) as exc:
        read_session(folder)
    assert exc.value.file == str(folder / "session.json")
    before_sessions, before_files = store.sessions.list(), files(store.data_dir)
    with pytest.raises(InputError, match=message):
        import_session_folder(store, folder)
    assert store.sessions.list() == before_sessions and files(store.data_dir) == before_files
