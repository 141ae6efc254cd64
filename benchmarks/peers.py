"""The desk against FIGAROH on FIGAROH's own published real data (sample_sessions/figaroh, SOURCES.md there).

For each robot, the same train/held-out splits for both tools (calib_core.io.figaroh_data: 10 random splits by
configuration, 30% held out, seeds 0-9; TIAGo also by FIGAROH's frozen two-session protocol), the desk's plain
profiles (what the URDF import and the marker give: no mode, prior or limit written) in modes `offsets`,
`origins` and `auto` against FIGAROH's levels `joint_offset` and `full_params`. FIGAROH runs in its own virtual
environment (benchmarks/peers_figaroh.py), on the same kinematic URDF the profile imports. Both tools' held-out
predictions are scored by one function (figaroh_data.pose_errors): the RMS over held-out configurations of the
measured point's distance (mm), and for the UR10e's 6-D camera poses also of the rotation (deg).

    python3 -m venv .venv-peer && .venv-peer/bin/pip install figaroh==1.0.2
    python benchmarks/peers.py [--peer-python .venv-peer/bin/python] [--robots talos tiago ur10e-pose]
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
import time
from collections import Counter
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from calib_core import calibrate, load_profile
from calib_core.dataset import Dataset
from calib_core.estimation.problem import Problem
from calib_core.io.figaroh_data import (
    HELD_OUT,
    POSE_AXIS_M,
    POSE_POINTS,
    ROBOTS,
    SPLITS,
    PoseErrors,
    pooled,
    pose_errors,
    rpy_matrix,
    splits,
)
from calib_core.model.profile import Profile
from calib_core.model.urdf_import import profile_urdf_path
from calib_core.units import length_factor

ROOT = Path(__file__).resolve().parents[1]
FOLDER = ROOT / "sample_sessions" / "figaroh"
MODES = {"offsets": "joint_offset", "origins": "full_params"}  # desk mode -> FIGAROH calibration level
COMPARED = ("talos", "tiago", "ur10e-pose")  # the plain profiles (ur10e.yaml reads each pose as 7 points)

# How FIGAROH's examples set each robot up: the frame the measured point or pose hangs from, what is
# measured (x, y, z, roll, pitch, yaw), the outlier threshold of its configuration (m) and its cost's
# orientation weight (per rad; the UR10 example's, unused where only positions are measured).
PEER_SETUP = {
    "talos": {"tool": "arm_left_7_link", "dof": [True] * 3 + [False] * 3, "outlier_m": 0.03, "orient_weight": 0.5},
    "tiago": {"tool": "wrist_ft_tool_link", "dof": [True] * 3 + [False] * 3, "outlier_m": 0.05, "orient_weight": 0.5},
    "ur10e": {"tool": "wrist_3_link", "dof": [True] * 6, "outlier_m": 0.02, "orient_weight": 0.5},
}
PEER_SETUP["ur10e-pose"] = PEER_SETUP["ur10e"]


@dataclass
class DeskRun:
    """The desk's held-out errors in one mode over a robot's splits, and what it estimated: the parameters' counts,
    what `auto` chose in each split (its candidates' names) and the mean time of one calibration (s)."""

    errors: PoseErrors
    counts: list[int]
    chosen: Counter
    seconds: float


def desk_errors(profile: Profile, robot: str, mode: str, sessions: bool = False) -> DeskRun:
    """The desk's held-out errors (as figaroh_data.heldout_errors) and how it got them."""
    parts, counts, chosen, seconds = [], [], Counter(), []
    for train, heldout in splits(profile, FOLDER, robot, sessions):
        start = time.perf_counter()
        cal = calibrate(profile, train, mode)
        seconds.append(time.perf_counter() - start)
        p = cal.params(profile)
        parts.append(pose_errors(profile, heldout, Problem(profile, heldout, [], p, noise_model=False).predict(p)))
        counts.append(sum(q.estimated for q in cal.parameters))
        if cal.choice is not None:
            chosen[cal.choice.picked.name] += 1
    return DeskRun(pooled(parts), sorted(set(counts)), chosen, float(np.mean(seconds)))


def _rows_of(robot: str, data: Dataset) -> list[str]:
    """The lines of FIGAROH's CSV (the verbatim file) for a dataset's configurations, in its order."""
    spec = ROBOTS[robot]
    source = Path(data.source)
    if spec.pose is not None:
        source = FOLDER / spec.pose
    lines = source.read_text().splitlines()
    return [lines[0]] + [lines[int(f)] for f in data.frame_ids]


def peer_errors(
    profile: Profile, robot: str, level: str, python: str, sessions: bool = False
) -> tuple[PoseErrors, dict]:
    """FIGAROH's held-out errors at `level` on the same splits, and what it ran with."""
    pairs = splits(profile, FOLDER, robot, sessions)
    with tempfile.TemporaryDirectory() as tmp:
        folds = []
        for k, (train, heldout) in enumerate(pairs):
            names = (Path(tmp) / f"train{k}.csv", Path(tmp) / f"heldout{k}.csv")
            for path, data in zip(names, (train, heldout), strict=True):
                path.write_text("\n".join(_rows_of(robot, data)) + "\n")
            folds.append([str(n) for n in names])
        job = {"urdf": str(_urdf(profile)), "level": level, "folds": folds, **PEER_SETUP[robot]}
        run = subprocess.run(
            [python, str(Path(__file__).with_name("peers_figaroh.py"))],
            input=json.dumps(job),
            capture_output=True,
            text=True,
            check=False,
        )
    if run.returncode != 0:
        raise SystemExit(f"FIGAROH failed on {robot} ({level}):\n{run.stderr[-2000:]}")
    out = json.loads(run.stdout)
    parts = []
    for (_, heldout), fold in zip(pairs, out["folds"], strict=True):
        parts.append(pose_errors(profile, heldout, _as_points(profile, heldout, np.array(fold["predicted"]))))
    n_params = sorted({len(f["parameters"]) for f in out["folds"]})
    return pooled(parts), {"figaroh": out["figaroh"], "pinocchio": out["pinocchio"], "parameters": n_params}


def _as_points(profile: Profile, data: Dataset, predicted: np.ndarray) -> np.ndarray:
    """FIGAROH's predicted point (x, y, z) or pose (and roll, pitch, yaw) per configuration, in m and rad,
    as the desk's predicted observations (M, 3) in the profile's length unit."""
    scale = length_factor("m", profile.length_unit)
    if profile.sensors[profile.data.sensor].rotation_axes:  # a pose sensor: position and rotation vector (rad)
        from scipy.spatial.transform import Rotation

        poses = predicted[data.cfg]
        rotvec = Rotation.from_matrix([rpy_matrix(*pose[3:6]) for pose in poses]).as_rotvec()
        return np.hstack([poses[:, :3] * scale, rotvec])
    out = np.zeros((data.n_observations, 3))
    for k in range(data.n_observations):
        pose = predicted[data.cfg[k]]
        point = pose[:3]
        if data.vertex[k] >= 0:
            point = point + POSE_AXIS_M * rpy_matrix(*pose[3:6]) @ POSE_POINTS[data.vertex[k]]
        out[k] = point * scale
    return out


def _urdf(profile: Profile) -> Path:
    path = profile_urdf_path(profile)
    assert path is not None, f"profile {profile.name} names no URDF"
    return path


def _cell(e: PoseErrors) -> str:
    deg = e.rms_deg()
    return f"{e.rms_mm():.3f} mm" + ("" if deg is None else f" / {deg:.3f} deg")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--peer-python", default=str(ROOT / ".venv-peer" / "bin" / "python"))
    parser.add_argument("--robots", nargs="+", default=list(COMPARED), choices=list(COMPARED))
    args = parser.parse_args()
    if not Path(args.peer_python).exists():
        raise SystemExit(
            f"no FIGAROH environment at {args.peer_python}: make it with "
            "`python3 -m venv .venv-peer && .venv-peer/bin/pip install figaroh==1.0.2`, or pass --peer-python"
        )
    print(
        "| robot (splits) | desk offsets | FIGAROH joint_offset | desk origins | FIGAROH full_params | desk auto | "
        "auto / FIGAROH's best | parameters (offsets, origins / joint_offset, full_params) |"
    )
    print("|---|---|---|---|---|---|---|---|")
    versions, chosen = set(), []
    for robot in args.robots:
        profile = load_profile(FOLDER / ROBOTS[robot].profile)
        for sessions in (False, True) if ROBOTS[robot].heldout else (False,):
            start = time.perf_counter()
            desk = {mode: desk_errors(profile, robot, mode, sessions) for mode in (*MODES, "auto")}
            peer = {}
            for level in MODES.values():
                peer[level], info = peer_errors(profile, robot, level, args.peer_python, sessions)
                versions.add(f"figaroh {info['figaroh']}, pinocchio {info['pinocchio']}")
                peer[level + " parameters"] = info["parameters"]
            best = min(MODES.values(), key=lambda level: peer[level].rms_mm())
            ratio = desk["auto"].errors.rms_mm() / peer[best].rms_mm()
            ratios = f"{ratio:.3f}"
            if peer[best].rms_deg() is not None:
                ratios += f" / {desk['auto'].errors.rms_deg() / peer[best].rms_deg():.3f}"
            counts = ", ".join("-".join(str(n) for n in desk[m].counts) for m in MODES)
            counts += " / " + ", ".join(
                "-".join(str(n) for n in peer[f"{level} parameters"]) for level in MODES.values()
            )
            where = "FIGAROH's two sessions" if sessions else f"{SPLITS} x {HELD_OUT:.0%} held out"
            cells = [
                _cell(desk["offsets"].errors),
                _cell(peer["joint_offset"]),
                _cell(desk["origins"].errors),
                _cell(peer["full_params"]),
                _cell(desk["auto"].errors),
                f"{ratios} ({best})",
                counts,
            ]
            print(f"| {robot} ({where}) | " + " | ".join(cells) + " |", flush=True)
            picks = ", ".join(f"{name} {n}" for name, n in desk["auto"].chosen.most_common())
            chosen.append(f"- {robot} ({where}): {picks}; {desk['auto'].seconds:.1f} s a calibration")
            print(f"  ({robot}: {time.perf_counter() - start:.0f} s)", file=sys.stderr)
    print("\nWhat `auto` chose (in how many splits), and the time of one `auto` calibration:\n")
    print("\n".join(chosen))
    print(f"\n{', '.join(sorted(versions))}; Python {sys.version.split()[0]}")


if __name__ == "__main__":
    main()
