"""Hand-eye: the desk against OpenCV's five calibrateHandEye methods and its two calibrateRobotWorldHandEye ones.

The set-ups of tests/profiles (handeye-in-hand: a camera on the sample arm's flange, a 7x6 board of 30 mm squares
on the table; handeye-to-hand: the camera in the room, the board on the flange), 0.3 px corner noise, the arm with
exact joints or with 0.2-0.5 deg joint offsets, 15 or 40 configurations to calibrate from and 30 new ones to judge
by, several seeds (tests/handeye_data.py). The profile gives no pose: the desk starts from nothing (its closed-form
start) in mode `handeye` (the two poses) and `offsets` (and the joint offsets). OpenCV gets what its users feed it:
each image's board pose from cv2.solvePnP on the same noisy corners, and the flange's pose from the arm's believed
(nominal) kinematics; its result is judged with those kinematics, as it would be used.

Figures per cell, the median over the seeds: held-out px (RMS corner distance on the 30 new configurations; the
floor is the true model's), where the camera is seen from the board at those configurations (RMS mm, largest deg:
tests/handeye_data.camera_error), seconds, and how many seeds reach the floor from no guess (held-out px within 5%
of the true model's, and for the desk, reported converged).

OpenCV 4 runs in an environment of its own (OpenCV 5.0's Python package has no calibrateHandEye), started as a
subprocess on benchmarks/handeye_opencv.py:

    python3 -m venv .venv-cv4 && .venv-cv4/bin/pip install "opencv-python-headless<5" numpy
    python benchmarks/handeye.py [--seeds 5] [--poses 15 40] [--cv4-python .venv-cv4/bin/python]
    python benchmarks/handeye.py --quick --desk-only    # a few seconds: one seed, 15 poses, no OpenCV
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "tests"))

from handeye_data import PROFILES, SETUPS, camera_error, rms_px, seeded_data  # noqa: E402

from calib_core import calibrate, load_profile  # noqa: E402
from calib_core.estimation.camera_registration import pose_parameters  # noqa: E402
from calib_core.estimation.handeye import inverse, pose  # noqa: E402
from calib_core.model.kinematics import forward  # noqa: E402
from calib_core.model.profile import Profile  # noqa: E402
from calib_core.sim.simulator import Simulation  # noqa: E402

DESK_MODES = ("handeye", "offsets")
OPENCV_METHODS = ("TSAI", "PARK", "HORAUD", "ANDREFF", "DANIILIDIS", "SHAH", "LI")  # as handeye_opencv.py
AT_FLOOR = 1.05  # held-out px within 5% of the true model's
CV4_PYTHON = ROOT / ".venv-cv4" / "bin" / "python"


@dataclass(frozen=True)
class Case:
    setup: str
    offsets: bool
    poses: int
    seed: int


@dataclass(frozen=True)
class Outcome:
    heldout_px: float
    camera_mm: float
    camera_deg: float
    seconds: float
    at_floor: bool


def frames_of(profile: Profile) -> tuple[int, int, bool]:
    """The camera's and the board's registration frames, and whether the camera rides on the arm."""
    camera = profile.frame("camera_mount")
    moving = any(op.joint >= 0 for f in profile.chain(camera) for op in profile.frames[f].ops)
    return camera, profile.frame("board_frame"), moving


def flange_poses(profile: Profile, data) -> np.ndarray:
    """The moving registration frame's parent in the fixed one's (N, 4, 4) by the believed (nominal) kinematics:
    the flange in the robot's base, what an OpenCV user computes from the joint readings."""
    camera, board, in_hand = frames_of(profile)
    moving, fixed = (camera, board) if in_hand else (board, camera)
    p0 = profile.nominal()  # registrations at the identity: each registration frame is where its parent is
    poses = forward(profile, p0, np.nan_to_num(data.joints), frames=[moving, fixed])

    def at(f: int) -> np.ndarray:
        return pose(poses.R[f], poses.t[f])

    return inverse(at(fixed)) @ at(moving)


def opencv_params(profile: Profile, X: np.ndarray, Z: np.ndarray) -> np.ndarray:
    """The believed kinematics with OpenCV's camera pose X (optical frame) and board pose Z as the registrations."""
    camera, board, _ = frames_of(profile)
    sensor = profile.sensors[profile.data.sensor]
    p = profile.nominal()
    p[[op.param for op in profile.frames[camera].ops]] = pose_parameters(
        X @ inverse(pose(sensor.R_frame_optical, np.zeros(3)))
    )
    p[[op.param for op in profile.frames[board].ops]] = pose_parameters(Z)
    return p


def judged(profile: Profile, new: Simulation, p: np.ndarray, seconds: float, converged: bool) -> Outcome:
    px = rms_px(profile, new.data, p)
    mm, deg = camera_error(profile, p, new.true_params, new.true_joints)
    floor = rms_px(profile, new.data, new.true_params)
    return Outcome(px, mm, deg, seconds, converged and px < AT_FLOOR * floor)


def desk(profile: Profile, sim: Simulation, new: Simulation, mode: str) -> Outcome:
    started = time.perf_counter()
    cal = calibrate(profile, sim.data, mode)
    seconds = time.perf_counter() - started
    return judged(profile, new, cal.params(profile), seconds, cal.converged and cal.solver.fits_noise)


def opencv_inputs(profile: Profile, sims: list[Simulation]) -> dict[str, np.ndarray]:
    """handeye_opencv.py's npz: the board, the camera matrix, per case the corners and the flange's poses."""
    sensor = profile.sensors[profile.data.sensor]
    assert sensor.intrinsics is not None
    fx, fy, cx, cy = profile.nominal()[list(sensor.intrinsics)]
    grid = profile.targets[profile.data.target].grid
    assert grid is not None
    out = {"object_points": grid, "camera_matrix": np.array([[fx, 0, cx], [0, fy, cy], [0, 0, 1.0]])}
    for k, sim in enumerate(sims):
        d = sim.data
        assert np.array_equal(d.vertex, np.tile(np.arange(len(grid)), d.n_configurations))  # whole boards, in order
        out[f"corners_{k}"] = d.measured[:, :2].reshape(d.n_configurations, len(grid), 2)
        out[f"gripper_{k}"] = flange_poses(profile, d)
        out[f"eye_in_hand_{k}"] = np.array(frames_of(profile)[2])
    return out


def run_opencv(python: Path, inputs: dict[str, np.ndarray]) -> dict:
    with tempfile.TemporaryDirectory() as tmp:
        src, dst = Path(tmp) / "cases.npz", Path(tmp) / "out.json"
        np.savez(src, **inputs)
        env = {k: v for k, v in os.environ.items() if k != "PYTHONPATH"}  # its own packages only
        subprocess.run(
            [str(python), str(ROOT / "benchmarks" / "handeye_opencv.py"), str(src), str(dst)], check=True, env=env
        )
        return json.loads(dst.read_text())


def table(results: dict[tuple[Case, str], Outcome], methods: list[str], floors: dict[Case, float]) -> list[str]:
    """Markdown rows: per cell (set-up, joints, poses) and method, the medians over the seeds."""
    cells = sorted({(c.setup, c.offsets, c.poses) for c, _ in results})
    lines = [
        "| set-up | joints | poses | method | held-out px (floor) | camera mm | camera deg | seconds | at floor |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    for setup, offsets, poses in cells:
        cases = [c for c in floors if (c.setup, c.offsets, c.poses) == (setup, offsets, poses)]
        floor = float(np.median([floors[c] for c in cases]))
        for method in methods:
            got = [results[(c, method)] for c in cases if (c, method) in results]
            if not got:
                continue

            def med(field: str, got=got) -> float:
                return float(np.median([getattr(o, field) for o in got]))

            joints = "offsets 0.2-0.5 deg" if offsets else "exact"
            lines.append(
                f"| {setup.removeprefix('handeye-')} | {joints} | {poses} | {method} | {med('heldout_px'):.3f} "
                f"({floor:.3f}) | {med('camera_mm'):.2f} | {med('camera_deg'):.3f} | {med('seconds'):.3f} | "
                f"{sum(o.at_floor for o in got)}/{len(got)} |"
            )
    return lines


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, default=5)
    parser.add_argument("--poses", type=int, nargs="+", default=[15, 40])
    parser.add_argument("--setups", nargs="+", default=list(SETUPS), choices=SETUPS)
    parser.add_argument("--cv4-python", type=Path, default=CV4_PYTHON, help="a Python with opencv-python-headless<5")
    parser.add_argument("--desk-only", action="store_true", help="leave OpenCV out")
    parser.add_argument("--quick", action="store_true", help="one seed, 15 poses")
    args = parser.parse_args(argv)
    if args.quick:
        args.seeds, args.poses = 1, [15]
    opencv = not args.desk_only
    if opencv and not args.cv4_python.exists():
        print(
            f"no OpenCV 4 at {args.cv4_python}: the desk alone (python3 -m venv .venv-cv4 && "
            '.venv-cv4/bin/pip install "opencv-python-headless<5" numpy, or --cv4-python)'
        )
        opencv = False
    results: dict[tuple[Case, str], Outcome] = {}
    floors: dict[Case, float] = {}
    version = None
    for setup in args.setups:
        profile = load_profile(PROFILES / f"{setup}.yaml")
        cases = [Case(setup, o, n, s) for o in (False, True) for n in args.poses for s in range(args.seeds)]
        data = {c: seeded_data(profile, c.seed, c.offsets, c.poses) for c in cases}
        for c, (sim, new) in data.items():
            floors[c] = rms_px(profile, new.data, new.true_params)
            for mode in DESK_MODES:
                results[(c, f"desk {mode}")] = desk(profile, sim, new, mode)
        if opencv:
            out = run_opencv(args.cv4_python, opencv_inputs(profile, [sim for sim, _ in data.values()]))
            version = out["opencv"]
            for c, solved in zip(cases, out["cases"], strict=True):
                for method, r in solved.items():
                    if r["X"] is None:  # failed outright (handeye_opencv.py keeps OpenCV's reason)
                        continue
                    p = opencv_params(profile, np.array(r["X"]), np.array(r["Z"]))
                    results[(c, method)] = judged(profile, data[c][1], p, r["seconds"], True)
    methods = [f"desk {m}" for m in DESK_MODES] + (list(OPENCV_METHODS) if opencv else [])
    print(
        f"{args.seeds} seeds per cell, 30 held-out configurations, 0.3 px corner noise; OpenCV {version or 'not run'}"
    )
    print("\n".join(table(results, methods, floors)))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
