"""The NAO sandal boards: rendered images of the simulated stances, their vertices found as in the paper,
with the right identities, and rejections (ambiguous, far off, partial, nothing there) that say why."""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np
import pytest

from calib_core import Profile, SimulatedRobot, load_profile
from calib_core.vision.sandal_board import BoardImage, board_corners, detect_board, render_board_image

SHARP = {"blur_px": 0.0, "noise": 0.0, "light": 0.0}


@dataclass
class Session:
    profile: Profile
    robot: SimulatedRobot
    q: np.ndarray
    targets: np.ndarray
    spacing_px: np.ndarray  # per frame: how close the closest vertices are in the image
    frames: list[int]  # least oblique (widest spacing) first


@pytest.fixture(scope="module")
def session() -> Session:
    """One simulated session: 24 stances x 3 head postures per leg."""
    profile = load_profile("nao")
    robot = SimulatedRobot.from_profile(profile, seed=0)
    q, targets = robot.configurations()
    truth = profile.true_params()
    grid = np.array([board_corners(profile, truth, q[n], targets[n]) for n in range(len(q))]).reshape(-1, 4, 6, 2)
    spacing_px = np.linalg.norm(np.diff(grid, axis=2), axis=3).min(axis=(1, 2))
    return Session(profile, robot, q, targets, spacing_px, [int(n) for n in np.argsort(-spacing_px)])


def render(s: Session, n: int, seed: int = 0, **effects) -> tuple[BoardImage, np.ndarray]:
    """Frame n as the camera sees it (true parameters), and the nominal parameters' prediction."""
    rng = np.random.default_rng(seed)
    board = render_board_image(s.profile, s.profile.true_params(), s.q[n], s.targets[n], rng, **effects)
    return board, board_corners(s.profile, s.profile.nominal(), s.q[n], s.targets[n])


def rms_px(a: np.ndarray, b: np.ndarray) -> float:
    return float(np.sqrt(((a - b) ** 2).sum(axis=1).mean()))


def test_rendered_corners_are_the_simulators_exact_measurements(session):
    n = session.frames[0]
    board, _ = render(session, n, **SHARP)
    exact = session.robot.measure(session.q[n : n + 1], session.targets[n : n + 1]).exact
    np.testing.assert_allclose(board.corners_true, exact, atol=1e-9)
    assert board.image.shape == (480, 640) and board.image.dtype == np.uint8
    assert board.obliquity_deg >= 70.0


def test_sharp_images_are_measured_to_a_tenth_of_a_pixel_with_the_right_identities(session):
    for n in session.frames[:3]:
        board, predicted = render(session, n, **SHARP)
        assert np.linalg.norm(predicted - board.corners_true, axis=1).mean() > 20.0  # nominal != truth
        detection = detect_board(board.image, predicted=predicted)
        assert detection.found, detection
        assert rms_px(detection.corners, board.corners_true) <= 0.1


def test_blurred_noisy_unevenly_lit_images_are_measured_with_small_error(session):
    # the least oblique frames and some with the closest vertices only 4-5 px apart
    frames = session.frames[:2] + [n for n in session.frames if 4.0 <= session.spacing_px[n] < 5.0][:2]
    for n in frames:
        board, predicted = render(session, n, seed=n)
        detection = detect_board(board.image, predicted=predicted)
        assert detection.found, detection
        errors_px = np.linalg.norm(detection.corners - board.corners_true, axis=1)
        assert np.sqrt((errors_px**2).mean()) <= 0.2 and errors_px.max() <= 0.6


def test_identities_survive_a_camera_turned_by_180_degrees(session):
    board, predicted = render(session, session.frames[1])
    far_corner = np.array([639.0, 479.0])
    detection = detect_board(board.image[::-1, ::-1].copy(), predicted=far_corner - predicted)
    assert detection.found, detection
    assert rms_px(detection.corners, far_corner - board.corners_true) <= 0.2


@pytest.mark.parametrize("order", ["as found", "reversed", "rows mirrored", "columns mirrored"])
def test_identities_whatever_order_opencv_returns(session, monkeypatch, order):
    """The 6 x 4 grid looks the same turned by 180 degrees (and OpenCV knows no handedness): the
    prediction, tens of px off, picks the vertex order."""
    reorder = {
        "as found": lambda g: g,
        "reversed": lambda g: g[::-1, ::-1],
        "rows mirrored": lambda g: g[:, ::-1],
        "columns mirrored": lambda g: g[::-1],
    }[order]
    find = cv2.findChessboardCorners

    def find_reordered(image, size, *args, **kwargs):
        found, corners = find(image, size, *args, **kwargs)
        if found:
            corners = np.ascontiguousarray(reorder(corners.reshape(size[1], size[0], 2)).reshape(-1, 1, 2))
        return found, corners

    monkeypatch.setattr(cv2, "findChessboardCorners", find_reordered)
    board, predicted = render(session, session.frames[0])
    detection = detect_board(board.image, predicted=predicted)
    assert detection.found, detection
    assert rms_px(detection.corners, board.corners_true) <= 0.2


def frontal_board(tile_px: int = 30, left: int = 170, top: int = 120) -> tuple[np.ndarray, np.ndarray]:
    """A 7 x 5 checkerboard seen head-on (corner tiles black, a white margin) and its 24 inner corners."""
    image = np.full((480, 640), 30.0)
    image[top - tile_px : top + 6 * tile_px, left - tile_px : left + 8 * tile_px] = 220.0
    for j in range(5):
        for i in range(7):
            if (i + j) % 2 == 0:
                image[top + j * tile_px : top + (j + 1) * tile_px, left + i * tile_px : left + (i + 1) * tile_px] = 40.0
    image = cv2.GaussianBlur(image, (0, 0), 1.0)
    row, col = np.divmod(np.arange(24), 6)
    corners = np.stack([left + (col + 1) * tile_px - 0.5, top + (row + 1) * tile_px - 0.5], axis=1)
    return np.rint(image).astype(np.uint8), corners


def test_without_a_prediction_rows_run_left_to_right_from_the_top_left():
    image, corners = frontal_board()
    for turned in (False, True):
        detection = detect_board(image[::-1, ::-1].copy() if turned else image)
        assert detection.found, detection
        expected = np.array([639.0, 479.0]) - corners[::-1] if turned else corners
        assert rms_px(detection.corners, expected) <= 0.05
    doc = detection.to_json()
    assert doc["found"] is True and doc["reason"] == "ok"
    assert len(doc["corners"]) == 24 and all(len(uv) == 2 for uv in doc["corners"])


def test_an_oblique_board_is_found_without_a_prediction_by_its_bright_margin(session):
    # Seen at 70-86 deg from its normal the tiles are too flat for OpenCV in the raw image; the margin's
    # outline rectifies them. Which vertex is which is not known without a prediction: compare as a set.
    # (139 of this session's 144 frames; the misses are 82-86 deg from the normal.)
    ordered = session.frames
    for n in [ordered[0], ordered[len(ordered) // 2], *[n for n in ordered if 4.0 <= session.spacing_px[n] < 5.0][:1]]:
        board, _ = render(session, n, seed=n)
        detection = detect_board(board.image)
        assert detection.found, (n, detection)
        truth = board.corners_true.reshape(4, 6, 2)
        symmetric = [truth, truth[::-1, ::-1], truth[:, ::-1], truth[::-1]]
        assert min(rms_px(detection.corners, t.reshape(-1, 2)) for t in symmetric) <= 0.2


def test_a_prediction_without_orientation_is_ambiguous_and_a_distant_one_far():
    image, corners = frontal_board()
    centre = np.repeat(corners.mean(axis=0, keepdims=True), 24, axis=0)
    ambiguous = detect_board(image, predicted=centre)
    assert (ambiguous.found, ambiguous.reason, ambiguous.corners) == (False, "ambiguous", None)
    far = detect_board(image, predicted=centre + np.array([150.0, 0.0]))
    assert (far.found, far.reason) == (False, "far from prediction")
    doc = far.to_json()
    assert (doc["found"], doc["corners"], doc["reason"]) == (False, None, "far from prediction")


def test_a_grid_opencv_cannot_look_for_is_refused():
    with pytest.raises(ValueError, match="3 x 3"):
        detect_board(frontal_board()[0], cols=2, rows=4)


def test_noise_is_no_board(session):
    _, predicted = render(session, session.frames[0], **SHARP)
    noise = np.random.default_rng(3).integers(0, 256, (480, 640)).astype(np.uint8)
    for prediction in (None, predicted):
        detection = detect_board(noise, predicted=prediction)
        assert not detection.found and detection.corners is None
        assert detection.reason in ("not found", "partial")


def test_a_half_hidden_board_is_rejected_as_partial(session):
    board, predicted = render(session, session.frames[0])
    corners = board.corners_true
    # The other sandal's grey plate hides rows 2 and 3 of the board.
    across = corners[18] - corners[0]
    v, u = np.mgrid[:480, :640]
    image = board.image.copy()
    image[(u - corners[:, 0].mean()) * across[0] + (v - corners[:, 1].mean()) * across[1] > 0] = 120
    detection = detect_board(image, predicted=predicted)
    assert (detection.found, detection.reason) == (False, "partial")
    assert detection.detail.endswith("of 24 corners")


def test_a_hard_view_is_found_whatever_ran_before_it():
    """OpenCV's sector-based detector draws from a global generator, so a hard view (here one it missed in 1 of 5
    draws) was found or not depending on what the process had run before: CI lost it, the laptop did not. It is
    found from every state of that generator, and always the same corners."""
    profile = load_profile("nao")
    robot = SimulatedRobot.from_profile(profile, seed=4)
    q, targets = robot.configurations(24)
    n = 17
    image, _ = robot.render(q[n], int(targets[n]))
    predicted = board_corners(profile, profile.nominal(), robot.readings(q[n]), targets[n])
    found = []
    for state in range(8):
        cv2.setRNGSeed(1000 + state)
        cv2.findChessboardCornersSBWithMeta(image["image"], (3, 3), cv2.CALIB_CB_LARGER)  # what ran before
        found.append(detect_board(image["image"], predicted=predicted))
    assert all(d.found for d in found), [d.reason for d in found]
    assert all(np.array_equal(d.corners, found[0].corners) for d in found)


@pytest.mark.parametrize("shape", [(1, 1), (1, 200), (14, 14), (200, 14), (14, 200, 3)])
def test_an_image_too_small_for_a_board_is_not_found_without_an_opencv_error(shape):
    """OpenCV's detectors raise on an image with a side under 15 px (its adaptive threshold's block size; the
    sector-based detector's "image must be continuous"): such an image holds no board, as a damaged file decoded
    to a few pixels showed (tests/test_malformed.py)."""
    detection = detect_board(np.random.default_rng(0).integers(0, 256, shape, dtype=np.uint8), 6, 4)
    assert (detection.found, detection.reason) == (False, "not found")
    assert detection.detail == f"an image of {shape[1]} x {shape[0]} px holds no board"


def test_the_smallest_image_the_detector_takes_raises_nothing():
    for shape in [(15, 15), (15, 200), (200, 15)]:
        assert detect_board(np.zeros(shape, np.uint8), 6, 4).reason == "not found"
