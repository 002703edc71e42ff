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

__all__ = [
    "SETUPS",
    "CalibrationError",
    "CalibrationResult",
    "DegenerateMotionError",
    "DepthError",
    "ExtractionError",
    "HandeyeError",
    "InsufficientDataError",
    "MarkerNotFoundError",
    "Observation",
    "Residuals",
]
