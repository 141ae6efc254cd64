"""Real URDFs as robot profiles: every URDF under a folder (pybullet's data by default), loaded,
and each serial chain calibrated from a simulated laser tracker.

For every file: a profile naming it (units mm, deg) with a tracker whose pose is estimated and a
reflector 30, 20, 40 mm off the last link of its first chain (or its root link) is loaded; what is refused is grouped
by the reason given (names and numbers left out), what loads with notes is counted by note.
For every serial chain (the root link to a leaf of the imported tree, at least one joint that can
move): hidden joint offsets (N(0, 1) deg per revolute joint, N(0, 1) mm per prismatic one), 60
random configurations within the joint limits, the tracker's noise 0.005 mm per axis; the default
`offsets` mode is calibrated and each offset the identifiability check does not hold is compared
with the truth. A chain recovers its offsets when the largest error is under 0.01 deg (revolute)
and 0.01 mm (prismatic). Held offsets (what a tracker cannot see: a first axis turning with the
tracker's pose, a last one turning the reflector about itself) are counted, not compared.

The URDFs stay where their package installs them (nothing is copied into the repository). pybullet's
data ships in its wheel: install it into a venv of its own, e.g.

    python -m venv /tmp/pyb && /tmp/pyb/bin/pip install --no-deps pybullet
    python benchmarks/urdf_sweep.py --root /tmp/pyb/lib/python3.11/site-packages/pybullet_data

(without --root: `pybullet_data` where this Python can import it). `--chains N` calibrates a random
sample of N chains (seeded) when there are more, to keep the run within minutes; it says so.
"""

from __future__ import annotations

import argparse
import collections
import math
import re
import sys
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import yaml

from calib_core import InputError, SimulatedRobot, calibrate, load_profile
from calib_core.model.profile import Profile
from calib_core.model.urdf_import import UrdfRobot, read_urdf

NOISE_MM = 0.005
CONFIGURATIONS = 60
LIMIT_DEG = 0.01  # a recovered revolute offset's largest error
LIMIT_MM = 0.01  # ... a prismatic one's
REFLECTOR_MM = {"x": 30.0, "y": 20.0, "z": 40.0}  # off the chain's last link
TRACKER = {"x": 2000.0, "y": -300.0, "z": 200.0, "yaw": 150.0, "pitch": 1.0, "roll": -2.0}  # mm, deg


@dataclass
class Sweep:
    files: int = 0
    loaded: int = 0
    refused: collections.Counter = field(default_factory=collections.Counter)
    refused_example: dict[str, str] = field(default_factory=dict)
    notes: collections.Counter = field(default_factory=collections.Counter)
    files_with_notes: int = 0
    chains: list[tuple[Path, list[str]]] = field(default_factory=list)  # (file, links root to leaf)
    without_motion: int = 0  # loaded files whose tree has no joint that can move


def profile_doc(urdf: Path, leaf: str) -> dict:
    return {
        "profile": 1,
        "name": "sweep",
        "units": {"length": "mm", "angle": "deg"},
        "urdf": str(urdf.resolve()),
        "frames": [{"name": "tracker_pose", "parent": "__root__", "registration": True}],
        "targets": [{"name": "smr", "frame": leaf, "point": REFLECTOR_MM}],
        "sensors": [
            {
                "name": "tracker",
                "frame": "tracker_pose",
                "model": "point3d",
                "noise": {"model": "isotropic", "sigma": NOISE_MM},
            }
        ],
        "data": {
            "sensor": "tracker",
            "target": "smr",
            "measurement": {"columns": ["x", "y", "z"], "unit": "mm"},
            "prediction_columns": ["px", "py", "pz"],
        },
        "simulation": {"noise": {"point": NOISE_MM}},
    }


def load(urdf: Path, robot: UrdfRobot, leaf: str, folder: Path) -> Profile:
    """The profile of the tracker and a reflector on `leaf` (on the root link: a mount frame there)."""
    doc = profile_doc(urdf, leaf)
    doc["frames"][0]["parent"] = robot.root
    if leaf == robot.root:  # a single link (an object): the reflector on a frame of the profile's own
        doc["frames"].append({"name": "reflector_mount", "parent": robot.root, "urdf": {"xyz": [0, 0, 0]}})
        doc["targets"][0]["frame"] = "reflector_mount"
    path = folder / "sweep.yaml"
    path.write_text(yaml.safe_dump(doc), encoding="utf-8")
    return load_profile(path)


def chains(robot: UrdfRobot) -> list[list[str]]:
    """Each path from the root link to a leaf of the imported tree, as links, with a joint that can move."""
    below: dict[str, list[str]] = collections.defaultdict(list)
    movable: dict[str, bool] = {}
    for j in robot.joints:
        below[j.parent].append(j.child)
        movable[j.child] = j.movable and j.lower != j.upper
    out: list[list[str]] = []
    stack = [[robot.root]]
    while stack:
        path = stack.pop()
        children = below.get(path[-1], [])
        if not children and any(movable.get(link, False) for link in path):
            out.append(path)
        stack += [[*path, c] for c in reversed(children)]
    return out


def reason(exc: InputError) -> str:
    """The refusal without names and numbers, to group files by it."""
    text = re.sub(r"'[^']*'", "'…'", exc.message)
    text = re.sub(r'"[^"]*"', '"…"', text)
    return re.sub(r"line \d+, column \d+", "line …", text)


def note_kind(note: str) -> str:
    for key in ("XML declaration says version", "XML declaration is not at the start", "NUL bytes"):
        if key in note:
            return key
    if "has no <limit lower" in note:
        return "joint without <limit lower upper> (0, the URDF default)"
    if "cannot move" in note:
        return "joint that cannot move, its offset estimated"
    return note


def survey(root: Path, folder: Path) -> Sweep:
    sweep = Sweep()
    for urdf in sorted(root.rglob("*.urdf")):
        sweep.files += 1
        try:
            robot = read_urdf(urdf)
            found = chains(robot)
            leaf = found[0][-1] if found else robot.root
            profile = load(urdf, robot, leaf, folder)
        except InputError as exc:
            sweep.refused[reason(exc)] += 1
            sweep.refused_example.setdefault(reason(exc), str(exc).replace(str(root) + "/", ""))
            continue
        sweep.loaded += 1
        sweep.files_with_notes += bool(profile.notes)
        for note in profile.notes:
            sweep.notes[note_kind(note)] += 1
        sweep.chains += [(urdf, c) for c in found]
        sweep.without_motion += not found
    return sweep


@dataclass
class ChainResult:
    ok: bool
    free: int  # offsets the mode estimates
    held: int  # of which the identifiability check holds
    prismatic: int  # compared offsets of prismatic joints
    worst_deg: float
    worst_mm: float
    seconds: float
    what: str = ""


def calibrate_chain(urdf: Path, links: list[str], folder: Path, seed: int) -> ChainResult:
    start = time.perf_counter()
    robot = read_urdf(urdf)
    profile = load(urdf, robot, links[-1], folder)
    rng = np.random.default_rng(seed)
    truth = profile.nominal()
    offsets = {}
    for j in profile.joints:
        if j.name not in profile.data.joint_columns:
            continue
        i = profile.param(j.name)
        offsets[j.name] = rng.normal(0.0, 1.0)  # deg or mm
        truth[i] = profile.from_display(i, offsets[j.name])
    for k, v in TRACKER.items():
        truth[profile.param(f"tracker_pose.{k}")] = profile.from_display(profile.param(f"tracker_pose.{k}"), v)
    smr = list(profile.targets[0].point_params or ())
    truth[smr] += rng.normal(0.0, 0.5, 3)
    sim = SimulatedRobot.from_profile(profile, seed=seed, truth=truth).simulate(CONFIGURATIONS)
    cal = calibrate(profile, sim.data, "offsets")
    est = {p.name: p for p in cal.parameters}
    worst = {"deg": 0.0, "mm": 0.0}
    held = prismatic = 0
    for name, value in offsets.items():
        p = est[name]
        if p.note and "held" in p.note:
            held += 1
            continue
        unit = "deg" if p.unit == "deg" else "mm"
        prismatic += unit == "mm"
        worst[unit] = max(worst[unit], abs(p.value - value))
    ok = worst["deg"] < LIMIT_DEG and worst["mm"] < LIMIT_MM
    what = "" if ok else f"rms after {cal.figures['after'].rms:.3g} mm"
    seconds = time.perf_counter() - start
    return ChainResult(ok, len(offsets), held, prismatic, worst["deg"], worst["mm"], seconds, what)


def default_root() -> Path:
    try:
        import pybullet_data  # only when no --root is given
    except ImportError:
        sys.exit("no --root and pybullet_data is not importable here: see this file's docstring")
    return Path(pybullet_data.getDataPath())


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--root", type=Path, help="folder searched for *.urdf (default: pybullet_data's)")
    parser.add_argument("--chains", type=int, default=200, help="calibrate at most this many chains (sampled)")
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args()
    root = args.root or default_root()
    t0 = time.perf_counter()
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp)
        sweep = survey(root, folder)
        print(f"URDF files under {root}: {sweep.files}")
        print(f"  loaded as robot profiles: {sweep.loaded} ({sweep.files_with_notes} with notes)")
        for kind, n in sweep.notes.most_common():
            print(f"    note: {kind}: {n}")
        print(f"  refused: {sum(sweep.refused.values())}")
        for why, n in sweep.refused.most_common():
            print(f"    {n} x {why}\n        e.g. {sweep.refused_example[why]}")
        print(f"  loaded with no joint that can move (objects, fixed assemblies): {sweep.without_motion}")
        files = len({f for f, _ in sweep.chains})
        print(f"serial chains (root link to a leaf, a joint that can move): {len(sweep.chains)} in {files} files")
        picked = list(range(len(sweep.chains)))
        if len(picked) > args.chains:
            picked = sorted(np.random.default_rng(args.seed).choice(picked, args.chains, replace=False).tolist())
            print(f"  calibrating a random sample of {args.chains} (--chains; seed {args.seed})")
        results = []
        failures = []
        for k in picked:
            urdf, links = sweep.chains[k]
            try:
                r = calibrate_chain(urdf, links, folder, args.seed + k)
            except InputError as exc:
                r = ChainResult(False, 0, 0, 0, math.nan, math.nan, 0.0, f"refused: {exc.message}")
            results.append(r)
            if not r.ok:
                failures.append((urdf.relative_to(root), links[-1], r))
        seen = [r for r in results if r.free > r.held or not r.ok]
        print(
            f"  recovered their offsets (max error < {LIMIT_DEG} deg, < {LIMIT_MM} mm on the identifiable ones): "
            f"{sum(r.ok for r in seen)} of the {len(seen)} with an offset a tracker can see "
            f"({len(results) - len(seen)} more whose every offset is held)"
        )
        free = sum(r.free for r in results)
        held = sum(r.held for r in results)
        print(
            f"  offsets: {free} hidden, {free - held} identifiable and compared "
            f"({sum(r.prismatic for r in results)} prismatic), {held} held (what no tracker sees)"
        )
        worst_deg = max((r.worst_deg for r in results if r.ok), default=0.0)
        worst_mm = max((r.worst_mm for r in results if r.ok), default=0.0)
        print(f"  largest error among the recovered: {worst_deg:.2g} deg, {worst_mm:.2g} mm")
        for path, leaf, r in failures:
            print(f"    not recovered: {path} to {leaf}: {r.worst_deg:.3g} deg, {r.worst_mm:.3g} mm; {r.what}")
        seconds = [r.seconds for r in results]
        if seconds:
            print(f"  per chain: median {np.median(seconds):.2f} s, max {max(seconds):.2f} s")
    print(f"total {time.perf_counter() - t0:.0f} s")


if __name__ == "__main__":
    main()
