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

from importlib import import_module
from typing import TYPE_CHECKING, Any

_EXPORTS = {
    "Calibration": "estimation.calibration",
    "Dataset": "dataset",
    "InputError": "errors",
    "Problem": "estimation.problem",
    "SENSOR_MODELS": "sensors",
    "Sensor": "sensors",
    "Profile": "model.profile",
    "SimulatedRobot": "sim.simulator",
    "Simulation": "sim.simulator",
    "Visibility": "vision.visibility",
    "Evaluation": "estimation.evaluation",
    "FrameStatus": "frame_status",
    "AccuracyPrediction": "estimation.planning",
    "Plan": "estimation.planning",
    "calibrate": "estimation.calibrate",
    "evaluate": "estimation.evaluation",
    "fit_parameters": "estimation.calibrate",
    "load_profile": "model.loader",
    "merge": "dataset",
    "parse_dataset": "io.csv_format",
    "plan": "estimation.planning",
    "predict_accuracy": "estimation.planning",
    "read_dataset": "io.csv_format",
    "register": "estimation.registration",
    "select_rows": "io.csv_format",
    "to_csv": "io.csv_format",
    "write_atomic": "files",
}
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


def __getattr__(name: str) -> Any:
    if name not in _EXPORTS:
        raise AttributeError(f"module 'calib_core' has no attribute {name!r}")
    value = getattr(import_module(f".{_EXPORTS[name]}", __name__), name)
    globals()[name] = value
    return value


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
