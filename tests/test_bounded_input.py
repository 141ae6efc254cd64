"""Input that would make the desk hang or run out of memory is refused with a sentence, and changes nothing.

YAML documents are bounded in size, nesting and what their aliases expand to (a 2.7 kB alias bomb uploaded as a
profile ran past 120 s at 19.5 GB and was stored; a 50,000-deep document answered 500); a file named on the
server is read only when it is a regular file of a bounded size (a FIFO hung the request and, seven of them,
the next import; /dev/zero read until memory ran out); open job-event streams hold no thread while they wait,
so they cannot starve the requests that need one.
"""

from __future__ import annotations

import os
import sys
import threading
from collections.abc import Iterator
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import pytest
from fastapi.testclient import TestClient

from app.cli import main as calib
from app.jobs.runner import JobContext
from calib_core import InputError, load_profile
from calib_core.safe_yaml import MAX_DEPTH, MAX_NODES, load_yaml

SAMPLES = Path(__file__).resolve().parent.parent / "sample_sessions"


def alias_bomb(levels: int = 9, width: int = 9) -> str:
    """Nine levels of nine aliases each: 2.7 kB of YAML for 9**9 (387 million) strings once expanded."""
    lines = ["a0: &a0 [" + ", ".join(["lol"] * width) + "]"]
    lines += [f"a{k}: &a{k} [" + ", ".join([f"*a{k - 1}"] * width) + "]" for k in range(1, levels + 1)]
    return "\n".join([*lines, f"name: *a{levels}", "profile: 1"]) + "\n"


def deep(levels: int = 50_000) -> str:
    return "name: " + "[" * levels + "]" * levels + "\n"


def test_a_yaml_document_beyond_its_bounds_is_refused_before_it_is_built() -> None:
    with pytest.raises(InputError) as err:
        load_yaml(alias_bomb(), "bomb.yaml")
    assert str(err.value).startswith("bomb.yaml, line ")
    assert f"expands to more than {MAX_NODES:,} nodes (aliases of aliases)" in str(err.value)
    for text in (deep(), "k:\n" + "".join(" " * (i + 1) + f"k{i}:\n" for i in range(MAX_DEPTH + 1))):
        with pytest.raises(InputError, match=r"deep\.yaml, line \d+: .*(nest|depth)"):
            load_yaml(text, "deep.yaml")
    # Anchors, aliases and merge keys within the bounds read as PyYAML reads them.
    doc = load_yaml("base: &b {lower: -90, upper: 90}\nelbow: *b\nwrist: {<<: *b, upper: 45}\n", "ok.yaml")
    assert doc == {
        "base": {"lower": -90, "upper": 90},
        "elbow": {"lower": -90, "upper": 90},
        "wrist": {"lower": -90, "upper": 45},
    }


def _stored(client: TestClient) -> tuple:
    data_dir = client.app.state.desk.store.data_dir
    kept = sorted(p.name for p in (data_dir / "robots").iterdir()) if (data_dir / "robots").is_dir() else []
    return [r["name"] for r in client.get("/api/robots").json()], kept


def test_an_uploaded_alias_bomb_or_deep_profile_answers_422_and_stores_nothing(client: TestClient) -> None:
    before = _stored(client)
    for text, words in ((alias_bomb(), "expands to more than"), (deep(), "nest")):
        r = client.post("/api/robots", data={"name": "bomb"}, files={"profile_file": ("bomb.yaml", text.encode())})
        assert r.status_code == 422, r.text
        assert r.json()["detail"].startswith("bomb.yaml, line ") and words in r.json()["detail"], r.json()
        assert _stored(client) == before


@pytest.mark.skipif(not hasattr(os, "mkfifo") or not Path("/dev/zero").exists(), reason="POSIX special files")
def test_a_profile_named_on_the_server_must_be_a_regular_file_of_bounded_size(
    client: TestClient, tmp_path: Path
) -> None:
    """A FIFO (which blocks whoever opens it to read) and /dev/zero (which never ends) are refused at once; a
    directory and a file too large too. The requests run in threads with a deadline: before the check, the FIFO
    never answered."""
    fifo = tmp_path / "arm.yaml"
    os.mkfifo(fifo)
    (tmp_path / "big.yaml").write_bytes(b"#" * (2 * 1024 * 1024))
    before = _stored(client)
    cases = {
        str(fifo): "is not a regular file",
        "/dev/zero": "is not a regular file",
        str(tmp_path): "is a directory",
        str(tmp_path / "big.yaml"): "is larger than 1.0 MB",
    }
    with ThreadPoolExecutor(len(cases)) as pool:
        answers = {p: pool.submit(client.post, "/api/robots", data={"name": "named", "profile": p}) for p in cases}
        for path, words in cases.items():
            r = answers[path].result(timeout=60)
            assert r.status_code == 422, r.text
            assert words in r.json()["detail"] and "robot profile file" in r.json()["detail"], r.json()
    assert _stored(client) == before
    # The command line reads profiles, desk files and data through the same checks: exit 2, a sentence.
    assert calib(["serve", "--desk", str(fifo)]) == 2
    with pytest.raises(InputError, match="not a regular file"):
        load_profile(fifo)


def test_a_desk_file_that_is_an_alias_bomb_exits_2(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    (tmp_path / "desk.yaml").write_text(alias_bomb())
    assert calib(["serve", "--desk", str(tmp_path / "desk.yaml")]) == 2
    assert "expands to more than" in capsys.readouterr().err


def _waiting_in_wait_version() -> int:
    """Threads parked in JobRunner.wait_version (where a stream used to wait for its job's next change)."""
    return sum(
        1 for frame in sys._current_frames().values() if any(f.f_code.co_name == "wait_version" for f in _stack(frame))
    )


def _stack(frame) -> Iterator:
    while frame is not None:
        yield frame
        frame = frame.f_back


def test_open_job_event_streams_hold_no_thread_and_an_import_answers(client: TestClient) -> None:
    """20 pages following a running job: their streams wait on the event loop, not in the small pool of threads
    that imports and uploads run in (before: each held one of its six threads for a second at a time, and a
    five-row import took 3 s)."""
    release = threading.Event()

    def held(ctx: JobContext) -> None:
        release.wait(60)

    job = client.app.state.desk.jobs.submit_thread("test", held, session_id=None)
    first_events = threading.Barrier(21)
    ended = []

    def follow() -> None:
        with client.stream("GET", f"/api/jobs/{job}/events") as r:
            lines = r.iter_lines()
            next(line for line in lines if line.startswith("data:"))
            first_events.wait(60)
            ended.append([line for line in lines if line.startswith("data:")][-1])

    with ThreadPoolExecutor(20) as pool:
        streams = [pool.submit(follow) for _ in range(20)]
        first_events.wait(60)  # every stream has its first snapshot and waits for the next change
        try:
            assert _waiting_in_wait_version() == 0
            csv = (SAMPLES / "robonaut-a-day1" / "data.csv").read_text().splitlines()[:6]
            r = client.post(
                "/api/sessions/import",
                data={"robot": "robonaut-a", "name": "five rows"},
                files={"data": ("five.csv", ("\n".join(csv) + "\n").encode())},
            )
            assert r.status_code == 201, r.text
        finally:
            release.set()
        for s in streams:
            s.result(timeout=60)
    assert len(ended) == 20 and all('"state":"done"' in line for line in ended)
