"""handeye's calibration library: pure functions over numpy arrays.

Imports nothing from ``drivers``, ``mocks`` or ``app``.
"""

from handeye.calib.errors import (
    CalibrationError,
    DegenerateMotionError,
    DepthError,
    ExtractionError,
    HandeyeError,
    InsufficientDataError,
    MarkerNotFoundError,
)
from handeye.calib.observation import Observation
from handeye.calib.problem import CalibrationProblem
from handeye.calib.setup import Setup, check_setup
from handeye.calib.result import CalibrationResult, Residuals
from handeye.calib.api import METHODS, MethodInfo, observations_to_arrays, solve, solve_observations

__all__ = [
    "CalibrationError",
    "CalibrationProblem",
    "CalibrationResult",
    "DegenerateMotionError",
    "DepthError",
    "ExtractionError",
    "HandeyeError",
    "InsufficientDataError",
    "METHODS",
    "MethodInfo",
    "MarkerNotFoundError",
    "Observation",
    "Residuals",
    "Setup",
    "check_setup",
    "observations_to_arrays",
    "solve",
    "solve_observations",
]
