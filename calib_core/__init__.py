"""calib_core: kinematic self-calibration of robots that see themselves, usable without the web app.

from calib_core import load_profile, read_dataset, calibrate, plan
profile = load_profile("robonaut-a")
data = read_dataset(profile, "day1.csv")
cal = calibrate(profile, data, "full", holdout=0.3)
print(cal.summary()); cal.save("full.json")
planned = plan(profile, "full", 32)      # the configurations to measure next, and their predicted accuracy

The subpackages, by concern: `model` (profiles, URDF import, kinematics), `sensors` (measurement
models), `vision` (detectors, renderers, and what a sensor sees where a model puts the targets:
`Visibility`), `estimation` (problem, solver, calibration, identifiability, validation, registration,
planning), `sim` (the simulated robot: truth, noise, rendering) and `io` (CSV formats, session folders,
bags, exports). The names below load their module on first use, so `import calib_core`
stays light (no SciPy or OpenCV until something needs them).
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from ._lazy import lazy_exports

__getattr__ = lazy_exports(
    __name__,
    {
        "dataset": ("Dataset", "merge"),
        "errors": ("InputError",),
        "estimation.calibrate": ("calibrate", "fit_parameters"),
        "estimation.calibration": ("Calibration",),
        "estimation.evaluation": ("Evaluation", "evaluate"),
        "estimation.planning": ("AccuracyPrediction", "Plan", "plan", "predict_accuracy"),
        "estimation.problem": ("Problem",),
        "estimation.registration": ("register",),
        "files": ("write_atomic",),
        "frame_status": ("FrameStatus",),
        "io.csv_format": ("parse_dataset", "read_dataset", "select_rows", "to_csv"),
        "model.loader": ("load_profile",),
        "model.profile": ("Profile",),
        "sensors": ("SENSOR_MODELS", "Sensor"),
        "sim.simulator": ("SimulatedRobot", "Simulation"),
        "vision.visibility": ("Visibility",),
    },
)
__all__ = [
    "SENSOR_MODELS",
    "AccuracyPrediction",
    "Calibration",
    "Dataset",
    "Evaluation",
    "FrameStatus",
    "InputError",
    "Plan",
    "Problem",
    "Profile",
    "Sensor",
    "SimulatedRobot",
    "Simulation",
    "Visibility",
    "calibrate",
    "evaluate",
    "fit_parameters",
    "load_profile",
    "merge",
    "parse_dataset",
    "plan",
    "predict_accuracy",
    "read_dataset",
    "register",
    "select_rows",
    "to_csv",
    "write_atomic",
]


if TYPE_CHECKING:
    from .dataset import Dataset, merge
    from .errors import InputError
    from .estimation.calibrate import calibrate, fit_parameters
    from .estimation.calibration import Calibration
    from .estimation.evaluation import Evaluation, evaluate
    from .estimation.planning import AccuracyPrediction, Plan, plan, predict_accuracy
    from .estimation.problem import Problem
    from .estimation.registration import register
    from .files import write_atomic
    from .frame_status import FrameStatus
    from .io.csv_format import parse_dataset, read_dataset, select_rows, to_csv
    from .model.loader import load_profile
    from .model.profile import Profile
    from .sensors import SENSOR_MODELS, Sensor
    from .sim.simulator import SimulatedRobot, Simulation
    from .vision.visibility import Visibility
