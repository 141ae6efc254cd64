"""The `calib` command as a user runs it (specs/cli.md): a real subprocess, real files, exit status,
stdout and stderr.

Happy paths: simulate -> solve full -> simulate day 2 -> solve daily -> predict (Robonaut), and
simulate -> solve -> predict (NAO). Error paths: every kind of bad input of the spec's "Errors"
section must end with exit status 2 and one or two lines on stderr naming the problem and where,
never a traceback, and a failed solve must not create or overwrite its --out file.

The error cases run concurrently (one module-scoped pool) because each start of the command costs
about a second of imports.
"""

from __future__ import annotations

import csv
import json
import math
import os
import re
import socket
import subprocess
import sys
from collections.abc import Iterator
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import dataclass
from pathlib import Path

import pytest
import yaml

from calib_core import load_profile

ROOT = Path(__file__).resolve().parents[1]
CALIB = Path(sys.executable).with_name("calib")
TIMEOUT = 180
pytestmark = pytest.mark.subprocess


def _command() -> list[str]:
    return [str(CALIB)] if CALIB.exists() else [sys.executable, "-m", "app.cli"]


def _env() -> dict[str, str]:
    env = {k: v for k, v in os.environ.items() if k != "CALIB_DEBUG"}
    if not CALIB.exists():  # `python -m app.cli` from another folder needs the project on the path
        env["PYTHONPATH"] = os.pathsep.join(p for p in (str(ROOT), env.get("PYTHONPATH", "")) if p)
    env["COLUMNS"] = "100"
    return env


def calib(*args: str, cwd: Path) -> subprocess.CompletedProcess[str]:
    """Run `calib ARGS...` in `cwd`, as a user would, and capture everything."""
    return subprocess.run(
        [*_command(), *args], cwd=cwd, capture_output=True, text=True, timeout=TIMEOUT, env=_env(), check=False
    )


def ok(proc: subprocess.CompletedProcess[str]) -> subprocess.CompletedProcess[str]:
    assert proc.returncode == 0, f"exit {proc.returncode}\nstdout:\n{proc.stdout}\nstderr:\n{proc.stderr}"
    assert "Traceback" not in proc.stderr, proc.stderr
    return proc


def read_rows(path: Path) -> tuple[list[str], list[dict[str, str]]]:
    with open(path, newline="", encoding="utf-8") as fh:
        reader = csv.DictReader(fh)
        rows = list(reader)
        return list(reader.fieldnames or []), rows


def _columns(text: str) -> list[str]:
    return text.split(",")


ROBONAUT_COLUMNS = _columns(
    "frame,shoulder_roll,shoulder_pitch,elbow_roll,elbow_pitch,wrist_roll,wrist_pitch,wrist_yaw,"
    "neck_yaw,neck_pitch,neck_roll,x,y,z"
)
NAO_COLUMNS = _columns(
    "frame,chain,vertex,u,v,bx,by,bz,HeadYaw,HeadPitch,LHipYawPitch,LHipRoll,LHipPitch,LKneePitch,"
    "LAnklePitch,LAnkleRoll,RHipYawPitch,RHipRoll,RHipPitch,RKneePitch,RAnklePitch,RAnkleRoll"
)


# --- happy paths: Robonaut ----------------------------------------------------------------------


def _robonaut_workflow(d: Path) -> dict:
    """The paper's workflow on the simulated Robonaut, each step a command run in one folder."""
    runs = {}
    runs["sim1"] = calib("simulate", "--robot", "robonaut-a", "--configurations", "67", "--out", "day1.csv", cwd=d)
    runs["full"] = calib(
        "solve", "--robot", "robonaut-a", "--mode", "full", "--data", "day1.csv", "--out", "full.json", cwd=d
    )
    runs["sim2"] = calib(
        "simulate", "--robot", "robonaut-a", "--day", "2", "--configurations", "150", "--out", "day2.csv", cwd=d
    )
    runs["daily"] = calib(
        "solve",
        "--robot",
        "robonaut-a",
        "--mode",
        "daily",
        "--base",
        "full.json",
        "--data",
        "day2.csv",
        "--holdout",
        "0.5",
        "--out",
        "daily.json",
        cwd=d,
    )
    runs["predict"] = calib(
        "predict",
        "--robot",
        "robonaut-a",
        "--calibration",
        "full.json",
        "--data",
        "day1.csv",
        "--out",
        "pred.csv",
        cwd=d,
    )
    runs["nominal"] = calib(
        "predict", "--robot", "robonaut-a", "--data", "day1.csv", "--out", "pred_nominal.csv", cwd=d
    )
    return {"dir": d, **runs}


def _nao_workflow(d: Path) -> dict:
    runs = {}
    runs["sim"] = calib("simulate", "--robot", "nao", "--configurations", "24", "--out", "nao.csv", cwd=d)
    runs["full"] = calib("solve", "--robot", "nao", "--mode", "full", "--data", "nao.csv", "--out", "nao.json", cwd=d)
    runs["predict"] = calib(
        "predict", "--robot", "nao", "--calibration", "nao.json", "--data", "nao.csv", "--out", "pred.csv", cwd=d
    )
    return {"dir": d, **runs}


@pytest.fixture(scope="module")
def pool() -> Iterator[ThreadPoolExecutor]:
    """Commands run side by side: each start of `calib` spends about a second importing."""
    executor = ThreadPoolExecutor(max_workers=max(2, min(6, (os.cpu_count() or 2) + 1)))
    yield executor
    executor.shutdown(wait=True, cancel_futures=True)


@pytest.fixture(scope="module")
def workflows(tmp_path_factory: pytest.TempPathFactory, pool: ThreadPoolExecutor) -> dict[str, Future]:
    return {
        "robonaut": pool.submit(_robonaut_workflow, tmp_path_factory.mktemp("robonaut")),
        "nao": pool.submit(_nao_workflow, tmp_path_factory.mktemp("nao")),
    }


@pytest.fixture(scope="module")
def robonaut_runs(workflows: dict[str, Future], help_runs: dict) -> dict:
    return workflows["robonaut"].result()


@pytest.fixture(scope="module")
def nao_runs(workflows: dict[str, Future]) -> dict:
    return workflows["nao"].result()


def _mean_distance(rows: list[dict[str, str]], measured: list[str], predicted: list[str]) -> float:
    total = 0.0
    for r in rows:
        total += math.dist([float(r[c]) for c in measured], [float(r[c]) for c in predicted])
    return total / len(rows)


def test_simulate_writes_the_robonaut_csv_format(robonaut_runs: dict) -> None:
    proc = ok(robonaut_runs["sim1"])
    assert "day1.csv" in proc.stdout
    assert "note" not in proc.stderr and "see the notes" not in proc.stdout  # the profile has a simulation
    header, rows = read_rows(robonaut_runs["dir"] / "day1.csv")
    assert sorted(header) == sorted(ROBONAUT_COLUMNS)
    assert len(rows) == 67
    assert len({r["frame"] for r in rows}) == 67
    for r in rows:
        assert all(math.isfinite(float(r[c])) for c in ROBONAUT_COLUMNS)


def test_solve_full_prints_figures_and_writes_the_calibration(robonaut_runs: dict) -> None:
    proc = ok(robonaut_runs["full"])
    out = proc.stdout
    assert re.search(r"before.*\d", out), out
    assert re.search(r"after.*\d", out), out
    cal = json.loads((robonaut_runs["dir"] / "full.json").read_text(encoding="utf-8"))
    assert cal["robot"] == "robonaut-a"
    assert cal["mode"] == "full"

    profile = load_profile("robonaut-a")
    params = {p["name"]: p for p in cal["parameters"]}
    assert set(params) == set(profile.parameter_names)
    for name, p in params.items():
        assert {"value", "unit", "std"} <= set(p), name
        assert isinstance(p["value"], int | float) and math.isfinite(p["value"]), name
        assert p["unit"] in {"cm", "deg", "px", ""}, name
        if p.get("estimated"):
            assert p["std"] is not None and math.isfinite(p["std"]) and p["std"] >= 0, name
    assert params["shoulder_roll.theta"]["unit"] == "deg"
    assert params["shoulder_roll.d"]["unit"] == "cm"
    # the full mode estimates the joint offsets (the daily ones) and more
    assert sum(bool(p.get("estimated")) for p in params.values()) > 10

    before, after = cal["figures"]["before"], cal["figures"]["after"]
    assert before["unit"] == after["unit"] == "cm"
    assert 5.0 < before["mean"] < 40.0  # the paper: 13.75 cm
    assert after["mean"] < 0.25 * before["mean"]  # the paper: 1.85 cm
    for key in (f"{before['mean']:.3f}", f"{after['mean']:.3f}"):
        assert key in out, (key, out)

    assert isinstance(cal["iterations"], int) and cal["iterations"] >= 1
    assert cal["iterations"] == cal["solver"]["iterations"]
    assert isinstance(cal["solve_seconds"], float) and 0.0 < cal["solve_seconds"] < 60.0
    assert cal["solve_seconds"] == cal["solver"]["solve_seconds"]


def test_solve_daily_on_a_later_day_with_a_held_out_half(robonaut_runs: dict) -> None:
    ok(robonaut_runs["sim2"])
    proc = ok(robonaut_runs["daily"])
    assert re.search(r"held out", proc.stdout), proc.stdout
    cal = json.loads((robonaut_runs["dir"] / "daily.json").read_text(encoding="utf-8"))
    assert cal["robot"] == "robonaut-a"
    assert cal["mode"] == "daily"
    f = cal["figures"]
    assert f["before"]["n"] + f["holdout_before"]["n"] == 150
    assert abs(f["before"]["n"] - 75) <= 1
    assert f["after"]["mean"] < 0.25 * f["before"]["mean"]
    assert f["holdout_after"]["mean"] < 0.25 * f["holdout_before"]["mean"]
    # daily estimates only the joint offsets and keeps the rest of the full calibration
    full = {
        p["name"]: p for p in json.loads((robonaut_runs["dir"] / "full.json").read_text(encoding="utf-8"))["parameters"]
    }
    for p in cal["parameters"]:
        if not p["name"].endswith(".theta"):
            assert not p["estimated"], p["name"]
            assert p["value"] == pytest.approx(full[p["name"]]["value"], abs=1e-9), p["name"]


def test_a_reading_beyond_a_joint_limit_is_a_note_on_stderr(tmp_path: Path) -> None:
    lines = (ROOT / "sample_sessions" / "robonaut-a-day1" / "data.csv").read_text().splitlines()
    cells = lines[3].split(",")
    cells[5] = "95.0"  # shoulder_pitch, whose upper limit is 90 deg
    lines[3] = ",".join(cells)
    (tmp_path / "past.csv").write_text("\n".join(lines) + "\n")
    proc = ok(calib("predict", "--robot", "robonaut-a", "--data", "past.csv", "--out", "p.csv", cwd=tmp_path))
    assert (
        "calib predict: note: past.csv, line 4, column 'shoulder_pitch': shoulder_pitch reads 95.00 deg, beyond its "
        "upper limit 90.00 deg"
    ) in proc.stderr


def test_simulate_without_a_simulation_section_says_the_data_are_perfect(tmp_path: Path) -> None:
    """A profile without `simulation:` gets the nominal robot measured exactly: valid data (a check of the
    profile's plumbing), but a calibration of them finds nothing, so the command says so and what to add."""
    doc = yaml.safe_load((ROOT / "sample_sessions" / "arm" / "arm.yaml").read_text())
    del doc["simulation"]
    (tmp_path / "arm.yaml").write_text(yaml.safe_dump(doc, sort_keys=False))
    (tmp_path / "arm.urdf").write_bytes((ROOT / "sample_sessions" / "arm" / "arm.urdf").read_bytes())
    proc = ok(calib("simulate", "--robot", "arm.yaml", "--configurations", "5", "--out", "a.csv", cwd=tmp_path))
    assert "(the nominal robot itself, no measurement noise: see the notes)" in proc.stdout
    notes = [line for line in proc.stderr.splitlines() if line.startswith("calib simulate: note: robot 'my-arm'")]
    assert len(notes) == 2, proc.stderr
    assert "has no simulation.truth" in notes[0] and "`simulation: {truth: {PARAMETER: VALUE, ...}}`" in notes[0]
    assert "has no simulation.noise" in notes[1] and "arm.yaml" in notes[1]
    _, rows = read_rows(tmp_path / "a.csv")
    assert len(rows) == 5


def test_a_truth_written_as_an_error_is_noted_with_the_value_meant(tmp_path: Path) -> None:
    """`simulation.truth` holds values, not errors (a user wrote `elbow.z: 0.5` meaning an error and got a 419 mm
    "before"): the docs say so, and a value that reads like the other reading is noted with the value meant."""
    doc = yaml.safe_load((ROOT / "sample_sessions" / "arm" / "arm.yaml").read_text())
    nominal_z = load_profile(ROOT / "sample_sessions" / "arm" / "arm.yaml").nominal()
    doc["simulation"]["truth"]["elbow.z"] = 0.5
    (tmp_path / "arm.yaml").write_text(yaml.safe_dump(doc, sort_keys=False))
    (tmp_path / "arm.urdf").write_bytes((ROOT / "sample_sessions" / "arm" / "arm.urdf").read_bytes())
    profile = load_profile(tmp_path / "arm.yaml")
    z = profile.to_display(profile.param("elbow.z"), nominal_z[profile.param("elbow.z")])
    proc = ok(calib("simulate", "--robot", "arm.yaml", "--configurations", "5", "--out", "a.csv", cwd=tmp_path))
    (note,) = [line for line in proc.stderr.splitlines() if "simulation.truth.elbow.z" in line]
    assert f"0.5 mm is {z - 0.5:.4g} mm from its nominal value {z:.6g} mm" in note
    assert f"not their errors (an error of 0.5 mm is {z + 0.5:.6g})" in note
    assert load_profile(ROOT / "sample_sessions" / "arm" / "arm.yaml").notes == ()  # values as meant: no note


@pytest.mark.parametrize("mask", [0o022, 0o027])
def test_files_written_follow_the_umask(tmp_path: Path, mask: int) -> None:
    """A simulated CSV, its truth, a calibration and its exports were written 0600 whatever the umask (a driver
    running as another user could not read them); now as any file of the user's: 0666 less the umask."""

    def run(*args: str) -> None:
        proc = subprocess.run(
            [*_command(), *args],
            cwd=tmp_path,
            capture_output=True,
            text=True,
            timeout=TIMEOUT,
            env=_env(),
            preexec_fn=lambda: os.umask(mask),
        )
        assert proc.returncode == 0, proc.stderr

    robot = ("--robot", "robonaut-a")
    run("simulate", *robot, "--configurations", "30", "--out", "d.csv", "--truth", "t.json")
    run("solve", *robot, "--mode", "daily", "--data", "d.csv", "--out", "c.json")
    for fmt in ("urdf", "yaml"):
        run("export", *robot, "--calibration", "c.json", "--format", fmt, "--out", f"x.{fmt}")
    for name in ("d.csv", "t.json", "c.json", "x.urdf", "x.yaml"):
        assert oct((tmp_path / name).stat().st_mode & 0o777) == oct(0o666 & ~mask), name


def test_serve_on_a_taken_port_says_so_and_exits_2(tmp_path: Path) -> None:
    """`scripts/run.sh` on a busy port announced "open http://127.0.0.1:8000/" and then failed."""
    with socket.socket() as taken:
        taken.bind(("127.0.0.1", 0))
        taken.listen()
        port = taken.getsockname()[1]
        proc = calib("serve", "--port", str(port), "--data-dir", "data", cwd=tmp_path)
    assert proc.returncode == 2, proc.stderr
    assert "open http" not in proc.stdout and "Traceback" not in proc.stderr
    assert f"port {port} on 127.0.0.1 is taken" in proc.stderr and f"--port {port + 1}" in proc.stderr
    assert not (tmp_path / "data").exists()  # nothing started


def test_the_served_connections_send_at_once() -> None:
    """The socket `calib serve` listens on says it is TCP, so asyncio turns Nagle's algorithm off on its
    connections (TCP_NODELAY): with it on, every answer on a kept-alive connection (a page's second request
    and on) waited about 40 ms for the browser's delayed ACK."""
    import asyncio

    from app.web.server import listen

    async def accepted() -> int:
        options: list[int] = []
        sock = listen("127.0.0.1", 0)

        def connected(reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
            options.append(writer.get_extra_info("socket").getsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY))
            writer.close()

        server = await asyncio.start_server(connected, sock=sock)
        async with server:
            _, writer = await asyncio.open_connection(*sock.getsockname()[:2])
            while not options:
                await asyncio.sleep(0)  # the server's callback runs on this loop: no wall time waited
            writer.close()
        return options[0]

    assert asyncio.run(accepted()) != 0


def test_a_closed_output_pipe_ends_quietly(tmp_path: Path) -> None:
    """`calib detect-board ... | head -1`: the reader goes away before the answer is written; the command ends
    with 141 (a shell's status for SIGPIPE) and nothing on stderr, neither a traceback nor an internal error."""
    image = ROOT / "sample_sessions" / "nao" / "images" / "0001_image.jpg"
    board = ("detect-board", "--image", str(image), "--cols", "6", "--rows", "4")
    for args, statuses in ((board, {141}), (("--help",), {0, 141})):  # argparse's help ignores a failed write
        read, write = os.pipe()
        os.close(read)
        try:
            proc = subprocess.run(
                [*_command(), *args], stdout=write, stderr=subprocess.PIPE, text=True, timeout=TIMEOUT, env=_env()
            )
        finally:
            os.close(write)
        assert proc.returncode in statuses and proc.stderr == "", (args, proc.returncode, proc.stderr)


def test_a_solve_that_hits_the_iteration_limit_says_it_did_not_converge(tmp_path: Path) -> None:
    """A daily calibration of the first sample day from the nominal model (8 deg off) stops at the
    iteration limit: the summary, the warning and the file say it did not converge."""
    out = tmp_path / "daily.json"
    data = ROOT / "sample_sessions" / "robonaut-a-day1" / "data.csv"
    proc = ok(
        calib("solve", "--robot", "robonaut-a", "--mode", "daily", "--data", str(data), "--out", str(out), cwd=tmp_path)
    )
    assert "DID NOT CONVERGE: maximum iterations reached" in proc.stdout
    assert "warning: the solver did not converge" in proc.stdout
    cal = json.loads(out.read_text(encoding="utf-8"))
    assert cal["converged"] is False and cal["solver"]["converged"] is False
    assert cal["solver"]["status"] == "max_iterations" and cal["solver"]["iterations"] == 100
    assert {"severity": "warning", "code": "not-converged"}.items() <= next(
        d for d in cal["diagnostics"] if d["code"] == "not-converged"
    ).items()


def test_predict_with_the_calibration_is_close_to_the_measurements(robonaut_runs: dict) -> None:
    proc = ok(robonaut_runs["predict"])
    assert "pred.csv" in proc.stdout
    in_header, in_rows = read_rows(robonaut_runs["dir"] / "day1.csv")
    header, rows = read_rows(robonaut_runs["dir"] / "pred.csv")
    assert header == [*in_header, "pred_x", "pred_y", "pred_z"]
    assert len(rows) == len(in_rows)
    for r, s in zip(rows, in_rows, strict=True):
        assert {k: r[k] for k in in_header} == s
    assert _mean_distance(rows, ["x", "y", "z"], ["pred_x", "pred_y", "pred_z"]) < 1.0


def test_predict_without_calibration_uses_the_nominal_model(robonaut_runs: dict) -> None:
    ok(robonaut_runs["predict"])
    proc = ok(robonaut_runs["nominal"])
    assert "nominal" in proc.stdout
    _, calibrated = read_rows(robonaut_runs["dir"] / "pred.csv")
    header, nominal = read_rows(robonaut_runs["dir"] / "pred_nominal.csv")
    assert header[-3:] == ["pred_x", "pred_y", "pred_z"]
    cols = (["x", "y", "z"], ["pred_x", "pred_y", "pred_z"])
    e_nominal = _mean_distance(nominal, *cols)
    assert e_nominal > 5.0
    assert e_nominal > 5 * _mean_distance(calibrated, *cols)


# --- happy paths: NAO ---------------------------------------------------------------------------


def test_nao_simulate_solve_predict(nao_runs: dict) -> None:
    ok(nao_runs["sim"])
    header, rows = read_rows(nao_runs["dir"] / "nao.csv")
    assert sorted(header) == sorted(NAO_COLUMNS)
    assert {r["chain"] for r in rows} <= {"left", "right"}
    assert {int(r["vertex"]) for r in rows} <= set(range(24))

    proc = ok(nao_runs["full"])
    assert re.search(r"before.*\d", proc.stdout) and re.search(r"after.*\d", proc.stdout)
    cal = json.loads((nao_runs["dir"] / "nao.json").read_text(encoding="utf-8"))
    assert cal["robot"] == "nao" and cal["mode"] == "full"
    params = {p["name"]: p for p in cal["parameters"]}
    paper = ["CamYaw", "CamPitch", "CamRoll"]
    paper += [f"{s}{j}" for s in "LR" for j in ("HipYawPitch", "HipRoll", "HipPitch", "KneePitch", "AnklePitch")]
    paper += [f"{s}AnkleRoll" for s in "LR"]
    paper += [f"{s}{k}" for s in "LR" for k in ("RotZ", "TransX", "TransY")]
    assert len(paper) == 21
    for name in paper:
        assert name in params, name
        assert params[name]["unit"] == ("mm" if "Trans" in name else "deg"), name
    f = cal["figures"]
    assert f["before"]["unit"] == "px"
    assert f["after"]["mean"] < 0.1 * f["before"]["mean"]
    assert cal["iterations"] >= 1 and cal["solve_seconds"] > 0

    ok(nao_runs["predict"])
    pheader, prow = read_rows(nao_runs["dir"] / "pred.csv")
    assert pheader == [*header, "pred_u", "pred_v"]
    assert len(prow) == len(rows)
    assert _mean_distance(prow, ["u", "v"], ["pred_u", "pred_v"]) < 3.0


# --- error paths ----------------------------------------------------------------------------------


@dataclass(frozen=True)
class Case:
    """One bad command: its arguments, what stderr must mention (regexes), and which --out it names."""

    id: str
    args: tuple[str, ...]
    must: tuple[str, ...] = ()
    usage: bool = False  # an argparse usage error: usage lines plus the error line
    out: str | None = None  # the --out file that must not appear (or must keep its old content)
    existing_out: bool = False  # create `out` before the run with known content


def _solve(data: str, *more: str, robot: str = "robonaut-a", mode: str = "full", out: str) -> tuple[str, ...]:
    return ("solve", "--robot", robot, "--mode", mode, "--data", data, *more, "--out", out)


def _case_solve(cid: str, data: str, *more: str, must: tuple[str, ...], **kw) -> Case:
    out = f"out-{cid}.json"
    robot = kw.pop("robot", "robonaut-a")
    mode = kw.pop("mode", "full")
    return Case(cid, _solve(data, *more, robot=robot, mode=mode, out=out), must, out=out, **kw)


def _case_predict(cid: str, *args: str, must: tuple[str, ...]) -> Case:
    out = f"pred-{cid}.csv"
    return Case(cid, ("predict", *args, "--out", out), must, out=out)


LINE = r"\bline\s+{}\b"


def _col(name: str) -> str:
    return r"column\s+['\"]?" + re.escape(name) + r"\b"


ERROR_CASES = [
    _case_solve("missing-column", "nocol.csv", must=("nocol.csv", _col("neck_pitch"))),
    _case_solve("not-a-number", "abc.csv", must=("abc.csv", LINE.format(5), _col("x"), "abc")),
    _case_solve("nan-joint", "nanjoint.csv", must=("nanjoint.csv", LINE.format(7), _col("elbow_roll"))),
    _case_solve("inf-measurement", "inf.csv", must=("inf.csv", LINE.format(3), _col("z"))),
    _case_solve("empty-file", "empty.csv", must=("empty.csv", "empty")),
    _case_solve("header-only", "header.csv", must=("header.csv", "no data|no rows")),
    _case_solve("too-few-fields", "short.csv", must=("short.csv", LINE.format(4), "field")),
    _case_solve("frame-contradicts", "twice.csv", must=("twice.csv", LINE.format(3), "frame")),
    _case_solve("unknown-robot", "day1.csv", must=("robonaut-x",), robot="robonaut-x"),
    _case_solve("unknown-mode", "day1.csv", must=("weekly",), mode="weekly"),
    _case_solve("nao-daily-mode", "nao.csv", must=("daily", "nao"), robot="nao", mode="daily"),
    _case_solve("missing-data-file", "nope.csv", must=("nope.csv", "not exist|no such")),
    _case_solve(
        "base-missing", "day1.csv", "--base", "nope.json", must=("nope.json", "not exist|no such"), mode="daily"
    ),
    _case_solve("base-not-json", "day1.csv", "--base", "notjson.json", must=("notjson.json", "JSON"), mode="daily"),
    _case_solve("base-other-robot", "day1.csv", "--base", "nao-cal.json", must=("nao-cal.json", "nao"), mode="daily"),
    _case_solve("data-is-directory", "adir", must=("adir", "director")),
    _case_solve("data-is-binary", "binary.csv", must=("binary.csv",)),
    _case_solve("holdout-too-large", "day1.csv", "--holdout", "1.5", must=("holdout", "1.5")),
    _case_solve(
        "nao-chain-middle", "middle.csv", must=("middle.csv", LINE.format(10), _col("chain"), "middle"), robot="nao"
    ),
    _case_solve("nao-vertex-30", "v30.csv", must=("v30.csv", LINE.format(10), _col("vertex"), "30"), robot="nao"),
    _case_solve("existing-out-kept", "abc.csv", must=("abc.csv", LINE.format(5)), existing_out=True),
    Case(
        "out-folder-missing",
        _solve("day1.csv", out="no-such-folder/cal.json"),
        ("no-such-folder",),
        out="no-such-folder",
    ),
    Case(
        "missing-required-out",
        ("solve", "--robot", "robonaut-a", "--mode", "full", "--data", "day1.csv"),
        ("--out",),
        usage=True,
    ),
    Case(
        "missing-required-data",
        ("solve", "--robot", "robonaut-a", "--mode", "full", "--out", "x.json"),
        ("--data",),
        usage=True,
        out="x.json",
    ),
    Case("no-subcommand", (), ("required|command",), usage=True),
    _case_predict(
        "predict-missing-column", "--robot", "robonaut-a", "--data", "nocol.csv", must=("nocol.csv", _col("neck_pitch"))
    ),
    _case_predict("predict-unknown-robot", "--robot", "robonaut-x", "--data", "day1.csv", must=("robonaut-x",)),
    _case_predict(
        "predict-calibration-missing",
        "--robot",
        "robonaut-a",
        "--calibration",
        "nope.json",
        "--data",
        "day1.csv",
        must=("nope.json",),
    ),
    _case_predict(
        "predict-calibration-other-robot",
        "--robot",
        "robonaut-a",
        "--calibration",
        "nao-cal.json",
        "--data",
        "day1.csv",
        must=("nao-cal.json", "nao"),
    ),
    _case_predict("predict-binary", "--robot", "robonaut-a", "--data", "binary.csv", must=("binary.csv",)),
    Case(
        "simulate-unknown-robot", ("simulate", "--robot", "robonaut-x", "--out", "s.csv"), ("robonaut-x",), out="s.csv"
    ),
    Case(
        "simulate-out-folder-missing",
        ("simulate", "--robot", "robonaut-a", "--configurations", "3", "--out", "no-such-folder/s.csv"),
        ("no-such-folder",),
        out="no-such-folder",
    ),
]

# Bad input found by these tests that once ended in an internal error or an unnamed file.
REGRESSION_CASES = [
    pytest.param(
        _case_solve("huge-measurement", "huge.csv", must=("huge.csv",)),
        id="huge-measurement",
    ),
    pytest.param(
        _case_solve("frame-beyond-int64", "bigframe.csv", must=("bigframe.csv", LINE.format(2), _col("frame"))),
        id="frame-beyond-int64",
    ),
    pytest.param(
        _case_solve("base-unknown-parameter", "day1.csv", "--base", "bogus.json", must=("bogus.json",), mode="daily"),
        id="base-unknown-parameter",
    ),
    pytest.param(
        _case_solve("too-few-rows", "three.csv", must=("three.csv",)),
        id="too-few-rows",
    ),
]


def _write_csv(path: Path, rows: list[list[str]]) -> None:
    path.write_text("".join(",".join(r) + "\n" for r in rows), encoding="utf-8")


def _prepare_bad_files(d: Path, day1: Path, nao_csv: Path, nao_cal: Path, full_cal: Path) -> None:
    rows = list(csv.reader(day1.read_text(encoding="utf-8").splitlines()))
    h = rows[0]
    (d / "day1.csv").write_text(day1.read_text(encoding="utf-8"), encoding="utf-8")

    def mutated(name: str, line: int, column: str, value: str) -> None:
        r = [list(x) for x in rows]
        r[line - 1][h.index(column)] = value
        _write_csv(d / name, r)

    i = h.index("neck_pitch")
    _write_csv(d / "nocol.csv", [r[:i] + r[i + 1 :] for r in rows])
    mutated("abc.csv", 5, "x", "abc")
    mutated("nanjoint.csv", 7, "elbow_roll", "NaN")
    mutated("inf.csv", 3, "z", "inf")
    mutated("huge.csv", 4, "x", "1e200")
    mutated("bigframe.csv", 2, "frame", "1e19")
    twice = [list(x) for x in rows]
    twice[2] = [*twice[1]]
    twice[2][h.index("shoulder_roll")] = str(float(twice[1][h.index("shoulder_roll")]) + 1.0)
    _write_csv(d / "twice.csv", twice)
    (d / "empty.csv").write_text("", encoding="utf-8")
    _write_csv(d / "header.csv", rows[:1])
    short = [list(x) for x in rows]
    short[3] = short[3][:-2]
    _write_csv(d / "short.csv", short)
    _write_csv(d / "three.csv", rows[:4])
    (d / "adir").mkdir()
    (d / "binary.csv").write_bytes(bytes(range(256)) * 8 + b"\x89PNG\r\n\x1a\n\xff\xfe")
    (d / "notjson.json").write_text("{not json", encoding="utf-8")
    (d / "nao-cal.json").write_text(nao_cal.read_text(encoding="utf-8"), encoding="utf-8")
    bogus = json.loads(full_cal.read_text(encoding="utf-8"))
    bogus["parameters"][0]["name"] = "bogus"
    (d / "bogus.json").write_text(json.dumps(bogus), encoding="utf-8")

    nrows = list(csv.reader(nao_csv.read_text(encoding="utf-8").splitlines()))
    nh = nrows[0]
    (d / "nao.csv").write_text(nao_csv.read_text(encoding="utf-8"), encoding="utf-8")
    r = [list(x) for x in nrows]
    r[9][nh.index("chain")] = "middle"
    _write_csv(d / "middle.csv", r)
    r = [list(x) for x in nrows]
    r[9][nh.index("vertex")] = "30"
    _write_csv(d / "v30.csv", r)


SENTINEL = '{"sentinel": "an older calibration that a failed solve must keep"}\n'


@pytest.fixture(scope="module")
def error_runs(
    tmp_path_factory: pytest.TempPathFactory, pool: ThreadPoolExecutor, robonaut_runs: dict, nao_runs: dict
) -> dict:
    """Every bad command, started concurrently in one folder of bad files; id -> (folder, future)."""
    ok(robonaut_runs["full"])
    ok(nao_runs["full"])
    d = tmp_path_factory.mktemp("errors")
    _prepare_bad_files(
        d,
        robonaut_runs["dir"] / "day1.csv",
        nao_runs["dir"] / "nao.csv",
        nao_runs["dir"] / "nao.json",
        robonaut_runs["dir"] / "full.json",
    )
    cases = [*ERROR_CASES, *(p.values[0] for p in REGRESSION_CASES)]
    for c in cases:
        if c.existing_out:
            assert c.out is not None
            (d / c.out).write_text(SENTINEL, encoding="utf-8")
    futures: dict[str, Future] = {c.id: pool.submit(calib, *c.args, cwd=d) for c in cases}
    return {"dir": d, "futures": futures}


def check_bad_input(case: Case, proc: subprocess.CompletedProcess[str], folder: Path) -> None:
    err = proc.stderr
    shown = f"calib {' '.join(case.args)}\nexit {proc.returncode}\nstdout:\n{proc.stdout}\nstderr:\n{err}"
    assert "Traceback" not in err, shown
    assert proc.returncode == 2, shown
    lines = [ln for ln in err.splitlines() if ln.strip()]
    if case.usage:
        assert any("error" in ln for ln in lines), shown
    else:
        assert 1 <= len(lines) <= 2, shown
        assert "error" in err.lower(), shown
    for pattern in case.must:
        assert re.search(pattern, err, re.IGNORECASE), f"stderr lacks /{pattern}/\n{shown}"
    if case.out is not None:
        out = folder / case.out
        if case.existing_out:
            assert out.read_text(encoding="utf-8") == SENTINEL, f"the failed command overwrote {case.out}\n{shown}"
        else:
            assert not out.exists(), f"the failed command created {case.out}\n{shown}"
    # no stray temporary files of an interrupted atomic write
    assert not [p.name for p in folder.glob(".*.tmp")], shown


@pytest.mark.parametrize("case", ERROR_CASES, ids=[c.id for c in ERROR_CASES])
def test_bad_input_exits_2_with_a_short_message(case: Case, error_runs: dict) -> None:
    proc = error_runs["futures"][case.id].result(timeout=TIMEOUT)
    check_bad_input(case, proc, error_runs["dir"])


@pytest.mark.parametrize("case", REGRESSION_CASES)
def test_bad_input_regressions(case: Case, error_runs: dict) -> None:
    proc = error_runs["futures"][case.id].result(timeout=TIMEOUT)
    check_bad_input(case, proc, error_runs["dir"])


def test_failed_solve_names_the_problem_not_python(error_runs: dict) -> None:
    """The messages are written for people: the command, 'error', the file; no Python class names."""
    for cid in ("missing-column", "not-a-number", "nan-joint", "empty-file", "missing-data-file", "data-is-binary"):
        err = error_runs["futures"][cid].result(timeout=TIMEOUT).stderr
        assert err.startswith("calib solve"), err
        assert not re.search(r"\b(ValueError|KeyError|TypeError|IndexError|Exception)\b", err), err


# --- --help ---------------------------------------------------------------------------------------

HELP_PARAMS = [
    pytest.param((), id="calib"),
    pytest.param(("solve",), id="solve"),
    pytest.param(("predict",), id="predict"),
    pytest.param(("simulate",), id="simulate"),
    pytest.param(("detect-sphere",), id="detect-sphere"),
    pytest.param(("detect-board",), id="detect-board"),
    pytest.param(("serve",), id="serve"),
    pytest.param(("import-bag",), id="import-bag"),
    pytest.param(("export",), id="export"),
    pytest.param(("self-observe",), id="self-observe"),
]


@pytest.fixture(scope="module")
def help_runs(
    tmp_path_factory: pytest.TempPathFactory, pool: ThreadPoolExecutor, workflows: dict
) -> dict[tuple[str, ...], Future]:
    """Started right after the workflows (see `robonaut`), so that they run side by side."""
    d = tmp_path_factory.mktemp("help")
    return {p.values[0]: pool.submit(calib, *p.values[0], "--help", cwd=d) for p in HELP_PARAMS}


@pytest.mark.parametrize("sub", HELP_PARAMS)
def test_every_subcommand_answers_help(sub: tuple[str, ...], help_runs: dict) -> None:
    proc = help_runs[sub].result(timeout=TIMEOUT)
    assert proc.returncode == 0, proc.stderr
    assert "usage:" in proc.stdout
    assert "Traceback" not in proc.stderr
    options: dict[str, list[str]] = {
        "solve": ["--robot", "--mode", "--data", "--base", "--out", "--where"],
        "predict": ["--robot", "--calibration", "--data", "--out", "--where"],
        "simulate": ["--robot", "--out"],
        "detect-sphere": ["--depth", "--fx", "--fy", "--cx", "--cy", "--radius", "--seed", "--json"],
        "detect-board": ["--image", "--cols", "--rows", "--json"],
        "serve": ["--host", "--port", "--data-dir"],
        "import-bag": ["--robot", "--out", "--joint-topic", "--image-topic", "--still-deg-s", "--still-s"],
        "export": ["--robot", "--calibration", "--format", "--out"],
        "self-observe": ["--robot", "--mode", "--data", "--source", "--holdout", "--out"],
    }
    for opt in options.get(sub[0] if sub else "", ["solve", "predict", "simulate"]):
        assert opt in proc.stdout, (opt, proc.stdout)


@pytest.fixture(scope="module")
def evaluated(tmp_path_factory: pytest.TempPathFactory) -> dict:
    """A full calibration from day 1, evaluated on 40 fresh configurations of the same robot."""
    d = tmp_path_factory.mktemp("evaluate")
    ok(calib("simulate", "--robot", "robonaut-a", "--configurations", "67", "--out", "day1.csv", cwd=d))
    ok(calib("simulate", "--robot", "robonaut-a", "--configurations", "40", "--seed", "5", "--out", "fresh.csv", cwd=d))
    ok(
        calib(
            "simulate", "--robot", "robonaut-a", "--configurations", "40", "--out", "x.csv", "--truth", "t.json", cwd=d
        )
    )
    ok(calib("solve", "--robot", "robonaut-a", "--mode", "full", "--data", "day1.csv", "--out", "full.json", cwd=d))
    args = ("evaluate", "--robot", "robonaut-a", "--calibration", "full.json", "--data", "fresh.csv")
    return {"dir": d, "text": ok(calib(*args, cwd=d)), "json": ok(calib(*args, "--json", cwd=d))}


def test_evaluate_prints_the_figures_on_data_it_was_not_fitted_on(evaluated: dict) -> None:
    from calib_core import Problem, read_dataset

    d = evaluated["dir"]
    figures = json.loads(evaluated["json"].stdout)
    assert set(figures) == {"mean", "rms", "max", "n", "unit"}
    assert figures["n"] == 40 and figures["unit"] == "cm"
    assert f"mean {figures['mean']:.3f} cm" in evaluated["text"].stdout
    # The same figures from the predictions `calib predict` writes, computed here.
    ok(
        calib(
            "predict",
            "--robot",
            "robonaut-a",
            "--calibration",
            "full.json",
            "--data",
            "fresh.csv",
            "--out",
            "p.csv",
            cwd=d,
        )
    )
    _, rows = read_rows(d / "p.csv")
    e = [math.dist([float(r[k]) for k in "xyz"], [float(r[f"pred_{k}"]) for k in "xyz"]) for r in rows]
    assert figures["mean"] == pytest.approx(sum(e) / len(e), abs=1e-5)
    assert figures["max"] == pytest.approx(max(e), abs=1e-5)
    # Against the truth: the calibrated model is at the noise floor (the truth's own error on these data).
    rn = load_profile("robonaut-a")
    truth = rn.params_from_display(json.loads((d / "t.json").read_text())["parameters"])
    data = read_dataset(rn, d / "fresh.csv")
    err = (Problem(rn, data, [], truth).predict(truth) - data.measured) ** 2
    floor = math.sqrt(float(err.sum(axis=1).mean()))
    assert 0.8 * floor <= figures["rms"] <= 1.3 * floor, (figures["rms"], floor)


@pytest.mark.parametrize(
    ("content", "must"),
    [
        ("frame,x,y\n1,2,3\n", r"fresh\.csv.*(column|z)"),
        (None, r"fresh\.csv.*line 3.*shoulder_pitch"),
    ],
    ids=["missing-column", "not-a-number"],
)
def test_evaluate_bad_input_exits_2_naming_file_line_and_column(evaluated: dict, content, must: str) -> None:
    d = evaluated["dir"]
    bad = d / "bad" / "fresh.csv"
    bad.parent.mkdir(exist_ok=True)
    if content is None:
        lines = (d / "fresh.csv").read_text().splitlines()
        cells = lines[2].split(",")
        cells[5] = "abc"  # shoulder_pitch of line 3
        lines[2] = ",".join(cells)
        content = "\n".join(lines) + "\n"
    bad.write_text(content)
    proc = calib("evaluate", "--robot", "robonaut-a", "--calibration", "full.json", "--data", str(bad), cwd=d)
    assert proc.returncode == 2 and "Traceback" not in proc.stderr, proc.stderr
    assert re.search(must, proc.stderr, re.IGNORECASE), proc.stderr
    missing = calib("evaluate", "--robot", "robonaut-a", "--calibration", "none.json", "--data", "fresh.csv", cwd=d)
    assert missing.returncode == 2 and "none.json" in missing.stderr, missing.stderr


def test_a_talos_origins_solve_prints_one_line_per_kind_of_warning(tmp_path) -> None:
    """FIGAROH's TALOS data in `origins` mode: 33 parameters held and 30 weak ones (61 findings) are two lines,
    the weak ones first (they change how far to trust the estimate) and every parameter named; --verbose lists
    each finding under its line."""
    figaroh = ROOT / "sample_sessions" / "figaroh"
    args = ("solve", "--robot", str(figaroh / "talos.yaml"), "--mode", "origins")
    args += ("--data", str(figaroh / "talos_left_arm_02_10_contact.csv"), "--out", "talos.json")
    short = ok(calib(*args, cwd=tmp_path)).stdout.splitlines()
    warnings = [line for line in short if line.startswith("  warning: ")]
    assert len(warnings) == 2, short
    assert warnings[0].startswith("  warning: 30 parameters weakly determined")
    assert warnings[1].startswith("  warning: 33 parameters held at their base values")
    saved = json.loads((tmp_path / "talos.json").read_text())["diagnostics"]
    for code, line in (("weak", warnings[0]), ("held-fixed", warnings[1])):
        named = {p for d in saved if d["code"] == code for p in d["parameters"]}
        assert named and all(p in line for p in named)
    assert "  (61 findings grouped above: --verbose lists each)" in short

    long = ok(calib(*args, "--verbose", cwd=tmp_path)).stdout.splitlines()
    listed = [line for line in long if line.startswith("    - ")]
    assert len(listed) == len(saved) == 61
    assert sum("cannot be told apart" in line for line in listed) == 33
    assert not any("--verbose" in line for line in long)
