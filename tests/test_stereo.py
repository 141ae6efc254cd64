"""The rendered stereo head: the sphere where the pinhole model puts it, exact ray-cast depth, and SGBM depth
with a real head's accuracy (growing with distance) and holes (NaN, never 0 or negative)."""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np
import pytest

from calib_core import SimulatedRobot, load_profile
from calib_core.model.profile import Profile, Sensor
from calib_core.vision.stereo import (
    NONE,
    OBJECT_NAMES,
    SPHERE,
    StereoHead,
    StereoImages,
    depth_from_pair,
    no_depth_band_px,
    render_pair,
    sphere_views,
)

N_FRAMES = 16
RADIUS_M = 0.04
pytestmark = pytest.mark.slow  # stereo pairs rendered and detected


@dataclass
class Scene:
    profile: Profile
    sensor: Sensor
    p: np.ndarray
    q: np.ndarray
    head: StereoHead
    centres_m: np.ndarray  # (N, 3) noise-free fixture centres in the left optical frame, from the simulator
    frames: list[StereoImages]
    depths_m: list[np.ndarray]


@pytest.fixture(scope="module")
def scene() -> Scene:
    profile = load_profile("robonaut-a")
    robot = SimulatedRobot.from_profile(profile, seed=1)
    q, targets = robot.configurations(N_FRAMES)
    p = robot.true_params
    head = StereoHead.from_profile(profile, p)
    sensor = profile.sensors[profile.data.sensor]
    centres_eye_cm = robot.measure(q, targets).exact  # the simulator's own path to the fixture centre
    frames = [render_pair(profile, p, row, head, np.random.default_rng(i)) for i, row in enumerate(q)]
    depths = [depth_from_pair(f.left, f.right, head) for f in frames]
    return Scene(profile, sensor, p, q, head, centres_eye_cm @ sensor.R_frame_optical * 0.01, frames, depths)


def _silhouette(head: StereoHead, centre_m: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The sphere's image: pixels inside its outline (the conic of the tangent cone) and the ellipse's centre."""
    K = np.array([[head.fx_px, 0, head.cx_px], [0, head.fy_px, head.cy_px], [0, 0, 1]])
    K_inv = np.linalg.inv(K)
    Q = np.outer(centre_m, centre_m) - (centre_m @ centre_m - RADIUS_M**2) * np.eye(3)
    A = K_inv.T @ Q @ K_inv
    u, v = np.meshgrid(np.arange(head.width_px), np.arange(head.height_px))
    m = np.stack([u, v, np.ones_like(u)], axis=-1).astype(float)
    inside = np.einsum("hwi,ij,hwj->hw", m, A, m) > 0
    return inside, np.linalg.solve(A[:2, :2], -A[:2, 2])


def _centroid(mask: np.ndarray) -> np.ndarray:
    v, u = np.nonzero(mask)
    return np.array([u.mean(), v.mean()])


def _interior(frame: StereoImages, margin_px: float = 3.0) -> np.ndarray:
    """Sphere pixels more than margin_px inside its visible silhouette."""
    sphere = (frame.object_id == SPHERE).astype(np.uint8)
    return cv2.distanceTransform(sphere, cv2.DIST_L2, 3) > margin_px


def test_head_from_the_profile(scene):
    head = scene.head
    assert (head.fx_px, head.fy_px, head.cx_px, head.cy_px) == (525.0, 525.0, 319.5, 239.5)
    assert (head.width_px, head.height_px) == (640, 480)
    assert head.baseline_m == pytest.approx(0.09)
    np.testing.assert_array_equal(head.R_frame_optical, scene.sensor.R_frame_optical)
    assert head.disparity_px(1.0) == pytest.approx(47.25)


def test_images_are_an_8_bit_pair_with_true_depth(scene):
    f = scene.frames[0]
    for image in (f.left, f.right):
        assert image.shape == (480, 640) and image.dtype == np.uint8
        assert image.std() > 20  # textured, not blank
    assert f.depth_true.dtype == np.float32 and f.object_id.dtype == np.uint8
    np.testing.assert_array_equal(np.isnan(f.depth_true), f.object_id == NONE)
    assert f.object_id.max() < len(OBJECT_NAMES) and (f.object_id == SPHERE).any()
    # The scene's texture is fixed; only the photometric noise comes from rng.
    again = render_pair(scene.profile, scene.p, scene.q[0], scene.head, np.random.default_rng(0))
    np.testing.assert_array_equal(again.left, f.left)
    other = render_pair(scene.profile, scene.p, scene.q[0], scene.head, np.random.default_rng(99))
    assert 0 < np.abs(other.left.astype(int) - f.left).mean() < 4


def _whole_sphere(head: StereoHead, ids: np.ndarray, centre_m: np.ndarray) -> tuple[np.ndarray, np.ndarray] | None:
    """Centroid of the sphere's pixels and the centre of its outline when nothing hides it, else None.

    Checks on the way that no pixel shows the sphere outside its outline.
    """
    inside, ellipse_centre = _silhouette(head, centre_m)
    sphere = ids == SPHERE
    assert not (sphere & ~inside).any(), "sphere pixels outside its outline"
    on_border = inside[[0, -1], :].any() or inside[:, [0, -1]].any()
    if not inside.any() or on_border or sphere.sum() < inside.sum():  # cut by the image border or occluded
        return None
    return _centroid(sphere), ellipse_centre


def test_sphere_appears_where_the_pinhole_projection_puts_it(scene):
    head, R = scene.head, scene.sensor.R_frame_optical
    baseline_m = np.array([head.baseline_m, 0.0, 0.0])
    whole = 0
    for n, f in enumerate(scene.frames):
        c_left, c_right = scene.centres_m[n], scene.centres_m[n] - baseline_m  # in each camera's frame
        left = _whole_sphere(head, f.object_id, c_left)
        right = _whole_sphere(head, f.object_id_right, c_right)
        if left is None or right is None:
            continue
        whole += 1
        (left_centroid, left_ellipse), (right_centroid, right_ellipse) = left, right
        np.testing.assert_allclose(left_centroid, left_ellipse, atol=0.1)
        np.testing.assert_allclose(right_centroid, right_ellipse, atol=0.1)
        # Perspective puts the outline's centre off the projected centre, by up to ~1 px in the eye's range.
        for centroid, c in ((left_centroid, c_left), (right_centroid, c_right)):
            x_eye_cm = R @ c * 100
            np.testing.assert_allclose(centroid, scene.sensor.project(scene.p, x_eye_cm[None])[0], atol=1.5)
        # The right image is the left one shifted by the disparity fx * b / z.
        assert left_centroid[0] - right_centroid[0] == pytest.approx(head.disparity_px(c_left[2]), abs=0.5)
        assert left_centroid[1] == pytest.approx(right_centroid[1], abs=0.2)
    assert whole >= 4


def test_true_depth_is_the_sphere_surface(scene):
    head = scene.head
    for n, f in enumerate(scene.frames):
        v, u = np.nonzero(f.object_id == SPHERE)
        if not len(u):
            continue
        d = np.stack([(u - head.cx_px) / head.fx_px, (v - head.cy_px) / head.fy_px, np.ones(len(u))], axis=1)
        c = scene.centres_m[n]
        a, b = np.einsum("ni,ni->n", d, d), d @ c
        z = (b - np.sqrt(b * b - a * (c @ c - RADIUS_M**2))) / a  # first hit of the ray t d, at depth t
        np.testing.assert_allclose(f.depth_true[v, u], z, atol=1e-5)


def _sphere_errors(scene) -> list[tuple[float, np.ndarray, float]]:
    """(distance, SGBM error on the interior (m, finite), valid fraction) for frames with a visible sphere."""
    out = []
    for f, depth_m in zip(scene.frames, scene.depths_m, strict=True):
        interior = _interior(f)
        error = (depth_m - f.depth_true)[interior]
        if np.isfinite(error).sum() >= 200:
            out.append((float(np.median(f.depth_true[interior])), error[np.isfinite(error)], np.isfinite(error).mean()))
    return out


def test_sgbm_depth_on_the_sphere_is_accurate(scene):
    errors = _sphere_errors(scene)
    assert len(errors) >= 8
    for z_m, error_m, valid in errors:
        assert np.median(np.abs(error_m)) < 3e-3, f"at {z_m:.2f} m"
        assert np.median(error_m) == pytest.approx(0.0, abs=2e-3)  # no gross bias
        assert valid > 0.8


def test_sgbm_depth_noise_grows_with_distance(scene):
    errors = _sphere_errors(scene)
    near = np.concatenate([e for z, e, _ in errors if z < 0.85])
    far = np.concatenate([e for z, e, _ in errors if z > 0.9])
    assert np.median(np.abs(far)) > 1.4 * np.median(np.abs(near))
    assert np.percentile(np.abs(far), 90) > 1.4 * np.percentile(np.abs(near), 90)


def test_no_data_is_nan_never_zero_or_negative(scene):
    for depth_m in scene.depths_m:
        assert depth_m.dtype == np.float32 and depth_m.shape == (480, 640)
        valid = np.isfinite(depth_m)
        assert (depth_m[valid] > 0.3).all()
        band = no_depth_band_px(scene.head)  # no right-camera match is searched for the leftmost columns
        assert band == 128
        assert not valid[:, :band].any() and valid[:, band : band + 4].any()
        assert valid.mean() > 0.5
    # An untextured pair gives no depth at all.
    flat = np.full((480, 640), 128, np.uint8)
    assert np.isnan(depth_from_pair(flat, flat, scene.head)).all()


def test_sphere_views_say_how_much_of_the_sphere_each_rendered_image_shows(scene):
    """The visible share `sphere_views` computes without rendering against the rendered images' sphere
    pixels, over configurations where the arm hides none, some or all of it (not the simulator's)."""
    rng = np.random.default_rng(5)
    lo, hi = scene.profile.joint_limits()
    q = rng.uniform(lo, hi, (3000, len(lo)))
    views = sphere_views(scene.profile, scene.p, q, scene.head)
    u0, u1, v0, v1 = views.box_px.T
    with np.errstate(invalid="ignore"):
        whole = (u0 > 1) & (u1 < 638) & (v0 > 1) & (v1 < 478)  # the outline inside the left image
    share = views.visible.min(axis=1)
    picks = [np.flatnonzero(whole & (share == 0))[:2], np.flatnonzero(whole & (share > 0.1) & (share < 0.9))[:5]]
    picks.append(np.flatnonzero(whole & (share == 1))[:2])
    assert all(len(p) for p in picks)
    baseline_m = np.array([scene.head.baseline_m, 0.0, 0.0])
    for n in np.concatenate(picks):
        f = render_pair(scene.profile, scene.p, q[n], scene.head, np.random.default_rng(0))
        centre_m = _sphere_centre_m(scene, q[n])
        for camera, ids, offset in ((0, f.object_id, np.zeros(3)), (1, f.object_id_right, baseline_m)):
            inside, _ = _silhouette(scene.head, centre_m - offset)
            if inside[[0, -1], :].any() or inside[:, [0, -1]].any():
                continue  # the right image may cut it
            rendered = (ids == SPHERE).sum() / inside.sum()
            assert views.visible[n, camera] == pytest.approx(rendered, abs=0.04), (n, camera)


def _sphere_centre_m(scene, q: np.ndarray) -> np.ndarray:
    robot = SimulatedRobot.from_profile(scene.profile)
    exact = robot.measure(q[None], np.zeros(1, int)).exact[0]  # the simulator's path, eye frame, cm
    return exact @ scene.sensor.R_frame_optical * 0.01
