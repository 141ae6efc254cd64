"""calib_core: kinematic self-calibration of robots that see themselves, usable without the web app.

from calib_core import load_profile, read_dataset, calibrate
profile = load_profile("robonaut-a")
data = read_dataset(profile, "day1.csv")
cal = calibrate(profile, data, "full", holdout=0.3)
print(cal.summary()); cal.save("full.json")
"""

from .calibrate import calibrate, fit_parameters
from .calibration import Calibration, write_atomic
from .dataset import Dataset, parse_dataset, read_dataset, select_rows, to_csv
from .errors import InputError
from .problem import Problem
from .profile import Profile, load_profile
from .registration import register
from .self_observation import calibrate_sensors
from .simulator import SimulatedRobot, Simulation

__all__ = [
    "Calibration",
    "Dataset",
    "InputError",
    "Problem",
    "Profile",
    "SimulatedRobot",
    "Simulation",
    "calibrate",
    "calibrate_sensors",
    "fit_parameters",
    "load_profile",
    "parse_dataset",
    "read_dataset",
    "register",
    "select_rows",
    "to_csv",
    "write_atomic",
]
