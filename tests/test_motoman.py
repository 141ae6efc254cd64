"""The `motoman` profile (specs/motoman.md): its kinematics against an independent standard-DH
product, the tracker registration and calibration against a hidden truth, the CLI on the real CTU
files, self-observation from camera pixels, and identifiability on real data."""

from __future__ import annotations

import csv
import json
import math
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
from jacobian_check import check_jacobian

from app.cli import main
from calib_core import calibrate, load_profile
from calib_core.dataset import Dataset, merge
from calib_core.errors import InputError
from calib_core.estimation.calibrate import observed_mode
from calib_core.estimation.identifiability import find_dependencies
from calib_core.estimation.problem import Problem
from calib_core.estimation.registration import register, registration_params, rigid_fit
from calib_core.estimation.validation import holdout_split
from calib_core.io.csv_format import parse_dataset, to_csv
from calib_core.io.ctu_motoman import camera_dataset, leica_subset, recording
from calib_core.model.kinematics import forward

DATA = Path(__file__).resolve().parents[1] / "sample_sessions" / "motoman-ctu"


def dh_matrix(a: float, d: float, alpha: float, theta: float) -> np.ndarray:
    """Rot_z(theta) Trans_z(d) Trans_x(a) Rot_x(alpha), written out (Utils/KinUtils/dhpars2tfmat.m)."""
    ct, st, ca, sa = math.cos(theta), math.sin(theta), math.cos(alpha), math.sin(alpha)
    return np.array([[ct, -st * ca, st * sa, a * ct], [st, ct * ca, -ct * sa, a * st], [0, sa, ca, d], [0, 0, 0, 1]])


def reference_chain(rows: list[list[float]], q: list[float]) -> np.ndarray:
    T = np.eye(4)
    for (a, d, alpha, offset), qi in zip(rows, q, strict=True):
        T = T @ dh_matrix(a, d, alpha, offset + qi)
    return T


def random_configurations(motoman, n: int, seed: int) -> np.ndarray:
    rng = np.random.default_rng(seed)
    lo, hi = (np.array(v) for v in motoman.joint_limits())
    q = rng.uniform(lo, hi, size=(n, len(motoman.joints)))
    q[:, motoman.joint("E")] = rng.normal(0, 1e-4, n)  # E stands still, as in every CTU file
    return q


def test_kinematics_match_the_data_sets_dh_convention(motoman) -> None:
    """Reflectors, marker faces and cameras against the README's nominal rows, multiplied by hand."""
    right = [
        [0, -0.263, math.radians(15), -math.pi / 2],
        [0.150, 1.4159, -math.pi / 2, 0],
        [0.614, 0, math.pi, -math.pi / 2],
        [0.200, 0, -math.pi / 2, 0],
        [0, -0.640, math.pi / 2, 0],
        [0.030, 0, math.pi / 2, -math.pi / 2],
        [0, 0.200, 0, 0],
    ]
    left = [list(r) for r in right]
    left[0][2] = -math.radians(15)
    p = motoman.nominal()
    qs = random_configurations(motoman, 20, 1)
    poses = forward(motoman, p, qs)
    for arm, rows, end in ((1, right, [0.045, 0.245, 0, -0.38]), (2, left, [0.05, 0.25, 0, 0])):
        names = ["E"] + [f"{j}{arm}" for j in "SLURBT"]
        for n, q in enumerate(qs):
            T = reference_chain([*rows, end], [q[motoman.joint(j)] for j in names] + [0.0])
            lr = motoman.frame(f"LR{arm}")
            np.testing.assert_allclose(poses.t[lr][n], T[:3, 3], atol=1e-12)
            np.testing.assert_allclose(poses.R[lr][n], T[:3, :3], atol=1e-12)
    # Camera 1 after the toolbox's calibration: base -> head (E) -> eye.
    cam = motoman.frame("camera1")
    for n, q in enumerate(qs):
        T = reference_chain([[0.0741, 1.8034, -2.5086, -2.7753], [0, -0.567, 0, 0.2863]], [q[motoman.joint("E")], 0.0])
        np.testing.assert_allclose(poses.t[cam][n], T[:3, 3], atol=1e-12)


def synthetic_tracker(
    motoman, truth: np.ndarray, n: int, seed: int, noise_m: float = 2e-5, arm: str = "right"
) -> Dataset:
    """What a tracker standing at `truth`'s registration would report for random configurations."""
    q = random_configurations(motoman, n, seed)
    target = motoman.target("LR1" if arm == "right" else "LR2")
    data = Dataset(
        robot="motoman",
        frame_ids=np.arange(1, n + 1),
        joints=q,
        cfg=np.arange(n),
        target=np.full(n, target),
        point=np.zeros((n, 3)),
        vertex=np.full(n, -1),
        measured=np.zeros((n, 3)),
        sensor=np.full(n, motoman.data.sensor),
    )
    rng = np.random.default_rng(seed + 100)
    exact = Problem(motoman, data, [], truth).predict(truth)
    return replace(data, measured=exact + rng.normal(0, noise_m, exact.shape))


def perturbed_truth(motoman, seed: int) -> np.ndarray:
    """The nominal model with mm-sized and sub-degree errors on the full mode's parameters, and a
    tracker standing 3 m away, turned by 100 deg."""
    rng = np.random.default_rng(seed)
    truth = motoman.nominal().copy()
    for i in motoman.mode("full").free:
        kind = motoman.parameters[i].kind
        truth[i] += rng.normal(0, 0.002) if kind == "length" else rng.normal(0, math.radians(0.2))
    reg = registration_params(motoman)
    truth[reg] = [2.5, -1.2, 0.4, math.radians(100), math.radians(3), math.radians(-2)]
    return truth


@pytest.mark.parametrize("mode", ["offsets", "full"])
def test_calibration_recovers_a_hidden_truth_and_the_tracker_pose(motoman, mode: str) -> None:
    truth = perturbed_truth(motoman, 7)
    if mode == "offsets":  # only the offsets and the reflector row differ from nominal
        keep = set(motoman.mode("offsets").free)
        truth = np.where([i in keep for i in range(len(truth))], truth, motoman.nominal())
    data = synthetic_tracker(motoman, truth, 300, seed=3)
    cal = calibrate(motoman, data, mode, holdout=0.3, seed=1)
    p = cal.params(motoman)
    assert cal.figures["holdout_before"].rms > 20 * cal.figures["holdout_after"].rms
    assert cal.figures["holdout_after"].rms < 2.5 * math.sqrt(3) * 2e-5  # the tracker's noise, 3 axes
    reg = registration_params(motoman)
    np.testing.assert_allclose(p[reg][:3], truth[reg][:3], atol=1e-4)  # m
    np.testing.assert_allclose(p[reg][3:], truth[reg][3:], atol=math.radians(0.02))
    for i in observed_mode(motoman, data, motoman.mode(mode)).free:
        tol = 5e-4 if motoman.parameters[i].kind == "length" else math.radians(0.05)
        assert abs(p[i] - truth[i]) < tol, (motoman.parameters[i].name, p[i], truth[i])


def test_rigid_fit_needs_points_off_a_line() -> None:
    a = np.array([[0.0, 0, 0], [1, 0, 0], [2, 0, 0]])
    with pytest.raises(InputError, match="not on one line"):
        rigid_fit(a, a)


def test_the_other_arm_is_left_alone_and_rows_of_two_setups_are_warned_about(motoman) -> None:
    truth = perturbed_truth(motoman, 8)
    data = synthetic_tracker(motoman, truth, 120, seed=4)
    cal = calibrate(motoman, data, "offsets")
    estimated = {q.name for q in cal.parameters if q.estimated}
    assert "L1.offset" in estimated and "L2.offset" not in estimated
    assert not any("L2" in w for w in cal.warnings)
    moved = replace(data, measured=data.measured + np.where(np.arange(120) < 60, 0.0, 1.5)[:, None])
    mixed = calibrate(motoman, moved, "offsets")
    assert any("two tracker set-ups" in w for w in mixed.warnings)


def test_csv_without_frame_column_and_default_arm(motoman) -> None:
    truth = perturbed_truth(motoman, 9)
    data = synthetic_tracker(motoman, truth, 10, seed=5)
    text = to_csv(motoman, data)
    header = text.splitlines()[0].split(",")
    assert "frame" not in header and "reflector_arm" in header
    back = parse_dataset(motoman, text)
    np.testing.assert_allclose(back.measured, data.measured, atol=1e-6)
    # Without the reflector_arm column every row is the right arm's.
    cols = [c for c in header if c != "reflector_arm"]
    rows = list(csv.DictReader(text.splitlines()))
    no_arm = "\n".join([",".join(cols)] + [",".join(r[c] for c in cols) for r in rows])
    assert (parse_dataset(motoman, no_arm).target == motoman.target("LR1")).all()
    with pytest.raises(InputError, match="'middle' is not one of right, left"):
        parse_dataset(motoman, text.replace("\nright,", "\nmiddle,", 1))


@pytest.mark.parametrize(
    ("subset", "mode", "readme_rms_mm"),
    [("feb2019-A-right", "full", 0.42), ("feb2019-B-right-cube", "full", 0.073), ("aug2019-right", "full", 2.52)],
)
@pytest.mark.slow
def test_real_tracker_data_held_out_as_good_as_plain_least_squares(
    motoman, subset: str, mode: str, readme_rms_mm: float
) -> None:
    """Mean held-out RMS over 10 random 70/30 splits, within 5% of the README's plain least squares
    (the same splits' count there), with every robot parameter within 25 mm and 2 deg of nominal."""
    data = leica_subset(motoman, DATA, subset)
    rms, nominal = [], motoman.nominal()
    for seed in range(10):
        cal = calibrate(motoman, data, mode, holdout=0.3, seed=seed)
        p = cal.params(motoman)
        test = data.select(holdout_split(data, 0.3, seed)[1])
        e = np.linalg.norm(Problem(motoman, test, [], p).predict(p) - test.measured, axis=1)
        rms.append(1000 * np.sqrt(np.mean(e**2)))
        for i, prm in enumerate(motoman.parameters):
            if i in registration_params(motoman):
                continue
            limit = 0.025 if prm.kind == "length" else math.radians(2.0)
            assert abs(p[i] - nominal[i]) <= limit, (prm.name, p[i] - nominal[i])
    assert np.mean(rms) <= 1.05 * readme_rms_mm


def test_cli_solves_one_setup_and_predicts_in_the_tracker_frame(tmp_path: Path) -> None:
    cal = tmp_path / "cal.json"
    args = ["solve", "--robot", "motoman", "--mode", "offsets", "--data", str(DATA / "leica_feb2019.csv")]
    assert main([*args, "--where", "leica_frame_group=A", "--where", "reflector_arm=right", "--out", str(cal)]) == 0
    out = tmp_path / "pred.csv"
    where = ["--where", "leica_frame_group=A", "--where", "reflector_arm=right"]
    assert (
        main(
            [
                "predict",
                "--robot",
                "motoman",
                "--calibration",
                str(cal),
                "--data",
                str(DATA / "leica_feb2019.csv"),
                *where,
                "--out",
                str(out),
            ]
        )
        == 0
    )
    rows = list(csv.DictReader(out.open()))
    assert len(rows) == 324
    e = [
        math.dist(
            [float(r[c]) for c in ("x_m", "y_m", "z_m")], [float(r[c]) for c in ("pred_x_m", "pred_y_m", "pred_z_m")]
        )
        for r in rows
    ]
    assert np.sqrt(np.mean(np.square(e))) < 0.001  # metres: the calibration's registration puts it in the tracker frame
    assert main([*args, "--where", "frame_group=A", "--out", str(tmp_path / "x.json")]) == 2
    assert main([*args, "--where", "leica_frame_group=Z", "--out", str(tmp_path / "x.json")]) == 2
    assert not (tmp_path / "x.json").exists()


def test_identifiability_names_what_the_tracker_cannot_separate(motoman) -> None:
    """Freeing S, T and the torso row: the data cannot tell them from the registration and the
    reflector row while E stands still, and the report says which."""
    data = leica_subset(motoman, DATA, "feb2019-A-right")
    names = motoman.parameter_names
    extra = [names.index(n) for n in ("TT1.offset", "TT1.d", "S1.offset", "T1.offset", "T1.d")]
    free = list(observed_mode(motoman, data, motoman.mode("full")).free) + extra
    p0 = register(motoman, data, motoman.nominal())
    problem = Problem(motoman, data, free, p0)
    deps = find_dependencies(motoman, problem.residuals_jacobian(problem.x0)[1][: problem.n_data_rows], free)
    held = {names[d.fixed] for d in deps}
    assert held == {"TT1.offset", "TT1.d", "S1.offset", "T1.offset", "T1.d"}
    text = " ".join(d.describe(motoman) for d in deps)
    assert "yaw(tracker)" in text and "offset(LR1)" in text


def camera_truth(motoman, rng: np.random.Generator, truth: np.ndarray | None = None) -> np.ndarray:
    """`truth` (default nominal) with mm-sized, sub-degree and 10 px errors on the cameras mode's parameters."""
    truth = motoman.nominal().copy() if truth is None else truth.copy()
    for i in motoman.mode("cameras").free:
        kind = motoman.parameters[i].kind
        if kind == "length":
            truth[i] += rng.normal(0, 0.002)
        elif kind == "angle":
            truth[i] += rng.normal(0, math.radians(0.2))
        elif kind == "px":
            truth[i] += rng.normal(0, 10.0)
    return truth


def synthetic_cameras(motoman, truth: np.ndarray, q: np.ndarray, rng: np.random.Generator) -> Dataset:
    """Both cameras' pixels (0.5 px noise) of the marker faces in front of them, configurations q."""
    n = len(q)
    parts = []
    for cam in ("camera1", "camera2"):
        cfg = np.repeat(np.arange(n), 40)
        target = np.tile(np.repeat([motoman.target("markers1"), motoman.target("markers2")], 20), n)
        vertex = np.tile(np.arange(20), 2 * n)
        data = Dataset(
            "motoman",
            np.arange(1, n + 1),
            q,
            cfg,
            target,
            motoman.targets[target[0]].points[vertex],
            vertex,
            np.zeros((40 * n, 2)),
            np.full(40 * n, [s.name for s in motoman.sensors].index(cam)),
        )
        uv = Problem(motoman, data, [], truth).predict(truth)
        x = Problem(motoman, data, [], truth).sensor_points(truth)
        seen = (x[:, 2] > 0.3) & (np.abs(uv - 2500).max(axis=1) < 2500)  # in front, inside a 5000 px image
        data = data.observations(seen)
        exact = Problem(motoman, data, [], truth).predict(truth)
        parts.append(replace(data, measured=exact + rng.normal(0, 0.5, exact.shape)))
    return merge(parts)


def test_self_observation_recovers_a_hidden_truth_from_pixels(motoman) -> None:
    """Two cameras seeing the marker faces of both arms, pixels made from a hidden truth."""
    rng = np.random.default_rng(11)
    truth = camera_truth(motoman, rng)
    cal = calibrate(
        motoman,
        synthetic_cameras(motoman, truth, random_configurations(motoman, 150, 12), rng),
        "cameras",
        holdout=0.3,
        seed=2,
    )
    assert set(cal.sensor_figures) == {"camera1", "camera2"}
    for f in cal.sensor_figures.values():
        assert f["before"].rms > 10 * f["after"].rms
        assert f["after"].rms < 1.0  # px: the 0.5 px noise
        assert f["holdout_after"].rms < 1.3 * f["after"].rms
        assert f["holdout_after"].n > 0.2 * (f["holdout_after"].n + f["after"].n)
    p = cal.params(motoman)
    offsets = [motoman.param(f"{j}{a}.offset") for j in "LURB" for a in (1, 2)]
    for i in offsets:
        assert abs(p[i] - truth[i]) < math.radians(0.05), motoman.parameters[i].name
    # The reported standard deviations are honest: every estimate within 4 of them of the truth.
    z = [abs(e.value - motoman.to_display(i, truth[i])) / e.std for i, e in enumerate(cal.parameters) if e.std]
    assert max(z) < 4.0, max(z)


def test_tracker_and_cameras_in_one_calibration(motoman) -> None:
    """One session's three sensors: the tracker's 3-D points (m) and both cameras' pixels of the same
    poses, each weighed by its own noise, solved together; a hidden truth in the robot, the tracker's
    pose and the cameras, recovered within the reported standard deviations."""
    rng = np.random.default_rng(21)
    free = set(motoman.mode("tracker-cameras").free)
    truth = camera_truth(
        motoman,
        rng,
        np.where([i in free for i in range(len(motoman.parameters))], perturbed_truth(motoman, 8), motoman.nominal()),
    )
    q = random_configurations(motoman, 120, 22)
    tracker = synthetic_tracker(motoman, truth, 120, seed=23)
    tracker = replace(
        tracker, joints=q, measured=Problem(motoman, replace(tracker, joints=q), [], truth).predict(truth)
    )
    tracker = replace(tracker, measured=tracker.measured + rng.normal(0, 2e-5, tracker.measured.shape))
    data = merge([tracker, synthetic_cameras(motoman, truth, q, rng)])
    assert data.sensors == [0, 1, 2] and data.n_configurations == 120
    cal = calibrate(motoman, data, "tracker-cameras", holdout=0.25, seed=1)
    assert cal.converged and set(cal.sensor_figures) == {"tracker", "camera1", "camera2"}
    assert cal.sensor_figures["tracker"]["holdout_after"].rms < 1e-4  # m: the 20 um noise
    for name in ("camera1", "camera2"):
        assert cal.sensor_figures[name]["holdout_after"].rms < 1.0  # px: the 0.5 px noise
    held = {h.parameter for h in cal.identifiability.held_fixed}
    offsets = [f"{j}{a}.offset" for j in "LURB" for a in (1, 2)]
    for e in cal.parameters:
        if e.name in offsets and e.name not in held:
            i = motoman.param(e.name)
            assert abs(e.value - motoman.to_display(i, truth[i])) < 4 * e.std, (e.name, e.value, e.std)


def test_mixed_sensors_have_an_exact_jacobian(motoman) -> None:
    """3-D points and pixels in one problem: every column against central differences."""
    rng = np.random.default_rng(31)
    q = random_configurations(motoman, 80, 32)
    tracker = replace(synthetic_tracker(motoman, motoman.nominal(), 80, seed=33), joints=q)
    data = merge([tracker, synthetic_cameras(motoman, motoman.nominal(), q, rng)])
    data = replace(data, measured=data.measured + rng.normal(0, 0.01, data.measured.shape))
    assert data.sensors == [0, 1, 2]
    mode = motoman.mode("tracker-cameras")
    problem = Problem(
        motoman, data, list(mode.free), camera_truth(motoman, rng, perturbed_truth(motoman, 9)), mode.ties, mode.priors
    )
    assert check_jacobian(problem, [motoman.parameters[i].name for i in mode.free]) > 40


@pytest.mark.slow
def test_a_real_recording_of_three_sensors_calibrates_per_mode(motoman) -> None:
    """The left arm's 6x6x6 cube as one session: per pose the tracker's reading and both cameras'
    pixels. Each mode fits the sensors it names (the tracker's modes the tracker alone, exactly as on
    the tracker file); `tracker-cameras` fits all three, each weighed by its own scatter."""
    data = recording(motoman, DATA, "leica_left_hand_6x6x6_dataset.mat")
    assert data.sensors == [0, 1, 2] and data.n_configurations == 216
    assert int(np.sum(data.sensor == 0)) == 208  # the poses the tracker read
    alone = calibrate(motoman, leica_subset(motoman, DATA, "feb2019-left-cube"), "offsets")
    in_session = calibrate(motoman, data, "offsets")
    assert in_session.sensor_figures == {}  # the tracker's observations only
    assert in_session.figures["after"].rms == pytest.approx(alone.figures["after"].rms, rel=1e-9)
    both = calibrate(motoman, data, "tracker-cameras", holdout=0.3)
    assert both.converged
    f = both.sensor_figures
    assert f["tracker"]["holdout_after"].rms < 0.7 * f["tracker"]["holdout_before"].rms
    for cam in ("camera1", "camera2"):
        assert f[cam]["holdout_after"].rms < 0.1 * f[cam]["holdout_before"].rms
    with pytest.raises(InputError, match="fits observations of tracker"):
        calibrate(motoman, data.of_sensor(1), "offsets")


@pytest.mark.slow
def test_real_camera_pixels_calibrate_and_the_tracker_agrees(motoman) -> None:
    """The CTU pixels (four source files, for speed): the camera-only calibration explains them far
    better than nominal, and the tracker it never saw finds the left arm's cube no worse."""
    sources = {
        "leica_left_hand_6x6x6_dataset.mat",
        "leica_right_hand_6x6x6_dataset.mat",
        "no_leica_self_upper1_4x4_dataset.mat",
        "no_leica_wall_table1_5x5_dataset.mat",
    }
    cal = calibrate(motoman, camera_dataset(motoman, DATA, sources), "cameras")
    for f in cal.sensor_figures.values():
        assert f["after"].median < 0.4 * f["before"].median
    cube = leica_subset(motoman, DATA, "feb2019-left-cube")
    errors = {}
    for label, p in (("nominal", motoman.nominal()), ("cameras", cal.params(motoman))):
        q = register(motoman, cube, p)
        errors[label] = np.sqrt(
            np.mean(np.sum((Problem(motoman, cube, [], q).predict(q) - cube.measured) ** 2, axis=1))
        )
    assert errors["cameras"] < errors["nominal"]


def test_a_parameter_beyond_its_bound_stops_there_with_a_warning(motoman) -> None:
    """The toolbox's bound on the reflector row is 5 cm: a reflector mounted 8 cm further out is
    not physical for the profile, and the calibration says so instead of wandering off."""
    truth = motoman.nominal().copy()
    d = motoman.param("LR1.d")
    truth[d] += 0.08
    truth[registration_params(motoman)] = [2.0, 1.0, 0.5, 0.3, 0.0, 0.0]
    data = synthetic_tracker(motoman, truth, 150, seed=6)
    cal = calibrate(motoman, data, "offsets")
    p = cal.params(motoman)
    assert abs(p[d] - motoman.nominal()[d]) <= 0.05 + 1e-12
    assert any("d(LR1)" in w and "bound" in w for w in cal.warnings), cal.warnings


def test_a_mode_without_the_registration_needs_a_base_from_the_same_setup(motoman) -> None:
    truth = perturbed_truth(motoman, 10)
    data = synthetic_tracker(motoman, truth, 60, seed=7)
    offsets = motoman.mode("offsets")
    arm_only = replace(
        offsets, name="arm", free=tuple(i for i in offsets.free if i not in registration_params(motoman))
    )
    motoman = replace(motoman, modes={**motoman.modes, "arm": arm_only})
    with pytest.raises(InputError, match="does not estimate the registration of 'tracker'"):
        calibrate(motoman, data, "arm")
    first = calibrate(motoman, data, "registration")
    again = calibrate(motoman, data, "arm", first)  # the registration comes from the base
    assert again.figures["before"].rms < 0.01  # m: the base's registration puts the model in place
    with pytest.raises(
        InputError, match="mode 'cameras' fits observations of camera1, camera2; these data hold tracker"
    ):
        calibrate(motoman, data, "cameras")


@pytest.mark.slow
def test_cli_self_observe_writes_a_calibration_export_takes(tmp_path: Path) -> None:
    cal, yaml_out = tmp_path / "cams.json", tmp_path / "cams.yaml"
    sources = ["--source", "leica_left_hand_6x6x6_dataset.mat", "--source", "no_leica_wall_table1_5x5_dataset.mat"]
    assert main(["self-observe", "--robot", "motoman", "--data", str(DATA), *sources, "--out", str(cal)]) == 0
    doc = json.loads(cal.read_text())
    figs = doc["figures"]
    assert figs["holdout_after"]["median"] < 0.4 * figs["holdout_before"]["median"]  # px
    offsets = {p["name"]: p for p in doc["parameters"] if p["name"].endswith(".offset") and p["estimated"]}
    assert {"L2.offset", "U2.offset"} <= set(offsets) and all(p["std"] > 0 for p in offsets.values())
    assert (
        main(["export", "--robot", "motoman", "--calibration", str(cal), "--format", "yaml", "--out", str(yaml_out)])
        == 0
    )
    assert "L2:" in yaml_out.read_text()


@pytest.mark.parametrize(
    ("line", "column", "value", "words"),
    [(3, 4, "7", "arm 7 is not 1 or 2"), (3, 6, "abc", "'abc' is not a number"), (3, 3, "21", "face 21 is not")],
)
def test_self_observe_names_the_bad_line_and_writes_nothing(
    tmp_path: Path, line: int, column: int, value: str, words: str
) -> None:
    (tmp_path / "camera_poses.csv").write_text(
        "source_file,pose_id,E_deg," + ",".join(f"{j}{a}_deg" for a in (1, 2) for j in "SLURBT") + "\n"
        "f.mat,1," + ",".join(["0"] * 13) + "\n"
    )
    rows = ["source_file,pose_id,face_id,arm,camera,u_px,v_px"] + ["f.mat,1,3,1,1,1500.5,3300.25"] * 3
    cells = rows[line - 1].split(",")
    cells[column - 1] = value
    rows[line - 1] = ",".join(cells)
    (tmp_path / "camera_observations.csv").write_text("\n".join(rows) + "\n")
    out = tmp_path / "x.json"
    with pytest.raises(InputError, match=words) as err:
        camera_dataset(load_profile("motoman"), tmp_path)
    assert f"line {line}" in str(err.value)
    assert main(["self-observe", "--robot", "motoman", "--data", str(tmp_path), "--out", str(out)]) == 2
    assert not out.exists()
