"""A robot added through the API with its URDF's meshes (`meshes_zip`, app/store/meshes.py): unpacked beside its
profile in the data directory, found by the review as a URDF on disk finds its meshes (package:// and relative
paths), kept after a restart; a zip that escapes its folder, holds a link or a file that is no mesh, is corrupt
or too large is refused naming the problem (422, 413), and nothing changes."""

from __future__ import annotations

import io
import os
import shutil
import stat
import zipfile
from pathlib import Path

import pytest
import trimesh
from browser import desk_served, ready_page
from fastapi.testclient import TestClient
from PIL import Image
from test_robot_look import meshed_arm
from test_urdf_import import PROFILE, arm_urdf

from app.scene.robot_look import read_look, robot_look
from app.store.robots import PACKAGE_ROOT
from app.web.limits import Limits
from app.web.server import create_app
from calib_core import SimulatedRobot, load_profile, to_csv

DRAWN = {"box", "cylinder", "mesh package://meshed_arm/meshes/upper.stl", "mesh ../meshes/fore.obj"}
LIMITS = Limits(upload_bytes=256 * 1024)  # 2 MB unpacked at most


def zipped(entries: dict[str, bytes], *, links: tuple[str, ...] = ()) -> bytes:
    """A zip of `entries` (path -> bytes), `links` as symbolic links (their bytes the target)."""
    buf = io.BytesIO()
    with zipfile.ZipFile(buf, "w", zipfile.ZIP_DEFLATED) as zf:
        for path, data in entries.items():
            info = zipfile.ZipInfo(path)
            info.compress_type = zipfile.ZIP_DEFLATED
            info.external_attr = ((stat.S_IFLNK | 0o777) if path in links else (stat.S_IFREG | 0o644)) << 16
            zf.writestr(info, data)
    return buf.getvalue()


def package_meshes(root: Path) -> dict[str, bytes]:
    """The description package's meshes/ folder as zip entries, relative to the package's root."""
    return {f"meshes/{f.name}": f.read_bytes() for f in sorted((root / "meshes").iterdir())}


def add(client: TestClient, name: str, files: dict[str, tuple[str, bytes]], **data: str):
    return client.post("/api/robots", data={"name": name, **data}, files=files)


def _review_warnings(client: TestClient, robot: str, profile: Path) -> list[str]:
    """The warnings of the review of a session of `robot` (simulated from `profile`, imported)."""
    model = load_profile(profile)
    csv = to_csv(model, SimulatedRobot.from_profile(model, seed=1).simulate(4).data)
    r = client.post("/api/sessions/import", data={"robot": robot, "name": "d1"}, files={"data": ("a.csv", csv)})
    assert r.status_code == 201, r.text
    review = client.post("/api/review", json={"session": r.json()["id"], "old": None})
    assert review.status_code == 200, review.text
    return review.json()["warnings"]


def kept_files(folder: Path) -> list[str]:
    return sorted(str(p.relative_to(folder)) for p in folder.rglob("*") if p.is_file())


def drawn_whole(client: TestClient, robot: str) -> None:
    """The robot's look draws every visual of meshed_arm's URDF, with no warning."""
    look = robot_look(client.app.state.desk.robots.get(robot).profile)
    assert look is not None and look.warning is None and {v.what for v in look.visuals} == DRAWN
    assert look.links == {"base_link", "shoulder", "upper", "fore", "tool0"}


def test_meshes_uploaded_with_the_urdf_are_drawn_and_kept_after_a_restart(tmp_path: Path) -> None:
    profile = meshed_arm(tmp_path)  # meshed_arm/{arm.yaml, urdf/arm.urdf, meshes/{upper.stl, fore.obj}}
    root = profile.parent
    data_dir = tmp_path / "data"
    files = {
        "profile_file": ("arm.yaml", profile.read_bytes()),
        "urdf_file": ("arm.urdf", (root / "urdf" / "arm.urdf").read_bytes()),
        # A macOS Finder zip: its __MACOSX/ resource forks and .DS_Store are left out, not refused.
        "meshes_zip": (
            "meshes.zip",
            zipped({**package_meshes(root), "__MACOSX/meshes/._upper.stl": b"\0", ".DS_Store": b""}),
        ),
    }
    with TestClient(create_app(data_dir, sample_dir=None)) as client:
        r = add(client, "meshed", files)
        assert r.status_code == 201, r.text
        kept = data_dir / "robots" / "meshed"
        # The URDF where the profile's `urdf: urdf/arm.urdf` puts it, the meshes beside the profile.
        assert kept_files(kept) == [
            PACKAGE_ROOT,
            "arm.yaml",
            "meshes/fore.obj",
            "meshes/upper.stl",
            "urdf/arm.urdf",
        ]
        assert (kept / "meshes" / "upper.stl").read_bytes() == (root / "meshes" / "upper.stl").read_bytes()
        drawn_whole(client, "meshed")
        # The review of a session of it answers no warning: every link drawn with its own visuals.
        assert _review_warnings(client, "meshed", kept / "arm.yaml") == []
    with TestClient(create_app(data_dir, sample_dir=None)) as client:
        drawn_whole(client, "meshed")


def test_uploaded_meshes_are_looked_for_in_their_folder_only(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """Kept with its meshes (PACKAGE_ROOT in its folder), a URDF takes them from there: not an installed package
    of the same name (ROS_PACKAGE_PATH), and nothing a path leading out of the folder finds."""
    root = meshed_arm(tmp_path / "kept").parent
    installed = tmp_path / "ros" / "meshed_arm" / "meshes"
    installed.mkdir(parents=True)
    trimesh.creation.box(extents=(1, 1, 1)).export(installed / "upper.stl")  # 8 vertices; the kept one 34
    monkeypatch.setenv("ROS_PACKAGE_PATH", str(tmp_path / "ros"))
    urdf = root / "urdf" / "arm.urdf"
    upper = {v.link: len(v.vertices) for v in read_look(urdf).visuals}["upper"]
    assert upper == 8  # a description on disk: ROS finds the installed package first
    (root / PACKAGE_ROOT).write_text("")
    look = read_look(urdf)
    assert {v.link: len(v.vertices) for v in look.visuals}["upper"] == 34 and look.warning is None
    # The folder kept is urdf/ alone: ../meshes/fore.obj leads out of it and package:// looks in it only.
    (root / PACKAGE_ROOT).unlink()
    (root / "urdf" / PACKAGE_ROOT).write_text("")
    look = read_look(urdf)
    assert look.problems == (
        "mesh package://meshed_arm/meshes/upper.stl cannot be found (link 'upper')",
        "mesh ../meshes/fore.obj cannot be found (link 'fore')",
    )


def test_an_uploaded_urdf_reads_no_file_outside_its_folder_even_without_meshes(tmp_path: Path) -> None:
    """An uploaded URDF whose meshes name files elsewhere on the server (an absolute path, `../..`): with no
    meshes zip the desk used to read them and stream them to every viewer. Its folder is its only root now."""
    profile = meshed_arm(tmp_path / "server")  # the meshes exist on the server, outside the data directory
    root = profile.parent
    urdf = (root / "urdf" / "arm.urdf").read_text()
    urdf = urdf.replace("package://meshed_arm/meshes/upper.stl", str(root / "meshes" / "upper.stl"))
    kept = tmp_path / "data" / "robots" / "prying" / "urdf"  # where the desk keeps the URDF (`urdf: urdf/arm.urdf`)
    out = os.path.relpath(root / "meshes" / "fore.obj", kept)  # ../../../../server/meshed_arm/meshes/fore.obj
    urdf = urdf.replace("../meshes/fore.obj", out)
    files = {"profile_file": ("arm.yaml", profile.read_bytes()), "urdf_file": ("arm.urdf", urdf.encode())}
    with TestClient(create_app(tmp_path / "data", sample_dir=None)) as client:
        assert add(client, "prying", files).status_code == 201
        look = robot_look(client.app.state.desk.robots.get("prying").profile)
    assert look is not None and look.problems == (
        f"mesh {root / 'meshes' / 'upper.stl'} cannot be found (link 'upper')",
        f"mesh {out} cannot be found (link 'fore')",
    )
    assert {v.what for v in look.visuals} == {"box", "cylinder"}


def test_a_zip_written_by_pythons_writestr_is_taken(tmp_path: Path) -> None:
    """zipfile.writestr(name, data) records permissions without a file type: a regular file all the same."""
    profile = meshed_arm(tmp_path)
    root = profile.parent
    buf = io.BytesIO()
    with zipfile.ZipFile(buf, "w") as zf:
        for path, data in package_meshes(root).items():
            zf.writestr(path, data)
    files = {
        "profile_file": ("arm.yaml", profile.read_bytes()),
        "urdf_file": ("arm.urdf", (root / "urdf" / "arm.urdf").read_bytes()),
        "meshes_zip": ("meshes.zip", buf.getvalue()),
    }
    with TestClient(create_app(tmp_path / "data", sample_dir=None)) as client:
        r = add(client, "written", files)
        assert r.status_code == 201, r.text
        drawn_whole(client, "written")


def test_a_profile_file_named_brings_its_urdfs_meshes_and_needs_its_folder_no_more(tmp_path: Path) -> None:
    """A profile file on this machine named on a loopback desk: the meshes its URDF's visuals name are kept with
    it (app/robots/profile_meshes.py), each where the kept URDF's name finds it, an OBJ's material and its texture
    beside it, nothing else of the folder; drawn with no warning, after a restart and with the original folder
    moved away, then deleted, too."""
    profile = meshed_arm(tmp_path / "disk")
    root = profile.parent
    fore = root / "meshes" / "fore.obj"
    fore.write_text("mtllib fore.mtl\nusemtl steel\n" + fore.read_text())
    (root / "meshes" / "fore.mtl").write_text("newmtl steel\nKd 0.2 0.4 0.6\nmap_Kd -s 1 1 1 tex/steel.png\n")
    (root / "meshes" / "tex").mkdir()
    Image.new("RGB", (4, 4), (50, 100, 150)).save(root / "meshes" / "tex" / "steel.png")
    (root / "meshes" / "unused.stl").write_bytes(STL)
    data_dir = tmp_path / "data"
    with TestClient(create_app(data_dir, sample_dir=None)) as client:
        r = add(client, "meshed", {}, profile=str(profile))
        assert r.status_code == 201, r.text
        kept = data_dir / "robots" / "meshed"
        gathered = ["meshes/fore.mtl", "meshes/fore.obj", "meshes/tex/steel.png", "meshes/upper.stl"]  # no unused.stl
        assert kept_files(kept) == [PACKAGE_ROOT, "arm.yaml", *gathered, "urdf/arm.urdf"]
        assert (kept / "meshes" / "tex" / "steel.png").read_bytes() == (
            root / "meshes" / "tex" / "steel.png"
        ).read_bytes()
        drawn_whole(client, "meshed")
        assert _review_warnings(client, "meshed", profile) == []
    moved = shutil.move(root, tmp_path / "elsewhere")
    with TestClient(create_app(data_dir, sample_dir=None)) as client:
        drawn_whole(client, "meshed")
        shutil.rmtree(moved)
        look = read_look(kept / "urdf" / "arm.urdf")  # read again, not the look kept in memory
        assert look.warning is None and {v.what for v in look.visuals} == DRAWN
        (session,) = [x["id"] for x in client.get("/api/sessions").json() if x["robot"] == "meshed"]
        review = client.post("/api/review", json={"session": session, "old": None})
        assert review.status_code == 200 and review.json()["warnings"] == [], review.text


def test_a_mesh_of_a_named_profile_file_that_is_not_there_leaves_the_robot_added_with_a_warning(
    tmp_path: Path,
) -> None:
    profile = meshed_arm(tmp_path)
    (profile.parent / "meshes" / "fore.obj").unlink()
    with TestClient(create_app(tmp_path / "data", sample_dir=None)) as client:
        r = add(client, "meshed", {}, profile=str(profile))
        assert r.status_code == 201, r.text
        look = robot_look(client.app.state.desk.robots.get("meshed").profile)
        assert look is not None and look.problems == ("mesh ../meshes/fore.obj cannot be found (link 'fore')",)
        assert look.links == {"base_link", "shoulder", "upper", "tool0"}  # the upper arm's STL found, kept and drawn
        assert _review_warnings(client, "meshed", profile) == [look.warning]


def test_a_named_profile_files_meshes_too_large_together_are_refused_413(client: TestClient, tmp_path: Path) -> None:
    data_dir = client.app.state.desk.data_dir
    profile = meshed_arm(tmp_path)
    (profile.parent / "meshes" / "upper.stl").write_bytes(bytes(3 * 2**20))  # the desk takes 2 MB of meshes
    before = client.get("/api/robots").json()
    r = add(client, "arm-big", {}, profile=str(profile))
    assert r.status_code == 413, r.text
    # As every error the desk answers, it names no path of the server: the URDF by its file name.
    assert (
        r.json()["detail"]
        == "the meshes of arm.urdf: larger than 2 MB unpacked (the desk's limit for a robot's meshes)"
    )
    assert client.get("/api/robots").json() == before
    assert not (data_dir / "robots").is_dir() or list((data_dir / "robots").iterdir()) == []


@pytest.fixture(scope="module")
def desk_options() -> dict:
    return {"sample_dir": None, "limits": LIMITS}


STL = b"solid x\nendsolid x\n"
ARM = {"profile_file": ("arm.yaml", PROFILE.encode()), "urdf_file": ("arm.urdf", arm_urdf().encode())}
BAD = {
    "outside the folder": (ARM, zipped({"../meshes/base.stl": STL}), 422, "../meshes/base.stl reaches outside"),
    "a hidden way out": (ARM, zipped({"meshes/../../base.stl": STL}), 422, "reaches outside the package's folder"),
    "an absolute path": (ARM, zipped({"/etc/base.stl": STL}), 422, "/etc/base.stl is an absolute path"),
    "a drive": (ARM, zipped({"C:\\meshes\\base.stl": STL}), 422, "is an absolute path"),
    "a symbolic link": (
        ARM,
        zipped({"meshes/base.stl": b"/etc/passwd"}, links=("meshes/base.stl",)),
        422,
        "meshes/base.stl is a symbolic link",
    ),
    "not a mesh": (
        ARM,
        zipped({"meshes/base.stl": STL, "launch/arm.py": b"x"}),
        422,
        "launch/arm.py is not a mesh file",
    ),
    "not a zip": (ARM, b"PK\x03\x04 this is not a zip", 422, "m.zip: not a readable zip"),
    "a corrupt entry": (ARM, "crc", 422, "m.zip: cannot be unpacked (Bad CRC-32"),
    "a size that lies": (ARM, "size", 422, "m.zip: cannot be unpacked (Bad CRC-32"),
    "no mesh": (ARM, zipped({"meshes/": b""}), 422, "m.zip: holds no mesh file"),
    "twice": (ARM, zipped({"meshes/a.stl": STL, "meshes//a.stl": STL}), 422, "meshes//a.stl is in the zip twice"),
    "a zip bomb": (ARM, zipped({"meshes/big.stl": bytes(3 * 2**20)}), 413, "larger than 2 MB unpacked"),
    "too large": (ARM, b"PK" + bytes(300 * 1024), 413, "larger than"),
    "too many files": (ARM, zipped({f"meshes/{k}.stl": b"" for k in range(2001)}), 413, "more than 2000 files"),
    "without a URDF": (
        {"profile_file": ("p.yaml", PROFILE.replace("urdf: arm.urdf\n", "").encode())},
        zipped({"meshes/base.stl": STL}),
        422,
        "meshes go with a URDF",
    ),
    "without a profile": ({}, zipped({"meshes/base.stl": STL}), 422, "meshes go with an uploaded profile"),
}


def _crc_broken() -> bytes:
    """A zip whose directory reads but whose one entry's bytes do not match its CRC."""
    data = bytearray(zipped({"meshes/base.stl": STL * 50}))
    start = data.index(b"meshes/base.stl") + len("meshes/base.stl")  # the local header's name, then the data
    data[start + 2] ^= 0xFF
    return bytes(data)


def _lying_size() -> bytes:
    """A zip bomb whose directory says 100 bytes for an entry of 3 MB (zipfile stops at 100: its CRC fails)."""
    data = bytearray(zipped({"meshes/big.stl": bytes(3 * 2**20)}))
    local = data.index(b"PK\x03\x04")
    central = data.index(b"PK\x01\x02")
    data[local + 22 : local + 26] = (100).to_bytes(4, "little")
    data[central + 24 : central + 28] = (100).to_bytes(4, "little")
    return bytes(data)


@pytest.mark.parametrize("case", list(BAD))
def test_a_bad_meshes_zip_is_refused_naming_the_problem_and_changes_nothing(client: TestClient, case: str) -> None:
    data_dir = client.app.state.desk.data_dir
    form, data, status, words = BAD[case]
    data = {"crc": _crc_broken, "size": _lying_size}[data]() if isinstance(data, str) else data
    before = client.get("/api/robots").json()
    extra = {} if form else {"profile": "nao"}
    r = add(client, "arm-bad", {**form, "meshes_zip": ("m.zip", data)}, **extra)
    assert r.status_code == status, r.text
    assert words in r.json()["detail"], r.json()
    assert str(data_dir) not in r.json()["detail"]
    assert client.get("/api/robots").json() == before
    assert not (data_dir / "robots").is_dir() or list((data_dir / "robots").iterdir()) == []


# The meshes of the browser's scene (viser's client store in the page's iframe): node name -> vertex floats.
MESHES = """() => Object.fromEntries(Object.entries(window.__viserSceneTree.getState())
  .filter(([k, v]) => v.message && v.message.type === 'MeshMessage')
  .map(([k, v]) => [k, v.message.props.vertices.length]))"""


@pytest.mark.browser
@pytest.mark.subprocess
def test_a_robot_added_on_the_page_with_its_meshes_is_drawn_with_them(
    chromium, tmp_path: Path, desk_data: Path
) -> None:
    """The page's "Add a robot" with a profile, its URDF and a zip of its meshes; a session imported for it:
    the review's scene in the browser holds the STL mesh (its own vertices, not a stand-in) and no warning."""
    profile = meshed_arm(tmp_path)
    root = profile.parent
    meshes = tmp_path / "meshes.zip"
    meshes.write_bytes(zipped(package_meshes(root)))
    model = load_profile(profile)
    csv = tmp_path / "day1.csv"
    csv.write_bytes(to_csv(model, SimulatedRobot.from_profile(model, seed=2).simulate(4).data).encode())
    upper = trimesh.load(root / "meshes" / "upper.stl", force="mesh")
    with desk_served(desk_data) as server:
        page = ready_page(chromium, server.url)
        page.click("#add-robot-toggle")
        page.fill("#add-robot input[name=name]", "meshed")
        page.set_input_files("#add-robot input[name=profile_file]", str(profile))
        page.set_input_files("#add-robot input[name=urdf_file]", str(root / "urdf" / "arm.urdf"))
        page.set_input_files("#add-robot input[name=meshes_zip]", str(meshes))
        page.click("#add-robot button[type=submit]")
        page.wait_for_function("document.querySelector('#robot-select').value === 'meshed'")
        page.click("#new-session-toggle")
        page.set_input_files("#import-session input[name=data]", str(csv))
        page.fill("#import-session input[name=name]", "day 1")
        page.click("#import-session button[type=submit]")
        page.wait_for_selector("#sessions li.selected")
        page.click("#tabs button[data-tab='review']")
        page.wait_for_selector("#frames tr.selected", state="attached")
        frame = next(f for f in page.frames if f != page.main_frame)
        frame.wait_for_function(f"() => Object.keys(({MESHES})()).some(k => k.includes('/upper/'))", timeout=60_000)
        shown = frame.evaluate(MESHES)
        # The upper link's own node holds the STL's 34 vertices (the stand-in cylinder would have 50).
        upper_link = {k: n for k, n in shown.items() if k.split("/")[-2] == "upper"}
        assert list(upper_link.values()) == [3 * len(upper.vertices)], shown
        assert page.text_content("#review-warnings") == ""  # every mesh found: nothing drawn with simple shapes
