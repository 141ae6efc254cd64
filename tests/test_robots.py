"""Robots on the desk: instances of profiles with plug-in drivers.

The driver registry (a kind is a module and one line), the desk configuration file (every mistake named by
file and field before anything starts, `calib serve` exits 2), two robots of one profile keeping their own
calibrations and apply histories, and robots added to the running desk (uploaded or named profiles, a
URDF-based one, a broken one that changes nothing), kept after a restart and removed with their driver
closed.
"""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest
import recording_driver
from desk_jobs import wait_job
from fastapi.testclient import TestClient
from test_urdf_import import JOINTS, PROFILE, arm_urdf

from app.cli import main as calib
from app.drivers import registry
from app.drivers.registry import DriverContext, DriverSpec
from app.drivers.simulated import SimulatedDriver
from app.robots.desk_config import DeskConfig, default_config, load_desk_config
from app.store.profiles import PROFILE_DIR
from app.web.server import create_app
from calib_core import InputError, SimulatedRobot, load_profile

SAMPLES = Path(__file__).resolve().parent.parent / "sample_sessions"
NAOS = """\
robots:
  - {name: nao-1, profile: nao, driver: simulated}
  - {name: nao-2, profile: nao, driver: {kind: simulated, seed: 2}}
connected: nao-2
"""


def write(path: Path, text: str) -> Path:
    path.write_text(text, encoding="utf-8")
    return path


# --- the registry and the configuration file ----------------------------------------------------------
def test_a_driver_kind_is_a_module_and_one_registry_line(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """A new kind plugs in by name; the desk makes its driver at the start and closes it when it stops."""
    monkeypatch.setitem(registry.KINDS, "recording", "recording_driver")
    config = load_desk_config(write(tmp_path / "desk.yaml", "robots: [{name: arm-1, profile: nao, driver: recording}]"))
    assert config.robots[0].driver == DriverSpec("recording", {})
    recording_driver.CLOSED.clear()
    with TestClient(create_app(tmp_path / "data", config=config, sample_dir=None, time_scale=50.0)) as client:
        (robot,) = client.get("/api/robots").json()
        assert (robot["name"], robot["model"], robot["driver"]) == ("arm-1", "nao", "recording")
        assert robot["drivable"] is True and robot["simulated"] is False
        assert client.get("/api/robot").json()["robot"] == "arm-1"
        assert recording_driver.CLOSED == []
    assert recording_driver.CLOSED == ["arm-1"]


def test_the_simulated_kind_checks_its_options_and_makes_the_robot() -> None:
    nao = load_profile("nao")
    assert registry.check(DriverSpec("simulated"), nao) == DriverSpec("simulated", {"seed": 1, "day": 1})
    with pytest.raises(InputError, match=r"driver\.seed: expected a whole number from 0, got -1"):
        registry.check(DriverSpec("simulated", {"seed": -1}), nao)
    with pytest.raises(InputError, match=r"driver\.speed: no such option"):
        registry.check(DriverSpec("simulated", {"speed": 2}), nao)
    with pytest.raises(InputError, match=r"driver\.kind: unknown driver kind 'ros3' \(known: simulated, ros2, naoqi\)"):
        registry.check(DriverSpec("ros3"), nao)
    driver = registry.create(registry.check(DriverSpec("simulated"), nao), nao, DriverContext(time_scale=50.0))
    assert isinstance(driver, SimulatedDriver) and driver.status().connected
    driver.close()
    assert not driver.status().connected


def test_the_default_desk_is_the_built_in_robots_as_before() -> None:
    config = default_config()
    assert [(r.name, r.profile, r.origin) for r in config.robots] == [
        ("robonaut-a", "robonaut-a", "builtin"),
        ("nao", "nao", "builtin"),
        ("motoman", "motoman", "builtin"),
        ("arm-handeye", "arm-handeye", "builtin"),
    ]
    assert [r.driver for r in config.robots] == [
        DriverSpec("simulated", {"seed": 1, "day": 2}),  # the later day of its day-2 sample session
        DriverSpec("simulated", {"seed": 1, "day": 1}),
        DriverSpec("simulated", {"seed": 1, "day": 1}),
        DriverSpec("simulated", {"seed": 1, "day": 1}),
    ]


BAD_CONFIGS = [
    ("robots: [{name: a, profile: nao, driver: ros3}]", "robots[0].driver.kind: unknown driver kind 'ros3'"),
    ("robots: [{name: a, profile: nao, driver: {kind: simulated, seed: x}}]", "robots[0].driver.seed: expected"),
    ("robots: [{name: a, profile: nao}, {name: a, profile: nao}]", "robots[1].name: 'a' is on the desk already"),
    ("robots: [{name: a, profile: nao, colour: red}]", "robots[0].colour: no such field"),
    ("robots: [{name: ../a, profile: nao}]", "robots[0].name: robot name '../a' must be"),
    ("robots: [{name: a, profile: r2d2.yaml}]", "robot profile file does not exist"),
    ("robots: [{name: a, profile: arm.yaml, driver: simulated}]", "robots[0].driver: a cannot be simulated"),
    ("robots: [{name: a, profile: broken.yaml}]", "broken.yaml: targets[0].point.x"),
    ("robots: [{name: a, profile: nao}]\nconnected: a", "connected: 'a' is no robot with a driver here"),
    ("robots: []", "robots: expected a list of robots"),
    ("robots: [{name: a, profile: nao}", "not valid YAML"),
]


@pytest.mark.parametrize(("text", "words"), BAD_CONFIGS)
def test_a_bad_desk_configuration_is_named_and_calib_serve_exits_2(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], text: str, words: str
) -> None:
    write(tmp_path / "arm.urdf", arm_urdf())
    write(tmp_path / "arm.yaml", PROFILE)
    write(tmp_path / "broken.yaml", PROFILE.replace("point: {x: 30,", "point: {x: thirty,"))
    path = write(tmp_path / "desk.yaml", text)
    with pytest.raises(InputError) as err:
        load_desk_config(path)
    assert words in str(err.value) and str(tmp_path) in str(err.value), err.value  # the file, and the field
    assert calib(["serve", "--desk", str(path), "--data-dir", str(tmp_path / "data"), "--port", "1"]) == 2
    lines = capsys.readouterr().err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("calib serve: error: ") and words in lines[0], lines
    assert not (tmp_path / "data").exists()  # nothing started


def test_a_desk_configuration_takes_profile_files_relative_to_itself(tmp_path: Path) -> None:
    (tmp_path / "robots").mkdir()
    write(tmp_path / "robots" / "arm.urdf", arm_urdf())
    write(tmp_path / "robots" / "arm.yaml", PROFILE)
    config = load_desk_config(
        write(
            tmp_path / "desk.yaml",
            NAOS.replace("connected:", "  - {name: arm, profile: robots/arm.yaml, driver: null}\nconnected:"),
        )
    )
    assert isinstance(config, DeskConfig) and config.connected == "nao-2"
    assert [(r.name, r.driver and r.driver.options) for r in config.robots] == [
        ("nao-1", {"seed": 1, "day": 1}),
        ("nao-2", {"seed": 2, "day": 1}),
        ("arm", None),
    ]
    assert config.robots[2].profile == str(tmp_path / "robots" / "arm.yaml")


# --- two robots of one profile ------------------------------------------------------------------------
@pytest.fixture(scope="module")
def naos(tmp_path_factory: pytest.TempPathFactory) -> Iterator[tuple[Path, DeskConfig]]:
    root = tmp_path_factory.mktemp("naos")
    yield root / "data", load_desk_config(write(root / "desk.yaml", NAOS))


def _import_nao(client: TestClient, robot: str) -> str:
    csv = (SAMPLES / "nao" / "data.csv").read_bytes()
    r = client.post(
        "/api/sessions/import", data={"robot": robot, "name": f"{robot} day 1"}, files={"data": ("nao.csv", csv)}
    )
    assert r.status_code == 201, r.text
    return r.json()["id"]


@pytest.mark.slow
def test_two_robots_of_one_profile_keep_their_own_calibrations(naos: tuple[Path, DeskConfig]) -> None:
    data_dir, config = naos
    with TestClient(create_app(data_dir, config=config, sample_dir=SAMPLES, time_scale=50.0)) as client:
        robots = {r["name"]: r for r in client.get("/api/robots").json()}
        assert set(robots) == {"nao-1", "nao-2"}
        assert client.get("/api/sessions").json() == []  # the samples are of robots not on this desk
        assert all(r["model"] == "nao" and r["drivable"] and r["simulated"] for r in robots.values())
        assert client.get("/api/robot").json()["robot"] == "nao-2"  # the configuration's connected robot
        sessions = {robot: _import_nao(client, robot) for robot in ("nao-1", "nao-2")}
        cals = {}
        for robot, holdout in (("nao-1", 0.0), ("nao-2", 0.3)):
            r = client.post(f"/api/sessions/{sessions[robot]}/calibrations", json={"mode": "full", "holdout": holdout})
            job = wait_job(client, r.json()["job"])
            assert job["state"] == "done", job
            cals[robot] = job["result"]
            assert client.get(f"/api/calibrations/{cals[robot]}").json()["robot"] == robot
        for robot in ("nao-1", "nao-2"):
            r = client.post(f"/api/calibrations/{cals[robot]}/apply", json={"confirm": True})
            assert r.json() == {"active": cals[robot], "previous": None, "robot": robot, "recorded": True}
        # A calibration belongs to its robot: another robot of the same profile neither starts from it nor
        # reviews with it (and no request applies it to another robot: apply names the calibration only).
        r = client.post(f"/api/sessions/{sessions['nao-2']}/calibrations", json={"mode": "full", "base": cals["nao-1"]})
        assert r.status_code == 422 and "is for robot 'nao-1', not 'nao-2'" in r.json()["detail"]
        r = client.post("/api/review", json={"session": sessions["nao-2"], "new": cals["nao-1"]})
        assert r.status_code == 422 and "is for robot nao-1, not nao-2" in r.json()["detail"]
        again = client.post(f"/api/calibrations/{cals['nao-1']}/apply", json={"note": "again"}).json()
        assert again["recorded"] is False  # already nao-1's active one: pushed again, its history unchanged
        _check_separate(client, cals)
    # After a restart: the same robots, each with its own active calibration, given to its own driver.
    with TestClient(create_app(data_dir, config=config, sample_dir=None, time_scale=50.0)) as client:
        _check_separate(client, cals)


def _check_separate(client: TestClient, cals: dict[str, str]) -> None:
    for robot, cal in cals.items():
        assert client.get("/api/robot/calibration", params={"robot": robot}).json()["id"] == cal
        assert client.get("/api/robot", params={"robot": robot}).json()["calibration"] == cal
    history = {robot: client.get("/api/robot/history", params={"robot": robot}).json() for robot in cals}
    assert [h["calibration"] for h in history["nao-1"]] == [cals["nao-1"]]
    assert [h["calibration"] for h in history["nao-2"]] == [cals["nao-2"]]


# --- robots added to the running desk -------------------------------------------------------------------
@pytest.fixture
def desk_dir(tmp_path: Path) -> Path:
    return tmp_path / "data"


def _add(client: TestClient, **form: str | tuple[str, bytes]) -> object:
    files = {k: v for k, v in form.items() if isinstance(v, tuple)}
    data = {k: v for k, v in form.items() if isinstance(v, str)}
    return client.post("/api/robots", data=data, files=files or None)


@pytest.mark.slow
def test_robots_added_while_the_desk_runs_stay_after_a_restart(desk_dir: Path, tmp_path: Path) -> None:
    robonaut_yaml = (PROFILE_DIR / "robonaut-a.yaml").read_bytes()
    with TestClient(create_app(desk_dir, sample_dir=None, time_scale=50.0)) as client:
        # A profile file uploaded, with a driver: an instance named as asked, its model named by the file.
        r = _add(client, name="robonaut-b", profile_file=("robonaut-a.yaml", robonaut_yaml), driver="simulated")
        assert r.status_code == 201, r.text
        added = r.json()
        assert (added["name"], added["model"], added["drivable"], added["simulated"]) == (
            "robonaut-b",
            "robonaut-a",
            True,
            True,
        )
        assert (desk_dir / "robots" / "robonaut-b" / "robonaut-a.yaml").read_bytes() == robonaut_yaml
        assert client.get("/api/robot", params={"robot": "robonaut-b"}).json()["robot"] == "robonaut-b"
        # A profile that says `urdf: arm.urdf`, with its URDF: real data only (no driver asked for).
        r = _add(
            client,
            name="arm",
            profile_file=("arm.yaml", PROFILE.encode()),
            urdf_file=("arm.urdf", arm_urdf().encode()),
        )
        assert r.status_code == 201, r.text
        arm = r.json()
        assert (arm["model"], arm["drivable"], arm["driver"]) == ("test-arm", False, None)
        assert [j["name"] for j in arm["joints"]] == [*JOINTS, "finger_joint"]
        assert arm["joints"][-1]["type"] == "prismatic" and arm["notes"] == []
        # A built-in profile by name: one more NAO, simulated.
        r = _add(client, name="nao-3", profile="nao", driver="simulated")
        assert r.status_code == 201 and r.json()["model"] == "nao", r.text
        # A profile file on this machine (the desk is bound to loopback), its URDF copied with it.
        write(tmp_path / "arm.urdf", arm_urdf())
        r = _add(client, name="arm-2", profile=str(write(tmp_path / "arm.yaml", PROFILE)))
        assert r.status_code == 201, r.text
        assert (desk_dir / "robots" / "arm-2" / "arm.urdf").read_text() == arm_urdf()
        names = [r["name"] for r in client.get("/api/robots").json()]
        assert names == ["robonaut-a", "nao", "motoman", "arm-handeye", "robonaut-b", "arm", "nao-3", "arm-2"]
    with TestClient(create_app(desk_dir, sample_dir=None, time_scale=50.0)) as client:
        robots = {r["name"]: r for r in client.get("/api/robots").json()}
        assert list(robots) == names
        assert robots["robonaut-b"]["drivable"] and robots["nao-3"]["simulated"] and not robots["arm"]["drivable"]
        assert client.get("/api/robot", params={"robot": "nao-3"}).json()["connected"] is True


BROKEN = [
    (
        {"profile_file": ("arm.yaml", PROFILE.replace("x: 30", "x: thirty").encode()), "urdf_file": ("arm.urdf", b"")},
        ["arm.yaml", "targets[0].point.x"],
    ),
    ({"profile_file": ("arm.yaml", PROFILE.encode())}, ["arm.yaml", "urdf: arm.urdf is not given with the profile"]),
    (
        {"profile_file": ("arm.yaml", PROFILE.encode()), "urdf_file": ("arm.urdf", b"<robot name='x'><link")},
        ["arm.urdf"],
    ),
    (
        {"profile_file": ("arm.yaml", PROFILE.encode()), "urdf_file": ("a.urdf", b"x"), "driver": "simulated"},
        ["a.urdf"],
    ),
    (
        {"profile_file": ("arm.yaml", PROFILE.encode()), "urdf_file": ("arm.urdf", b""), "driver": "simulated"},
        ["driver: broken cannot be simulated"],
    ),
    ({"profile_file": ("p.yaml", b"name: [unclosed")}, ["p.yaml", "not valid YAML"]),
    ({"profile_file": ("arm.yaml", PROFILE.encode()), "urdf_file": ("arm.yaml", b"")}, ["both named arm.yaml"]),
    ({"profile": "nao", "driver": "ros3"}, ["driver: unknown driver kind 'ros3' (known: simulated, ros2, naoqi)"]),
    (
        {"profile": "nao", "driver": "simulated", "driver_options": '{"seed": -1}'},
        ["driver_options.seed: expected a whole number from 0, got -1"],
    ),
    (
        {"profile": "nao", "driver": "simulated", "driver_options": '{"speed": 2}'},
        ["driver_options.speed: no such option of the simulated driver (options: seed, day)"],
    ),
    (
        {"profile": "nao", "driver": "simulated", "driver_options": "seed=2"},
        ["driver_options: not valid JSON (Expecting value at character 0)"],
    ),
    ({"profile": "nao", "driver": "simulated", "driver_options": "[2]"}, ["driver_options: expected a JSON object"]),
    ({"profile": "nao", "driver_options": '{"seed": 2}'}, ["driver_options: options of which driver?"]),
    ({"profile": "r2d2"}, ["r2d2", "does not exist"]),
    ({}, ["give the robot's profile"]),
]


@pytest.mark.slow
@pytest.mark.parametrize(("form", "words"), BROKEN)
def test_a_broken_profile_answers_422_naming_file_and_field_and_changes_nothing(
    desk_dir: Path, form: dict, words: list[str]
) -> None:
    form = {**form}
    for key, value in form.items():  # an empty URDF stands for the real one
        if key == "urdf_file" and value[1] == b"":
            form[key] = (value[0], arm_urdf().encode())
    with TestClient(create_app(desk_dir, sample_dir=None, time_scale=50.0)) as client:
        before = client.get("/api/robots").json()
        store = client.app.state.desk.store
        rows = store.robots.list()
        r = _add(client, name="broken", **form)
        assert r.status_code == 422, r.text
        detail = r.json()["detail"]
        assert all(w in detail for w in words), detail
        assert str(desk_dir) not in detail  # a file is named by its name only
        assert client.get("/api/robots").json() == before
        assert store.robots.list() == rows
        assert not (desk_dir / "robots").is_dir() or list((desk_dir / "robots").iterdir()) == []


@pytest.mark.slow
def test_a_robot_added_with_driver_options_keeps_them_after_a_restart(desk_dir: Path) -> None:
    """`driver_options` (JSON) reach the kind's own checks and its driver, are kept with the robot, and make the
    same driver after a restart: the simulated NAO of seed 2 on its third day, not the default seed 1 day 1."""
    nao = load_profile("nao")
    truth = SimulatedRobot.from_profile(nao, seed=2).on_day(3).true_params
    assert not np.array_equal(truth, SimulatedRobot.from_profile(nao, seed=1).true_params)
    for restart in (False, True):
        with TestClient(create_app(desk_dir, sample_dir=None, time_scale=50.0)) as client:
            if not restart:
                form = {
                    "name": "nao-7",
                    "profile": "nao",
                    "driver": "simulated",
                    "driver_options": '{"seed": 2, "day": 3}',
                }
                r = client.post("/api/robots", data=form)
                assert r.status_code == 201, r.text
                assert (r.json()["driver"], r.json()["simulated"]) == ("simulated", True)
            driver = client.app.state.desk.robots.driver("nao-7")
            assert isinstance(driver, SimulatedDriver)
            np.testing.assert_array_equal(driver.true_params(), truth)
            record = client.app.state.desk.store.robots.get("nao-7")
            assert (record.driver, record.options, record.origin) == ("simulated", {"seed": 2, "day": 3}, "api")


def test_a_robot_is_removed_with_its_driver_closed_unless_data_name_it(desk_dir: Path) -> None:
    with TestClient(create_app(desk_dir, sample_dir=None, time_scale=50.0)) as client:
        for name in ("nao-3", "nao-4"):
            assert _add(client, name=name, profile="nao", driver="simulated").status_code == 201
        driver = client.app.state.desk.robots.driver("nao-3")
        assert client.post("/api/robot/connect", json={"robot": "nao-3"}).status_code == 200
        r = client.delete("/api/robots/nao-3")
        assert r.status_code == 200 and r.json() == {"deleted": "nao-3"}
        assert not driver.status().connected  # closed
        assert "nao-3" not in [r["name"] for r in client.get("/api/robots").json()]
        assert client.get("/api/robot").json()["robot"] != "nao-3"  # another robot is connected
        assert not (desk_dir / "robots" / "nao-3").exists()
        # A robot with a session stays (its data name it); one from the configuration too; unknown: 404.
        assert client.post("/api/sessions", json={"robot": "nao-4", "name": "kept"}).status_code == 201
        r = client.delete("/api/robots/nao-4")
        assert r.status_code == 422 and "has sessions or calibrations" in r.json()["detail"]
        r = client.delete("/api/robots/nao")
        assert r.status_code == 422 and "desk's configuration" in r.json()["detail"]
        assert client.delete("/api/robots/nao-9").status_code == 404
        # A name taken, or one a stored session still names, is refused.
        r = _add(client, name="nao-4", profile="nao")
        assert r.status_code == 422 and "exists already" in r.json()["detail"]


def test_a_profile_file_on_the_server_is_named_only_on_a_loopback_desk(
    desk_dir: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    path = PROFILE_DIR / "robonaut-a.yaml"
    with TestClient(create_app(desk_dir, sample_dir=None, time_scale=50.0)) as client:
        monkeypatch.setattr(client.app.state.desk.robot_service, "loopback", False)
        r = _add(client, name="far", profile=str(path))
        assert r.status_code == 403 and "upload it" in r.json()["detail"]
        r = _add(client, name="near", profile="nao")  # a built-in profile by name is fine anywhere
        assert r.status_code == 201, r.text
