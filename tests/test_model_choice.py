"""Mode `auto` (calib_core.estimation.model_choice): the profile's mode and the strength of its priors chosen by
cross-validation on the training configurations alone, and said: every candidate's cross-validated figure.

Against ground truth: a URDF arm whose true geometry (an independent URDF reader, test_urdf_import.Truth) is off
in its joint origins or only in its offsets; `auto` predicts the truth at least as well as the better of the
named modes. Against the held-out data: they cannot change its choice."""

from __future__ import annotations

import json
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
from desk_jobs import wait_job
from test_urdf_import import FLOOR_MM, Truth, _dataset, _readings, _setup, _write_csv

from app.cli import main
from calib_core import Calibration, InputError, calibrate, load_profile, read_dataset
from calib_core.estimation.calibrate import check_can_fit
from calib_core.estimation.model_choice import PRIOR_SCALES, SHUFFLES
from calib_core.estimation.problem import Problem
from calib_core.io.figaroh_data import ROBOTS
from calib_core.model.profile import AUTO

FIGAROH = Path(__file__).resolve().parents[1] / "sample_sessions" / "figaroh"


def test_auto_is_offered_first_where_there_is_a_choice(tmp_path: Path) -> None:
    """A URDF's default modes and a built-in's: `auto` first, under it the richest mode (what a plan for it makes
    accurate); a profile of one mode without priors has nothing to choose; no profile may name a mode `auto`."""
    arm = load_profile(_setup(tmp_path))
    assert [m.name for m in arm.offered_modes()] == [AUTO, "handeye", "offsets", "origins"]
    auto = arm.mode(AUTO)
    assert auto.free == arm.modes["origins"].free and auto.priors == arm.modes["origins"].priors
    assert [m.name for m in load_profile("robonaut-a").offered_modes()] == [AUTO, "daily", "full"]

    one = (tmp_path / "arm.yaml").read_text() + "modes:\n  mine: {free: [elbow, wrist_1]}\n"
    (tmp_path / "one.yaml").write_text(one)
    assert [m.name for m in load_profile(tmp_path / "one.yaml").offered_modes()] == ["mine"]
    (tmp_path / "auto.yaml").write_text(one.replace("mine:", "auto:"))
    with pytest.raises(InputError, match=r"modes\.auto: the name 'auto' is reserved") as err:
        load_profile(tmp_path / "auto.yaml")
    assert err.value.file == str(tmp_path / "auto.yaml")
    with pytest.raises(InputError, match=r"unknown mode 'full' .*known: handeye, offsets, origins, auto"):
        arm.mode("full")


def test_auto_refuses_only_what_no_mode_can_fit() -> None:
    """Two poses determine the UR10e's `offsets` (a camera pose each) but not its `origins`: `auto` may be asked;
    one pose determines neither, and `auto` is refused with the first mode's reason."""
    ur10 = load_profile(FIGAROH / ROBOTS["ur10e-pose"].profile)
    data = read_dataset(ur10, FIGAROH / ROBOTS["ur10e-pose"].data)
    two, one = data.select(np.arange(3)), data.select(np.arange(1))
    with pytest.raises(InputError):
        check_can_fit(ur10, two, "origins")
    check_can_fit(ur10, two, AUTO)
    with pytest.raises(InputError, match="cannot calibrate mode 'handeye'"):
        check_can_fit(ur10, one, AUTO)


@pytest.mark.slow
def test_the_held_out_configurations_cannot_change_the_choice() -> None:
    """TIAGo's 37 real postures, 30% held out: the choice and the estimate are made on the training part alone,
    so the held-out measurements moved by 6 cm change neither (the held-out figures do: every moved one is an
    outlier of the fit). The choice is
    the candidate of the least score, every candidate (each mode, each prior scale) is reported with its
    cross-validated figure, and the result names the mode `auto`, says what it chose and keeps it in its file."""
    tiago = load_profile(FIGAROH / ROBOTS["tiago"].profile)
    data = read_dataset(tiago, FIGAROH / ROBOTS["tiago"].data)
    cal = calibrate(tiago, data, AUTO, holdout=0.3, seed=4)
    held = np.isin(data.frame_ids[data.cfg], cal.frames["holdout"])
    moved = data.measured.copy()
    moved[held] += [50.0, -20.0, 30.0]
    other = calibrate(tiago, replace(data, measured=moved), AUTO, holdout=0.3, seed=4)

    choice = cal.choice
    assert choice is not None and other.choice is not None
    assert [c.score for c in other.choice.candidates] == [c.score for c in choice.candidates]
    assert other.choice.chosen == choice.chosen
    assert other.values() == cal.values()
    held_out = len(cal.frames["holdout"])
    assert other.figures["holdout_after"].excluded == held_out > cal.figures["holdout_after"].excluded

    names = [c.name for c in choice.candidates]
    assert names == ["handeye", "offsets", *(f"origins (priors x{_scale(s)})" for s in PRIOR_SCALES)]
    scores = [c.score for c in choice.candidates]
    assert choice.chosen == int(np.argmin(scores))
    assert all(c.figures is not None and c.figures.unit == "mm" for c in choice.candidates)
    assert choice.compared <= choice.held_out == SHUFFLES * len(cal.frames["train"])
    assert cal.mode == AUTO and sum(p.estimated for p in cal.parameters) > 0
    note = next(d for d in cal.diagnostics if d.code == "model-choice")
    assert note.mode == choice.picked.mode and choice.picked.name in note.message
    assert "origins with priors x1/16, x1/8, x1/4, x1/2, x1, x2, x4, x8, x16: " in note.message
    assert all(f"{c.figures.rms:.4g} mm" in note.message for c in choice.candidates)
    again = Calibration.from_dict(json.loads(json.dumps(cal.to_dict())))
    assert again.choice == choice
    assert f"chosen: {choice.picked.name}" in cal.summary()


def _scale(s: float) -> str:
    return f"1/{1 / s:g}" if s < 1 else f"{s:g}"


@pytest.mark.slow
@pytest.mark.parametrize("origin_errors", [True, False])
def test_auto_predicts_the_truth_as_well_as_the_better_named_mode(tmp_path: Path, origin_errors: bool) -> None:
    """40 configurations of the arm, 0.02 mm tracker noise. With origin errors (0.5 mm, 0.1 deg a joint) `offsets`
    misses the truth by 20 times the noise and `auto` chooses `origins`; without, both named modes reach the
    noise. Either way `auto`'s prediction of the true robot at 60 other configurations (no noise) is within 10%
    of the better named mode's."""
    profile = load_profile(_setup(tmp_path))
    truth = Truth(tmp_path, seed=2 if origin_errors else 1, origin_errors=origin_errors)
    train = read_dataset(profile, _dataset(tmp_path, truth, 40, seed=31))
    q = _readings(np.random.default_rng(32), 60)
    _write_csv(tmp_path / "truth.csv", q, truth.measure(q))
    test = read_dataset(profile, tmp_path / "truth.csv")

    def true_error(cal: Calibration) -> float:
        p = cal.params(profile)
        predicted = Problem(profile, test, [], p, noise_model=False).predict(p)[:, :3]
        return float(np.sqrt(np.mean(np.sum((predicted - test.measured[:, :3]) ** 2, axis=1))))

    auto = calibrate(profile, train, AUTO)
    named = {mode: true_error(calibrate(profile, train, mode)) for mode in ("offsets", "origins")}
    assert auto.choice is not None
    if origin_errors:
        assert auto.choice.picked.mode == "origins"
        assert named["offsets"] > 20 * FLOOR_MM
    assert min(named.values()) < FLOOR_MM
    assert true_error(auto) <= 1.1 * min(named.values()), (auto.choice.picked.name, true_error(auto), named)


@pytest.mark.slow
def test_the_api_offers_auto_first_and_shows_what_it_chose(client) -> None:
    """The robot's modes list `auto` first (the page's selector shows them in this order); a calibration in mode
    `auto` answers with its choice and its note, as the calibration file holds them."""
    robots = {r["name"]: r for r in client.get("/api/robots").json()}
    assert [m["name"] for m in robots["robonaut-a"]["modes"]] == [AUTO, "daily", "full"]
    r = client.post("/api/sessions/robonaut-a-day1/calibrations", json={"mode": AUTO, "holdout": 0.3})
    assert r.status_code == 202, r.text
    job = wait_job(client, r.json()["job"])
    assert job["state"] == "done", job
    cal = client.get(f"/api/calibrations/{job['result']}").json()
    choice = cal["choice"]
    assert cal["mode"] == AUTO and [c["mode"] for c in choice["candidates"]] == ["daily", "full"]
    scores = [c["score"] for c in choice["candidates"]]
    assert choice["chosen"] == int(np.argmin(scores))
    assert all(c["figures"]["unit"] == "cm" and c["figures"]["rms"] > 0 for c in choice["candidates"])
    assert next(g["code"] for g in cal["diagnostic_groups"] if g["severity"] == "info") == "model-choice"


@pytest.mark.parametrize("command", ["solve", "self-observe", "plan"])
def test_each_command_with_a_mode_says_auto_in_its_help(command: str, capsys: pytest.CaptureFixture[str]) -> None:
    """`--mode auto` works wherever a command takes a mode; `--help` says so, and what it does (solve's listed the
    named modes only)."""
    assert main([command, "--help"]) == 0
    words = " ".join(capsys.readouterr().out.split())
    said = words.split("--mode MODE ")[-1].split(" --")[0]  # the option's help, after the usage line's mention
    assert "auto" in said, said
    if command == "plan":
        assert "richest mode" in said, said  # what a plan for `auto` makes accurate (Profile.mode)
    else:
        assert "k-fold cross-validation on the training" in said, said


@pytest.mark.slow
def test_cross_validating_auto_repeats_the_choice_without_each_fold(monkeypatch: pytest.MonkeyPatch) -> None:
    """`folds` with `auto`: each fold's calibration chooses again on the other folds alone (the choice made on all
    the training data would have seen the fold it is judged on). The UR10e's 23 poses, 30% held out, 3 folds."""
    from calib_core.estimation import calibrate as pipeline

    seen: list[set[int]] = []
    real = pipeline.choose

    def spy(profile, train, *args, **kwargs):
        seen.append({int(f) for f in train.frame_ids})
        return real(profile, train, *args, **kwargs)

    monkeypatch.setattr(pipeline, "choose", spy)
    ur10 = load_profile(FIGAROH / ROBOTS["ur10e-pose"].profile)
    data = read_dataset(ur10, FIGAROH / ROBOTS["ur10e-pose"].data)
    cal = calibrate(ur10, data, AUTO, holdout=0.3, folds=3)
    train = set(cal.frames["train"])
    assert seen[0] == train and not train & set(cal.frames["holdout"])
    assert len(seen) == 4 and all(s < train for s in seen[1:])
    assert set().union(*(train - s for s in seen[1:])) == train  # each training pose left out of one choice
    assert cal.figures["cv_after"].n == len(train) - cal.figures["cv_after"].excluded
