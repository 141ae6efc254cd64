"""The round-off case of issue 14 on a real 7-axis URDF: pybullet's KUKA LBR iiwa (kuka_iiwa/model.urdf)
seen by a laser tracker whose reflector sits at the last link's origin, on joint 7's axis. Turning j7
moves nothing the tracker sees, so its offset cannot be estimated: the calibration must hold it and
say so, and every other estimate must stay within 4 sd of the simulator's truth.

    .venv/bin/python benchmarks/roundoff.py --urdf .../pybullet_data/kuka_iiwa/model.urdf

(pybullet_data comes with `pip install pybullet`, in any virtual environment: only the file is read.)
"""

from __future__ import annotations

import argparse
import tempfile
from pathlib import Path

from calib_core import SimulatedRobot, calibrate, load_profile

PROFILE = """
profile: 1
name: iiwa-urdf-tracker
units: {{length: mm, angle: deg}}
urdf: {urdf}
frames:
  - {{name: tracker, parent: lbr_iiwa_link_0, registration: true}}
targets:
  - {{name: reflector, frame: lbr_iiwa_link_7}}
sensors:
  - {{name: tracker, frame: tracker, model: point3d, noise: {{model: isotropic, sigma: 0.02}}}}
data:
  sensor: tracker
  target: reflector
  measurement: {{columns: [x, y, z], unit: mm}}
  prediction_columns: [pred_x, pred_y, pred_z]
modes:
  offsets:
    free: ["tracker.*", "lbr_iiwa_joint_[2-7]"]
simulation:
  truth: {{lbr_iiwa_joint_2: -0.34, lbr_iiwa_joint_3: 0.52, lbr_iiwa_joint_4: -0.27, lbr_iiwa_joint_5: 0.43,
          lbr_iiwa_joint_6: -0.61, lbr_iiwa_joint_7: 0.709,
          tracker.x: 2500, tracker.y: -1200, tracker.z: 400, tracker.yaw: 35.0, tracker.pitch: 0.3,
          tracker.roll: -0.2}}
  noise: {{point: 0.02}}
"""


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--urdf", type=Path, required=True)
    ap.add_argument("--configurations", type=int, default=60)
    args = ap.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "iiwa.yaml"
        path.write_text(PROFILE.format(urdf=args.urdf.resolve()))
        profile = load_profile(path)
        sim = SimulatedRobot.from_profile(profile, seed=3).simulate(args.configurations)
        cal = calibrate(profile, sim.data, "offsets", holdout=0.3, seed=1)
    held = {h.parameter: h.message for h in cal.identifiability.held_fixed}
    print(f"{args.configurations} configurations, 30% held out; held: {held or 'nothing'}")
    print("| parameter | estimate | sd | truth | (estimate - truth) / sd |")
    print("|---|---|---|---|---|")
    for e in cal.parameters:
        if not e.estimated and e.name not in held:
            continue
        i = profile.param(e.name)
        truth = profile.to_display(i, sim.true_params[i])
        z = "held" if not e.estimated else f"{(e.value - truth) / e.std:+.2f}"
        sd = "-" if not e.estimated or e.std is None else f"{e.std:.4g}"
        print(f"| {e.name} | {e.value:.4f} | {sd} | {truth:.4f} | {z} |")
    print(f"held-out RMS {cal.figures['holdout_after'].rms:.4f} mm")


if __name__ == "__main__":
    main()
