"""Visibility (calib_core.vision.visibility): which points of which target each sensor sees at q with p, the one
test the simulator, the planner, the dry run and bag import share."""

from __future__ import annotations

import numpy as np

from calib_core import Visibility, load_profile
from calib_core.model.kinematics import sensor_points
from calib_core.vision.sampling import Sampler


def test_points_are_the_ones_inside_the_image_and_a_board_is_seen_only_whole(nao) -> None:
    """Turning the head away from a board seen whole: the points Visibility keeps are exactly those the camera
    projects inside the image margin px clear of the border, and `sees` holds only while all are."""
    p = nao.true_params()
    view = Visibility(nao, p, margin_px=10.0)
    q, targets = Sampler(view, np.random.default_rng(0)).configurations(6)
    assert view.sees(q, targets).all() and view.points(q, targets).all()
    yaw = nao.joint("HeadYaw")
    turned = np.repeat(q[:1], 80, axis=0)
    turned[:, yaw] += np.linspace(0.0, 1.5, 80)
    t = np.full(80, targets[0])
    inside = view.points(turned, t)
    uv = nao.sensors[nao.data.sensor].project(p, sensor_points(nao, p, turned, t).reshape(-1, 3)).reshape(80, -1, 2)
    w, h = nao.sensors[nao.data.sensor].image
    with np.errstate(invalid="ignore"):
        expected = (uv[..., 0] >= 10) & (uv[..., 0] <= w - 11) & (uv[..., 1] >= 10) & (uv[..., 1] <= h - 11)
    partly = inside.any(axis=1) & ~inside.all(axis=1)
    assert partly.any() and (~inside.any(axis=1)).any()  # the sweep passes through part and none in view
    assert np.array_equal(inside[partly], expected[partly])
    assert np.array_equal(view.sees(turned, t), inside.all(axis=1))


def test_targets_in_view_names_the_board_of_the_lifted_foot(nao) -> None:
    """A stance aims the head at one foot's board: that board is in view, the other foot's is not."""
    view = Visibility(nao, nao.true_params())
    q, targets = Sampler(view, np.random.default_rng(1)).configurations(6)
    for qk, t in zip(q, targets, strict=True):
        assert view.targets_in_view(qk) == [int(t)]


def test_points_beyond_a_target_s_own_are_not_seen() -> None:
    """Targets of different sizes in one call (the Motoman: a reflector and 20 marker faces): the rows of the
    one-point target are False beyond its point, and the tracker (no field of view) sees every real point."""
    mm = load_profile("motoman")
    view = Visibility(mm, mm.true_params())
    q = np.zeros((2, len(mm.joints)))
    targets = np.array([mm.target("LR1"), mm.target("markers1")])
    ok = view.points(q, targets, mm.sensors.index(next(s for s in mm.sensors if s.name == "tracker")))
    assert ok.shape == (2, 20)
    assert ok[0, 0] and not ok[0, 1:].any() and ok[1].all()


def test_a_board_is_seen_whole_exactly_where_its_every_point_is_checked(monkeypatch) -> None:
    """`sees` checks a board at its outline first (`Visibility.outline`): on 4000 uniform draws of the hand-eye arm
    (its wrist camera sees its board in a few of them) and of NAO, the same answers as checking every point of
    every draw, and a draw whose outline is out of view is one `points` does not see whole."""
    import calib_core.vision.visibility as visibility

    for name in ("arm-handeye", "nao"):
        profile = load_profile(name)
        view = Visibility(profile, profile.true_params())
        lo, hi = profile.joint_limits()
        q = np.random.default_rng(7).uniform(lo, hi, (4000, len(lo)))
        targets = np.arange(4000) % len(profile.targets)
        seen = view.sees(q, targets)
        outline = view.outline(q, targets)
        assert not (seen & ~outline).any() and outline.sum() < 4000  # the outline does rule draws out
        with monkeypatch.context() as m:
            m.setattr(visibility, "OUTLINE_POINTS", 10**9)  # every point of every draw
            assert view.outline(q, targets).all()
            assert np.array_equal(view.sees(q, targets), seen), name
        assert not view.points(q[~outline], targets[~outline]).all(axis=1).any()


def test_draws_checked_ahead_are_those_of_one_batch_at_a_time(monkeypatch) -> None:
    """`Sampler.uniform` checks several batches of draws at once where few are in view, and puts the random stream
    back after the batch that found enough: the same configurations, and the same numbers from the stream after
    them, as drawing one batch at a time."""
    import calib_core.vision.sampling as sampling

    profile = load_profile("arm-handeye")
    view = Visibility(profile, profile.true_params())

    def draw(seed: int, n: int) -> tuple[np.ndarray, np.ndarray]:
        rng = np.random.default_rng(seed)
        q, _ = Sampler(view, rng).uniform(n)
        return q, rng.random(4)

    for seed, n in ((0, 1), (1, 8), (2, 20)):
        ahead = draw(seed, n)
        with monkeypatch.context() as m:
            m.setattr(sampling, "AHEAD_ROWS", 1)  # one batch at a time
            alone = draw(seed, n)
        assert np.array_equal(ahead[0], alone[0]) and np.array_equal(ahead[1], alone[1]), (seed, n)
