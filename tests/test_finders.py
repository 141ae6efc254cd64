"""Finders (calib_core/vision/finders): the registry picks each shipped profile's finder; a ChArUco board rendered
by the simulator is found at sub-pixel accuracy against the simulator's truth, partial views keep their corner
ids, fewer than 6 corners are no measurement; a plain checkerboard on an arm is found; bad board specs are
refused naming the field; a ChArUco drive recorded as a ROS 2 bag imports through the same finder."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest

from calib_core import InputError, Profile, load_profile
from calib_core.frame_status import FrameStatus
from calib_core.io.bag_import import import_bag
from calib_core.io.session import read_session
from calib_core.model.boards import DICTIONARIES
from calib_core.sim.recorded_drive import BagSpec, camera_images, make_drive, write_bag
from calib_core.sim.simulator import SimulatedRobot
from calib_core.vision.finders import finder_for
from calib_core.vision.finders.charuco import CharucoFinder, opencv_board
from calib_core.vision.finders.checkerboard import CheckerboardFinder
from calib_core.vision.finders.sandal import SandalFinder
from calib_core.vision.finders.sphere import SphereFinder
from calib_core.vision.sandal_board import board_corners

PROFILES = Path(__file__).resolve().parent / "profiles"
CHARUCO = PROFILES / "charuco-arm.yaml"
MAX_ERROR_PX = 0.5  # a corner given another corner's id is a square (20 px and more) off


def finders_of(profile) -> dict[tuple[str, str], type | None]:
    return {
        (s.name, t.name): type(finder_for(profile, i, k)) if finder_for(profile, i, k) else None
        for i, s in enumerate(profile.sensors)
        for k, t in enumerate(profile.targets)
    }


def test_the_registry_gives_each_shipped_profile_its_finder() -> None:
    nao = finders_of(load_profile("nao"))
    assert nao == {("lower_camera", "left_board"): SandalFinder, ("lower_camera", "right_board"): SandalFinder}
    assert finders_of(load_profile("robonaut-a")) == {("eye", "fixture"): SphereFinder}
    # The Motoman's tracker reads its reflectors and its cameras their ArUco face centres directly: no finder.
    motoman = finders_of(load_profile("motoman"))
    assert {s for s, _ in motoman} == {"tracker", "camera1", "camera2"} and set(motoman.values()) == {None}
    # Every profile of tests/profiles: a camera over a grid or a ChArUco board, or sensors that read directly.
    camera = {("cam", "board"): CheckerboardFinder}
    expected = {
        "charuco-arm.yaml": {("cam", "board"): CharucoFinder},
        "handeye-charuco.yaml": {("cam", "board"): CharucoFinder},
        "handeye-two-boards.yaml": {("cam", "board"): CharucoFinder, ("cam", "side"): CharucoFinder},
        "handeye-in-hand.yaml": camera,
        "handeye-to-hand.yaml": camera,
        "handeye-intrinsics.yaml": camera,
        "wrist-camera.yaml": camera,
        "iiwa-tracker.yaml": None,
        "probe-arm.yaml": None,
        "tracked-arm.yaml": None,
    }
    assert sorted(expected) == sorted(f.name for f in PROFILES.glob("*.yaml"))
    for name, finders in expected.items():
        found = finders_of(load_profile(PROFILES / name))
        assert found == finders if finders else set(found.values()) == {None}, name


def test_dictionaries_and_corner_layout_are_opencvs() -> None:
    for name, markers in DICTIONARIES.items():
        assert len(cv2.aruco.getPredefinedDictionary(getattr(cv2.aruco, name)).bytesList) == markers, name
    board = load_profile(CHARUCO).targets[0]
    assert board.charuco is not None and board.grid is not None
    assert np.array_equal(board.grid, opencv_board(board.charuco).getChessboardCorners())
    assert board.grid_shape == (5, 7)


@pytest.fixture(scope="module")
def charuco_profile() -> Profile:
    return load_profile(CHARUCO)


@pytest.fixture
def charuco_sim(charuco_profile: Profile) -> SimulatedRobot:
    """A fresh simulated robot per test: its configurations are the same draws whichever tests ran before."""
    return SimulatedRobot.from_profile(charuco_profile, seed=4)


def truth_px(sim: SimulatedRobot, q: np.ndarray, p: np.ndarray | None = None) -> np.ndarray:
    return board_corners(sim.profile, sim.true_params if p is None else p, q, 0)


def test_a_rendered_charuco_board_is_found_at_sub_pixel_accuracy(charuco_sim: SimulatedRobot) -> None:
    """Six poses the simulator shows (corners 18 px apart or more, at most 70 deg oblique), found with the
    nominal model's prediction: every corner within 0.5 px of the truth (measured: 186 corners, RMS 0.075 px,
    max 0.18 px)."""
    sim = charuco_sim
    q, _ = sim.configurations(6)
    errors = []
    for k in range(len(q)):
        capture = sim.capture(k + 1, q[k], 0, sim.profile.nominal())
        s = capture.sighting
        assert s.status == FrameStatus.MEASURED, s.detail
        assert s.measured is not None and len(s.vertices) >= 6
        assert np.array_equal(s.points, sim.profile.targets[0].grid[s.vertices])
        errors.append(np.linalg.norm(s.measured - truth_px(sim, q[k])[s.vertices], axis=1))
    e = np.concatenate(errors)
    assert e.max() < MAX_ERROR_PX and np.sqrt((e**2).mean()) < 0.15, (e.max(), np.sqrt((e**2).mean()))


def shifted(sim: SimulatedRobot, q: np.ndarray, keep: int) -> np.ndarray:
    """The truth with the camera's cx moved so that the image's left border leaves about `keep` corners inside."""
    p = sim.true_params.copy()
    cx = sim.profile.sensors[0].intrinsics[2]  # type: ignore[index]
    u = np.sort(truth_px(sim, q)[:, 0])[::-1]
    p[cx] -= (u[keep - 1] + u[keep]) / 2
    return p


def test_a_half_hidden_board_gives_the_visible_corners_with_their_ids(charuco_sim: SimulatedRobot) -> None:
    sim = charuco_sim
    q = sim.configurations(1)[0][0]
    p = shifted(sim, q, 17)  # the border through the middle of the board
    finder = finder_for(sim.profile, 0, 0)
    assert finder is not None
    s = finder.find(p, q, finder.render(p, q, np.random.default_rng(1)).images)
    assert s.status == FrameStatus.MEASURED and s.measured is not None, s.detail
    truth = truth_px(sim, q, p)[s.vertices]
    assert 6 <= len(s.vertices) <= 17 and np.all(truth[:, 0] > 0)  # corners in the image only (measured: 10)
    assert np.linalg.norm(s.measured - truth, axis=1).max() < MAX_ERROR_PX


def test_fewer_than_six_corners_are_not_a_measurement(charuco_sim: SimulatedRobot) -> None:
    sim = charuco_sim
    q = sim.configurations(1)[0][0]
    p = shifted(sim, q, 6)  # a sliver of the board: a few markers, a few corners (measured: 1 found)
    finder = finder_for(sim.profile, 0, 0)
    assert finder is not None
    s = finder.find(p, q, finder.render(p, q, np.random.default_rng(2)).images)
    assert s.status == FrameStatus.NOT_FOUND and s.measured is None and s.reason == "partial"
    assert 1 <= s.detail["corners"] < 6 and f"corners found: {s.detail['corners']} " in s.detail["detail"]
    assert s.detail["detail"].endswith("fewer than 6")


def board_profile(tmp_path: Path, charuco: str) -> Path:
    text = CHARUCO.read_text(encoding="utf-8")
    text = text.replace("{squares: [8, 6], square: 30, marker: 22, dictionary: DICT_5X5_100}", charuco)
    text = text.replace(
        "../../sample_sessions/arm/arm.urdf", str(CHARUCO.parent.parent.parent / "sample_sessions/arm/arm.urdf")
    )
    (tmp_path / "board.yaml").write_text(text, encoding="utf-8")
    return tmp_path / "board.yaml"


@pytest.mark.parametrize(
    ("charuco", "message"),
    [
        (
            "{squares: [8, 6], square: 30, marker: 22, dictionary: DICT_5X5_99}",
            "targets[0].charuco.dictionary: unknown ArUco dictionary 'DICT_5X5_99': expected OpenCV's name, such as "
            "DICT_4X4_50, DICT_5X5_100",
        ),
        (
            "{squares: [12, 10], square: 30, marker: 22, dictionary: DICT_APRILTAG_16h5}",
            "targets[0].charuco.dictionary: DICT_APRILTAG_16h5 has 30 markers, the board needs 60",
        ),
        ("{squares: [8, 6], square: 30, marker: 30, dictionary: DICT_5X5_100}", "targets[0].charuco.marker"),
        ("{squares: [3, 3], square: 30, marker: 22, dictionary: DICT_5X5_100}", "targets[0].charuco.squares: 4 inner"),
    ],
)
def test_a_board_opencv_would_not_take_is_refused_naming_the_field(tmp_path: Path, charuco: str, message: str) -> None:
    with pytest.raises(InputError) as info:
        load_profile(board_profile(tmp_path, charuco))
    assert message in str(info.value) and "board.yaml" in str(info.value)


def test_a_checkerboard_on_an_arm_is_found_by_the_checkerboard_finder() -> None:
    """The sample arm's wrist camera over a 7 x 6 board: findChessboardCorners and cornerSubPix, the corners'
    order from the calibrated model's prediction (the profile's guess is 300 mm off: the order needs a start
    within a few tens of px). Measured: max 0.14 px from the truth."""
    sim = SimulatedRobot.from_profile(load_profile(PROFILES / "wrist-camera.yaml"), seed=3)
    assert isinstance(sim.finder(0), CheckerboardFinder)
    q, _ = sim.configurations(5)
    for k in range(len(q)):
        s = sim.capture(k + 1, q[k], 0, sim.true_params).sighting
        assert s.status == FrameStatus.MEASURED and s.measured is not None, s.reason
        assert np.array_equal(s.vertices, np.arange(42))
        assert np.linalg.norm(s.measured - truth_px(sim, q[k]), axis=1).max() < MAX_ERROR_PX


def test_a_charuco_drive_recorded_as_a_ros2_bag_imports_through_its_finder(tmp_path: Path) -> None:
    drive = make_drive(str(CHARUCO), 3, seed=5, hold_s=1.0, move_s=1.0)
    bag = write_bag(tmp_path / "charuco_ros2", drive, camera_images(drive, 2.0), BagSpec(ros=2))
    result = import_bag(bag, drive.robot.profile, tmp_path / "session")
    assert result.measured == 3, [f.reason for f in result.frames]
    data = read_session(tmp_path / "session", drive.robot.profile).data
    for k in range(3):
        rows = data.cfg == k
        truth = board_corners(drive.robot.profile, drive.robot.true_params, drive.poses_rad[k], 0)
        assert rows.sum() >= 6
        assert np.linalg.norm(data.measured[rows] - truth[data.vertex[rows]], axis=1).max() < MAX_ERROR_PX


def test_a_checkerboard_with_no_guess_is_ordered_by_its_squares_colours() -> None:
    """The hand-eye profile gives no pose (the nominal model's prediction is hundreds of px off): a 7 x 6 board
    (13 odd: half a turn changes its squares' colours) is ordered from its face's handedness and its squares,
    whichever of its four orders the detector gives. Measured: every corner within 0.12 px of the truth."""
    sim = SimulatedRobot.from_profile(load_profile(PROFILES / "handeye-in-hand.yaml"), seed=3)
    finder = sim.finder(0)
    assert isinstance(finder, CheckerboardFinder)
    nominal = sim.profile.nominal()
    q, _ = sim.configurations(6)
    for k in range(len(q)):
        s = sim.capture(k + 1, q[k], 0, nominal).sighting
        assert s.status == FrameStatus.MEASURED and s.measured is not None, s.detail
        assert s.detail["prediction_px"] > 100  # the prediction could not have ordered them
        truth = truth_px(sim, q[k])
        assert np.linalg.norm(s.measured - truth, axis=1).max() < MAX_ERROR_PX
        grey = finder.render(sim.true_params, q[k], np.random.default_rng(k)).images["image"]
        rows, cols = finder.shape
        turned = truth.reshape(rows, cols, 2)
        for order in (turned, turned[::-1], turned[:, ::-1], turned[::-1, ::-1]):  # as the detector may give them
            corners = finder._by_colour(grey, order.reshape(-1, 2), truth).measured
            assert corners is not None and np.array_equal(corners, truth)


def test_a_symmetric_checkerboard_with_no_guess_says_it_needs_one(tmp_path: Path) -> None:
    """A 7 x 5 board (12 even) looks the same turned by half a turn: without a guess it is not measured, with a
    sentence that says what would do; with the truth as the guess it is."""
    text = (PROFILES / "handeye-in-hand.yaml").read_text(encoding="utf-8").replace("rows: 6", "rows: 5")
    text = text.replace("../../docs/", str(PROFILES.parent.parent / "docs") + "/")
    (tmp_path / "symmetric.yaml").write_text(text, encoding="utf-8")
    sim = SimulatedRobot.from_profile(load_profile(tmp_path / "symmetric.yaml"), seed=3)
    q = sim.configurations(1)[0][0]
    s = sim.capture(1, q, 0, sim.profile.nominal()).sighting
    assert s.status == FrameStatus.NOT_FOUND and s.reason == "far from prediction"
    assert "7 x 5 inner corners looks the same turned by half a turn" in s.detail["detail"]
    assert "a ChArUco board" in s.detail["detail"]
    s = sim.capture(1, q, 0, sim.true_params).sighting
    assert s.status == FrameStatus.MEASURED and s.measured is not None
    assert np.linalg.norm(s.measured - truth_px(sim, q), axis=1).max() < MAX_ERROR_PX


@pytest.mark.parametrize(
    "row",
    [
        (1e-4, 2e-4, 0.5),  # the plane ahead everywhere: the whole image
        (-1e-4, 2e-5, -0.5),  # behind everywhere
        (1e-3, -2e-3, 0.4),  # its horizon crosses the image
        (0.0, 1e-3, -0.9),  # a horizontal horizon
    ],
)
def test_the_board_planes_side_of_the_camera_is_each_pixels(row: tuple[float, float, float]) -> None:
    """What the ChArUco renderer takes as the board's plane in front of the camera: per px the sign of the
    homography's third row, given for the whole image at once only where its corners agree."""
    from calib_core.vision.finders.charuco import _ahead

    width, height = 640, 480
    u, v = np.meshgrid(np.arange(width, dtype=np.float32), np.arange(height, dtype=np.float32))
    every = np.array(row[0]) * u + np.array(row[1]) * v + np.array(row[2]) > 0
    ahead = _ahead(np.array(row), width, height)
    np.testing.assert_array_equal(np.broadcast_to(ahead, every.shape), every)
    assert isinstance(ahead, bool) == (every.all() or not every.any())
