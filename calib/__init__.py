"""handeye's calibration library: pure functions over numpy arrays.

Imports nothing from ``drivers``, ``mocks`` or ``app``.
"""

from calib.errors import (
    CalibrationError,
    DegenerateMotionError,
    DepthError,
    ExtractionError,
    HandeyeError,
    InsufficientDataError,
    MarkerNotFoundError,
)
from calib.observation import Observation
from calib.problem import CalibrationProblem
from calib.setup import Setup, check_setup
from calib.result import CalibrationResult, Residuals
from calib.api import METHODS, MethodInfo, observations_to_arrays, solve, solve_observations

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
