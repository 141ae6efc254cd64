"""A first plan for a camera and a board of unknown pose (calib_core.estimation.plan_seed): seeded by one view of
the board, its configurations are seen by the true robot."""

from __future__ import annotations

import numpy as np
import pytest

from calib_core import InputError, load_profile
from calib_core.estimation import plan
from calib_core.estimation.plan_seed import SEED_SPREAD_DEG, around_seed, needs_seed, seeded_model
from calib_core.sim import SimulatedRobot
from calib_core.vision import Sampler, Visibility
from calib_core.vision.finders import finder_for
from calib_core.vision.sighting import predicted_points


def test_a_plan_around_one_view_of_the_board_is_measured_by_the_true_robot() -> None:
    profile = load_profile("arm-handeye")
    assert needs_seed(profile) and not needs_seed(load_profile("robonaut-a"))
    truth = SimulatedRobot.from_profile(profile, seed=1).true_params
    (q0, *_), _ = Sampler(Visibility(profile, truth), np.random.default_rng(2)).configurations(4)
    finder = finder_for(profile, 0, 0)
    nominal = profile.nominal()
    assert not Visibility(profile, nominal).sees(q0[None], np.array([0]))[0]  # no pose: nothing in view
    seen = finder.find(nominal, q0, finder.render(truth, q0, np.random.default_rng(0)).images)
    p = seeded_model(profile, nominal, q0, seen)
    # The seed's view as found, through the seeded model (the camera's mount left at the flange).
    predicted = profile.sensors[0].predict(p, predicted_points(profile, p, q0, 0))[0][seen.vertices]
    assert np.abs(predicted - seen.measured).max() < 2.0
    made = plan(profile, "handeye", 8, p, around=around_seed(q0))
    assert np.degrees(np.abs(made.q - q0)).max() <= SEED_SPREAD_DEG + 1e-9
    rng = np.random.default_rng(1)
    found = [finder.find(p, q, finder.render(truth, q, rng).images).measured is not None for q in made.q]
    assert all(found), found


def test_a_view_without_the_board_seeds_nothing() -> None:
    profile = load_profile("arm-handeye")
    truth = SimulatedRobot.from_profile(profile, seed=1).true_params
    q = np.zeros(len(profile.joints))  # stretched out: the camera looks away from the table
    finder = finder_for(profile, 0, 0)
    seen = finder.find(profile.nominal(), q, finder.render(truth, q, np.random.default_rng(0)).images)
    with pytest.raises(InputError, match="not found"):
        seeded_model(profile, profile.nominal(), q, seen)
