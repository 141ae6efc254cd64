"""The desk's front door for hand-eye: images and reported flange poses imported as a robot known by its flange pose
and a session of it (POST /api/sessions/import-handeye), then calibrated, reviewed with numbers and applied as any
robot; bad input named and nothing written."""

from __future__ import annotations

import io
import zipfile
from pathlib import Path

import numpy as np
import pytest
from desk_jobs import wait_job
from fastapi.testclient import TestClient

VISP = Path(__file__).resolve().parents[1] / "sample_sessions" / "handeye-visp"


def _files(images: list[Path] | None = None, *, poses: bytes | None = None, zipped: bool = False) -> list[tuple]:
    images = images if images is not None else sorted((VISP / "images").iterdir())
    out = [
        ("poses", ("poses.csv", poses if poses is not None else (VISP / "poses.csv").read_bytes(), "text/csv")),
        ("camera", ("camera.yaml", (VISP / "camera.yaml").read_bytes(), "application/x-yaml")),
    ]
    if zipped:
        buffer = io.BytesIO()
        with zipfile.ZipFile(buffer, "w") as zf:
            for p in images:
                zf.write(p, f"visp/images/{p.name}")
        return [*out, ("images", ("images.zip", buffer.getvalue(), "application/zip"))]
    return out + [("images", (p.name, p.read_bytes(), "image/png")) for p in images]


def _form(robot: str = "visp-arm", **extra: str) -> dict[str, str]:
    board = (VISP / "board.txt").read_text().strip()
    return {"robot": robot, "name": "ViSP's tutorial", "board": board, "setup": "eye-in-hand"} | extra


def _state(client: TestClient) -> tuple[list[str], list[str]]:
    robots = sorted(r["name"] for r in client.get("/api/robots").json())
    sessions = sorted(s["id"] for s in client.get("/api/sessions").json())
    return robots, sessions


def test_images_and_poses_become_a_robot_and_a_session_that_calibrates_reviews_and_applies(client) -> None:
    r = client.post("/api/sessions/import-handeye", data=_form(), files=_files())
    assert r.status_code == 201, r.text
    out = r.json()
    assert out["robot"] == "visp-arm" and out["added"] and out["notes"] == []
    robot = next(x for x in client.get("/api/robots").json() if x["name"] == "visp-arm")
    assert [m["name"] for m in robot["modes"]] == ["auto", "handeye", "handeye-lens"]
    session = client.get(f"/api/sessions/{out['id']}").json()
    assert session["robot"] == "visp-arm" and len(session["frames"]) == 8 and session["measured"] == 8
    job = client.post(f"/api/sessions/{out['id']}/calibrations", json={"mode": "handeye"}).json()["job"]
    done = wait_job(client, job)
    assert done["state"] == "done", done
    cal = client.get(f"/api/calibrations/{done['result']}").json()
    camera = {p["name"]: p for p in cal["parameters"] if p["name"].startswith("camera_mount.")}
    # ViSP's camera on the flange, as `calib handeye` finds it (-32.5, -57.6, 30.8) +/- 0.3 mm
    for axis, mm in zip("xyz", (-32.5, -57.6, 30.8), strict=True):
        assert abs(camera[f"camera_mount.{axis}"]["value"] - mm) < 1.0
        assert 0.05 < camera[f"camera_mount.{axis}"]["std"] < 1.0
    assert not [d for d in cal["diagnostics"] if d["severity"] == "warning"], cal["diagnostics"]
    table = client.post("/api/review/table", json={"session": out["id"], "old": None, "new": done["result"]}).json()
    errors = [f["err_new"] for f in table["table"]]
    assert len(errors) == 8 and all(e is not None and 0 < e < 3 for e in errors), errors
    assert table["summary"]["measured"] == 8
    applied = client.post(f"/api/calibrations/{done['result']}/apply")
    assert applied.status_code == 200 and applied.json()["active"] == done["result"], applied.text
    active = client.get("/api/robot/calibration", params={"robot": "visp-arm"}).json()
    assert active["id"] == done["result"] and active["mode"] == "handeye"


def test_a_zip_of_the_images_is_another_session_of_the_same_robot(client) -> None:
    before = client.post("/api/sessions/import-handeye", data=_form("visp-zip"), files=_files()).json()
    r = client.post("/api/sessions/import-handeye", data=_form("visp-zip"), files=_files(zipped=True))
    assert r.status_code == 201, r.text
    assert not r.json()["added"] and r.json()["id"] != before["id"]
    a = client.get(f"/api/sessions/{before['id']}").json()["frames"]
    b = client.get(f"/api/sessions/{r.json()['id']}").json()["frames"]
    joints = [[f["joints_deg"] if "joints_deg" in f else f["joints"] for f in s] for s in (a, b)]
    assert joints[0] == joints[1]  # the same readings against the robot's own reference


@pytest.mark.parametrize(
    ("form", "poses", "field"),
    [
        ({"board": "chessboard:9x6"}, None, "board"),
        ({}, b"image,x,y,z,rx,ry\n1.png,0,0,0,0,0\n", "poses.csv"),
        ({"board": "chessboard:11x8:26.2"}, None, "found in 0 of 8"),
        ({"setup": "eye-on-knee"}, None, "setup"),
    ],
)
def test_bad_input_is_named_and_changes_nothing(client, form: dict, poses: bytes | None, field: str) -> None:
    before = _state(client)
    r = client.post("/api/sessions/import-handeye", data=_form("visp-bad", **form), files=_files(poses=poses))
    assert r.status_code == 422, r.text
    assert field in r.text
    assert _state(client) == before


def test_an_image_that_is_not_one_is_named(client, tmp_path: Path) -> None:
    bad = tmp_path / "3.png"
    bad.write_bytes(b"not a png")
    images = [p for p in sorted((VISP / "images").iterdir()) if p.name != "3.png"] + [bad]
    before = _state(client)
    r = client.post("/api/sessions/import-handeye", data=_form("visp-bad-image"), files=_files(images))
    assert r.status_code == 422 and "3.png" in r.text and "not an image" in r.text, r.text
    assert _state(client) == before


def test_the_review_has_both_sides_numbers_the_old_through_poses_registered_on_the_frames(client) -> None:
    """The nominal model of a robot known by its flange pose places neither camera nor board (zero poses): the
    review's old side predicts through the camera's and board's poses registered on the session's frames (the
    reported poses taken as exact), the new side through the calibration; every frame has both errors."""
    out = client.post("/api/sessions/import-handeye", data=_form("visp-review"), files=_files()).json()
    job = client.post(f"/api/sessions/{out['id']}/calibrations", json={"mode": "handeye"}).json()["job"]
    done = wait_job(client, job)
    table = client.post("/api/review/table", json={"session": out["id"], "old": None, "new": done["result"]}).json()
    both = np.array([[f["err_old"], f["err_new"]] for f in table["table"]], float)
    assert both.shape == (8, 2) and np.isfinite(both).all() and both.max() < 3


def test_its_camera_exports_where_calib_handeye_s_goes(client) -> None:
    """No number copied by hand: the desk's calibration of a flange-pose robot exports in calib handeye's form (the
    camera and the board where `calib handeye` puts them on the same images, the board in the detector's frame) and
    as the ROS 2 launch file, URDF joint and easy_handeye YAML; another robot's calibration refuses those forms."""
    from calib_core.estimation import calibrate_flange, find_views
    from calib_core.io import parse_board, read_camera, read_flange_poses

    out = client.post("/api/sessions/import-handeye", data=_form("visp-export"), files=_files()).json()
    job = client.post(f"/api/sessions/{out['id']}/calibrations", json={"mode": "handeye"}).json()["job"]
    cal_id = wait_job(client, job)["result"]
    form = client.get(f"/api/calibrations/{cal_id}/export", params={"format": "handeye"}).json()
    import cv2

    names = sorted(p.name for p in (VISP / "images").iterdir())
    board = parse_board((VISP / "board.txt").read_text().strip())
    camera = read_camera(VISP / "camera.yaml")
    grey = {n: cv2.imread(str(VISP / "images" / n), cv2.IMREAD_GRAYSCALE) for n in names}
    views = find_views(grey, board, camera)
    ref = calibrate_flange(views, read_flange_poses(VISP / "poses.csv", names), camera, board, "eye-in-hand")
    ref = ref.to_json()
    assert form["setup"] == "eye-in-hand"
    for key in ("camera_in_flange", "board_in_base"):
        assert np.allclose(form[key]["matrix"], ref[key]["matrix"], atol=0.05), key  # mm, and rotations
        assert all(0 < v < 2 for v in form[key]["std"].values()), form[key]["std"]
    launch = client.get(
        f"/api/calibrations/{cal_id}/export", params={"format": "ros2-static-tf", "parent": "panda_hand"}
    )
    assert launch.status_code == 200 and "static_transform_publisher" in launch.text and "panda_hand" in launch.text
    x_m = form["camera_in_flange"]["matrix"][0][3] / 1000
    assert f"{x_m:.6f}"[:8] in launch.text.replace("'", "")
    for fmt in ("urdf-joint", "easy-handeye"):
        assert client.get(f"/api/calibrations/{cal_id}/export", params={"format": fmt}).status_code == 200
    job = client.post("/api/sessions/robonaut-a-day1/calibrations", json={"mode": "daily"}).json()["job"]
    other = wait_job(client, job)["result"]
    refused = client.get(f"/api/calibrations/{other}/export", params={"format": "ros2-static-tf"})
    assert refused.status_code == 422 and "flange pose" in refused.json()["detail"]


def test_images_of_more_than_a_megabyte_together_are_taken(client) -> None:
    """A request's body is capped at 1 MB unless it is an upload: the images of a session are one (ViSP's 8 are
    1.0 MB; a day's images of a camera are megabytes each). Here 16, twice the 8 (the copies without a pose are
    left out, each named)."""
    copies = [("images", (f"copy-{p.name}", p.read_bytes(), "image/png")) for p in sorted((VISP / "images").iterdir())]
    files = _files() + copies
    assert sum(len(f[1][1]) for f in files) > 1.9 * 2**20
    r = client.post("/api/sessions/import-handeye", data=_form("visp-big"), files=files)
    assert r.status_code == 201, r.text
    assert r.json()["notes"] == [f"copy-{k}.png: no pose for it; left out" for k in range(1, 9)]
    assert client.get(f"/api/sessions/{r.json()['id']}").json()["measured"] == 8
