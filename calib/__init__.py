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
from calib.observation import SETUPS, Observation
from calib.result import CalibrationResult, Residuals
from calib.api import METHODS, MethodInfo, observations_to_arrays, solve

__all__ = [
    "SETUPS",
    "CalibrationError",
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
    "observations_to_arrays",
    "solve",
]
