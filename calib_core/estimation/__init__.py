"""From observations to a calibration: the problem, the solver, identifiability, validation, the result."""
