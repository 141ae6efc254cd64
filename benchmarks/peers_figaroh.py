"""FIGAROH's side of benchmarks/peers.py: run in FIGAROH's own virtual environment (figaroh 1.0.2 with
Pinocchio), never in the desk's. Reads one job as JSON on stdin and writes JSON on stdout:

    {"urdf": ..., "tool": frame, "dof": [x, y, z, rx, ry, rz measured], "level": "joint_offset" | "full_params",
     "outlier_m": ..., "orient_weight": ..., "folds": [[train_csv, heldout_csv], ...]}
 -> {"folds": [{"parameters": [names], "predicted": [[x, y, z(, roll, pitch, yaw)] per held-out row]}]}

Each fold is FIGAROH's calibration as its examples run it: BaseCalibration with the base and tool frames
unknown (estimated, started at FIGAROH's closed-form guess), the structural choice of parameters,
Levenberg-Marquardt with its outlier exclusion, and the examples' cost: the SE(3) log-map residual,
position weighed 1 per m and orientation `orient_weight` per rad (UR10 example: 0.5).
"""

from __future__ import annotations

import contextlib
import io
import json
import logging
import sys
import tempfile
import warnings
from pathlib import Path

import numpy as np
import pinocchio as pin
import yaml
from figaroh.calibration.base_calibration import BaseCalibration
from figaroh.calibration.calibration_tools import calc_updated_fkm
from figaroh.tools.robot import load_robot


class ExampleCalibration(BaseCalibration):
    """BaseCalibration with the examples' cost function (UR10Calibration's, TALOS and TIAGo position only)."""

    orient_weight = 0.5

    def cost_function(self, var: np.ndarray) -> np.ndarray:
        estimated = calc_updated_fkm(self.model, self.data, var, self.q_measured, self.calib_config)
        residuals = self._compute_logmap_residuals(self.PEE_measured, estimated)
        return self.apply_measurement_weighting(residuals, pos_weight=1.0, orient_weight=self.orient_weight)


def write_config(path: Path, job: dict, train: str, heldout: str) -> None:
    """FIGAROH's unified configuration of one fold."""
    task = {
        "enabled": True,
        "parameters": {
            "calibration_level": job["level"],
            "include_non_geometric": False,
            "outlier_threshold": job["outlier_m"],
        },
        "kinematics": {"base_frame": "universe", "tool_frame": job["tool"]},
        "measurements": {"markers": [{"name": "marker", "measurable_dof": job["dof"]}]},
        "data": {"source_file": train, "validation_data_file": heldout},
    }
    doc = {"_metadata": {"schema_version": "2.0"}, "robot": {"name": "peer"}, "tasks": {"calibration": task}}
    path.write_text(yaml.safe_dump(doc))


def run_fold(robot, job: dict, train: str, heldout: str, folder: Path) -> dict:
    config = folder / "config.yaml"
    write_config(config, job, train, heldout)
    calib = ExampleCalibration(robot, str(config))
    calib.orient_weight = job["orient_weight"]
    calib.calib_config["known_baseframe"] = False
    calib.calib_config["known_tipframe"] = False
    with contextlib.redirect_stdout(io.StringIO()):  # FIGAROH prints its quality report
        calib.initialize()
        calib.solve(enable_logging=False, plotting=False)
    q = calib._q_val  # the held-out rows, as FIGAROH read them
    predicted = calc_updated_fkm(
        calib.model, calib.data, calib.LM_result.x, q, dict(calib.calib_config, NbSample=len(q))
    )
    return {
        "parameters": list(calib.calib_config["param_name"]),
        "predicted": predicted.reshape(sum(job["dof"]), len(q)).T.tolist(),
    }


def main() -> None:
    warnings.filterwarnings("ignore")
    logging.disable(logging.WARNING)
    job = json.load(sys.stdin)
    robot = load_robot(job["urdf"], load_by_urdf=True)
    with tempfile.TemporaryDirectory() as tmp:
        folds = [run_fold(robot, job, train, heldout, Path(tmp)) for train, heldout in job["folds"]]
    json.dump({"figaroh": _version(), "pinocchio": pin.__version__, "folds": folds}, sys.stdout)


def _version() -> str:
    from importlib.metadata import version

    return version("figaroh")


if __name__ == "__main__":
    main()
