"""Makes the small inputs the README's examples need that a capture session does not hold, with the project's
own simulator (seeds fixed: the same files every time):

- sample_sessions/bags/nao.bag: a ROS 1 bag of the simulated NAO holding 3 poses for 1 s each, its joint
  states at 50 Hz and its lower camera's images (JPEG, sensor_msgs/CompressedImage) at 1.5 Hz, for
  `calib import-bag`;
- sample_sessions/depth/robonaut-sphere.npy: the stereo depth (SGBM, float32 m) of the simulated Robonaut's
  sphere, cropped to 160 x 160 px around it, and depth.json beside it: the crop's intrinsics, the nominal
  model's prediction of the centre (the seed) and the simulator's true centre, for `calib detect-sphere`;
- the `simulation:` block of sample_sessions/arm/arm.yaml (docs/urdf-robots.md's profile of the arm whose
  URDF, arm.urdf, tests/test_urdf_import.py writes): the hidden true arm `calib simulate` measures.

Run from the repository's root: `.venv/bin/python scripts/make_samples.py`.
"""

from __future__ import annotations

import json
import random
from pathlib import Path

import numpy as np

from calib_core import SimulatedRobot, load_profile
from calib_core.sim.recorded_drive import BagSpec, camera_images, make_drive, write_bag
from calib_core.units import length_factor
from calib_core.vision.ballfinder import find_sphere
from calib_core.vision.sighting import predicted_points
from calib_core.vision.stereo import StereoHead, depth_from_pair, render_pair

OUT = Path("sample_sessions")
CROP_PX = 160


def make_bag() -> Path:
    drive = make_drive("nao", 3, seed=7, hold_s=1.0, move_s=0.8)
    path = OUT / "bags" / "nao.bag"
    path.unlink(missing_ok=True)
    path.parent.mkdir(parents=True, exist_ok=True)
    spec = BagSpec(ros=1, image_topics={"image": "/camera/image_raw"}, compressed=True, jpeg_quality=80)
    return write_bag(path, drive, camera_images(drive, 1.5), spec)


def make_depth() -> tuple[Path, dict]:
    profile = load_profile("robonaut-a")
    robot = SimulatedRobot.from_profile(profile, seed=5)
    q, targets = robot.configurations(1)
    truth, nominal = robot.true_params, profile.nominal()
    head = StereoHead.from_profile(profile, truth, profile.sensors[profile.data.sensor].name)
    pair = render_pair(profile, truth, q[0], head, np.random.default_rng(5))
    depth = depth_from_pair(pair.left, pair.right, head)
    to_m = length_factor(profile.length_unit, "m")
    target = int(targets[0])
    true_m = (predicted_points(profile, truth, q[0], target)[0] @ head.R_frame_optical) * to_m
    seed_m = (predicted_points(profile, nominal, q[0], target)[0] @ head.R_frame_optical) * to_m
    u, v = head.fx_px * true_m[0] / true_m[2] + head.cx_px, head.fy_px * true_m[1] / true_m[2] + head.cy_px
    x0 = int(np.clip(round(u) - CROP_PX // 2, 0, head.width_px - CROP_PX))
    y0 = int(np.clip(round(v) - CROP_PX // 2, 0, head.height_px - CROP_PX))
    crop = np.ascontiguousarray(depth[y0 : y0 + CROP_PX, x0 : x0 + CROP_PX], dtype=np.float32)
    radius_m = float(profile.targets[target].radius) * to_m
    info = {
        "made_by": "scripts/make_samples.py (robonaut-a, seed 5, first configuration)",
        "fx": head.fx_px,
        "fy": head.fy_px,
        "cx": head.cx_px - x0,
        "cy": head.cy_px - y0,
        "radius_m": radius_m,
        "crop_origin_px": [x0, y0],
        "seed_m": [round(float(x), 4) for x in seed_m],
        "true_center_m": [float(x) for x in true_m],
    }
    found = find_sphere(crop, info["fx"], info["fy"], info["cx"], info["cy"], radius_m, seed_m)
    if not found.found:
        raise RuntimeError(f"the BallFinder does not find the sample sphere: {found.reason}")
    info["detected_error_mm"] = round(1000 * float(np.linalg.norm(found.center_m - true_m)), 2)
    folder = OUT / "depth"
    folder.mkdir(parents=True, exist_ok=True)
    np.save(folder / "robonaut-sphere.npy", crop)
    (folder / "depth.json").write_text(json.dumps(info, indent=2) + "\n")
    return folder / "robonaut-sphere.npy", info


def make_arm_truth() -> Path:
    """The arm's truth: joint offsets drawn with 0.5 deg, joint origins with 0.5 mm and 0.1 deg (seed 4)."""
    path = OUT / "arm" / "arm.yaml"
    text = path.read_text(encoding="utf-8").split("simulation:")[0]
    path.write_text(text, encoding="utf-8")
    nominal = load_profile(path).params_to_display(load_profile(path).nominal())
    rng = random.Random(4)
    joints = ["shoulder_pan", "shoulder_lift", "elbow", "wrist_1", "wrist_2", "wrist_3"]
    truth = {"tracker.x": 2500.0, "tracker.y": 300.0, "tracker.z": -200.0, "tracker.yaw": 170.0}
    truth |= {"tracker.pitch": 2.0, "tracker.roll": -1.0, "smr.x": 30.3, "smr.y": 9.6, "smr.z": 40.4}
    truth |= {j: round(nominal[j] + rng.gauss(0, 0.5), 3) for j in joints}
    for j in joints:
        truth |= {f"{j}.{k}": round(nominal[f"{j}.{k}"] + rng.gauss(0, 0.5), 3) for k in ("x", "y", "z")}
        truth |= {f"{j}.{k}": round(nominal[f"{j}.{k}"] + rng.gauss(0, 0.1), 3) for k in ("roll", "pitch", "yaw")}
    text += "simulation:  # the hidden true arm `calib simulate` measures (mm, deg): "
    text += "0.5 deg offsets, 0.5 mm / 0.1 deg origin errors\n"
    text += "  noise: {point: 0.02}\n  truth:\n" + "".join(f"    {k}: {v}\n" for k, v in truth.items())
    path.write_text(text, encoding="utf-8")
    return path


if __name__ == "__main__":
    bag = make_bag()
    depth, info = make_depth()
    make_arm_truth()
    for path in (bag, depth):
        size = sum(f.stat().st_size for f in path.rglob("*")) if path.is_dir() else path.stat().st_size
        print(f"{path}: {size / 1024:.0f} KB")
    print(json.dumps(info))
