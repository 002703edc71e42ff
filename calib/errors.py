"""The root of handeye's exception tree and the errors of the calibration library.

Every layer defines its errors next to the code that raises them, all under
`HandeyeError`, so that the CLI can print one line and exit 1 for any of them
and let anything else surface as a bug:

- here (``calib``): `ParameterError`, `CalibrationError` (> `InsufficientDataError`,
  `DegenerateMotionError`), `ExtractionError` (> `MarkerNotFoundError`, `DepthError`);
- ``handeye.drivers.errors``: `DeviceError` (> `ConnectionLostError`, `RobotStoppedError`,
  `LimitViolationError`);
- ``handeye.app.errors``: `ConfigError` (a `ParameterError` of a config file), `SessionError`.
"""


class HandeyeError(Exception):
    """Base of every error handeye expects and reports to users."""


class ParameterError(HandeyeError, ValueError):
    """A parameter of a library, device or simulator object is invalid (the message names it)."""


class CalibrationError(HandeyeError, ValueError):
    """Input to a solver is malformed: bad shape, NaN/inf, not a rigid transform."""


class FilterDivergedError(CalibrationError):
    """A monitoring update whose increment is not finite: the sample is far outside what the linearised model holds
    (the engine keeps its state and skips it)."""


class InsufficientDataError(CalibrationError):
    """Too few samples for the chosen method."""


class DegenerateMotionError(CalibrationError):
    """The motions do not constrain every unknown (e.g. all rotations about one axis)."""


class ExtractionError(HandeyeError):
    """A frame could not be turned into a marker measurement (the frame is skipped)."""


class MarkerNotFoundError(ExtractionError):
    """No marker (or not the requested one) was detected in the image."""


class DepthError(ExtractionError):
    """Too few valid depth pixels on the marker, or the plane fit is bad."""
