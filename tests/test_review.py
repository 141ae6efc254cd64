"""Review figures, marks and 3-D geometry against the simulator's ground truth.

Sessions are simulated: the truth is known (`Simulation.exact`, the noise-free measurements, and
the true parameters), and the readings are left unquantised, so with old = nominal and new = truth
the new errors must be exactly the measurement noise and the old ones large, marks must land where
the truth projects, and back-projected board vertices must lie on the predicted board and
reproject to the measured pixels.
"""

from __future__ import annotations

import csv
import io
from pathlib import Path

import numpy as np
import pytest
import yourdfpy
from fastapi.testclient import TestClient
from sim_frames import Frame, measured_frames, unmeasured_frames

from app.errors import NotFound
from app.scene.review import Review, live_geometry
from app.web.server import create_app
from calib_core import Problem, SimulatedRobot, Simulation, calibrate, load_profile, to_csv
from calib_core.model.kinematics import forward
from calib_core.model.profile import Profile


def session(name: str, n: int, unmeasured: int = 0, seed: int = 4) -> tuple[Profile, Simulation, list[Frame]]:
    """A simulated session: n measured frames, then `unmeasured` frames whose detector found nothing."""
    profile = load_profile(name)
    robot = SimulatedRobot.from_profile(profile, seed=seed)
    robot.quantise = False  # readings = the true joint angles: the truth predicts `exact` exactly
    sim = robot.simulate(n)
    frames = measured_frames(sim.data)
    frames += unmeasured_frames(robot, len(frames) + 1, unmeasured)
    return profile, sim, frames


@pytest.fixture(scope="module")
def robonaut_review() -> tuple[Profile, Simulation, list[Frame], Review]:
    profile, sim, frames = session("robonaut-a", 40, unmeasured=2)
    heldout = set(range(1, 11))
    review = Review.build(profile, frames, sim.data, profile.nominal(), sim.true_params, heldout_frames=heldout)
    return profile, sim, frames, review


@pytest.fixture(scope="module")
def nao_review() -> tuple[Profile, Simulation, list[Frame], Review]:
    profile, sim, frames = session("nao", 12, unmeasured=1)
    review = Review.build(profile, frames, sim.data, profile.nominal(), sim.true_params)
    return profile, sim, frames, review


def test_robonaut_errors_are_noise_for_the_truth_and_large_for_nominal(robonaut_review) -> None:
    profile, sim, frames, review = robonaut_review
    data = sim.data
    table = review.table()
    assert [r["index"] for r in table] == [f.index for f in frames]
    measured = [r for r in table if r["status"] == "measured"]
    # One fixture per frame: with the truth, the frame's error is the measurement's noise.
    noise_cm = np.linalg.norm(sim.exact - data.measured, axis=1)
    np.testing.assert_allclose([r["err_new"] for r in measured], noise_cm, rtol=0, atol=1e-9)
    # The old side is the nominal model, exactly as calib_core's Problem predicts it.
    nominal = Problem(profile, data, [], profile.nominal()).predict(profile.nominal())
    np.testing.assert_allclose(
        [r["err_old"] for r in measured], np.linalg.norm(nominal - data.measured, axis=1), rtol=0, atol=1e-9
    )
    s = review.summary()
    assert s["unit"] == "cm" and s["frames"] == 42 and s["measured"] == 40
    assert s["new"]["n"] == s["old"]["n"] == 40
    assert s["new"]["mean"] < 1.0 < 5.0 < s["old"]["mean"]
    assert s["new"]["max"] >= s["new"]["rms"] >= s["new"]["mean"]
    assert sum(s["histogram"]["old"]) == sum(s["histogram"]["new"]) == 40
    assert len(s["histogram"]["edges"]) == len(s["histogram"]["old"]) + 1


def test_heldout_figures_use_only_heldout_frames(robonaut_review) -> None:
    _, _, _, review = robonaut_review
    s = review.summary()
    rows = [r for r in review.table() if r["heldout"]]
    assert [r["index"] for r in rows] == list(range(1, 11)) and s["heldout_frames"] == 10
    for side in ("old", "new"):
        errors = np.array([r[f"err_{side}"] for r in rows])
        assert s[f"heldout_{side}"]["n"] == 10
        assert s[f"heldout_{side}"]["mean"] == pytest.approx(errors.mean())
        assert s[f"heldout_{side}"]["max"] == pytest.approx(errors.max())
        assert s[f"heldout_{side}"]["mean"] != pytest.approx(s[side]["mean"])


def test_frames_without_a_measurement_have_no_error_but_a_prediction(robonaut_review) -> None:
    _, _, _, review = robonaut_review
    row = review.table()[-1]
    assert row == {
        "index": 42,
        "status": "not found",
        "target": 0,
        "err_old": None,
        "err_new": None,
        "heldout": False,
        "band": None,
        "verdict": None,
    }
    g = review.frame_geometry(42)
    assert np.isnan(g.measured_m["old"]).all() and np.isfinite(g.predicted_m["new"]).all()
    marks = review.marks(42)
    assert marks["measured"] == [None] and marks["new"][0] is not None


def test_robonaut_marks_project_where_the_truth_projects(robonaut_review) -> None:
    profile, sim, _, review = robonaut_review
    sensor = profile.sensors[profile.data.sensor]
    truth_px = sensor.project(sim.true_params, sim.exact)
    for k in (0, 7, 23):
        marks = review.marks(k + 1)
        assert marks["role"] == "left" and (marks["width"], marks["height"]) == (640, 480)
        # The measurement carries stereo noise (0.3 px lateral); the truth's prediction is exact.
        assert np.linalg.norm(np.array(marks["measured"][0]) - truth_px[k]) < 1.5
        np.testing.assert_allclose(marks["new"][0], truth_px[k], atol=1e-6)
        assert np.linalg.norm(np.array(marks["old"][0]) - truth_px[k]) > 10


def test_robonaut_geometry_agrees_with_each_sides_urdf(robonaut_review) -> None:
    """The scene shows the URDF generated for each side at the readings: the points must sit on it."""
    _, _, frames, review = robonaut_review
    for side in ("old", "new"):
        urdf = yourdfpy.URDF.load(io.StringIO(review.urdf[side]), build_scene_graph=True, load_meshes=False)
        for f in (frames[0], frames[5], frames[-1]):
            g = review.frame_geometry(f.index)
            np.testing.assert_array_equal(g.joints_rad, f.joints_rad)
            urdf.update_cfg(dict(zip(review.profile.joint_names, g.joints_rad, strict=True)))
            fixture = urdf.get_transform(frame_to="fixture", frame_from="chest")[:3, 3]
            np.testing.assert_allclose(g.predicted_m[side][0], fixture, atol=1e-9)
    # A rigid transform keeps distances: prediction to measurement in 3-D is the frame's error.
    g = review.frame_geometry(3)
    distance_cm = 100 * np.linalg.norm(g.measured_m["new"][0] - g.predicted_m["new"][0])
    assert distance_cm == pytest.approx(review.table()[2]["err_new"])


def test_nao_errors_and_marks(nao_review) -> None:
    _, sim, frames, review = nao_review
    s = review.summary()
    n_measured = len(frames) - 1
    assert s["unit"] == "px" and s["old"]["n"] == s["new"]["n"] == 24 * n_measured
    assert s["new"]["mean"] < 1.0 and s["old"]["mean"] > 10.0
    assert s["heldout_old"] is None and s["heldout_new"] is None
    noise_px = np.linalg.norm(sim.exact - sim.data.measured, axis=1).reshape(n_measured, 24).mean(axis=1)
    errors = [r["err_new"] for r in review.table()[:n_measured]]
    np.testing.assert_allclose(errors, noise_px, rtol=0, atol=1e-9)
    marks = review.marks(2)
    assert marks["role"] == "image" and len(marks["measured"]) == len(marks["old"]) == len(marks["new"]) == 24
    np.testing.assert_allclose(marks["measured"], sim.data.measured[24:48], atol=1e-12)
    np.testing.assert_allclose(marks["new"], sim.exact[24:48], atol=1e-6)


def test_nao_measured_vertices_lie_on_each_sides_predicted_board(nao_review) -> None:
    """Back-projected pixels: on the plane of the board the side predicts, and seen by that side's
    camera exactly at the measured pixel."""
    profile, sim, frames, review = nao_review
    sensor = profile.sensors[profile.data.sensor]
    for k in (0, 4, 9):
        g = review.frame_geometry(frames[k].index)
        for side, p in (("old", profile.nominal()), ("new", sim.true_params)):
            predicted, measured = g.predicted_m[side], g.measured_m[side]
            centre = predicted.mean(axis=0)
            normal = np.linalg.svd(predicted - centre)[2][2]
            assert np.abs((measured - centre) @ normal).max() < 1e-9
            poses = forward(profile, p, frames[k].joints_rad[None], frames=[sensor.frame])
            x = (measured * 1000 - poses.t[sensor.frame][0]) @ poses.R[sensor.frame][0]
            np.testing.assert_allclose(sensor.predict(p, x)[0], sim.data.measured[24 * k : 24 * (k + 1)], atol=1e-6)
        # With the truth the measured vertices sit on the predicted ones, up to the pixel noise
        # (0.2 px, about 0.3 mm across the board, a few mm along grazing rays), well below nominal's offset.
        assert np.linalg.norm(g.measured_m["new"] - g.predicted_m["new"], axis=1).max() < 0.005
        noise_m = np.linalg.norm(g.measured_m["new"] - g.predicted_m["new"], axis=1).mean()
        assert noise_m < np.linalg.norm(g.predicted_m["old"] - g.predicted_m["new"], axis=1).mean() / 3


def test_without_a_new_calibration_only_the_old_side(robonaut_review) -> None:
    profile, sim, frames, _ = robonaut_review
    review = Review.build(profile, frames, sim.data, profile.nominal(), None)
    s = review.summary()
    assert s["new"] is None and s["heldout_new"] is None and s["histogram"]["new"] is None
    assert all(r["err_new"] is None for r in review.table())
    assert review.marks(1)["new"] is None
    assert set(review.frame_geometry(1).predicted_m) == {"old"}
    assert set(review.urdf) == {"old"}


def test_a_session_with_nothing_measured(robonaut_review) -> None:
    profile, _, frames, _ = robonaut_review
    review = Review.build(profile, frames[-2:], None, profile.nominal(), None)
    s = review.summary()
    assert s["measured"] == 0 and s["old"] == {"mean": None, "rms": None, "max": None, "n": 0}
    assert s["histogram"]["edges"] == []
    assert [r["err_old"] for r in review.table()] == [None, None]


def test_unknown_frame_is_a_clear_error(robonaut_review) -> None:
    _, _, _, review = robonaut_review
    for call in (review.frame_geometry, review.marks, review.row):
        with pytest.raises(NotFound, match=r"frame 999 is not in this review \(frames 1\.\.42\)"):
            call(999)


ROOT = Path(__file__).resolve().parents[1]
PROBE_ARM = ROOT / "tests" / "profiles" / "probe-arm.yaml"


@pytest.fixture(scope="module")
def probe_arm() -> tuple[Profile, Simulation, list[Frame]]:
    """Touches of a table and two walls (1-D measurements: the probe's distance from each plane)."""
    profile = load_profile(str(PROBE_ARM))
    robot = SimulatedRobot.from_profile(profile, seed=4)
    robot.quantise = False
    sim = robot.simulate(6)
    return profile, sim, measured_frames(sim.data)


def test_a_plane_s_distances_are_placed_along_its_normal(probe_arm) -> None:
    """Each plane reviewed on its own: the errors are the distance noise with the truth, the measured probe
    lies at the measured distance from that side's plane and off the prediction only along its normal, and
    there are no image marks (a plane makes no image)."""
    profile, sim, frames = probe_arm
    for s, sensor in enumerate(profile.sensors):
        review = Review.build(profile, frames, sim.data, profile.nominal(), sim.true_params, sensor=s)
        rows = np.flatnonzero(sim.data.sensor == s)
        touched = sorted({int(sim.data.frame_ids[sim.data.cfg[r]]) for r in rows})
        table = {r["index"]: r for r in review.table()}
        noise_mm = np.abs(sim.exact[rows, 0] - sim.data.measured[rows, 0])
        np.testing.assert_allclose([table[i]["err_new"] for i in touched], noise_mm, rtol=0, atol=1e-9)
        assert all(table[i]["err_new"] is None for i in table if i not in touched)
        assert review.summary()["unit"] == "mm"
        for i, r in zip(touched, rows, strict=True):
            g = review.frame_geometry(i)
            for side, p in (("old", profile.nominal()), ("new", sim.true_params)):
                poses = forward(profile, p, frames[i - 1].joints_rad[None], frames=[sensor.frame])
                R, t = poses.R[sensor.frame][0], poses.t[sensor.frame][0]
                measured = (g.measured_m[side][0] * 1000 - t) @ R  # the sensor frame, mm
                predicted = (g.predicted_m[side][0] * 1000 - t) @ R
                assert measured @ sensor.normal == pytest.approx(sim.data.measured[r, 0], abs=1e-9)
                off = measured - predicted
                np.testing.assert_allclose(off - (off @ sensor.normal) * sensor.normal, 0.0, atol=1e-9)
            marks = review.marks(i)
            assert marks["role"] is None and marks["width"] is None
            assert marks["measured"] == marks["old"] == marks["new"] == [None]


@pytest.mark.slow
def test_a_plane_sensor_s_review_answers_through_the_api(probe_arm, tmp_path: Path) -> None:
    """The probe arm added from its profile file, its touches imported as CSV: the review, a frame selected
    and its marks answer 200 for every plane (a 1-D measurement answered 500 before)."""
    profile, sim, _ = probe_arm
    with TestClient(create_app(tmp_path / "data", time_scale=20.0), raise_server_exceptions=False) as client:
        added = client.post(
            "/api/robots", data={"name": "arm"}, files={"profile_file": ("probe-arm.yaml", PROBE_ARM.read_bytes())}
        )
        assert added.status_code == 201, added.text
        csv = to_csv(profile, sim.data).encode()
        imported = client.post(
            "/api/sessions/import", data={"robot": "arm", "name": "touches"}, files={"data": ("t.csv", csv)}
        )
        assert imported.status_code == 201, imported.text
        sid = imported.json()["id"]
        for sensor in ("table", "wall", "side"):
            r = client.post("/api/review", json={"session": sid, "old": None, "sensor": sensor})
            assert r.status_code == 200, r.text
            body = r.json()
            assert body["sensor"] == sensor and body["summary"]["unit"] == "mm"
            measured = [row for row in body["table"] if row["err_old"] is not None]
            assert len(measured) == sum(1 for s in sim.data.sensor if profile.sensors[s].name == sensor)
            index = measured[0]["index"]
            assert client.post("/api/review/frame", json={"index": index}).status_code == 200
            marks = client.get(f"/api/review/marks/{index}")
            assert marks.status_code == 200 and marks.json()["role"] is None, marks.text


def test_a_live_look_shows_every_sensor_s_sighting_where_the_truth_puts_it() -> None:
    """A Motoman look at the data set's first pose of two arms in view (leica_rep_self1), through the true
    model: the tracker's reflector and both cameras' faces of both arms, as the data set's cameras saw them at
    that pose; every sighting's rows predicted and placed by its own sensor, the noise-free pixels
    back-projected onto exactly the predicted faces and the tracker's reading within its noise."""
    from app.drivers.simulated import SimulatedDriver

    mm = load_profile("motoman")
    with (ROOT / "sample_sessions" / "motoman-ctu" / "camera_poses.csv").open() as f:
        pose = next(r for r in csv.DictReader(f) if r["source_file"] == "leica_rep_self1_dataset.mat")
    q = np.radians([float(pose[f"{j.name}_deg"]) for j in mm.joints])
    with SimulatedDriver(mm, seed=3, time_scale=50.0, start_rad=q) as d:
        look = d.look()
        truth = d.true_params()
    seen = {(mm.sensors[s.sensor].name, mm.targets[s.target].name) for s in look.sightings}
    assert seen == {("tracker", "LR1")} | {(f"camera{c}", f"markers{a}") for c in (1, 2) for a in (1, 2)}
    g = live_geometry(mm, truth, look.readings_rad, look.sightings)
    rows = [len(s.points) for s in look.sightings]
    assert len(g.predicted_m["old"]) == len(g.measured_m["old"]) == sum(rows) == 1 + 4 * 20
    off = np.linalg.norm(g.measured_m["old"] - g.predicted_m["old"], axis=1)
    assert off[0] < 5 * mm.simulation["noise"]["point"]  # m: the tracker's reading
    assert off[rows[0] :].max() < 1e-9  # the cameras' pixels, noise-free


def _nao_calibrations(seeds: tuple[int, int]) -> tuple[Profile, Simulation, list]:
    """Two NAO sessions of 60 frames from independent draws of the same robot, each calibrated (full)."""
    profile = load_profile("nao")
    sims = [SimulatedRobot.from_profile(profile, seed=s).simulate(60) for s in seeds]
    return profile, sims[0], [calibrate(profile, s.data, "full") for s in sims]


@pytest.mark.slow
@pytest.mark.parametrize("seeds", [(1, 2), (3, 4)])
def test_two_calibrations_of_the_same_robot_are_the_same_on_nearly_every_frame(seeds) -> None:
    """Independent sessions of the same robot: both calibrations are as good, their difference on a frame is
    their uncertainty's (a 0.1-0.2 px shift of all its points, against 0.45 px of noise per point)."""
    profile, sim, (here, there) = _nao_calibrations(seeds)
    review = Review.build(
        profile,
        measured_frames(sim.data),
        sim.data,
        there.params(profile),
        here.params(profile),
        covariances={"old": there.covariance, "new": here.covariance},
    )
    table = review.table()
    verdicts = [r["verdict"] for r in table]
    assert verdicts.count("same") >= 0.9 * len(table)  # 54 and 60 of 60 (seeds 1-2, 3-4)
    changes = np.abs([r["err_new"] - r["err_old"] for r in table])
    assert np.median(changes) > 0.05  # what 0.45 px / sqrt(24 points) = 0.09 px of noise called "changed"
    band = review.summary()["band"]
    assert band["of"] == ["old", "new"] and band["k"] == 2.0 and 0.05 < band["median"] < 0.5


@pytest.mark.slow
def test_a_calibration_against_a_wrong_one_is_better_on_most_frames() -> None:
    """The old calibration's leg offsets off by 1 deg (no covariance: the band is the new calibration's)."""
    profile, sim, (here, _) = _nao_calibrations((5, 6))
    wrong = here.params(profile)
    for name in ("LHipPitch", "LKneePitch", "RHipPitch", "RKneePitch", "LAnklePitch", "RAnklePitch"):
        wrong[profile.param(name)] += np.radians(1.0)
    review = Review.build(
        profile,
        measured_frames(sim.data),
        sim.data,
        wrong,
        here.params(profile),
        covariances={"old": None, "new": here.covariance},
    )
    verdicts = [r["verdict"] for r in review.table()]
    assert verdicts.count("better") >= 0.9 * len(verdicts)
    assert review.summary()["band"]["of"] == ["new"]
    # Without any covariance there is no band and no verdict.
    bare = Review.build(profile, measured_frames(sim.data), sim.data, wrong, here.params(profile))
    assert {r["verdict"] for r in bare.table()} == {None} and bare.summary()["band"]["median"] is None


def test_a_handeye_session_whose_rows_name_only_the_boards_corners_is_reviewed_with_numbers(client) -> None:
    """The hand-eye sample's rows name each ChArUco corner by its id, not its position (as the solver reads them):
    the review of its calibration has an error for every frame on both sides (it read none, "no error to show",
    when it took only the rows' own points), the nominal side through the camera's and board's poses registered
    on the session's frames, and its marks in the image."""
    from desk_jobs import wait_job

    job = wait_job(
        client, client.post("/api/sessions/arm-handeye/calibrations", json={"mode": "offsets"}).json()["job"]
    )
    review = client.post("/api/review/table", json={"session": "arm-handeye", "old": None, "new": job["result"]}).json()
    rows, summary = review["table"], review["summary"]
    assert len(rows) == summary["frames"] == summary["measured"] == 24
    assert all(r["err_old"] is not None and r["err_new"] is not None for r in rows)
    assert summary["new"]["mean"] < 0.2 < 1.0 < summary["old"]["mean"]  # px: the offsets fitted, the nominal's not
    built, _ = client.app.state.desk.reviews.build("arm-handeye", None, job["result"])
    marks = built.marks(1)
    seen = [k for k, uv in enumerate(marks["measured"]) if uv is not None]
    assert seen and all(marks["old"][k] is not None and marks["new"][k] is not None for k in seen)
