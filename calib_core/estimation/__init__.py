"""From observations to a calibration: the problem, the solver, identifiability, validation, the result.

The names below load their module on first use (calib_core/_lazy.py): SciPy only when one needs it. The
pipeline itself, `calibrate`, is calib_core's (a name here would be shadowed by its module)."""

from __future__ import annotations

from typing import TYPE_CHECKING

from .._lazy import lazy_exports

__getattr__ = lazy_exports(
    __name__,
    {
        "calibrate": ("METHODS", "check_can_fit", "fit_parameters"),
        "calibration": ("Calibration", "Covariance", "Outlier", "ParameterEstimate"),
        "change": ("frame_band",),
        "drift": (
            "DRIFT_LEVEL",
            "MOVED_SHOWN",
            "Drift",
            "Epoch",
            "Team",
            "Trend",
            "compare_epochs",
            "compare_team",
            "find_drift",
        ),
        "evaluation": ("Evaluation", "evaluate"),
        "flange_handeye": ("FlangeCalibration", "View", "calibrate_flange", "find_views"),
        "planning": (
            "AccuracyPrediction",
            "Around",
            "Plan",
            "PlanProgress",
            "SequentialPlan",
            "candidates",
            "plan",
            "predict_accuracy",
        ),
        "plan_seed": ("around_seed", "needs_seed", "seeded_model"),
        "problem": ("Problem", "local_points"),
        "registration": ("register", "registration_params"),
        "reports": (
            "Correlation",
            "Diagnostic",
            "DiagnosticGroup",
            "HeldParameter",
            "IdentifiabilityReport",
            "NoiseTest",
            "Severity",
            "SolverReport",
        ),
        "validation": ("Figures", "check_share", "figures"),
    },
)
__all__ = [
    "DRIFT_LEVEL",
    "METHODS",
    "MOVED_SHOWN",
    "AccuracyPrediction",
    "Around",
    "Calibration",
    "Correlation",
    "Covariance",
    "Diagnostic",
    "DiagnosticGroup",
    "Drift",
    "Epoch",
    "Evaluation",
    "Figures",
    "FlangeCalibration",
    "HeldParameter",
    "IdentifiabilityReport",
    "NoiseTest",
    "Outlier",
    "ParameterEstimate",
    "Plan",
    "PlanProgress",
    "Problem",
    "SequentialPlan",
    "Severity",
    "SolverReport",
    "Team",
    "Trend",
    "View",
    "around_seed",
    "calibrate_flange",
    "candidates",
    "check_can_fit",
    "check_share",
    "compare_epochs",
    "compare_team",
    "evaluate",
    "figures",
    "find_drift",
    "find_views",
    "fit_parameters",
    "frame_band",
    "local_points",
    "needs_seed",
    "plan",
    "predict_accuracy",
    "register",
    "registration_params",
    "seeded_model",
]

if TYPE_CHECKING:
    from .calibrate import METHODS, check_can_fit, fit_parameters
    from .calibration import Calibration, Covariance, Outlier, ParameterEstimate
    from .change import frame_band
    from .drift import (
        DRIFT_LEVEL,
        MOVED_SHOWN,
        Drift,
        Epoch,
        Team,
        Trend,
        compare_epochs,
        compare_team,
        find_drift,
    )
    from .evaluation import Evaluation, evaluate
    from .flange_handeye import FlangeCalibration, View, calibrate_flange, find_views
    from .plan_seed import around_seed, needs_seed, seeded_model
    from .planning import (
        AccuracyPrediction,
        Around,
        Plan,
        PlanProgress,
        SequentialPlan,
        candidates,
        plan,
        predict_accuracy,
    )
    from .problem import Problem, local_points
    from .registration import register, registration_params
    from .reports import (
        Correlation,
        Diagnostic,
        DiagnosticGroup,
        HeldParameter,
        IdentifiabilityReport,
        NoiseTest,
        Severity,
        SolverReport,
    )
    from .validation import Figures, check_share, figures
