"""Kinematics and measurement models against independent implementations written from the specs.

The reference chains below are built straight from specs/robonaut-a.md and specs/nao.md with plain 4 x 4
matrices and the spec's own numbers (hard-coded here, not read from the profiles), so a wrong op order,
sign, unit, axis or nominal value in the profiles or in calib_core.kinematics shows up as a mismatch.
The exact Jacobians are checked against central finite differences of the residuals, and the distortion
model against OpenCV's cv2.projectPoints.
"""

from __future__ import annotations

import csv
import io
import math
from dataclasses import replace
from importlib import resources

import cv2
import numpy as np
import pytest

# --- Robonaut (specs/robonaut-a.md) -----------------------------------------------------------------
from jacobian_check import check_jacobian, perturbed
from spec_tables import RN_ARM, RN_JOINTS, RN_NECK, RN_TABLE_I, RN_TABLE_II

from calib_core import Problem, SimulatedRobot, load_profile, parse_dataset, to_csv

RN_PE = np.array([10.0, 0.0, 0.0])  # nominal fixture centre in the hand frame, cm


def _trans(v) -> np.ndarray:
    T = np.eye(4)
    T[:3, 3] = v
    return T


def _rot(axis, angle: float) -> np.ndarray:
    """Homogeneous rotation by `angle` (rad) about the unit `axis` (Rodrigues, written out)."""
    x, y, z = np.asarray(axis, float) / np.linalg.norm(axis)
    c, s, C = math.cos(angle), math.sin(angle), 1 - math.cos(angle)
    T = np.eye(4)
    T[:3, :3] = [
        [c + x * x * C, x * y * C - z * s, x * z * C + y * s],
        [y * x * C + z * s, c + y * y * C, y * z * C - x * s],
        [z * x * C - y * s, z * y * C + x * s, c + z * z * C],
    ]
    return T


def _rx(a: float) -> np.ndarray:
    return _rot([1, 0, 0], a)


def _ry(a: float) -> np.ndarray:
    return _rot([0, 1, 0], a)


def _rz(a: float) -> np.ndarray:
    return _rot([0, 0, 1], a)


def robonaut_reference(table: dict, pe: np.ndarray, q_deg: dict[str, float]) -> np.ndarray:
    """P_e,i = T_CE(q)^-1 T_CH(q) P_e with A_i = Trans_x(a) Rot_x(alpha) Trans_z(d) Rot_z(theta + q)."""

    def A(k: int, name: str) -> np.ndarray:
        a, d = table["a"][k], table["d"][k]
        alpha, theta = math.radians(table["alpha"][k]), math.radians(table["theta"][k])
        return _trans([a, 0, 0]) @ _rx(alpha) @ _trans([0, 0, d]) @ _rz(theta + math.radians(q_deg[name]))

    T_CH = np.eye(4)
    for k, name in enumerate(RN_ARM):
        T_CH = T_CH @ A(k, name)
    T_CE = np.eye(4)
    for k, name in enumerate(RN_NECK):
        T_CE = T_CE @ A(len(RN_ARM) + k, name)
    return (np.linalg.inv(T_CE) @ T_CH @ np.append(pe, 1.0))[:3]


def _robonaut_csv(n: int, seed: int) -> tuple[str, list[dict[str, float]]]:
    """A CSV in the spec's format (columns shuffled, an extra column) with random joint readings."""
    rng = np.random.default_rng(seed)
    columns = ["frame", *RN_JOINTS, "x", "y", "z", "comment"]
    rng.shuffle(columns)
    rows, qs = [], []
    for f in range(n):
        q = {j: round(float(rng.uniform(-120, 120)), 6) for j in RN_JOINTS}
        values = {"frame": f + 1, "x": 1.0, "y": 2.0, "z": 3.0, "comment": "ignored", **q}
        rows.append([str(values[c]) for c in columns])
        qs.append(q)
    out = io.StringIO()
    writer = csv.writer(out)
    writer.writerow(columns)
    writer.writerows(rows)
    return out.getvalue(), qs


@pytest.mark.parametrize("which", ["nominal", "truth"])
def test_robonaut_prediction_matches_spec_chain(rn, which: str) -> None:
    text, qs = _robonaut_csv(40, seed=1)
    data = parse_dataset(rn, text, "random.csv")
    if which == "nominal":
        table, p = RN_TABLE_I, rn.nominal()
    else:
        table, p = RN_TABLE_II, rn.true_params()
    pred = Problem(rn, data, [], p, noise_model=False).predict(p)
    expected = np.array([robonaut_reference(table, RN_PE, q) for q in qs])
    assert pred.shape == (40, 3)
    # The points span tens of cm, so agreement to 1e-9 cm is not an accident.
    assert np.ptp(expected, axis=0).min() > 10.0
    np.testing.assert_allclose(pred, expected, rtol=0, atol=1e-9)


def test_robonaut_prediction_moves_with_the_fixture_point(rn) -> None:
    """P_e is a parameter: moving it in the profile moves the prediction as the spec chain says."""
    text, qs = _robonaut_csv(10, seed=2)
    data = parse_dataset(rn, text, "random.csv")
    pe = np.array([12.5, -1.5, 3.0])
    p = rn.params_from_display({"fixture.x": pe[0], "fixture.y": pe[1], "fixture.z": pe[2]})
    pred = Problem(rn, data, [], p, noise_model=False).predict(p)
    expected = np.array([robonaut_reference(RN_TABLE_I, pe, q) for q in qs])
    np.testing.assert_allclose(pred, expected, rtol=0, atol=1e-9)


# --- NAO (specs/nao.md) ------------------------------------------------------------------------------

NAO_LEG = ["HipYawPitch", "HipRoll", "HipPitch", "KneePitch", "AnklePitch", "AnkleRoll"]
NAO_TRUTH = {  # the means of the paper's Table 2 (deg, mm)
    "CamYaw": 0.4660,
    "CamPitch": -4.5338,
    "CamRoll": -1.8354,
    "LHipYawPitch": -2.5029,
    "LHipRoll": 0.9392,
    "LHipPitch": 0.8049,
    "LKneePitch": -1.5869,
    "LAnklePitch": 1.6285,
    "LAnkleRoll": -0.1476,
    "RHipYawPitch": -0.9565,
    "RHipRoll": 0.2258,
    "RHipPitch": 1.3778,
    "RKneePitch": -0.0065,
    "RAnklePitch": 0.7371,
    "RAnkleRoll": -0.7784,
    "LRotZ": -0.4419,
    "LTransX": -0.8538,
    "LTransY": 0.6988,
    "RRotZ": 0.8289,
    "RTransX": -1.5198,
    "RTransY": 1.8391,
}
NAO_PARAMS = list(NAO_TRUTH)


def nao_reference(params: dict[str, float], side: str, q: dict[str, float], p: np.ndarray) -> np.ndarray:
    """(u, v) of vertex p (sole frame, mm) of the `side` board: the spec's chain and its Eq. 1."""
    s = "L" if side == "left" else "R"
    r2 = 1 / math.sqrt(2)
    layout = [
        ((0, 50 if s == "L" else -50, 0), (0, r2, -r2) if s == "L" else (0, r2, r2)),
        ((0, 0, 0), (1, 0, 0)),
        ((0, 0, 0), (0, 1, 0)),
        ((0, 0, -100), (0, 1, 0)),
        ((0, 0, -102.9), (0, 1, 0)),
        ((0, 0, 0), (1, 0, 0)),
    ]
    T = np.eye(4)
    for joint, (pos, axis) in zip(NAO_LEG, layout, strict=True):
        name = s + joint
        T = T @ _trans(pos) @ _rot(axis, math.radians(q[name] + params[name]))
    T_sole = T @ _trans([0, 0, -45.19])
    board = (
        _rz(math.radians(params[s + "RotZ"]))
        @ _trans([params[s + "TransX"], 0, 0])
        @ _trans([0, params[s + "TransY"], 0])
    )
    T_C = (
        _trans([0, 0, 211.5])
        @ _rz(math.radians(q["HeadYaw"]))
        @ _ry(math.radians(q["HeadPitch"]))
        @ _trans([50.71, 0, 17.74])
        @ _ry(math.radians(39.7))
        @ _ry(math.radians(params["CamPitch"]))
        @ _rx(math.radians(params["CamRoll"]))
        @ _rz(math.radians(params["CamYaw"]))
    )
    x, y, z = (np.linalg.inv(T_C) @ T_sole @ board @ np.append(p, 1.0))[:3]
    f, cu, cv = 562.5, 324.0, 189.0
    return np.array([cu - f * y / x, cv - f * z / x])


@pytest.fixture(scope="module")
def nao_sim(nao):
    return SimulatedRobot.from_profile(nao, seed=5).simulate()


def test_nao_board_vertices_match_spec(nao) -> None:
    """6 x 4 inner vertices of 25 mm tiles, centred 17 mm ahead of the ankle projection, z = 0."""
    expected = sorted((17 + 25 * (c - 2.5), 25 * (r - 1.5), 0.0) for r in range(4) for c in range(6))
    for name in ("left_board", "right_board"):
        grid = nao.targets[nao.target(name)].grid
        got = sorted(tuple(float(v) for v in row) for row in grid)
        np.testing.assert_allclose(np.array(got), np.array(expected), atol=1e-12)


@pytest.mark.slow
@pytest.mark.parametrize("which", ["nominal", "truth"])
def test_nao_prediction_matches_spec_chain(nao, nao_sim, which: str) -> None:
    # Round-trip through the spec's CSV format; the reference reads the CSV columns itself.
    text = to_csv(nao, nao_sim.data)
    data = parse_dataset(nao, text, "nao.csv")
    rows = list(csv.DictReader(io.StringIO(text)))
    if which == "nominal":
        params, p = dict.fromkeys(NAO_PARAMS, 0.0), nao.nominal()
    else:
        params, p = NAO_TRUTH, nao_sim.true_params
        # The simulator's truth is the spec's Table 2 means.
        for name, value in NAO_TRUTH.items():
            i = nao.param(name)
            assert nao.to_display(i, p[i]) == pytest.approx(value, abs=1e-12)
    pred = Problem(nao, data, [], p, noise_model=False).predict(p)
    expected = []
    for row in rows:
        q = {k: float(v) for k, v in row.items() if k not in ("chain", "frame", "vertex")}
        vertex = np.array([q["bx"], q["by"], q["bz"]])
        expected.append(nao_reference(params, row["chain"], q, vertex))
    expected = np.array(expected)
    assert pred.shape == expected.shape == (3456, 2)
    np.testing.assert_allclose(pred, expected, rtol=0, atol=1e-6)


def test_nao_prediction_is_sensitive_to_every_parameter(nao, nao_sim) -> None:
    """Guard against a reference and a library that agree only because a parameter does nothing."""
    data = nao_sim.data.select(np.arange(0, 144, 6))
    base = Problem(nao, data, [], nao.nominal(), noise_model=False).predict(nao.nominal())
    for name in NAO_PARAMS:
        p = nao.params_from_display({name: 1.0})
        moved = Problem(nao, data, [], p, noise_model=False).predict(p)
        assert np.abs(moved - base).max() > 0.5, name


# --- exact Jacobians against central differences ------------------------------------------------------


def _random_robonaut_data(profile, n: int, seed: int):
    text, _ = _robonaut_csv(n, seed)
    data = parse_dataset(profile, text, "random.csv")
    rng = np.random.default_rng(seed)
    return replace(data, measured=rng.normal(0, 30, data.measured.shape))


def test_robonaut_jacobian_all_parameters(rn) -> None:
    rng = np.random.default_rng(11)
    data = _random_robonaut_data(rn, 25, seed=3)
    free = list(range(len(rn.parameters)))
    problem = Problem(rn, data, free, perturbed(rn, rng), noise_model=False)
    nonzero = check_jacobian(problem, rn.parameter_names)
    # Every kinematic parameter (10 joints x 4 DH values + P_e) moves the point; only the
    # intrinsics of a point3d sensor do not.
    assert nonzero == 43


def test_robonaut_jacobian_full_mode_with_ties_and_noise_model(rn) -> None:
    """The mode's free set with its ties, whitened by the stereo noise model (a fixed W)."""
    rng = np.random.default_rng(12)
    data = SimulatedRobot.from_profile(rn, seed=4).simulate(30).data
    mode = rn.mode("full")
    p0 = perturbed(rn, rng)
    for tie in mode.ties:
        p0[tie.follower] = tie.sign * p0[tie.leader]
    problem = Problem(rn, data, list(mode.free), p0, mode.ties, noise_model=True)
    # The ties hold in the parameters the problem builds.
    p = problem.params(problem.x0 + 0.01)
    for tie in mode.ties:
        assert p[tie.follower] == pytest.approx(tie.sign * p[tie.leader], abs=1e-12)
    names = [rn.parameters[i].name for i in mode.free]
    assert check_jacobian(problem, names) == len(mode.free)


def _random_nao_data(profile, sim, seed: int):
    """A subset of visible stances, readings moved at random by up to 3 deg (still in view)."""
    rng = np.random.default_rng(seed)
    data = sim.data.select(np.sort(rng.choice(sim.data.n_configurations, 16, replace=False)))
    joints = data.joints + np.radians(rng.uniform(-3, 3, data.joints.shape))
    return replace(data, joints=joints, measured=data.measured + rng.normal(0, 5, data.measured.shape))


def test_nao_jacobian_all_parameters(nao, nao_sim) -> None:
    rng = np.random.default_rng(13)
    data = _random_nao_data(nao, nao_sim, seed=6)
    free = list(range(len(nao.parameters)))
    problem = Problem(nao, data, free, perturbed(nao, rng), noise_model=False)
    assert (problem.sensor_points(problem.params(problem.x0))[:, 0] > 100).all()  # in front of the camera
    nonzero = check_jacobian(problem, nao.parameter_names)
    assert nonzero == len(nao.parameters)


DISTORTION = {
    "plumb-bob": "{k1: -0.2, k2: 0.05, p1: 0.001, p2: -0.002, k3: 0.01}",
    "rational": "{k1: -0.2, k2: 0.05, p1: 0.001, p2: -0.002, k3: 0.01, k4: 0.1, k5: -0.03, k6: 0.02}",
}


@pytest.fixture(scope="module", params=list(DISTORTION))
def nao_distorted(request, tmp_path_factory):
    text = (resources.files("calib_core.model") / "profiles" / "nao.yaml").read_text(encoding="utf-8")
    anchor = "    intrinsics: {fx: 562.5, fy: 562.5, cx: 324, cy: 189}\n"
    assert text.count(anchor) == 1
    path = tmp_path_factory.mktemp("profiles") / f"nao-{request.param}.yaml"
    line = f"    distortion: {DISTORTION[request.param]}\n"
    path.write_text(text.replace(anchor, anchor + line), encoding="utf-8")
    return load_profile(path)


def _coefficients(profile) -> tuple[str, ...]:
    return tuple(profile.parameter_names[i].split(".")[1] for i in profile.sensors[profile.data.sensor].distortion)


def test_distortion_profile_has_the_coefficients(nao_distorted) -> None:
    values = nao_distorted.params_to_display(nao_distorted.nominal())
    expected = {"k1": -0.2, "k2": 0.05, "p1": 0.001, "p2": -0.002, "k3": 0.01}
    if len(_coefficients(nao_distorted)) == 8:
        expected |= {"k4": 0.1, "k5": -0.03, "k6": 0.02}
    assert _coefficients(nao_distorted) == tuple(expected)
    for k, v in expected.items():
        assert values[f"lower_camera.{k}"] == pytest.approx(v)


def test_nao_jacobian_with_distortion(nao, nao_sim, nao_distorted) -> None:
    # The distorted profile has the same frames, joints and targets: the NAO data fit it.
    assert nao_distorted.parameter_names[: len(nao.parameters)] == nao.parameter_names
    rng = np.random.default_rng(14)
    data = _random_nao_data(nao_distorted, nao_sim, seed=7)
    free = list(range(len(nao_distorted.parameters)))
    p0 = perturbed(nao_distorted, rng)
    problem = Problem(nao_distorted, data, free, p0, noise_model=False)
    names = nao_distorted.parameter_names
    assert check_jacobian(problem, names) == len(names)
    # The intrinsics and distortion columns in particular (the loop above covers them; make sure
    # they are there and are not trivially zero).
    _, J = problem.residuals_jacobian(problem.x0)
    for k in ("fx", "fy", "cx", "cy", *_coefficients(nao_distorted)):
        assert np.linalg.norm(J[:, names.index(f"lower_camera.{k}")]) > 1e-3, k


def test_distortion_matches_opencv(nao_distorted) -> None:
    sensor = nao_distorted.sensors[nao_distorted.data.sensor]
    rng = np.random.default_rng(15)
    p = nao_distorted.nominal()
    n = 500
    x = rng.uniform(200, 1500, n)
    pts = np.stack([x, x * rng.uniform(-0.55, 0.55, n), x * rng.uniform(-0.4, 0.4, n)], axis=1)  # x forward
    uv, _, _ = sensor.predict(p, pts)
    values = nao_distorted.params_to_display(p)
    fx, fy, cx, cy = (values[f"lower_camera.{k}"] for k in ("fx", "fy", "cx", "cy"))
    K = np.array([[fx, 0, cx], [0, fy, cy], [0, 0, 1.0]])
    dist = np.array([values[f"lower_camera.{k}"] for k in _coefficients(nao_distorted)])
    X_cv = np.stack([-pts[:, 1], -pts[:, 2], pts[:, 0]], axis=1)
    ref, _ = cv2.projectPoints(X_cv, np.zeros(3), np.zeros(3), K, dist)
    ref = ref.reshape(-1, 2)
    # Distortion matters here (tens of px at the edge), so agreement is a real check.
    undistorted = np.stack([cx + fx * X_cv[:, 0] / X_cv[:, 2], cy + fy * X_cv[:, 1] / X_cv[:, 2]], axis=1)
    assert np.abs(ref - undistorted).max() > 10.0
    np.testing.assert_allclose(uv, ref, rtol=0, atol=1e-6)


def test_pinhole_without_distortion_is_eq1(nao) -> None:
    """The paper's Eq. 1: u = c_u - f y / x, v = c_v - f z / x."""
    sensor = nao.sensors[nao.data.sensor]
    rng = np.random.default_rng(16)
    pts = np.stack([rng.uniform(100, 900, 50), rng.uniform(-300, 300, 50), rng.uniform(-300, 300, 50)], axis=1)
    uv, _, _ = sensor.predict(nao.nominal(), pts)
    expected = np.stack([324 - 562.5 * pts[:, 1] / pts[:, 0], 189 - 562.5 * pts[:, 2] / pts[:, 0]], axis=1)
    np.testing.assert_allclose(uv, expected, rtol=0, atol=1e-9)
