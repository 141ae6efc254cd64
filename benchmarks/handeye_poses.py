"""`calib handeye` against OpenCV's closed forms on real images and reported flange poses (issue 35): leave
each image out, fit the rest, predict the held-out image's corners from its reported flange pose, and take the RMS
pixel distance to the corners found in it. Each with the camera's intrinsics fixed and free: `calib handeye` as it
runs (the reported poses' errors fitted or not as a cross-validation on the images fitted says), the same with the
poses' errors always fitted (variance components), and a plain reprojection bundle adjustment of the same
parameters (the reported flange poses taken as exact).

    python3 -m venv .venv-cv4 && .venv-cv4/bin/pip install "opencv-python-headless<5" numpy
    .venv/bin/python benchmarks/handeye_poses.py [FOLDER ...] [--cv4-python .venv-cv4/bin/python]

Each folder holds what `calib handeye` takes: images/, poses.csv, camera.yaml and board.txt (the --board value),
and setup.txt if not eye-in-hand; without a folder, every sample_sessions/handeye-*/ that has a board.txt (the
real data sets, their sources beside them). OpenCV 5's Python package has no calibrateHandEye: OpenCV 4's methods
run in an environment of their own (benchmarks/handeye_opencv.py, on the corners with the lens distortion undone).
"""

from __future__ import annotations

import argparse
import statistics
import time
from pathlib import Path

import cv2
import numpy as np

from calib_core.estimation import calibrate_flange, find_views
from calib_core.estimation.calibrate import calibrate
from calib_core.estimation.handeye import inverse
from calib_core.estimation.problem import Problem
from calib_core.io import flange_pose_session, parse_board, read_camera, read_flange_poses
from calib_core.io.flange_poses import natural_key

ROOT = Path(__file__).resolve().parent.parent


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("folders", type=Path, nargs="*")
    ap.add_argument("--cv4-python", type=Path, default=ROOT / ".venv-cv4" / "bin" / "python")
    args = ap.parse_args()
    folders = args.folders or sorted(p.parent for p in (ROOT / "sample_sessions").glob("handeye-*/board.txt"))
    for folder in folders:
        leave_one_out(folder, args.cv4_python)


def leave_one_out(folder: Path, cv4_python: Path) -> None:
    """One data set's leave-one-out: per method the held-out images' RMS px, a markdown table."""
    board = parse_board((folder / "board.txt").read_text().strip())
    setup = (folder / "setup.txt").read_text().strip() if (folder / "setup.txt").exists() else "eye-in-hand"
    camera = read_camera(folder / "camera.yaml")
    names = sorted(p.name for p in (folder / "images").iterdir())
    poses = read_flange_poses(folder / "poses.csv", names)
    images = {n: cv2.imread(str(folder / "images" / n), cv2.IMREAD_GRAYSCALE) for n in names}
    views = find_views(images, board, camera)
    found = sorted((n for n in names if views[n].corners is not None and n in poses), key=natural_key)
    spec = (folder / "board.txt").read_text().strip()
    print(f"\n{folder.name}: {len(names)} images, the board found in {len(found)}; {setup}; {spec}")
    calibrate_flange(views, poses, camera, board, setup)  # settles each chessboard's corner order once, for all
    points = board.points()
    errors: dict[str, list[float]] = {}
    started = time.perf_counter()
    opencv = _opencv(cv4_python, views, poses, found, points, camera, setup)
    failed: dict[str, str] = {}
    chosen: dict[str, list[bool]] = {}  # per split: did the cross-validation fit the reported poses' errors
    for k, held in enumerate(found):
        for method, got in opencv[k].items():
            if got.get("X") is None:
                failed[f"OpenCV {method}"] = got.get("error", "")
                continue
            X, Z = np.array(got["X"]), np.array(got["Z"])
            if np.all(np.isfinite(X)) and np.all(np.isfinite(Z)):
                error = _heldout_px(views[held], poses[held], X, Z, points, camera, setup)
                errors.setdefault(f"OpenCV {method}", []).append(error)
        for free in (False, True):
            flag = " --intrinsics free" if free else ""
            for label, pose_errors in (
                (f"calib handeye{flag}", None),
                (f"calib handeye{flag}, the poses' errors always fitted", True),
                (f"plain bundle adjustment{flag}", False),
            ):
                cal = calibrate_flange(
                    views, poses, camera, board, setup, heldout={held}, intrinsics_free=free, pose_errors=pose_errors
                )
                errors.setdefault(label, []).append(cal.heldout_rms_px)
                if pose_errors is None:
                    chosen.setdefault(label, []).append(cal.flange_errors["fitted"])
        for mode, error in _desk(views, poses, camera, board, setup, found, held).items():
            errors.setdefault(f"the desk's robot known by its flange pose, mode {mode}", []).append(error)
    print(f"leave one out over {len(found)} images ({time.perf_counter() - started:.0f} s): held-out corner RMS, px")
    print("| method | mean | median | max |\n|---|---|---|---|")
    for label, e in sorted(errors.items(), key=lambda kv: statistics.mean(kv[1])):
        fails = f" (failed outright on {len(found) - len(e)} of the {len(found)})" if len(e) < len(found) else ""
        print(f"| {label}{fails} | {statistics.mean(e):.3f} | {statistics.median(e):.3f} | {max(e):.3f} |")
    for label, why in failed.items():
        if label not in errors:
            print(f"| {label} (failed outright on every split: {why}) | | | |")
    for label, fitted in chosen.items():
        print(f"{label}: the cross-validation fitted the poses' errors in {sum(fitted)} of the {len(fitted)} splits")


def _desk(views, poses, camera, board, setup, found, held) -> dict[str, float]:
    """The desk's own estimation (POST /api/sessions/import-handeye's robot and session): the robot's profile made
    from the training images alone (its noise as they show it), the held-out image read against it, then per mode
    the held-out image's corners predicted at its reported pose: RMS px."""
    train = {n: views[n] for n in found if n != held}
    robot = flange_pose_session("bench", train, poses, camera, board, setup).profile
    session = flange_pose_session("bench", {n: views[n] for n in found}, poses, camera, board, setup, robot)
    data = session.data
    test = np.array([session.image_of[int(f)] == held for f in data.frame_ids])
    out = {}
    for mode in ("handeye", "handeye-lens", "auto"):
        cal = calibrate(robot, data.select(~test), mode)
        part = data.select(test)
        predicted = Problem(robot, part, [], cal.params(robot), noise_model=False).predict(cal.params(robot))
        out[mode] = float(np.sqrt(np.mean(np.sum((predicted[:, :2] - part.measured[:, :2]) ** 2, axis=1))))
    return out


def _opencv(python: Path, views, poses, found, points, camera, setup) -> list[dict]:
    """OpenCV 4's methods on each leave-one-out training set (benchmarks/handeye_opencv.py): per held-out image
    {method: {"X", "Z"}}; the corners with the lens distortion undone, as that script's pinhole takes them, each
    image's with the board's points it saw."""
    from handeye import run_opencv  # benchmarks/handeye.py: the OpenCV 4 environment's runner

    inputs = {"object_points": points, "camera_matrix": camera.matrix}
    for k, held in enumerate(found):
        train = [n for n in found if n != held]
        corners = [
            cv2.undistortPoints(views[n].corners[:, None], camera.matrix, camera.distortion, P=camera.matrix)[:, 0]
            for n in train
        ]
        inputs[f"corners_{k}"] = np.concatenate(corners)
        inputs[f"counts_{k}"] = np.array([len(c) for c in corners])
        inputs[f"object_points_{k}"] = np.concatenate([points[views[n].ids] for n in train])
        inputs[f"gripper_{k}"] = np.array([poses[n] for n in train])
        inputs[f"eye_in_hand_{k}"] = np.array(setup == "eye-in-hand")
    return run_opencv(python, inputs)["cases"]


def _heldout_px(view, F, X, Z, points, camera, setup) -> float:
    A = F if setup == "eye-in-hand" else inverse(F)
    C = inverse(X) @ inverse(A) @ Z
    uv, _ = cv2.projectPoints(points[view.ids], cv2.Rodrigues(C[:3, :3])[0], C[:3, 3], camera.matrix, camera.distortion)
    return float(np.sqrt(np.mean(np.sum((uv.reshape(-1, 2) - view.corners) ** 2, axis=1))))


if __name__ == "__main__":
    main()
